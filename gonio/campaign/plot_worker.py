"""One forked process that draws a campaign's plots while the campaign goes on.

Loading matplotlib and drawing a first figure (fonts, the Agg canvas, text layout) cost
~0.5 s of CPU once per process; a figure after that costs 0.1-0.3 s. A campaign that runs
its incidence angles in a process pool starts this worker first, before it traces the
pixel geometry and loads the compiled kernels in one thread (the one time the second core
is idle), so the worker is warm when the reduced samples arrive.

Every job then runs in a fork of the warm worker (``os.fork``: a few ms, and the child is
as warm as its parent), so jobs sent together draw in parallel on the free cores: the
campaign's two plots of the fitted model take the time of the slower one, not of both.

The worker is a plain ``multiprocessing`` process with a pipe, not a pool: its parent keeps
no helper threads, so forking the campaign's pool afterwards stays safe. :meth:`PlotWorker.wait`
returns when every job sent so far is done and re-raises the first error.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Sequence
from typing import Any

from gonio.campaign.executor import die_with_parent

__all__ = ["PlotWorker", "warm_matplotlib"]


def warm_matplotlib() -> None:
    """Import matplotlib's Agg backend and draw one small figure with what the campaign's
    plots use (log axis with :func:`gonio.plots.log_axis`, text, legend, colour bar, image,
    PNG encoding)."""
    import numpy as np

    from gonio.plots.figures import _figure, log_axis

    fig = _figure(2.0, 2.0)
    ax = fig.add_subplot(1, 2, 1)
    ax.plot([1.0, 2.0], [1.0, 10.0], "o-", label="θi = 0°")
    log_axis(ax)
    ax.set_xlabel("θo (deg)")
    ax.set_title("warm-up")
    ax.legend(fontsize=7)
    im = fig.add_subplot(1, 2, 2).imshow(np.eye(3), cmap="magma")
    fig.colorbar(im, ax=fig.axes, label="log10 BRDF (sr⁻¹)")
    fig.savefig(io.BytesIO(), format="png")


def _run_child(fn: Callable[..., None], args: tuple, out: Any) -> None:
    """In a forked child: run the job, send ``None`` or the exception, end the process."""
    code = 0
    try:
        fn(*args)
        res: BaseException | None = None
    except BaseException as exc:  # (reported to the parent, not swallowed)
        res, code = exc, 1
    try:
        try:
            out.send(res)
        except Exception:  # an exception that does not pickle
            out.send(RuntimeError(f"{type(res).__name__}: {res}"))
    finally:
        os._exit(code)  # no exit handlers, no flush of buffers inherited from the parent


def _serve(conn: Any, warm: Callable[..., None] | None, warm_args: tuple, parent: int) -> None:
    """The worker's loop: warm up, then fork one child per job until ``None`` or EOF.

    A message ``(fn, args, each)`` starts one child per entry ``v`` of ``each`` running
    ``fn(v, *args)`` (``each=None``: one child running ``fn(*args)``); each child's result
    (``None`` or its exception) goes back to the parent as it ends. BRDF models evaluate
    with their numpy paths here (``GONIO_NO_NUMBA``): a plot evaluates a model on ~10^5
    directions (~10 ms), less than loading numba and the compiled kernels into this process
    would take (~0.3 s).
    """
    import signal
    from multiprocessing.connection import wait

    from gonio.campaign.executor import child_signals

    # the parent owns this process's lifetime (close(), or EOF when it dies): a Ctrl-C on
    # the terminal reaches the whole process group and would print a traceback from here
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    child_signals()  # not the campaign's SIGTERM handler
    die_with_parent(parent)
    me = os.getpid()
    os.environ["GONIO_NO_NUMBA"] = "1"
    if warm is not None:
        try:
            warm(*warm_args)
        except Exception:  # only a head start: a real problem fails the jobs themselves
            pass
    children: dict[Any, int] = {}  # result pipe -> pid
    open_ = True
    while open_ or children:
        for r in wait([conn, *children] if open_ else list(children)):
            if r is conn:
                try:
                    job = conn.recv()
                except (EOFError, OSError):
                    job = None
                if job is None:
                    open_ = False
                    continue
                _fork_jobs(job, conn, children, me)
                continue
            res = _reap(r, children.pop(r))
            if open_:
                try:
                    conn.send(res)
                except OSError:  # the parent went away: finish the children, then end
                    open_ = False


def _fork_jobs(job: tuple, conn: Any, children: dict[Any, int], me: int) -> None:
    """One child per call of the message ``job`` (``(fn, args, each)``), each with a pipe
    for its result, kept in ``children``."""
    from multiprocessing.connection import Pipe

    fn, args, each = job
    calls = [args] if each is None else [(v, *args) for v in each]
    for call in calls:
        rd, wr = Pipe(duplex=False)
        pid = os.fork()
        if pid == 0:  # pragma: no cover - runs in the child
            die_with_parent(me)
            for inherited in (rd, conn, *children):  # (EOF when the worker dies)
                inherited.close()
            _run_child(fn, call, wr)
        wr.close()
        children[rd] = pid


def _reap(r: Any, pid: int) -> BaseException | None:
    """A child's result (``None`` or its exception) from its pipe ``r``, the child reaped;
    a child that died without one is reported by its exit code."""
    try:
        res = r.recv()
    except (EOFError, OSError):
        res = None
    r.close()
    _, status = os.waitpid(pid, 0)
    if res is None and os.waitstatus_to_exitcode(status) != 0:
        res = RuntimeError(f"a plot job ended with exit code {os.waitstatus_to_exitcode(status)}")
    return res


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
            target=_serve,
            args=(child, warm, warm_args, os.getpid()),
            name="gonio-plots",
            daemon=True,
        )
        self._proc.start()
        child.close()
        self._pending = 0

    def submit(
        self, fn: Callable[..., None], *args: Any, each: Sequence[Any] | None = None
    ) -> None:
        """Run ``fn(*args)`` in a fork of the worker, or with ``each``, ``fn(v, *args)`` for
        every ``v`` in it, each in its own fork, in parallel (``args`` are sent once).

        ``fn`` and the arguments must pickle; sending blocks while the worker is still
        warming up.
        """
        n = 1 if each is None else len(each)
        if n == 0:
            return
        self._conn.send((fn, args, None if each is None else list(each)))
        self._pending += n

    def wait(self) -> None:
        """Block until every job sent so far is done; re-raise the first job's error."""
        first: BaseException | None = None
        while self._pending:
            try:
                res = self._conn.recv()
            except (EOFError, OSError):  # (a socket pipe: reset when the peer died)
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
        """Stop the worker (after its running jobs); kill it if it does not stop in 5 s."""
        import time

        try:
            self._conn.send(None)
        except OSError:
            pass
        # poll (waitpid) rather than join: join waits on a pipe that a job's fork also holds
        deadline = time.monotonic() + 5.0
        while self._proc.is_alive() and time.monotonic() < deadline:
            time.sleep(0.005)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()

    def __enter__(self) -> PlotWorker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
