"""The campaign executor: write-behind, the in-process and pooled map, stage timings."""

from __future__ import annotations

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
