import os

import pytest

from gonio.campaign.plot_worker import PlotWorker, warm_matplotlib


def _append(path, text):
    with open(path, "a") as f:
        f.write(text)


def _fail(message):
    raise ValueError(message)


def _numba_switch(path):
    _append(path, os.environ.get("GONIO_NO_NUMBA", "unset"))


def _pid_after(delay, path):
    import time

    t0 = time.monotonic()
    time.sleep(delay)
    _append(path, f"{os.getpid()} {t0} {time.monotonic()}\n")


def test_jobs_run_after_the_warm_up_each_in_a_fork(tmp_path):
    log = tmp_path / "log.txt"
    with PlotWorker(_append, (log, "warm;")) as w:
        for k in range(3):
            w.submit(_append, log, f"{k};")
            w.wait()
        assert log.read_text() == "warm;0;1;2;"
        w.submit(_numba_switch, log)  # models use their numpy paths in the worker
        w.wait()
        assert log.read_text().endswith("1")
        pids = tmp_path / "pids.txt"
        w.submit(_pid_after, pids, each=(0.3, 0.3, 0.3))  # one fork per entry, in parallel
        w.wait()
    rows = [line.split() for line in pids.read_text().splitlines()]
    assert len({r[0] for r in rows}) == 3
    starts, ends = [float(r[1]) for r in rows], [float(r[2]) for r in rows]
    assert max(starts) < min(ends)  # they slept side by side, not one after the other


def test_the_first_error_is_raised_and_the_worker_goes_on(tmp_path):
    log = tmp_path / "log.txt"
    with PlotWorker() as w:
        w.submit(_fail, "first")
        with pytest.raises(ValueError, match="first"):
            w.wait()
        w.submit(_fail, "second")
        w.submit(_append, log, "after")
        with pytest.raises(ValueError, match="second"):
            w.wait()
        w.submit(_append, log, "!")
        w.wait()
    assert log.read_text() == "after!"


def test_a_failed_warm_up_is_only_a_missed_head_start(tmp_path):
    log = tmp_path / "log.txt"
    with PlotWorker(_fail, ("warm-up",)) as w:
        w.submit(_append, log, "ok")
        w.wait()
    assert log.read_text() == "ok"


def test_a_job_or_a_worker_that_dies_is_reported(tmp_path):
    w = PlotWorker()
    try:
        w.submit(os._exit, 3)  # the job's fork ends without a result
        with pytest.raises(RuntimeError, match="exit code 3"):
            w.wait()
        w.submit(_pid_after, 5.0, tmp_path / "late.txt")
        w._proc.kill()  # the worker itself
        with pytest.raises(RuntimeError, match="ended unexpectedly"):
            w.wait()
    finally:
        w.close()


def test_warm_matplotlib_draws():
    warm_matplotlib()  # in this process: no error, and matplotlib's Agg canvas is loaded
    import sys

    assert "matplotlib.backends.backend_agg" in sys.modules


def test_the_worker_ignores_ctrl_c(tmp_path):
    """A Ctrl-C reaches the whole process group; the worker leaves it to its parent."""
    import signal
    import time

    log = tmp_path / "log.txt"
    with PlotWorker() as w:
        w.submit(_append, log, "a")
        w.wait()  # (the worker is past its start-up)
        os.kill(w._proc.pid, signal.SIGINT)
        time.sleep(0.1)
        assert w._proc.is_alive()
        w.submit(_append, log, "b")
        w.wait()
    assert log.read_text() == "ab"
