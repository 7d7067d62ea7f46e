"""Shared pytest configuration: opt-in hardware tests and hypothesis profiles."""

from __future__ import annotations

import os

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


@pytest.fixture(autouse=True, scope="session")
def _calibration_cache(tmp_path_factory):
    """Campaigns keep their calibrations (gonio.campaign.calcache) in the session's folder,
    never in the user's cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("GONIO_CACHE_DIR", str(tmp_path_factory.mktemp("gonio-cache")))
    yield
    mp.undo()


def pytest_addoption(parser):
    parser.addoption(
        "--device-port",
        action="store",
        default=None,
        help="serial port of a real ESP300 for opt-in hardware tests",
    )


def pytest_collection_modifyitems(config, items):
    if config.getoption("--device-port"):
        return
    skip = pytest.mark.skip(reason="real-hardware test: pass --device-port to run it")
    for item in items:
        if "device" in item.keywords:
            item.add_marker(skip)
