"""Input validation shared by the whole package.

Every public function that takes user arrays or parameters funnels them through here so that
bad input raises :class:`ValueError` naming the argument, the value and what was expected
(``docs/architecture.md``, Conventions).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


def as_directions(w: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return ``w`` as a float64 array of shape ``(..., 3)`` with only finite entries.

    Raises
    ------
    ValueError
        If the last axis is not of length 3, or any entry is NaN or infinite.
    """
    try:
        a = np.asarray(w, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be an array of directions of shape (..., 3): {exc}"
        ) from None
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got shape {a.shape}")
    if not np.isfinite(a).all():
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN or inf)")
    return a


#: Largest accepted ``|‖w‖ − 1|`` of a direction given to a BRDF model. Directions built in
#: float64 from angles are unit to ~1e-16, float32 ones to ~1e-7; a vector farther off is
#: not a direction (a BRDF's value depends on the cosines, so 10 wi is not wi).
UNIT_TOLERANCE = 1e-6


def as_unit_directions(w: ArrayLike, name: str, tol: float = UNIT_TOLERANCE) -> NDArray[np.float64]:
    """:func:`as_directions`, and every vector of unit length within ``tol``.

    The one direction check of every BRDF model's public methods (evaluation, albedo,
    sampling, pdf, mirror part). Directions are not normalised silently: a non-unit vector
    is a caller's mistake (a ``wi`` scaled by 10 gave Ward 0.032 instead of 3.82 sr⁻¹).

    Raises
    ------
    ValueError
        As :func:`as_directions`, or naming how many vectors are not of unit length and the
        first one with its length.
    """
    a = as_directions(w, name)
    length = np.sqrt(np.einsum("...i,...i->...", a, a))
    bad = np.abs(length - 1.0) > tol
    if bad.any():
        idx = tuple(int(i[0]) for i in np.nonzero(np.atleast_1d(bad)))[: bad.ndim]
        first = f"{name}[{', '.join(map(str, idx))}]" if idx else name
        raise ValueError(
            f"{name} must hold unit vectors (| |w| - 1 | <= {tol:g}); "
            f"{int(np.count_nonzero(bad))} of {bad.size} are not, e.g. {first} = "
            f"{a[idx].tolist()} of length {float(length[idx]):.6g}"
        )
    return a


def as_finite_array(x: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return ``x`` as float64, raising ``ValueError`` if any entry is not finite."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains non-finite value(s) (NaN or inf)")
    return a


def check_scalar(
    value: Any,
    name: str,
    lower: float = -math.inf,
    upper: float = math.inf,
    *,
    lower_open: bool = False,
    upper_open: bool = False,
) -> float:
    """Return ``value`` as a finite float inside its bounds, else raise ``ValueError``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    lo_bad = v <= lower if lower_open else v < lower
    hi_bad = v >= upper if upper_open else v > upper
    if lo_bad or hi_bad:
        lb = "(" if lower_open else "["
        ub = ")" if upper_open else "]"
        raise ValueError(f"{name} = {v!r} is outside its allowed range {lb}{lower}, {upper}{ub}")
    return v


def check_choice(value: Any, name: str, choices) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` listing them."""
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; expected one of {sorted(map(str, choices))}")
    return value


#: Most worker processes a command starts: a small multiple of the CPU count (more only adds
#: memory and start-up time; each process holds its own copy of the instrument).
WORKERS_PER_CPU = 4


def max_workers() -> int:
    """The most worker processes any command starts (:data:`WORKERS_PER_CPU` per CPU)."""
    return WORKERS_PER_CPU * (os.cpu_count() or 1)


#: Most terms of a model sum (``"lambert + ward + ..."``): the papers' models have 1-3.
MAX_MODEL_TERMS = 8


def check_model_terms(text: str | None, option: str) -> None:
    """Refuse a model expression of more than :data:`MAX_MODEL_TERMS` terms."""
    if text is not None and (n := str(text).count("+") + 1) > MAX_MODEL_TERMS:
        raise ValueError(f"{option}: {n} terms, at most {MAX_MODEL_TERMS} in a model sum")
