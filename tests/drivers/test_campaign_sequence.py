"""A campaign-style loop written against the interfaces only, over the fakes, with faults."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from gonio.drivers.errors import DeviceError
from gonio.drivers.esp300 import ESP300
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.fake.esp300 import FakeESP300Server
from gonio.drivers.interfaces import Axis, Camera, MotionController, Spectrometer
from gonio.drivers.ptp import PTPCamera
from gonio.drivers.usb2000 import USB2000Plus
from gonio.simulator.bench import Bench

from gonio.io.atomic import atomic_write_bytes


def run_campaign(
    mc: MotionController, spec: Spectrometer, cam: Camera, angles, out_dir, on_step=None
) -> list[dict]:
    """Move, wait, read a spectrum and an image at every angle; save each record at once."""
    done = []
    arm = mc.axis("source")
    for k, a in enumerate(angles):
        if on_step:
            on_step(k)
        arm.move_to(a)
        pos = arm.wait(10.0)
        counts = spec.intensities()
        img, meta = cam.capture(timeout=10.0)
        rec = {
            "angle": pos,
            "sum_counts": float(counts.sum()),
            "img_mean": float(img.mean()),
            "filename": meta["filename"],
        }
        atomic_write_bytes(out_dir / f"rec{k:03d}.json", json.dumps(rec).encode())
        done.append(rec)
    return done


@pytest.fixture
def rig():
    bench = Bench.for_instrument("lbl", time_scale=200.0, rng=0, simulate=False)
    name = fakeusb.install(bench)
    with FakeESP300Server(bench, tcp=True) as srv:
        mc = ESP300.open(srv.port, axes={"source": 1, "sample": 2, "tilt": 3}, timeout=0.5)
        spec = USB2000Plus.open(name)
        cam = PTPCamera.open(name)
        mc.enable()
        spec.integration_time = 0.02
        cam.exposure = 0.01
        yield bench, srv, fakeusb.devices(name), mc, spec, cam
        spec.close()
        cam.close()
        mc.close()
    fakeusb.uninstall(name)


def test_drivers_satisfy_the_interfaces(rig):
    _, _, _, mc, spec, cam = rig
    assert isinstance(mc, MotionController) and isinstance(mc.axis("sample"), Axis)
    assert isinstance(spec, Spectrometer) and isinstance(cam, Camera)


def test_full_move_and_read_sequence(rig, tmp_path):
    bench, _, _, mc, spec, cam = rig
    angles = [0.0, 20.0, 40.0, 60.0]
    recs = run_campaign(mc, spec, cam, angles, tmp_path)
    assert [r["angle"] for r in recs] == angles
    sums = [r["sum_counts"] for r in recs]
    assert all(a > b for a, b in itertools.pairwise(sums))  # cos(theta) falls off
    assert len(list(tmp_path.glob("rec*.json"))) == 4
    assert bench.positions()["source"] == pytest.approx(60.0)


def test_faults_during_campaign_are_survived(rig, tmp_path):
    _, srv, fakes, mc, spec, cam = rig

    def inject(k):
        if k == 1:
            srv.faults.corrupt_reply_bytes = 2
        if k == 2:
            fakes["usb2000plus"].faults.disconnect_after_bytes = 700
        if k == 3:
            fakes["ptp"].faults.usb_pipe_errors = 1

    recs = run_campaign(mc, spec, cam, [5.0, 15.0, 25.0, 35.0], tmp_path, inject)
    assert [r["angle"] for r in recs] == [5.0, 15.0, 25.0, 35.0]
    assert len(list(tmp_path.glob("rec*.json"))) == 4


def test_fatal_fault_keeps_completed_records(rig, tmp_path):
    _, srv, _, mc, spec, cam = rig

    def inject(k):
        if k == 2:
            srv.firmware.inject_stall(1, 30.0)

    with pytest.raises(DeviceError) as ei:
        run_campaign(mc, spec, cam, [10.0, 20.0, 40.0, 50.0], tmp_path, inject)
    assert "HARDWARE LIMIT" in str(ei.value)
    saved = sorted(tmp_path.glob("rec*.json"))
    assert [json.loads(p.read_text())["angle"] for p in saved] == [10.0, 20.0]
    assert np.isfinite([json.loads(p.read_text())["sum_counts"] for p in saved]).all()
