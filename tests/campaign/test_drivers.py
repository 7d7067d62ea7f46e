"""Campaign runner through the driver interfaces: checkpoint/resume with injected faults, LBL."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gonio.simulator.cornell")

from gonio.drivers.errors import DeviceError
from gonio.drivers.fake.faults import Faults

from gonio.campaign.cornell import run_cornell_campaign
from gonio.campaign.drivers import Checkpoint, fake_cornell_rig

SMALL = dict(plan="incidence", plan_kw={"theta_i_deg": (45.0,)}, max_geometries=10, fit=False)
# resumed runs identical to uninterrupted ones: the ideal instrument (a realistic one's lamp
# is lit again and its stages start afresh: test_realistic_campaign_resumes_in_a_new_session)
IDEAL = dict(SMALL, effects=None)


class _Kill(Exception):
    pass


def test_checkpoint_roundtrip_and_guards(tmp_path):
    ck = Checkpoint(tmp_path / "c.npz", "k1", every=2)
    ck.add(0, {"v": np.arange(3.0), "t": 1.5})
    assert not (tmp_path / "c.npz").exists()  # not yet due
    ck.add(3, {"v": np.ones(3), "t": 2.0})
    assert (tmp_path / "c.npz").is_file()
    with pytest.raises(ValueError, match="duplicated"):
        ck.add(3, {"v": np.ones(3), "t": 2.0})
    again = Checkpoint(tmp_path / "c.npz", "k1")
    assert again.load() == 2 and 3 in again and 1 not in again
    np.testing.assert_array_equal(again.records[0]["v"], np.arange(3.0))
    with pytest.raises(ValueError, match="another campaign"):
        Checkpoint(tmp_path / "c.npz", "other").load()
    with pytest.raises(ValueError, match="every"):
        Checkpoint(tmp_path / "x.npz", "k", every=0)


def test_killed_campaign_resumes_without_lost_or_duplicated_samples(tmp_path):
    ref = run_cornell_campaign("laser_paper", seed=2, through_drivers=True, **IDEAL)

    def kill_at_6(j, n):
        if j == 5:
            raise _Kill

    with pytest.raises(_Kill):
        run_cornell_campaign(
            "laser_paper", seed=2, through_drivers=True, out=tmp_path, checkpoint_every=1000,
            on_measurement=kill_at_6, **IDEAL,
        )  # fmt: skip
    ck = np.load(tmp_path / "checkpoint.npz")
    assert ck["index"].tolist() == [0, 1, 2, 3, 4, 5]  # flushed on the way out
    s = run_cornell_campaign(
        "laser_paper", seed=2, through_drivers=True, out=tmp_path, resume=True, **IDEAL
    )
    assert s["resumed_geometries"] == 6
    a, b = ref["_samples"], s["_samples"]
    assert len(b) == len(a) == 10 * 31
    np.testing.assert_array_equal(a.wo, b.wo)  # each geometry once, in plan order
    # a restarted bench draws the same keyed noise: identical to the uninterrupted run
    np.testing.assert_allclose(a.value, b.value, rtol=1e-12, atol=1e-15)
    assert len(np.load(tmp_path / "checkpoint.npz")["index"]) == 10


def test_injected_disconnects_then_resume(tmp_path):
    """USB unplugs mid-campaign: the driver reconnects; a fault it cannot ride out stops
    the run with the checkpoint on disk, and the resumed run completes it."""
    ref = run_cornell_campaign("garnet_red_paint", seed=4, through_drivers=True, **IDEAL)
    usb_faults = Faults()
    esp_faults = Faults()

    def inject(j, n):
        if j == 2:  # a recoverable unplug of the spectrometer during the next reads
            usb_faults.disconnect_after_bytes = 0
            usb_faults.reconnect_after = 0.02
        if j == 6:  # the motion controller stops answering: more timeouts than retries
            esp_faults.drop_reply_bytes = 10**6

    with pytest.raises(DeviceError):
        run_cornell_campaign(
            "garnet_red_paint", seed=4, through_drivers=True, out=tmp_path, on_measurement=inject,
            faults={"usb2000plus": usb_faults, "esp300": esp_faults}, checkpoint_every=1,
            device_timeout=0.3, **IDEAL,
        )  # fmt: skip
    assert any("disconnect" in x for x in usb_faults.log)
    done = np.load(tmp_path / "checkpoint.npz")["index"].tolist()
    assert done == list(range(7))
    s = run_cornell_campaign(
        "garnet_red_paint", seed=4, through_drivers=True, out=tmp_path, resume=True, **IDEAL
    )
    a, b = ref["_samples"], s["_samples"]
    assert s["resumed_geometries"] == 7 and len(b) == len(a)
    np.testing.assert_array_equal(a.wo, b.wo)
    va, vb = a.value.reshape(10, 31), b.value.reshape(10, 31)
    # geometries measured after the resume are identical; those around the unplug were
    # read again (fresh noise draws) but are complete and statistically the same
    np.testing.assert_allclose(va[7:], vb[7:], rtol=1e-12, atol=1e-15)
    rel = np.abs(va - vb) / np.maximum(np.abs(va), 1e-12)
    assert np.median(rel[va > 0.05 * va.max()]) < 0.05


def test_realistic_campaign_resumes_in_a_new_session(tmp_path):
    """The realistic instrument through the fakes: stages with backlash and noise (the
    spectrometer reads at the load positions, the controllers report their encoders), the
    standard re-measured every 4 geometries; killed after 6 geometries, the resumed run
    measures a reference where it starts and completes without losing or repeating one."""
    kw = dict(SMALL, reference_every=4, seed=3)
    full = run_cornell_campaign("laser_paper", through_drivers=True, **kw)
    assert full["n_references"] == 4  # at 0, 4, 8 and after the 10th

    def kill_at_6(j, n):
        if j == 5:
            raise _Kill

    with pytest.raises(_Kill):
        run_cornell_campaign("laser_paper", through_drivers=True, out=tmp_path,
                             checkpoint_every=1000, on_measurement=kill_at_6, **kw)  # fmt: skip
    assert (tmp_path / "reference.npz").is_file() and (tmp_path / "reference_0_4.npz").is_file()
    s = run_cornell_campaign("laser_paper", through_drivers=True, out=tmp_path, resume=True, **kw)
    assert s["resumed_geometries"] == 6
    assert sorted(p.name for p in tmp_path.glob("reference_1_*.npz")) == [
        "reference_1_10.npz", "reference_1_6.npz", "reference_1_8.npz"]  # fmt: skip
    ck = np.load(tmp_path / "checkpoint.npz")
    assert ck["index"].tolist() == list(range(10)) and ck["session"].tolist() == [0] * 6 + [1] * 4
    assert "signal_s" not in ck.files  # the raw spectra: one file per geometry, written once
    assert sorted(int(p.stem) for p in (tmp_path / "spectra").glob("*.npz")) == list(range(10))
    a, b = full["_samples"], s["_samples"]
    np.testing.assert_array_equal(a.wo, b.wo)  # each geometry once, in plan order
    va, vb = a.value.reshape(10, 31), b.value.reshape(10, 31)
    # session 0 as before up to its last reference (4); 4 and 5 now held at that reference
    # (the one at 8 belongs to the uninterrupted run alone)
    np.testing.assert_allclose(va[:4], vb[:4], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(va[4:6], vb[4:6], rtol=5e-3)
    big = va > 0.05 * va.max()
    assert 0 < np.median((np.abs(va - vb) / np.abs(va))[big]) < 0.02  # a new session


def test_realistic_fakes_read_at_the_load_positions():
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_effects import realise

    fx = realise("cornell2005", 2)
    cfg = CornellConfig(effects=fx, instrument_seed=2)
    with fake_cornell_rig("laser_paper", seed=0, noise=False, config=cfg) as (rig, parts):
        got = rig.move_motors([40.0, 20.0, 10.0])
        rig.read(0.1)
        rig.move_motors([30.0, 10.0, 5.0])
        rig.read(0.1)
        load, enc = parts["bench"].positions(), parts["bench"].encoder_positions()
        inst = parts["instrument"]
    np.testing.assert_allclose(got, [40.0, 20.0, 10.0], atol=1e-9)  # encoders: commanded
    off = np.array([load[k] - enc[k] for k in ("arm", "turntable", "tilt")])
    # half the backlash band behind a move to lower angles, plus the positioning noise
    assert np.all(np.abs(off - fx["stage_backlash_deg"] / 2) < 5 * fx["stage_noise_deg"] + 1e-9)
    assert np.all(off != fx["stage_backlash_deg"] / 2)
    assert inst.event_clock and inst.clock_s > 0.2  # two reads and a move of the lamp's clock


def test_rig_reads_follow_the_accessories():
    with fake_cornell_rig("garnet_red_paint", seed=0, noise=False) as (rig, parts):
        rig.move_motors([40.0, 20.0, 10.0])
        sig = rig.read(0.1, polarizer="s")
        dark = rig.read(0.1, polarizer="s", shutter=False)
        nd = rig.read(0.1, polarizer="s", filter_in=True)
        std = rig.read(0.1, polarizer="p", target="standard")
        pos = parts["bench"].positions()
    assert pos["polarizer"] == 90.0 and pos["target"] == 25.0
    assert dark.max() < sig.max()  # shutter closed: bias + dark only
    assert np.all(nd - dark.min() < sig - dark.min() + 1e-9)
    assert std.sum() != sig.sum()
    assert rig.n_reads == 4


class _CountingAxis:
    """An Axis proxy that counts the moves it is asked for."""

    def __init__(self, axis):
        self.axis, self.moves = axis, 0

    def move_to(self, pos):
        self.moves += 1
        self.axis.move_to(pos)

    def __getattr__(self, name):
        return getattr(self.axis, name)


def test_each_geometry_turns_the_polarizer_once_and_the_shutter_twice():
    from gonio.simulator.cornell import first_polarizer, read_sequence

    from gonio.campaign.drivers import CornellRig, run_cornell_measurements

    assert read_sequence("s") == (("s", True), ("s", False), ("p", False), ("p", True))
    assert [first_polarizer(j) for j in range(4)] == ["s", "p", "s", "p"]
    with pytest.raises(ValueError, match="first"):
        read_sequence("x")
    ang = np.array([[60.0, 10.0, 5.0], [62.0, 10.0, 5.0], [64.0, 12.0, 5.0], [66.0, 12.0, 6.0]])
    snaps = []
    with fake_cornell_rig("laser_paper", seed=1, noise=False) as (rig, _parts):
        axes = {n: _CountingAxis(a) for n, a in rig.axes.items()}
        counted = CornellRig(axes, rig.spectrometer)

        def snap(j, n):
            snaps.append({k: a.moves for k, a in axes.items()})

        res = run_cornell_measurements(counted, ang, on_measurement=snap)
    # geometries 1..3: one polariser turn and two shutter moves each (signal, dark | dark,
    # signal), nothing else but the motors
    d = {k: snaps[-1][k] - snaps[0][k] for k in axes}
    assert (d["polarizer"], d["shutter"], d["target"], d["filter"]) == (3, 6, 0, 0), d
    assert res["value"].shape == (4, 31) and np.all(res["value"] > 0)


def test_lbl_campaign_through_drivers_matches_in_process_without_noise():
    """ESP300 source arm + sample rotation + changer, PTP camera: 16-bit frames reduced by the
    calibration pipeline give the in-process samples (noise off, fixed exposure)."""
    from gonio import campaign
    from gonio.campaign.drivers import fake_lbl_rig

    plan = campaign.Plan(
        material="rolled_brass", theta_i_deg=(40.0,), rotations_deg=(0.0,), noise=0.0,
        exposures_s=(0.002,), plots=False, preset="ideal",
    )  # fmt: skip
    ref = campaign.run(plan, None)
    with fake_lbl_rig("rolled_brass", noise=False, exposures_s=(0.002,)) as (dev, parts):
        got = campaign.run(plan, None, instrument=dev)
        assert dev.n_frames == 3  # standard, background, measured
        assert parts["bench"].positions()["source"] == 40.0
    a, b = ref.samples, got.samples
    assert len(a) == len(b) > 100
    np.testing.assert_allclose(b.theta_o, a.theta_o, atol=1e-9)
    np.testing.assert_allclose(b.value, a.value, rtol=1e-6, atol=1e-9)


def test_lbl_campaign_through_drivers_resumes_by_capture_group(tmp_path):
    from gonio import campaign
    from gonio.campaign.drivers import LBLDriverInstrument, run_lbl_through_drivers

    plan = campaign.Plan(
        material="rolled_brass", theta_i_deg=(20.0, 50.0), rotations_deg=(0.0,), noise=1.0,
        exposures_s=(0.002,), plots=False, seed=3,
    )  # fmt: skip
    calls = []
    real = LBLDriverInstrument.shoot

    def flaky(self, sample, theta_i, phi_i, seed):
        calls.append(round(float(np.degrees(theta_i)), 3))
        if len(calls) == 4:  # the 20-degree groups done; the camera dies on the 50-degree one
            raise DeviceError("PTP camera", "InitiateCapture", None, "unplugged")
        return real(self, sample, theta_i, phi_i, seed)

    LBLDriverInstrument.shoot = flaky
    try:
        with pytest.raises(DeviceError):
            run_lbl_through_drivers(plan, tmp_path)
        assert sorted(p.name for p in (tmp_path / "raw").iterdir() if (p / "done.json").exists()) \
            == ["t20.00", "t20.00_r000.0"]  # fmt: skip
        calls.clear()
        res = run_lbl_through_drivers(plan, tmp_path, resume=True)
    finally:
        LBLDriverInstrument.shoot = real
    assert calls == [50.0, 50.0, 50.0]  # only the missing groups: standard, background, sample
    assert res.summary["n_captures"]["resumed_groups"] == 2
    assert len(res.samples) > 100 and res.fit.converged
