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
