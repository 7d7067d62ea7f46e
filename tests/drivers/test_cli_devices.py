"""``gonio devices serve --json`` in a subprocess, reached from this process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from gonio.drivers.esp300 import ESP300
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.usb2000 import USB2000Plus


def test_devices_serve_json_and_reach_devices(tmp_path):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from gonio.cli import main; sys.exit(main())",
            "devices",
            "serve",
            "--json",
            "--time-scale",
            "100",
            "--instrument",
            "cornell",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # not the repository root: its gonio/ folder would shadow the installed package
        cwd=tmp_path,
    )
    try:
        recs = {}
        deadline = time.monotonic() + 30
        while len(recs) < 3 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            rec = json.loads(line)
            recs[rec["device"]] = rec
        assert set(recs) == {"esp300", "usb2000plus", "ptp"}, proc.stderr.read()
        esp = recs["esp300"]
        assert esp["port"].startswith("/dev/") and isinstance(esp["tcp"], int)
        assert esp["axes"] == {"1": "arm", "2": "turntable", "3": "tilt"}
        ctl = ESP300.open(esp["port"], axes={"arm": 1})
        assert ctl.version().startswith("ESP300 Version")
        ctl.close()
        ctl = ESP300.open(f"socket://127.0.0.1:{esp['tcp']}", axes={"arm": 1})
        assert ctl.axis("arm").position() == 0.0
        ctl.close()
        name = fakeusb.connect(recs["usb2000plus"]["usb_server"])
        try:
            spec = USB2000Plus.open(name, n_pixels=None)  # the Cornell bench's 1024 pixels
            assert spec.serial_number() == recs["usb2000plus"]["serial"]
            assert spec.intensities().shape == (1024,)
            spec.close()
        finally:
            fakeusb.uninstall(name)
    finally:
        os.kill(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode in (0, 130)


def test_devices_without_action_prints_usage(capsys):
    from gonio.cli import main

    assert main(["devices"]) == 2
    assert "gonio devices serve" in capsys.readouterr().err


def test_devices_serve_rejects_bad_material(capsys):
    from gonio.cli import main

    pytest.importorskip("gonio.materials")
    assert main(["devices", "serve", "--material", "no-such-material"]) == 2
    assert "--material" in capsys.readouterr().err
