"""The campaign executor: write-behind, the in-process and pooled map, stage timings."""

from __future__ import annotations

import os
import threading
import time

import pytest

from gonio.campaign import executor


def test_drain_waits_for_a_failing_write_and_still_counts_the_others():
    # a job that fails first while a later one is still running: the drain must wait for
    # both before it reads the writer's busy time (it read it first and a late job then
    # raised KeyError on the popped counter)
    started = threading.Event()

    def fails():
        raise OSError("disk full")

    def slow():
        started.set()
        time.sleep(0.05)

    executor.write_behind(slow)
    executor.write_behind(fails)
    started.wait(1.0)
    with pytest.raises(OSError, match="disk full"):
        executor.drain_writes()
    assert executor.drain_writes() == 0.0  # the writer is gone; a new one starts on demand
    executor.write_behind(slow)
    assert executor.drain_writes() >= 0.05


def _square(k):
    return k * k + executor.worker_state()["offset"]


def test_map_in_process_and_on_a_pool_give_the_same_results():
    square = _square
    calls = [(k,) for k in range(6)]
    with executor.CampaignExecutor(1) as ex:
        one = dict(ex.map(square, calls, state={"offset": 1}))
    with executor.CampaignExecutor(2) as ex:
        two = dict(ex.map(square, calls, state={"offset": 1}))
        with ex.stage("x"):
            pass
    assert one == two == {k: k * k + 1 for k in range(6)}
    assert set(ex.timings) == {"x"}


def _then():
    import os

    return executor.worker_state()["offset"], os.getpid()


def test_map_then_job_runs_after_the_tasks_here_or_on_a_worker():
    """A later stage's job queued behind the tasks: with one worker here when asked for,
    with a pool on a worker (which has the state), the pool closed after its result."""
    import os

    calls = [(k,) for k in range(4)]
    for workers in (1, 2):
        with executor.CampaignExecutor(workers) as ex:
            got = dict(ex.map(_square, calls, state={"offset": 2}, then=_then))
            offset, pid = ex.then_result()
            assert ex.then_result() is None  # taken
            ex.wait_plots()  # (the idle pool closed meanwhile)
            assert ex._pool is None
        assert got == {k: k * k + 2 for k in range(4)} and offset == 2
        assert (pid == os.getpid()) == (workers == 1)
    with executor.CampaignExecutor(2) as ex:
        dict(ex.map(_square, calls, state={"offset": 0}))
        assert ex.then_result() is None and ex._pool is None  # none queued


def test_workers_must_be_positive():
    with pytest.raises(ValueError, match="workers"):
        executor.CampaignExecutor(0)


def test_parallel_runs_closures_on_forked_processes_in_order():
    import os

    big = list(range(1000))  # inherited by the forked processes, not pickled
    jobs = [lambda k=k: (k, sum(big) + k, os.getpid()) for k in range(5)]
    with executor.CampaignExecutor(1) as ex:
        here = ex.parallel(jobs)
    with executor.CampaignExecutor(2) as ex:
        there = ex.parallel(jobs)
    assert [r[:2] for r in here] == [r[:2] for r in there] == [(k, 499500 + k) for k in range(5)]
    assert {r[2] for r in here} == {os.getpid()}
    assert os.getpid() not in {r[2] for r in there}


def test_parallel_raises_a_jobs_error_and_leaves_no_process():
    import multiprocessing as mp

    def bad():
        raise ValueError("job failed")

    with executor.CampaignExecutor(2) as ex:
        with pytest.raises(ValueError, match="job failed"):
            ex.parallel([lambda: 1, bad, lambda: time.sleep(30)])
    assert mp.active_children() == []


def test_start_runs_a_job_meanwhile_on_a_low_priority_process_or_later_here():
    calls = []
    big = list(range(1000))  # inherited, not pickled

    def job():
        calls.append(1)
        return sum(big), os.getpid(), os.nice(0), os.environ.get("OPENBLAS_NUM_THREADS")

    with executor.CampaignExecutor(1) as ex:
        later = ex.start(job)
        assert calls == []  # one worker: the job runs when its result is asked for
        assert later()[:2] == (499500, os.getpid())
    with executor.CampaignExecutor(2) as ex:
        there = ex.start(job)
        total, pid, nice, blas = there()
    assert total == 499500 and pid != os.getpid()
    assert nice == os.nice(0) + executor.BACKGROUND_NICE and blas == "1"


def test_start_raises_the_jobs_error_and_a_job_left_running_is_stopped():
    import multiprocessing as mp

    def bad():
        raise ValueError("job failed")

    with executor.CampaignExecutor(2) as ex:
        with pytest.raises(ValueError, match="job failed"):
            ex.start(bad)()
    assert mp.active_children() == []
    t = time.perf_counter()
    with pytest.raises(RuntimeError, match="the campaign failed"):
        with executor.CampaignExecutor(2) as ex:
            ex.start(lambda: time.sleep(30))
            raise RuntimeError("the campaign failed")
    assert mp.active_children() == [] and time.perf_counter() - t < 10


def _slow_start_then_default_sigterm():
    time.sleep(0.3)  # SIGTERM arrives here, before the start-up below
    executor.child_signals()
    time.sleep(30)


def test_a_child_forked_under_the_guard_ends_on_an_early_sigterm(capfd):
    """A child killed before its start-up has reset the campaign's SIGTERM handler: forked
    under :func:`executor.forking` it ends by the signal (exit -15), where without the guard
    it ran the inherited handler (KeyboardInterrupt, a traceback, exit 1)."""
    import multiprocessing as mp
    import signal

    def handler(signum, frame):
        raise KeyboardInterrupt("signal SIGTERM")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        for guarded in (True, False):
            proc = mp.get_context("fork").Process(target=_slow_start_then_default_sigterm)
            if guarded:
                with executor.forking():
                    proc.start()
            else:
                proc.start()
            time.sleep(0.05)
            proc.terminate()
            proc.join(10)
            assert proc.exitcode == (-signal.SIGTERM if guarded else 1), guarded
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert "KeyboardInterrupt" in capfd.readouterr().err  # (the unguarded child's traceback)


_BLAS_PROBE = """
import json, sys
from threadpoolctl import threadpool_info
from gonio.campaign.executor import CampaignExecutor

def blas():
    return sorted((d["filepath"].rsplit("/", 1)[-1], d["num_threads"])
                  for d in threadpool_info() if d["user_api"] == "blas")

def job():
    import cv2, numpy as np
    cv2.SVDecomp(np.eye(8))
    return blas()

assert "cv2" not in sys.modules and "scipy.linalg" not in sys.modules
with CampaignExecutor(int(sys.argv[1])) as ex:  # (one worker: the jobs run here)
    import cv2, scipy.linalg  # as a campaign loads them, after the executor began
    jobs = ex.parallel([job, job])
    here = blas()  # from its first children on
print(json.dumps({"here": here, "jobs": jobs, "after": blas()}))
"""


@pytest.mark.parametrize("workers", [2, 1])
def test_every_blas_is_on_one_thread_in_the_campaign_and_its_children_and_restored_after(
    workers,
):
    # numpy's, scipy's and OpenCV's OpenBLAS, also those a campaign loads after its
    # executor began (a fresh process): with two threads each next to the campaign's other
    # busy processes they spun on the cores those need (the lens job's system time); with
    # one worker, in the campaign's own process (there they ran on two threads, and the
    # same campaign with --workers 1 differed from the pooled one in the 11th digit)
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _BLAS_PROBE, str(workers)],
                         capture_output=True, text=True, timeout=120, check=True)  # fmt: skip
    got = json.loads(out.stdout.splitlines()[-1])
    libs = {name.split("-")[0] for name, _ in got["here"]}
    assert {"libscipy_openblas", "libscipy_openblas64_"} <= libs  # scipy's and numpy's
    assert all(n == 1 for _, n in got["here"])
    assert all(j == got["here"] for j in got["jobs"])
    if (os.cpu_count() or 1) > 1:  # the default thread count, restored
        assert all(n > 1 for _, n in got["after"])


def _pid_and(value):
    return value, os.getpid()


def _pipeline_jobs(log):
    Job = executor.Job

    def stage(name, value):
        log.append(name)
        return value

    def mapped(ex):
        return sorted(v for _, v in ex.map(_square, [(1,), (2,)], state={"offset": 0}))

    def plot(name, _):
        log.append(name)

    return [
        Job("a", lambda: stage("a", 3), (), ("x",)),
        Job("side", _pid_and, ("given",), ("pid",), kind="side"),
        Job("map", mapped, ("ex",), ("squares",)),
        Job("p1", plot, ("squares",), kind="plot"),
        Job("w", lambda x: stage("w", 0.25), ("x",), kind="write"),
        Job("p2", plot, ("squares",), kind="plot"),
        Job("heavy", lambda x: stage("heavy", x + 1), ("x",), ("y",), heavy=True, timed=True),
        Job("p3", plot, ("y",), kind="plot"),
        Job("b", lambda pid, y: stage("b", (pid, y)), ("pid", "y"), ("z",)),
    ]


def test_pipeline_sends_plots_writes_and_a_side_job_once_their_inputs_exist():
    """Stages run in order; a write and plots are sent once their inputs exist (beside a
    heavy stage only the first plot, the rest after it); the side job runs behind the
    map's tasks (on a worker with a pool, here when needed with one worker)."""
    for workers in (1, 2):
        log = []
        with executor.CampaignExecutor(workers) as ex:  # (no plot process: drawn here)
            got = ex.pipeline(_pipeline_jobs(log), ex=ex, given=7)
        (value, pid), y = got["z"]
        assert got["squares"] == [1, 4] and value == 7 and y == 4
        assert (pid == os.getpid()) == (workers == 1)
        assert ex.timings["w"] == 0.25 and {"heavy", "plots"} <= set(ex.timings)
        assert log.index("a") < log.index("p1") < log.index("heavy") < log.index("p2")
        assert log.index("heavy") < log.index("p3") and "w" in log


_MARK: list[int] = []


def _marks():
    return len(_MARK)


def test_inheriting_prepares_before_the_parallel_jobs_not_before_a_started_one():
    """The preparation runs once, before the first parallel jobs (forked: they inherit it),
    after a job begun by start (which does not); its time is not the enclosing stage's."""

    def prepare():
        time.sleep(0.05)
        _MARK.append(1)

    for workers in (1, 2):
        _MARK.clear()
        with executor.CampaignExecutor(workers) as ex:
            t = time.perf_counter()
            with ex.stage("outer"), ex.inheriting(prepare, "prep"):
                started = ex.start(_marks)
                assert _MARK == []
                got = ex.parallel([_marks, _marks])
                again = ex.parallel([_marks])
            wall = time.perf_counter() - t
            lens = started()
        assert got == [1, 1] and again == [1] and _MARK == [1]
        assert lens == (1 if workers == 1 else 0)  # one worker: run here, when asked for
        assert ex.timings["prep"] >= 0.05 and ex.timings["outer"] + ex.timings["prep"] <= wall


def test_compile_ahead_compiles_the_cold_groups_here_and_on_a_forked_process(tmp_path, monkeypatch):
    def group(name):
        def load():
            (tmp_path / f"{name}.{os.getpid()}").touch()

        return [(load, load)]

    def loaded():
        return sorted(p.name for p in tmp_path.iterdir())

    cold = {"a", "b"}
    monkeypatch.setattr(executor, "_in_numba_cache", lambda fn: fn.__name__ not in cold)

    def groups():
        a, b = group("a"), group("b")
        a[0][0].__name__, b[0][0].__name__ = "a", "b"
        return [a, b]

    with executor.CampaignExecutor(2) as ex:
        ex.compile_ahead(groups())
    got = loaded()
    assert [n.split(".")[0] for n in got] == ["a", "b"]
    assert got[0] == f"a.{os.getpid()}" and got[1] != f"b.{os.getpid()}"  # b: a child's
    assert "compile" in ex.timings
    for p in tmp_path.iterdir():
        p.unlink()
    cold = {"a"}  # one cold group: left to the kernels' first calls
    with executor.CampaignExecutor(2) as ex:
        ex.compile_ahead(groups())
    cold = {"a", "b"}
    with executor.CampaignExecutor(1) as ex:  # one worker: nothing ahead
        ex.compile_ahead(groups())
    assert loaded() == [] and "compile" not in ex.timings


def test_a_numba_cache_entry_is_found_by_its_function(tmp_path, monkeypatch):
    numba = pytest.importorskip("numba")
    if numba.config.CACHE_DIR:
        pytest.skip("numba's cache is in NUMBA_CACHE_DIR")  # (the entry goes next to the file)
    src = tmp_path / "kern_mod.py"
    src.write_text("def twice(x):\n    return 2 * x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import kern_mod

    assert not executor._in_numba_cache(kern_mod.twice)
    k = numba.njit(cache=True)(kern_mod.twice)
    k.compile((numba.types.float64,))
    assert executor._in_numba_cache(k) and executor._in_numba_cache(kern_mod.twice)


def _write_pid(name, folder):
    (folder / f"{name}.pid").write_text(str(os.getpid()))


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="a plot process needs two processors")
def test_a_one_worker_executor_draws_in_a_plot_process_only_when_asked(tmp_path):
    """plot_process=True gives a one-worker campaign (the Cornell one) its plot process:
    the plots are drawn in other processes, waited for by wait_plots; by default one worker
    draws here."""
    for own in (True, None):
        folder = tmp_path / str(own)
        folder.mkdir()
        with executor.CampaignExecutor(1, plots=True, plot_process=own) as ex:
            ex.plot(_write_pid, folder, each=["a", "b"])
            ex.wait_plots()
            pids = {int((folder / f"{n}.pid").read_text()) for n in ("a", "b")}
        if own:
            assert os.getpid() not in pids and len(pids) == 2  # two forks of the plot process
        else:
            assert pids == {os.getpid()}


def _one_worker_plots_here(folder):
    with executor.CampaignExecutor(1, plots=True, plot_process=True) as ex:
        ex.plot(_write_pid, folder, each=["d"])
        ex.wait_plots()
    return int((folder / "d.pid").read_text()) == os.getpid()


def test_no_plot_process_in_a_daemonic_process(tmp_path):
    """A daemonic process (a multiprocessing.Pool's worker) may have no children: the
    one-worker campaign's plots are drawn there, not refused."""
    import multiprocessing as mp

    with mp.get_context("fork").Pool(1) as pool:
        assert pool.apply(_one_worker_plots_here, (tmp_path,)) is True


def _default_workers_here():
    return executor.default_workers(21)


def test_default_workers_is_one_in_a_daemonic_process():
    """A daemonic process may not start processes: a campaign of 21 angles run there (a
    multiprocessing.Pool's or a Dask worker's) gets one worker, not a crash."""
    import multiprocessing as mp

    with mp.get_context("fork").Pool(1) as pool:
        assert pool.apply(_default_workers_here) == 1
    assert executor.default_workers(21) == min(os.cpu_count() or 1, 4)
