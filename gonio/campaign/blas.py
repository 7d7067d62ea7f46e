"""Single-threaded BLAS for a whole call (numpy's and scipy's OpenBLAS, via threadpoolctl)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["SingleThreadBLAS", "single_thread_blas"]


def single_thread_blas(fn: F) -> F:
    """Decorator: run ``fn`` with numpy's and scipy's BLAS on one thread, the previous
    limits restored afterwards.

    An OpenBLAS thread spins for a while after each call; next to a single busy process it
    only burns the second core (Cornell campaign, measured: 1.31-1.37 s wall and 1.98-2.05 s
    of CPU with the default two threads, 1.26-1.29 s and 1.12-1.19 s with one). See
    :class:`SingleThreadBLAS` (scipy's own OpenBLAS is loaded first, so the limit reaches it).
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with SingleThreadBLAS():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


class SingleThreadBLAS:
    """Context manager: OpenBLAS (numpy's and scipy's) on one thread, restored afterwards.

    A sum computed by a multi-threaded BLAS rounds differently from a single-threaded one
    (measured: a campaign's χ²/dof differed in the 16th digit in-process, with 2 BLAS threads,
    and on a Dask worker, which runs BLAS on 1 thread). Every executor of ``gonio sweep``
    therefore runs tasks with single-threaded BLAS, so results are bit-identical wherever they
    run; :func:`single_thread_blas` wraps a whole call (the Cornell campaign). Uses
    ``threadpoolctl`` when installed, else the OpenBLAS libraries' own
    ``*openblas_set_num_threads*`` through :mod:`ctypes`; a no-op where neither is found.
    """

    _SUFFIXES = ("64_", "")
    _PREFIXES = ("scipy_openblas", "openblas")

    def __enter__(self) -> SingleThreadBLAS:
        self._restore: list[Callable[[], Any]] = []
        controller = self._controller()
        if controller is not None:
            lim = controller.limit(limits=1, user_api="blas")
            self._restore.append(lim.restore_original_limits)
            return self
        for get, set_ in self._openblas():
            n = int(get())
            if n != 1:
                set_(1)
                self._restore.append(lambda s=set_, n=n: s(n))
        return self

    def __exit__(self, *exc: Any) -> None:
        for undo in reversed(self._restore):
            undo()

    _CONTROLLER: Any = None
    _N_MODULES = -1

    @classmethod
    def _controller(cls) -> Any:
        """A ``threadpoolctl.ThreadpoolController`` made after scipy's OpenBLAS is loaded;
        ``None`` without threadpoolctl.

        Scanning the loaded libraries costs ~0.6 ms (a third of a no-op task), so the
        controller is kept, and made again only when modules were imported since: an import
        can load another OpenBLAS (a kept controller did not see one loaded later, and left
        it at its default thread count).
        """
        import sys

        if cls._CONTROLLER is None or cls._N_MODULES != len(sys.modules):
            try:
                from threadpoolctl import ThreadpoolController
            except ImportError:
                return None
            import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, used by the fits)

            cls._CONTROLLER = ThreadpoolController()
            cls._N_MODULES = len(sys.modules)
        return cls._CONTROLLER

    @classmethod
    def _openblas(cls) -> list[tuple[Any, Any]]:
        import ctypes

        import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, used by the fits)

        found = []
        try:
            with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
                paths = {ln.split()[-1] for ln in fh if "openblas" in ln.lower() and "/" in ln}
        except OSError:  # not Linux: nothing to do without threadpoolctl
            return found
        for path in sorted(paths):
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for pre in cls._PREFIXES:
                for suf in cls._SUFFIXES:
                    get = getattr(lib, f"{pre}_get_num_threads{suf}", None)
                    set_ = getattr(lib, f"{pre}_set_num_threads{suf}", None)
                    if get is not None and set_ is not None:
                        found.append((get, set_))
                        break
                else:
                    continue
                break
        return found
