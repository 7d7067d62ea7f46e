"""How a campaign runs: the one place for its concurrency, thread limits and stage timings.

Every campaign (LBL, Cornell, through the drivers) is a short pipeline of named stages —
prepare, capture and reduce, fit, report — that reads top to bottom; *how* those stages use
the machine lives here, not in the stages. A stage may be declared as a :class:`Job` (what it
needs, what it makes, what kind of work it is) and a campaign's jobs run by
:meth:`CampaignExecutor.pipeline`, which decides when each runs (see there):

* **BLAS on one thread** for the whole campaign (numpy's and scipy's OpenBLAS, restored on
  exit). Its processes already fill the cores, and an OpenBLAS thread spins for a while after
  each call: with the default two threads per process the default LBL campaign took 2.8 s
  and 4.3 s of CPU on a 2-core machine, with one 2.3 s and 2.9 s. One thread also makes every
  sum, so every result, the same in every process (:class:`~gonio.campaign.blas.SingleThreadBLAS`).
* **A forked worker pool** (:meth:`CampaignExecutor.map`): tasks run in processes forked from
  the campaign, which inherit its imported modules and the instrument with its cached
  geometry (``state``); with one worker they run in this process, in order. A later
  stage's job that needs only what the workers inherited may follow the tasks
  (``then``): a worker runs it while this process merges and fits (the budget's direction
  fields, 0.2 s, which depend on the calibration alone).
* **Write-behind** (:func:`write_behind`): raw frames are written on a background thread of
  whichever process captured them (OpenCV encodes without the GIL), so saving overlaps the
  next captures; a task's writes are finished before its result is reported.
* **Parallel jobs** (:meth:`CampaignExecutor.parallel`): a stage's independent pieces that
  are not incidence angles (the calibration captures, the ChArUco detection) on processes
  forked for them, after what they must inherit is made (:meth:`CampaignExecutor.inheriting`:
  the instrument warmed up); one that needs nothing the campaign's process is still making
  is begun earlier (:meth:`CampaignExecutor.start`: the lens's calibration, while this
  process warms the instrument up).
* **An I/O thread** (:meth:`CampaignExecutor.background`) for the writes that overlap the
  fit (the samples table, the flush of the raw frames to the disk).
* **A plot process** (:meth:`CampaignExecutor.plot`, :mod:`gonio.campaign.plot_worker`),
  forked first so that it loads matplotlib on the idle core while the campaign prepares.
* **Kernels compiled ahead** (:meth:`CampaignExecutor.compile_ahead`): on an empty numba
  cache (the first campaign after an install) the kernels a campaign will load are
  compiled in groups on forked processes at once, this process compiling one group, into
  numba's cache, from which every process then loads them.
* **Stage timings** (:meth:`CampaignExecutor.stage`): seconds per named stage (without the
  stages timed inside it), reported in the summary.
* **Child lifetime**: no process outlives its campaign. SIGTERM (``kill PID``,
  ``Popen.terminate()``, ``subprocess.run(timeout=...)``) is handled like Ctrl-C: it raises
  ``KeyboardInterrupt`` in the campaign, whose exit terminates the pool workers and the plot
  process. Every child also carries a parent-death guard (:func:`die_with_parent`) for a
  parent killed by SIGKILL, which runs no exit code: before it, after SIGTERM a plot worker
  and two pool workers were still alive ten minutes later, one blocked writing a pipe.
"""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from gonio.malloc import keep_freed

__all__ = [
    "CampaignExecutor",
    "Job",
    "check_workers_may_fork",
    "child_signals",
    "die_with_parent",
    "drain_writes",
    "forking",
    "worker_state",
    "write_behind",
]

#: What a pool process inherits from the campaign (fork), and what in-process tasks see.
_STATE: dict[str, Any] = {}

#: This process's write-behind thread (made on first use, so never before a fork).
_WRITER: dict[str, Any] = {}


def worker_state() -> dict[str, Any]:
    """The ``state`` given to :meth:`CampaignExecutor.map`, in a pool process or this one."""
    return _STATE


def write_behind(fn: Callable[..., None], *args: Any) -> None:
    """Run ``fn(*args)`` on this process's background writer thread (in submission order).

    :func:`drain_writes` waits for them and re-raises the first error; the executor drains a
    task's writes before it reports the task's result.
    """
    w = _WRITER.get("pool")
    if w is None:
        from concurrent.futures import ThreadPoolExecutor

        w = _WRITER["pool"] = ThreadPoolExecutor(1, thread_name_prefix="gonio-writer")
        _WRITER["futures"] = []
        _WRITER["busy"] = 0.0

    def timed() -> None:
        t = time.perf_counter()
        try:
            fn(*args)
        finally:
            _WRITER["busy"] += time.perf_counter() - t

    _WRITER["futures"].append(w.submit(timed))


def drain_writes() -> float:
    """Wait for every :func:`write_behind` job of this process; return the seconds the writer
    was busy, and stop its thread (the next :func:`write_behind` starts another)."""
    pool = _WRITER.get("pool")
    if pool is None:
        return 0.0
    try:
        for f in _WRITER["futures"]:
            f.result()
    finally:
        pool.shutdown(wait=True)  # every job has ended (and added its time) after this
        busy = _WRITER.pop("busy")
        del _WRITER["pool"], _WRITER["futures"]
    return busy + 0.0


def die_with_parent(parent: int) -> None:
    """Parent-death guard of a forked child: it gets SIGKILL when its parent ends.

    Linux's ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; then, for a parent that ended before the
    call, the child exits at once if it has already been re-parented.
    """
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - no libc prctl
            pass
    if os.getppid() != parent:
        os._exit(1)


@contextlib.contextmanager
def forking() -> Iterator[None]:
    """SIGTERM held back in this thread while it forks children (it is let in afterwards).

    A child inherits the campaign's SIGTERM handler; one killed before its start-up reset
    it raised that handler's ``KeyboardInterrupt`` and printed a traceback instead of ending
    (a job forked just before a ``kill PID``). Forked under this, the child starts with
    SIGTERM blocked, and :func:`child_signals` lets it in once the default action is set.
    """
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def child_signals() -> None:
    """In a child forked under :func:`forking`: SIGTERM's default action, then SIGTERM let
    in (one sent meanwhile ends the child now)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})


#: Modules the campaign's process loads while it waits for its children (the first
#: :meth:`CampaignExecutor.parallel` or :meth:`~CampaignExecutor.map`), not on its own time
#: later: scipy.optimize (~0.1 s), for the calibration's mirror fit and the campaign's fit.
PRELOAD = ("scipy.optimize",)


def _preload() -> None:
    import importlib

    for name in PRELOAD:
        if name not in sys.modules:
            importlib.import_module(name)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def _init_worker(state: dict[str, Any], parent: int | None = None) -> None:
    if parent is not None:  # a pool process: default SIGTERM, dies with the campaign
        child_signals()
        die_with_parent(parent)
        keep_freed()  # (its life is the campaign's)
    _STATE.clear()
    _STATE.update(state)


#: The jobs of :meth:`CampaignExecutor.parallel`, inherited by its forked processes.
_JOBS: list[Callable[[], Any]] = []


def _init_jobs(jobs: list[Callable[[], Any]], parent: int) -> None:
    child_signals()
    die_with_parent(parent)
    # a BLAS a job loads itself (OpenCV's, for a job forked before the campaign loaded it)
    # starts on one thread too; the ones loaded already are limited before the fork
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    keep_freed()  # (its life is the campaign's)
    _JOBS[:] = jobs


def _init_background(jobs: list[Callable[[], Any]], parent: int) -> None:
    _init_jobs(jobs, parent)
    with contextlib.suppress(OSError):
        os.nice(BACKGROUND_NICE)


#: The niceness of a job begun by :meth:`CampaignExecutor.start`: it takes the cores the
#: campaign's other processes leave idle, not a share of theirs.
BACKGROUND_NICE = 10


def _job(k: int) -> Any:
    return _JOBS[k]()


#: The key of :meth:`CampaignExecutor.map`'s ``then`` job in a pool process's state.
_THEN = "__then__"


def _then_task() -> Any:
    return _STATE[_THEN]()


def _in_numba_cache(fn: Callable) -> bool:
    """Whether numba's cache holds compiled code of ``fn`` for its current source (an index
    file of this numba version and the source file's stamp); True when that cannot be told
    (the kernel is then left to its first call)."""
    try:
        from numba.core.caching import FunctionCache

        return bool(FunctionCache(getattr(fn, "py_func", fn))._cache_file._load_index())
    except Exception:  # (numba's private layout changed, or no numba)
        return True


def _numba_contexts() -> None:
    """numba's typing and target contexts made (0.37 s of processor time, which a process
    pays at its first compile: paid once when made before the compiling processes fork)."""
    with contextlib.suppress(Exception):  # (no numba, or its private layout changed)
        from numba.core.registry import cpu_target

        cpu_target.typing_context.refresh()
        cpu_target.target_context.refresh()


def _compile(group: Sequence[tuple[Callable, Callable[[], Any]]]) -> None:
    for _, load in group:
        load()


def _pool_task(fn: Callable[..., Any], args: tuple) -> tuple[Any, float]:
    """A task in a pool process: its result once its writes are on their way to the disk."""
    try:
        res = fn(*args)
    finally:
        busy = drain_writes()
    return res, busy


@dataclass(frozen=True)
class Job:
    """One step of a campaign as its stage declares it: what it needs, what it makes, and
    what kind of work it is; :meth:`CampaignExecutor.pipeline` decides when and where it runs.

    Kinds (``kind``):

    ``"stage"``
        A step of the pipeline proper: ``fn(*needs)`` in the campaign's process, the stages
        one after the other in the order given.
    ``"plot"``
        A figure: ``fn(name, *needs)``, drawn (in the plot process when there is one) once
        its inputs exist.
    ``"write"``
        A write: ``fn(*needs)`` on the I/O thread once its inputs exist; it returns the
        seconds it took, kept as the timing ``name``.
    ``"side"``
        A job off the pipeline's path that needs only what the workers of the next
        :meth:`~CampaignExecutor.map` inherit (``fn(*needs)``, its inputs given before that
        map); its output is waited for when a stage needs it.

    Parameters
    ----------
    name : str
        The stage's or the write's timing name, or the plot's name.
    fn : callable
    needs : tuple of str
        The names of ``fn``'s arguments, in order: values given to
        :meth:`~CampaignExecutor.pipeline` or made by an earlier job.
    makes : tuple of str
        The names of what ``fn`` returns (one name: its result; more: its result's items).
    kind : {"stage", "plot", "write", "side"}
    heavy : bool
        A stage that keeps a core busy for a while (the calibrated instrument's budget).
    timed : bool
        Time the stage as ``timings[name]`` (not for a stage that times its own parts).
    """

    name: str
    fn: Callable[..., Any]
    needs: tuple[str, ...] = ()
    makes: tuple[str, ...] = ()
    kind: Literal["stage", "plot", "write", "side"] = "stage"
    heavy: bool = False
    timed: bool = False


#: A side job's output not yet waited for (:meth:`CampaignExecutor.pipeline`).
_PENDING = object()


class CampaignExecutor:
    """The machine side of a campaign: BLAS limit, worker pool, I/O thread, plot process.

    Parameters
    ----------
    workers : int
        Processes for :meth:`map` (1: tasks run in this process, in order; more need the
        ``fork`` start method).
    plots : bool
        Start a plot process (by default only with ``workers > 1``; otherwise :meth:`plot`
        draws here, which costs no process start for a short campaign).
    plot_process : bool, optional
        With ``plots``: whether the plots get their own process whatever ``workers`` (a
        one-process campaign whose figures take a second: the Cornell campaign's); never on
        a machine with one processor or in a daemonic process (a ``multiprocessing.Pool``'s
        or a Dask worker's, which may have no children). Default: with ``workers > 1``.

    Notes
    -----
    Use it as a context manager; leaving it (normally or by an exception) stops the pool,
    the I/O thread and the plot process and restores the BLAS thread limits.
    ``timings`` holds the seconds of every :meth:`stage`.
    """

    def __init__(
        self, workers: int = 1, *, plots: bool = False, plot_process: bool | None = None
    ) -> None:
        if not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers {workers!r}: expected a positive integer")
        check_workers_may_fork(workers)
        self.workers = workers
        own = workers > 1 if plot_process is None else plot_process and _may_fork_plots()
        self.want_plots = plots and own
        self.timings: dict[str, float] = {}
        self.write_busy_s = 0.0
        self.t_start = time.perf_counter()
        self._stack = contextlib.ExitStack()
        self._pool: Any = None
        self._then: Any = None
        self._plotter: Any = None
        self._io: Any = None
        self._failed = False
        self._blas_modules = -1
        self._inner: list[float] = []  # seconds of the stages timed inside the open ones
        self._inherit: tuple[Callable[[], Any], str] | None = None
        self._side: Callable[[], Any] | None = None
        self._mapped = False

    # ------------------------------------------------------------------ lifetime
    def __enter__(self) -> CampaignExecutor:
        from threadpoolctl import threadpool_limits

        stack = self._stack.__enter__()
        if threading.current_thread() is threading.main_thread():
            # SIGTERM like Ctrl-C: the exit below then stops the children
            previous = signal.signal(signal.SIGTERM, _interrupt)
            stack.callback(signal.signal, signal.SIGTERM, previous)
        # numpy's BLAS on one thread (the processes forked later inherit it; those loaded
        # later are limited before the first children fork: _limit_blas)
        stack.enter_context(threadpool_limits(limits=1, user_api="blas"))
        self._blas_modules = len(sys.modules)
        if self.want_plots:
            from gonio.campaign.plot_worker import PlotWorker, warm_matplotlib

            # forked first: it loads matplotlib while this process prepares the instrument
            with forking():
                self._plotter = PlotWorker(warm_matplotlib)
            stack.callback(self._plotter.close)
        stack.callback(self._close_pool, cancel=True)
        stack.callback(self._close_io)
        return self

    def __exit__(self, *exc: Any) -> bool | None:
        self._failed = exc[0] is not None
        return self._stack.__exit__(*exc)

    def _limit_blas(self) -> None:
        """Every OpenBLAS loaded since on one thread too, before children are forked (they
        inherit it; restored when the executor ends): scipy's (the fits, the mirror spots)
        and OpenCV's own (the lens calibration), which a campaign loads after the executor
        began. With two threads each, next to the campaign's other busy processes, their
        spinning threads took CPU from them (measured: a cv2.fisheye fit took 0.071 s of
        wall and 0.14 s of CPU, with one thread 0.079 s and 0.079 s)."""
        if len(sys.modules) != self._blas_modules:  # an import may have loaded one
            from threadpoolctl import threadpool_limits

            self._stack.enter_context(threadpool_limits(limits=1, user_api="blas"))
            self._blas_modules = len(sys.modules)

    # ------------------------------------------------------------------ timings
    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the enclosed block as ``timings[name]`` (seconds, added up if repeated),
        without the stages timed inside it (the calibration's without the warm-up)."""
        t = time.perf_counter()
        self._inner.append(0.0)
        try:
            yield
        finally:
            dt = time.perf_counter() - t
            inner = self._inner.pop()
            if self._inner:
                self._inner[-1] += dt
            self.timings[name] = self.timings.get(name, 0.0) + dt - inner

    def elapsed(self) -> float:
        """Seconds since the executor was made."""
        return time.perf_counter() - self.t_start

    # ------------------------------------------------------------------ kernels
    def compile_ahead(self, groups: Sequence[Sequence[tuple[Callable, Callable[[], Any]]]]) -> None:
        """On an empty numba cache, the kernels of ``groups`` compiled now, the groups in
        parallel: one here, the others on processes forked for them (up to
        :attr:`workers` at once), timed as stage ``"compile"``; the compiled code goes to
        numba's cache (``cache=True``), from which this process and its children load a
        kernel at its first call. A group is a list of ``(function, load)``: ``function``
        (plain Python, or numba's dispatcher of it) names the cache entry that tells whether
        the kernel was compiled before, ``load()`` compiles it (or loads it from the cache).

        Nothing happens with one worker, or when fewer than two groups have a kernel that is
        not in the cache: the kernels are then compiled, or loaded, at their first call as
        before. Groups should share no compiled callee (each would write its cache entry).
        """
        if self.workers == 1:
            return
        cold = [g for g in groups if not all(_in_numba_cache(fn) for fn, _ in g)]
        if len(cold) < 2:
            return
        jobs = [functools.partial(_compile, g) for g in cold[1:]]
        with self.stage("compile"):
            _numba_contexts()  # made once, here: the forked processes inherit them
            here = functools.partial(_compile, cold[0])
            self._forked(jobs, min(self.workers - 1, len(jobs)), here)

    # ------------------------------------------------------------------ pool
    def map(
        self,
        fn: Callable[..., Any],
        calls: Sequence[tuple],
        *,
        state: dict[str, Any],
        prepare: Callable[[], None] | None = None,
        then: Callable[[], Any] | None = None,
    ) -> Iterator[tuple[int, Any]]:
        """``fn(*calls[k])`` for every ``k``; yields ``(k, result)``.

        With one worker in this process, in order; with more, in a pool forked from this
        process (after ``prepare()``, e.g. tracing the geometry and loading the kernels once,
        so every worker inherits them), in completion order. ``fn`` reads ``state`` through
        :func:`worker_state`. The seconds the tasks' write-behind threads were busy add up
        in :attr:`write_busy_s`.

        ``then`` is a later stage's job (no arguments, inherited like ``state``), run by a
        worker once every task is done, while this process goes on to its next stages (its
        result: :meth:`then_result`). With one worker it runs here when its result is
        asked for.
        """
        if then is None:  # a pipeline's side job (sent before this map)
            then, self._side = self._side, None
        self._then = then
        self._mapped = True
        if self.workers == 1 or len(calls) <= 1:
            self._limit_blas()  # (the same sums as in a pool's processes)
            _init_worker(state)
            try:
                for k, args in enumerate(calls):
                    yield k, fn(*args)
            finally:  # finish what was captured, also on an error
                self.write_busy_s += drain_writes()
            return
        from concurrent.futures import as_completed

        pool = self._start_pool({**state, _THEN: then}, prepare)
        with forking():  # the pool's processes start at the first submit
            futs = {pool.submit(_pool_task, fn, args): k for k, args in enumerate(calls)}
        _preload()
        for f in as_completed(futs):
            res, busy = f.result()
            self.write_busy_s += busy
            yield futs[f], res
        if then is None:
            self._close_pool()
        else:
            self._then = pool.submit(_then_task)

    def then_result(self) -> Any:
        """The result of the last :meth:`map`'s ``then`` job, None if it had none (waited
        for). The pool, idle from then on, is closed by :meth:`wait_plots` (joining its
        processes took 0.04-0.06 s, which the campaign spends waiting for its plots anyway)
        or when the executor ends."""
        then, self._then = self._then, None
        if then is None:
            return None
        # one worker: here, now; else the pool's (an error stops the pool as the executor ends)
        return then() if callable(then) else then.result()

    def parallel(self, jobs: Sequence[Callable[[], Any]]) -> list[Any]:
        """``[job() for job in jobs]``, the jobs on up to :attr:`workers` processes forked
        for them (which inherit everything, so a job may be any closure; its result is
        pickled back); with one worker or one job, here, in order.

        For a stage's independent pieces that are not incidence angles, e.g. the
        calibration captures and the ChArUco detection of the board views
        (:func:`gonio.campaign.calibrate.laboratory_calibration`). A job's error is
        raised here (after the others are stopped).
        """
        jobs = list(jobs)
        self._prepare_inherited()
        if self.workers == 1 or len(jobs) <= 1:
            self._limit_blas()  # (the same sums as in forked processes)
            return [job() for job in jobs]
        return self._forked(jobs, min(self.workers, len(jobs)), _preload)

    def _forked(self, jobs: list[Callable[[], Any]], n: int, here: Callable[[], Any]) -> list:
        """``jobs`` on ``n`` processes forked for them while ``here()`` runs in this
        process; their results in order (an error: the others stopped, then raised)."""
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        self._limit_blas()
        pool = ProcessPoolExecutor(
            n, mp_context=mp.get_context("fork"), initializer=_init_jobs,
            initargs=(jobs, os.getpid()),
        )  # fmt: skip
        ok = False
        try:
            with forking():
                futures = [pool.submit(_job, k) for k in range(len(jobs))]
            here()
            out = [f.result() for f in futures]
            ok = True
            return out
        finally:
            _shutdown(pool, stop=not ok)  # a job failed or the campaign was interrupted

    @contextlib.contextmanager
    def inheriting(self, prepare: Callable[[], Any], name: str) -> Iterator[None]:
        """Within the block, the jobs of :meth:`parallel` need what ``prepare()`` makes in
        this process (e.g. the instrument's traced geometry and loaded kernels): it runs
        once, timed as stage ``name``, just before the first of them (which, forked, inherit
        it), and not at all if none runs. A job begun by :meth:`start` needs none of it and
        is not kept waiting: the lens's calibration runs while the instrument warms up."""
        self._inherit = (prepare, name)
        try:
            yield
        finally:
            self._inherit = None

    def _prepare_inherited(self) -> None:
        if self._inherit is not None:
            (prepare, name), self._inherit = self._inherit, None
            with self.stage(name):
                prepare()

    def start(self, job: Callable[[], Any]) -> Callable[[], Any]:
        """Begin ``job()`` now on a process forked for it (which inherits everything, as
        :meth:`parallel`'s jobs do); returns the function that waits for its result (and
        raises its error). With one worker the job runs here when its result is asked for.

        For a job that needs this process only as it is now, begun before work it need not
        wait for: the lens's calibration (board views and ``cv2.fisheye``, 0.35-0.4 s) on
        the core left idle while this process warms the instrument up for the calibration's
        other captures (the plot process has loaded matplotlib by then). A job still
        running when the executor ends (an error, an interrupt) is stopped.
        """
        if self.workers == 1:
            return job
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        self._limit_blas()
        pool = ProcessPoolExecutor(
            1, mp_context=mp.get_context("fork"), initializer=_init_background,
            initargs=([job], os.getpid()),
        )  # fmt: skip
        self._stack.callback(_shutdown, pool, stop=True)  # (a no-op once it has ended)
        with forking():
            future = pool.submit(_job, 0)

        def result() -> Any:
            try:
                return future.result()
            finally:
                _shutdown(pool, stop=not future.done())  # (interrupted while waiting)

        return result

    def _start_pool(self, state: dict[str, Any], prepare: Callable[[], None] | None) -> Any:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        if prepare is not None:
            prepare()
        self._limit_blas()
        # with the fork start method the initializer's arguments are inherited, not pickled
        self._pool = ProcessPoolExecutor(
            self.workers, mp_context=mp.get_context("fork"), initializer=_init_worker,
            initargs=(state, os.getpid()),
        )  # fmt: skip
        return self._pool

    def _close_pool(self, cancel: bool = False) -> None:
        if self._pool is not None:
            # interrupted or failed: do not wait for the tasks
            _shutdown(self._pool, stop=cancel and self._failed, cancel=cancel)
            self._pool = None

    # ------------------------------------------------------------------ pipeline
    def pipeline(self, jobs: Sequence[Job], **given: Any) -> dict[str, Any]:
        """Run a campaign's ``jobs`` (:class:`Job`) on the values ``given``; returns every
        value, given and made.

        The stages run here, one after the other, in the order given. Before each, every
        other job whose inputs exist is sent on, in the order given: a write to the I/O
        thread, a side job to the next :meth:`map`'s workers, a plot to :meth:`plot` —
        beside a ``heavy`` stage only the first of the plots, the rest after it (measured,
        two cores: with both of the fit's plots beside the calibrated instrument's budget,
        ~0.4 s of CPU, the budget took 0.59 s and its own plot was drawn alone after it;
        with one beside it and the other beside the budget's plot, each core does one after
        the other). After the last stage the rest is sent, then the writes are waited for
        (no stage waits for the disk; their seconds are timings) and the plots
        (``timings["plots"]``).

        A stage after the first :meth:`map` runs with every BLAS on one thread
        (:meth:`blas`: scipy's too, loaded by then, which the fits use); before it the
        limits of :meth:`_limit_blas` hold, which load nothing (so nothing more is loaded
        before the workers fork).
        """
        return _Pipeline(self, jobs, given).run()

    # ------------------------------------------------------------------ I/O thread
    def background(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run ``fn(*args)`` on the campaign's I/O thread; returns its future."""
        if self._io is None:
            from concurrent.futures import ThreadPoolExecutor

            self._io = ThreadPoolExecutor(1, thread_name_prefix="gonio-io")
        return self._io.submit(fn, *args)

    def _close_io(self) -> None:
        if self._io is not None:
            self._io.shutdown(wait=True)
            self._io = None

    @staticmethod
    def blas() -> Any:
        """A context with scipy's BLAS on one thread too (loaded after the executor began)."""
        from gonio.campaign.blas import SingleThreadBLAS

        return SingleThreadBLAS()

    # ------------------------------------------------------------------ plots
    def plot(self, fn: Callable[..., None], *args: Any, each: Iterable[Any]) -> None:
        """``fn(v, *args)`` for every ``v`` of ``each``: in the plot process (in parallel
        forks) if there is one, else here and now."""
        each = list(each)
        if self._plotter is not None:
            self._plotter.submit(fn, *args, each=each)
            return
        for v in each:
            fn(v, *args)

    def wait_plots(self) -> None:
        """Block until every plot sent so far is drawn; re-raise the first error. An idle
        pool left by :meth:`then_result` is closed meanwhile."""
        self._close_pool()
        if self._plotter is not None:
            self._plotter.wait()


class _Pipeline:
    """One run of :meth:`CampaignExecutor.pipeline`: the values so far, the jobs not yet
    sent, the writes' futures."""

    def __init__(self, ex: CampaignExecutor, jobs: Sequence[Job], given: dict[str, Any]):
        self.ex = ex
        self.jobs = list(jobs)
        self.values = dict(given)
        self.waiting = [j for j in self.jobs if j.kind != "stage"]
        self.writes: dict[str, Any] = {}

    def run(self) -> dict[str, Any]:
        ex = self.ex
        for job in (j for j in self.jobs if j.kind == "stage"):
            self.send(plots=1 if job.heavy else None)
            args = [self.value(n) for n in job.needs]
            with contextlib.ExitStack() as limits:
                if job.timed:
                    limits.enter_context(ex.stage(job.name))
                if ex._mapped:
                    limits.enter_context(ex.blas())
                _keep(self.values, job.makes, job.fn(*args))
        self.send(plots=None)
        for name, future in self.writes.items():
            ex.timings[name] = future.result()
        with ex.stage("plots"):
            ex.wait_plots()
        return self.values

    def send(self, *, plots: int | None) -> None:
        """Send the waiting jobs whose inputs exist (at most ``plots`` plots); consecutive
        plots of one function and inputs go as one batch (their inputs are sent once)."""
        batch: list[Job] = []
        for job in [j for j in self.waiting if all(n in self.values for n in j.needs)]:
            if job.kind == "plot" and plots is not None and plots <= 0:
                continue
            self.waiting.remove(job)
            if job.kind == "plot":
                if batch and (batch[0].fn, batch[0].needs) != (job.fn, job.needs):
                    self.draw(batch)
                    batch = []
                batch.append(job)
                plots = None if plots is None else plots - 1
                continue
            self.draw(batch)
            batch = []
            args = [self.value(n) for n in job.needs]
            if job.kind == "write":
                self.writes[job.name] = self.ex.background(job.fn, *args)
            else:  # side: the next map's workers run it after its tasks
                if self.ex._side is not None or len(job.makes) != 1:
                    raise ValueError(f"side job {job.name!r}: one at a time, making one value")
                self.ex._side = functools.partial(job.fn, *args)
                self.values[job.makes[0]] = _PENDING
        self.draw(batch)

    def draw(self, batch: list[Job]) -> None:
        if batch:
            args = [self.value(n) for n in batch[0].needs]
            self.ex.plot(batch[0].fn, *args, each=[j.name for j in batch])

    def value(self, name: str) -> Any:
        """A value; a side job's output waited for (run here if no map took it)."""
        if self.values[name] is _PENDING:
            side, self.ex._side = self.ex._side, None
            self.values[name] = side() if side is not None else self.ex.then_result()
        return self.values[name]


def _keep(values: dict[str, Any], makes: tuple[str, ...], out: Any) -> None:
    """A job's result kept under the names it makes."""
    if len(makes) == 1:
        values[makes[0]] = out
    elif makes:
        values.update(zip(makes, out, strict=True))


def _shutdown(pool: Any, *, stop: bool, cancel: bool | None = None) -> None:
    """Shut a process pool down; ``stop``: terminate its processes first (their tasks are
    not waited for). ``cancel``: drop its queued tasks (default: ``stop``)."""
    if stop:
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(OSError):
                proc.terminate()
    pool.shutdown(wait=True, cancel_futures=stop if cancel is None else cancel)


def _daemonic() -> bool:
    """Whether this process is daemonic (a ``multiprocessing.Pool``'s or a Dask worker's):
    it may not start processes ("daemonic processes are not allowed to have children")."""
    import multiprocessing as mp

    return bool(mp.current_process().daemon)


def check_workers_may_fork(workers: int) -> None:
    """Refuse ``workers > 1`` in a daemonic process (:func:`_daemonic`), naming the cause
    and the remedy, before anything is prepared."""
    if workers > 1 and _daemonic():
        raise ValueError(
            f"workers {workers}: this process is daemonic (a multiprocessing.Pool's "
            "or a Dask worker's) and may not start worker processes; use workers=1 "
            "or leave workers to its default"
        )


def _may_fork_plots() -> bool:
    """Whether a plot process of its own helps and may start here: more than one
    processor, and not in a daemonic process (which may not have children)."""
    return (os.cpu_count() or 1) > 1 and not _daemonic()


def default_workers(n_tasks: int, *, minimum_tasks: int = 8, most: int = 4) -> int:
    """Worker processes for ``n_tasks`` parallel tasks: the CPU count (at most ``most``) when
    there are at least ``minimum_tasks`` and ``fork`` exists, else 1 — also in a daemonic
    process (a ``multiprocessing.Pool``'s or a Dask worker's), which may not start
    processes (a campaign there with 8 angles or more stopped with "daemonic processes are
    not allowed to have children")."""
    import multiprocessing as mp

    if n_tasks < minimum_tasks or "fork" not in mp.get_all_start_methods() or _daemonic():
        return 1
    return max(1, min(os.cpu_count() or 1, most))
