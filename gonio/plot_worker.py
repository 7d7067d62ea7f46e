"""One forked process that draws a campaign's plots while the campaign goes on.

Loading matplotlib and drawing a first figure (fonts, the Agg canvas, text layout) cost
~0.5 s of CPU once per process; a figure after that costs 0.1-0.2 s. A campaign that runs
its incidence angles in a process pool starts this worker first, before it traces the
pixel geometry and loads the compiled kernels in one thread (the one time the second core
is idle), so the worker is warm when the reduced samples arrive. All plots go to this one
process: one warm-up instead of one per pool worker.

The worker is a plain ``multiprocessing`` process with a pipe, not a pool: its parent keeps
no helper threads, so forking the campaign's pool afterwards stays safe. Jobs run in the
order sent; :meth:`PlotWorker.wait` returns when all are done and re-raises the first error.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

__all__ = ["PlotWorker", "warm_matplotlib"]


def warm_matplotlib() -> None:
    """Import matplotlib's Agg backend and draw one small figure with what the campaign's
    plots use (log axis, text, legend, colour bar, image, PNG encoding)."""
    import numpy as np

    from gonio.plots import _figure

    fig = _figure(2.0, 2.0)
    ax = fig.add_subplot(1, 2, 1)
    ax.plot([1.0, 2.0], [1.0, 10.0], "o-", label="θi = 0°")
    ax.set_yscale("log")
    ax.set_xlabel("θo (deg)")
    ax.set_title("warm-up")
    ax.legend(fontsize=7)
    im = fig.add_subplot(1, 2, 2).imshow(np.eye(3), cmap="magma")
    fig.colorbar(im, ax=fig.axes, label="log10 BRDF (sr⁻¹)")
    fig.savefig(io.BytesIO(), format="png")


def _serve(conn: Any, warm: Callable[..., None] | None, warm_args: tuple) -> None:
    """The worker's loop: warm up, then run ``(fn, args)`` jobs until ``None`` or EOF.

    BRDF models evaluate with their numpy paths here (``GONIO_NO_NUMBA``): a plot evaluates
    a model on ~10^5 directions (~10 ms), less than loading numba and the compiled kernels
    into this process would take (~0.3 s).
    """
    import os

    os.environ["GONIO_NO_NUMBA"] = "1"
    if warm is not None:
        try:
            warm(*warm_args)
        except Exception:  # only a head start: a real problem fails the jobs themselves
            pass
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        fn, args = job
        try:
            fn(*args)
            conn.send(None)
        except Exception as exc:
            try:
                conn.send(exc)
            except Exception:  # an exception that does not pickle
                conn.send(RuntimeError(f"{type(exc).__name__}: {exc}"))


class PlotWorker:
    """A forked worker process for plot jobs (see the module docstring).

    Parameters
    ----------
    warm : callable, optional
        Run first in the worker (e.g. :func:`warm_matplotlib`), while the parent goes on.
    warm_args : tuple
        Its arguments (inherited through ``fork``, not pickled).
    """

    def __init__(self, warm: Callable[..., None] | None = None, warm_args: tuple = ()) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve, args=(child, warm, warm_args), name="gonio-plots", daemon=True
        )
        self._proc.start()
        child.close()
        self._pending = 0

    def submit(self, fn: Callable[..., None], *args: Any) -> None:
        """Queue ``fn(*args)`` (both picklable; sending blocks until the worker takes it)."""
        self._conn.send((fn, args))
        self._pending += 1

    def wait(self) -> None:
        """Block until every job sent so far is done; re-raise the first job's error."""
        first: BaseException | None = None
        while self._pending:
            try:
                res = self._conn.recv()
            except EOFError:
                self._pending = 0
                raise RuntimeError(
                    f"the plot worker ended unexpectedly (exit code {self._proc.exitcode})"
                ) from None
            self._pending -= 1
            if res is not None and first is None:
                first = res
        if first is not None:
            raise first

    def close(self) -> None:
        """Stop the worker (after its current job); kill it if it does not stop in 5 s."""
        try:
            self._conn.send(None)
        except OSError:
            pass
        self._proc.join(5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()

    def __enter__(self) -> PlotWorker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
