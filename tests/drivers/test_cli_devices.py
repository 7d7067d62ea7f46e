"""``gonio devices serve --json`` in a subprocess, reached from this process."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from gonio.drivers.esp300 import ESP300
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.usb2000 import USB2000Plus


@contextlib.contextmanager
def _served(tmp_path, *extra: str):
    """Run ``gonio devices serve --json ...``; yield its records (up to the bench line)."""
    # stderr to a file: an unread pipe fills up (warnings, logs) and blocks the server
    err = open(tmp_path / "serve.stderr", "w+")
    proc = subprocess.Popen(
        [sys.executable, "-P", "-c", "import sys; from gonio.cli import main; sys.exit(main())",
         "devices", "serve", "--json", *extra],
        stdout=subprocess.PIPE,
        stderr=err,
        text=True,
        # not the repository root: its gonio/ folder would shadow the installed package
        cwd=tmp_path,
    )  # fmt: skip
    try:
        recs = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            recs.append(json.loads(line))
            if recs[-1]["device"] == "bench":
                break
        assert recs and recs[-1]["device"] == "bench", (tmp_path / "serve.stderr").read_text()
        yield recs
    finally:
        os.kill(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        err.close()
    assert proc.returncode in (0, 130), (tmp_path / "serve.stderr").read_text()[-3000:]


def test_devices_serve_json_and_reach_devices(tmp_path):
    with _served(tmp_path, "--time-scale", "100", "--instrument", "cornell") as recs:
        assert [r["device"] for r in recs] == ["esp300"] * 3 + ["usb2000plus", "ptp", "bench"]
        esps = {r["controller"]: r for r in recs[:3]}
        # every stage of the Cornell bench is served: motors, accessories, shutter
        assert esps["motors"]["axes"] == {"1": "arm", "2": "turntable", "3": "tilt"}
        assert esps["accessories"]["axes"] == {"1": "polarizer", "2": "target", "3": "filter"}
        assert esps["shutter"]["axes"] == {"1": "shutter"}
        served = {n for r in recs[:3] for n in r["axes"].values()}
        assert served == set(recs[-1]["stages"])
        esp = esps["motors"]
        assert esp["port"].startswith("/dev/") and isinstance(esp["tcp"], int)
        ctl = ESP300.open(esp["port"], axes={"arm": 1})
        assert ctl.version().startswith("ESP300 Version")
        ctl.close()
        ctl = ESP300.open(f"socket://127.0.0.1:{esp['tcp']}", axes={"arm": 1})
        assert ctl.axis("arm").position() == 0.0
        ctl.close()
        usb = {r["device"]: r for r in recs}["usb2000plus"]
        name = fakeusb.connect(usb["usb_server"])
        try:
            spec = USB2000Plus.open(name, n_pixels=None)  # the Cornell bench's 1024 pixels
            assert spec.serial_number() == usb["serial"]
            assert spec.intensities().shape == (1024,) == (usb["n_pixels"],)
            spec.close()
        finally:
            fakeusb.uninstall(name)


def test_lbl_bench_serves_the_sample_changer(tmp_path):
    with _served(tmp_path, "--instrument", "lbl") as recs:
        esps = {r["controller"]: r["axes"] for r in recs if r["device"] == "esp300"}
        assert esps == {"motors": {"1": "source", "2": "sample", "3": "tilt"},
                        "changer": {"1": "changer"}}  # fmt: skip


def test_external_script_runs_a_cornell_campaign_on_the_served_bench(tmp_path):
    """A driver script in another process than the fakes measures, through the drivers
    only, the samples the in-process simulation gives for the same seed."""
    pytest.importorskip("gonio.simulator.cornell")
    from gonio.campaign.cornell import build_plan, run_cornell_campaign
    from gonio.campaign.drivers import CornellRig, open_served_rig, run_cornell_measurements

    kw = dict(plan="incidence", plan_kw={"theta_i_deg": (45.0,)}, max_geometries=6)
    ref = run_cornell_campaign("laser_paper", seed=2, fit=False, effects=None, **kw)["_samples"]
    plan = build_plan(kw["plan"], max_geometries=6, **kw["plan_kw"])
    args = ("--instrument", "cornell", "--material", "laser_paper", "--seed", "2",
            "--time-scale", "10000")  # fmt: skip
    with _served(tmp_path, *args) as recs:
        with open_served_rig(recs, via="tcp") as (rig, parts):
            assert isinstance(rig, CornellRig) and len(parts["controllers"]) == 3
            res = run_cornell_measurements(rig, np.degrees(plan.angles))
            assert rig.n_reads > 5 * len(plan)  # preview, dark and signal per polarisation
    np.testing.assert_allclose(np.degrees(plan.angles), res["positions_deg"], atol=1e-9)
    np.testing.assert_allclose(res["value"].ravel(), ref.value, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res["sigma"].ravel(), ref.sigma, rtol=1e-12)


def test_open_served_rig_rejects_incomplete_records():
    from gonio.campaign.drivers import open_served_rig

    with pytest.raises(ValueError, match="esp300"), open_served_rig([{"device": "ptp"}]):
        pass
    with pytest.raises(ValueError, match="via"), open_served_rig([], via="serial"):
        pass


def test_devices_without_action_prints_usage(capsys):
    from gonio.cli import main

    assert main(["devices"]) == 2
    assert "gonio devices serve" in capsys.readouterr().err


def test_devices_serve_rejects_bad_material(capsys):
    from gonio.cli import main

    pytest.importorskip("gonio.materials")
    assert main(["devices", "serve", "--material", "no-such-material"]) == 2
    assert "--material" in capsys.readouterr().err


def test_devices_serve_rejects_bad_seed(capsys):
    from gonio.cli import main

    assert main(["devices", "serve", "--seed", "-1"]) == 2
    assert "--seed" in capsys.readouterr().err
