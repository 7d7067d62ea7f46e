"""Shared pytest configuration: opt-in hardware tests, hypothesis profiles, set-up made once
for the whole run (:func:`made_once`) and the order that lets a parallel run end together."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture(scope="session")
def write_mutated(tmp_path_factory):
    """``write(text, edits, raw)``: a new file holding ``text`` with each ``(position,
    insertion)`` of ``edits`` replacing the character at ``position`` (clipped to the end),
    then the bytes ``raw``; for the hostile-file tests of the file readers (session-scoped,
    so hypothesis may call it once per example)."""

    def write(text: str, edits, raw: bytes):
        for pos, ins in edits:
            pos = min(pos, len(text))
            text = text[:pos] + ins + text[pos + 1 :]
        p = tmp_path_factory.mktemp("mutated") / "x.csv"
        p.write_bytes(text.encode() + raw)
        return p

    return write


def _run_folder(tmp_path_factory) -> Path:
    """The test run's temporary folder, the same for every pytest-xdist worker (a worker's
    own folders, popen-gw0, ..., are in it)."""
    root = tmp_path_factory.getbasetemp()
    return root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root


@pytest.fixture(autouse=True, scope="session")
def _calibration_cache(tmp_path_factory):
    """Campaigns keep their calibrations (gonio.campaign.calcache) in the test run's folder,
    never in the user's cache; one folder for every worker (its entries are written
    atomically), so an instrument is calibrated once per run, not once per worker."""
    mp = pytest.MonkeyPatch()
    folder = _run_folder(tmp_path_factory) / "gonio-cache"
    folder.mkdir(exist_ok=True)
    mp.setenv("GONIO_CACHE_DIR", str(folder))
    yield
    mp.undo()


def pytest_addoption(parser):
    parser.addoption(
        "--device-port",
        action="store",
        default=None,
        help="serial port of a real ESP300 for opt-in hardware tests",
    )


@pytest.fixture(scope="session")
def made_once(tmp_path_factory) -> Callable:
    """``once(name, make)``: the folder ``make(folder)`` filled and the JSON value it returned,
    made once for the whole test run however many pytest-xdist workers ask for it (the first
    makes it under a file lock in the run's shared temporary folder, the others wait for it
    and read it), for expensive set-up that tests only read, such as an uninterrupted
    campaign that killed and resumed runs are compared with."""
    root = _run_folder(tmp_path_factory)

    def once(name: str, make: Callable[[Path], object]) -> tuple[Path, object]:
        folder, made = root / f"once-{name}", root / f"once-{name}.json"
        with open(root / f"once-{name}.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # (released when the file is closed)
            if not made.is_file():  # (a worker that failed to make it left no .json)
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir()
                made.write_text(json.dumps(make(folder)))
            return folder, json.loads(made.read_text())

    return once


def pytest_collection_modifyitems(config, items):
    _long_tests_first(items, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    if config.getoption("--device-port"):
        return
    skip = pytest.mark.skip(reason="real-hardware test: pass --device-port to run it")
    for item in items:
        if "device" in item.keywords:
            item.add_marker(skip)


def _long_tests_first(items: list, n_workers: int) -> None:
    """Reorder ``items`` so that each worker's first share (pytest-xdist's work stealing
    hands worker i the i-th of ``n_workers`` contiguous, near-equal shares, and an idle worker
    takes tests from the end of another's) starts with its part of the long tests (marked
    ``slow`` or ``early``, dealt out in turn): a long test started last would leave the
    other workers idle at the end of the run."""
    long = [it for it in items if "slow" in it.keywords or "early" in it.keywords]
    if not long:
        return
    chosen = {id(it) for it in long}
    rest = [it for it in items if id(it) not in chosen]
    order, left = [], len(items)
    for w in range(n_workers):
        size = left // (n_workers - w)  # (the share pytest-xdist sends worker w)
        share = long[w::n_workers]
        share += rest[: max(0, size - len(share))]
        rest = rest[len(share) - len(long[w::n_workers]) :]
        order += share
        left -= len(share)
    items[:] = order + rest
