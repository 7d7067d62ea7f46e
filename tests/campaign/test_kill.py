"""SIGKILL at points across a whole campaign, then ``--resume`` (issue 15): the result is
byte-identical to an uninterrupted run, no ``.tmp`` is left and no process outlives its parent.

Each run is killed several times in a row (every resume is killed again later), so one
campaign covers several kill points: for LBL once after every capture group but the last (some
groups written, the rest being written by the pool), then in the fit (``samples.csv`` on
disk); for Cornell once in the measurement (at a random time) and once in the fit. The slow
sweep kills one Cornell campaign at three more random times.

One killed-and-resumed run carries all its kill points and is compared once with the shared
uninterrupted run: the sweep was three seeds, each a killed run of its own that was also
killed in the fit, the same point every time (each launch of the campaign costs the
process's start-up, 1-2 s); it now visits every LBL group boundary, not two drawn at random.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

psutil = pytest.importorskip("psutil")

#: every test here runs several campaigns: started first in a parallel run
pytestmark = pytest.mark.early

_MAIN = "import sys; from gonio.cli import main; sys.exit(main(sys.argv[1:]))"
LBL = ["--angles", "20,60", "--rotations", "0,90", "--workers", "2"]
N_GROUPS_LBL = 6  # 2 x (standard+background) + 2 x 2 rotations
PLAN = "theta_i,phi_i,theta_o,phi_o\n" + "".join(
    f"{ti},0,{to},{po}\n" for ti in (10, 40, 70) for to, po in ((10, 180), (35, 180), (20, 90),
                                                                 (50, 135))
)  # fmt: skip


def _cmd(args: list[str], out: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-P",
        "-c",
        _MAIN,
        "campaign",
        *args,
        "--out",
        str(out),
        "--quiet",
        *extra,
    ]


def _done_groups(out: Path) -> int:
    return len(list(out.glob("raw/*/done.json")))


def _kill_when(args: list[str], out: Path, when, timeout: float = 120.0) -> bool:
    """Start the campaign (resuming), SIGKILL it once ``when(out, t)`` holds; True if killed
    (False: it finished first). Asserts that no child outlives it and no .tmp is left."""
    p = subprocess.Popen(_cmd(args, out, "--resume"), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)  # fmt: skip
    t0 = time.monotonic()
    proc = psutil.Process(p.pid)
    children: list = []
    look = 0.0  # (listing the children reads all of /proc: every 50 ms, not every 2 ms)
    try:
        while p.poll() is None and not when(out, time.monotonic() - t0):
            if time.monotonic() >= look:
                try:
                    children = proc.children(recursive=True) or children
                except psutil.Error:
                    pass
                look = time.monotonic() + 0.05
            assert time.monotonic() - t0 < timeout, "campaign did not reach its kill point"
            time.sleep(0.002)
        if p.poll() is not None:
            assert p.returncode in (0, 1), p.stderr.read().decode()
            return False
        children = proc.children(recursive=True) or children
        p.send_signal(signal.SIGKILL)
        p.wait()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        p.stderr.close()
    _gone, alive = psutil.wait_procs(children, timeout=10)
    for c in alive:  # (a failing test leaves nothing running either)
        with contextlib.suppress(psutil.Error):
            c.kill()
    assert not alive, f"processes left behind: {alive}"
    return True


#: JSON fields that are wall-clock times (the one thing a resumed run may change)
_TIMES = ("timings_s", "time_s")


def _files(out: Path) -> dict[str, bytes]:
    got = {}
    for f in sorted(out.rglob("*")):
        rel = f.relative_to(out).as_posix()
        if f.is_file() and rel != ".lock":
            got[rel] = f.read_bytes()
    for name in ("summary.json", "fit.json"):
        if name in got:
            doc = json.loads(got[name])
            for k in _TIMES:
                doc.pop(k, None)
            doc.get("n_captures", {}).pop("resumed_groups", None)
            got[name] = json.dumps(doc, sort_keys=True).encode()
    return got


def _check_same(ref: Path, out: Path) -> None:
    assert not list(out.rglob("*.tmp"))
    a, b = _files(ref), _files(out)
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k] == b[k], f"{k} differs from the uninterrupted run's"


@pytest.fixture(scope="module")
def lbl_ref(made_once) -> Path:
    """The uninterrupted LBL run, made once for every test of this module that compares a
    killed and resumed run with it (the same command and seeds: the same bytes), in whichever
    test process asks first."""

    def make(folder: Path) -> None:
        subprocess.run(_cmd(LBL, folder / "ref"), check=True, capture_output=True)

    return made_once("kill-lbl", make)[0] / "ref"


@pytest.fixture(scope="module")
def cornell_ref(made_once) -> tuple[list[str], Path, float]:
    """The Cornell campaign's arguments (its plan file, which every run of the module reads:
    the samples' header names its path), its uninterrupted run (made once, as
    :func:`lbl_ref`) and that run's wall time."""

    def make(folder: Path) -> float:
        (folder / "plan.csv").write_text(PLAN)
        t0 = time.monotonic()
        subprocess.run(_cmd(_cornell_args(folder), folder / "ref"), check=True,
                       capture_output=True)  # fmt: skip
        t_ref = time.monotonic() - t0
        # plan.json names the plan file's path: the same plan, another folder
        (folder / "ref" / "plan.json").unlink()
        return t_ref

    folder, t_ref = made_once("kill-cornell", make)
    return _cornell_args(folder), folder / "ref", t_ref


def _cornell_args(folder: Path) -> list[str]:
    return ["--instrument", "cornell", "--plan", str(folder / "plan.csv")]


def _lbl(ref: Path, tmp_path: Path, points: list) -> None:
    out = tmp_path / "killed"
    killed = [_kill_when(LBL, out, w) for w in points]
    assert all(killed)
    subprocess.run(_cmd(LBL, out, "--resume"), check=True, capture_output=True)
    _check_same(ref, out)


def _cornell(ref: tuple[list[str], Path, float], tmp_path: Path, points: list) -> None:
    args, ref, t_run = ref
    out = tmp_path / "killed"
    # a time point is a fraction of a run's wall time, the uninterrupted run's first
    # (absolute seconds were past the end of a fast run on an idle machine: the campaign
    # finished before its kill); a run that ends before its time point (faster now than the
    # run it was timed by, the load on the machine having changed) times the next attempt
    for _attempt in range(3):
        for w in points:
            t0 = time.monotonic()
            at = _after(w.fraction * t_run) if isinstance(w, _Fraction) else w
            if not _kill_when(args, out, at):
                assert isinstance(w, _Fraction), "the campaign ended before its kill point"
                t_run = time.monotonic() - t0
                shutil.rmtree(out)
                break
        else:
            break
    else:
        pytest.fail(f"the campaign ended before its kill point in 3 runs (last {t_run:.2f} s)")
    subprocess.run(_cmd(args, out, "--resume"), check=True, capture_output=True)
    # plan.json names the plan file's path: the same plan, another folder
    (out / "plan.json").unlink()
    _check_same(ref, out)


def _after_groups(k: int):
    return lambda out, t: _done_groups(out) >= k


def _in_fit(out: Path, t: float) -> bool:
    return (out / "samples.csv").is_file()


def _after(seconds: float):
    return lambda out, t: t >= seconds


class _Fraction:
    """A kill point at this fraction of the uninterrupted run's wall time."""

    def __init__(self, fraction: float) -> None:
        self.fraction = fraction


def test_lbl_killed_after_every_group_and_in_the_fit_resumes_identically(tmp_path, lbl_ref):
    every_group = [_after_groups(k) for k in range(1, N_GROUPS_LBL)]
    _lbl(lbl_ref, tmp_path, [*every_group, _in_fit])


def test_cornell_killed_in_the_measurement_and_in_the_fit_resumes_identically(
    tmp_path, cornell_ref
):
    rng = np.random.default_rng(15)
    _cornell(cornell_ref, tmp_path, [_Fraction(float(rng.uniform(0.2, 0.6))), _in_fit])


@pytest.mark.slow
def test_random_kill_points_sweep(tmp_path, cornell_ref):
    # each resumed run starts at the point its predecessor reached: fractions of the whole
    # run's time drawn low, so that each resume still reaches its own
    rng = np.random.default_rng(0)
    _cornell(cornell_ref, tmp_path, [_Fraction(float(f)) for f in rng.uniform(0.1, 0.4, 3)])


def test_sigterm_stops_the_campaign_and_every_child(tmp_path):
    """``kill PID`` / ``Popen.terminate()``: handled like Ctrl-C, no worker left running."""
    log = tmp_path / "stderr.txt"
    with open(log, "wb") as err:  # a file, not a pipe: a surviving child would hold a pipe open
        p = subprocess.Popen(_cmd(LBL, tmp_path / "t"), stdout=subprocess.DEVNULL, stderr=err)
    proc = psutil.Process(p.pid)
    t0 = time.monotonic()
    children: list = []
    try:
        while len(children) < 3 and p.poll() is None:  # plot worker + 2 pool workers
            assert time.monotonic() - t0 < 120
            children = proc.children(recursive=True)
            time.sleep(0.005)
        assert p.poll() is None, "campaign ended before its workers started"
        p.terminate()
        rc = p.wait(timeout=60)
        _gone, alive = psutil.wait_procs(children, timeout=10)
    finally:
        for c in [proc, *children]:
            with contextlib.suppress(psutil.Error):
                c.kill()
    assert not alive, f"processes left behind after SIGTERM: {alive}"
    text = log.read_text()
    assert rc == 130 and "interrupted" in text and "Traceback" not in text
    assert not list((tmp_path / "t").rglob("*.tmp"))
