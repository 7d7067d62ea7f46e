"""Opt-in tests against a real ESP300 (``pytest --device-port /dev/ttyUSB0``)."""

from __future__ import annotations

import pytest
from gonio.drivers.esp300 import ESP300


@pytest.fixture
def esp(request):
    port = request.config.getoption("--device-port")
    ctl = ESP300.open(port, timeout=2.0)
    yield ctl
    ctl.close()


@pytest.mark.device
def test_real_esp300_identifies_and_reports_no_error(esp):
    assert esp.version().startswith("ESP300")
    code, _, msg = esp.error()
    assert isinstance(code, int) and msg


@pytest.mark.device
def test_real_esp300_reads_positions_without_moving(esp):
    for ax in esp.axes.values():
        assert isinstance(ax.position(), float)
        lo, hi = ax.limits()
        assert lo < hi
