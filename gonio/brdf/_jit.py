"""Lazy numba compilation of the BRDF kernels.

Kernels are written as plain-Python functions; they are compiled on first use (importing
:mod:`gonio.brdf` does not import numba) with ``numba.njit(cache=True, fastmath=False,
nogil=True)``. With numba missing or the environment variable ``GONIO_NO_NUMBA`` set, no kernel
is compiled and the models use their numpy paths.

A kernel is one function, even past 80 lines: numba refuses a call to a plain-Python helper
("Untyped global name"), so every piece split off a kernel would have to be compiled first and
bound into the kernel's globals, outside this one lazy step; and the split costs time. The
Li-Torrance kernel split into three compiled helpers (the directional roughness, the
directional-diffuse term, the subsurface terms) gave bit-identical values but took 1.04-1.50
times as long (median of 7 interleaved runs each, 200 000 direction pairs, 31 bands, three
Cornell presets with and without the specular box, measured side by side in one process).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["interpreted", "is_interpreted", "lazy_kernel", "njit_or_none"]

#: depth of :func:`interpreted` blocks now open
_INTERPRETED = [0]


@contextlib.contextmanager
def interpreted() -> Iterator[None]:
    """Within this block the models take their numpy paths and no kernel is compiled or
    loaded (nothing is cached: the kernels come back after it). For a few evaluations
    whose numba import would cost more than the work: a campaign's check of its plan
    before capture (10 ms of numpy against 0.4 s of importing numba on the serial path,
    where the instrument's warm-up imports it later beside the lens's calibration)."""
    _INTERPRETED[0] += 1
    try:
        yield
    finally:
        _INTERPRETED[0] -= 1


def is_interpreted() -> bool:
    """Whether an :func:`interpreted` block is open."""
    return _INTERPRETED[0] > 0


def njit_or_none(fn: Callable, signatures: Callable[[Any], list] | None = None) -> Any:
    """``fn`` compiled by numba, or ``None`` (numba missing or ``GONIO_NO_NUMBA`` set).

    ``signatures(numba.types)``, if given, lists the only argument types ``fn`` takes: they
    are compiled (or loaded from the cache) now, and a call with other types raises
    ``TypeError`` instead of compiling another specialisation (each cost 0.23-0.26 s of
    processor time on an empty cache: the Ward kernel was compiled for four array layouts
    in one campaign).
    """
    if os.environ.get("GONIO_NO_NUMBA"):
        return None
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a declared dependency
        return None
    jit = numba.njit(cache=True, fastmath=False, nogil=True)
    if signatures is not None:
        jit = numba.njit(signatures(numba.types), cache=True, fastmath=False, nogil=True)
    return jit(fn)


def lazy_kernel(fn: Callable) -> Callable[[], Any]:
    """A function returning :func:`njit_or_none` of ``fn``, decided on its first call."""
    compiled: list[Any] = []

    def get() -> Any:
        if _INTERPRETED[0]:
            return None
        if not compiled:
            compiled.append(njit_or_none(fn))
        return compiled[0]

    get.__doc__ = f"The compiled ``{fn.__name__}``, or ``None`` (see :func:`njit_or_none`)."
    return get
