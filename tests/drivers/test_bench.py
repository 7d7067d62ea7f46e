"""The simulated bench: trapezoidal motion, limits, backlash, noise, scaled time, renders."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator.bench import Bench, SimClock, Stage, StageFault


def on(stage: Stage) -> Stage:
    stage.motor_on = True
    return stage


def test_trapezoidal_profile_times_and_midpoint():
    s = on(Stage("a", speed=10.0, acceleration=20.0))
    s.move_to(30.0, t=0.0)
    # accelerate 0.5 s (2.5°), cruise 2.5 s (25°), decelerate 0.5 s (2.5°)
    assert s.finish_time(0.0) == pytest.approx(3.5)
    assert s.motor_position(0.5) == pytest.approx(2.5)
    assert s.motor_position(1.75) == pytest.approx(15.0)
    assert s.is_moving(3.4) and not s.is_moving(3.5)
    assert s.motor_position(10.0) == 30.0


def test_triangular_profile_for_short_moves():
    s = on(Stage("a", speed=10.0, acceleration=20.0))
    s.move_to(-2.0, t=1.0)
    assert s.finish_time(1.0) == pytest.approx(1.0 + 2 * math.sqrt(2.0 / 20.0))
    assert s.motor_position(1.0 + math.sqrt(0.1)) == pytest.approx(-1.0)


def test_hardware_limit_stall():
    s = on(Stage("a", lower=-10.0, upper=10.0))
    s.move_to(25.0, t=0.0)
    assert s.motor_position(100.0) == 10.0 and s.limit_hit() == "+"
    s.move_to(-30.0, t=100.0)
    assert s.motor_position(200.0) == -10.0 and s.limit_hit() == "-"


def test_motor_off_and_fault_refuse_moves():
    s = Stage("a")
    with pytest.raises(StageFault):
        s.move_to(1.0, 0.0)
    s.motor_on, s.fault = True, "amplifier fault"
    with pytest.raises(StageFault):
        s.move_to(1.0, 0.0)


def test_backlash_depends_on_approach_direction():
    s = on(Stage("a", backlash=0.3))
    s.move_to(10.0, 0.0)
    from_below = s.load_position(100.0)
    s.move_to(20.0, 100.0)
    s.move_to(10.0, 200.0)
    from_above = s.load_position(300.0)
    assert s.motor_position(300.0) == 10.0
    assert from_above - from_below == pytest.approx(0.3)


def test_positioning_noise_is_seeded_and_sized():
    errs = []
    for seed in (1, 1, 2):
        s = on(Stage("a", noise=0.01, rng=seed))
        s.move_to(5.0, 0.0)
        errs.append(s.load_position(100.0) - 5.0)
    assert errs[0] == errs[1] != errs[2]
    s = on(Stage("a", noise=0.01, rng=3))
    e = []
    for k in range(400):
        s.move_to(float(k % 2), 10.0 * k)
        e.append(s.load_position(10.0 * k + 5) - (k % 2))
    assert np.std(e) == pytest.approx(0.01, rel=0.15)


def test_define_position_shifts_limits():
    s = on(Stage("a", lower=-10, upper=10))
    s.define_position(5.0, 0.0)
    assert (s.lower, s.upper) == (-5.0, 15.0) and s.motor_position(0.0) == 5.0


def test_clock_scale():
    c = SimClock(1000.0)
    assert c.real_seconds(2.0) == pytest.approx(0.002)
    with pytest.raises(ValueError, match="scale"):
        SimClock(0.0)


def test_bad_stage_arguments():
    with pytest.raises(ValueError, match="speed"):
        Stage("a", speed=0)
    with pytest.raises(ValueError, match="lower"):
        Stage("a", lower=5, upper=1)
    with pytest.raises(ValueError, match="unique"):
        Bench([Stage("a"), Stage("a")])
    with pytest.raises(ValueError, match="instrument"):
        Bench.for_instrument("nope")


def test_render_callbacks_receive_true_positions():
    seen = {}

    def cam(pos, exposure, fnum):
        seen["cam"] = (dict(pos), exposure, fnum)
        return np.full((4, 5), 7, np.uint16), {"x": 1}

    def spec(pos, it, wl):
        seen["spec"] = (dict(pos), it, wl.shape)
        return np.full(wl.shape, 123.4)

    b = Bench([on(Stage("a", backlash=0.2))], camera_render=cam, spectrum_render=spec)
    b.stage("a").move_to(1.0, b.now() - 100)  # long finished
    img, meta = b.render_image(0.5, 4.0)
    assert img.shape == (4, 5) and meta["x"] == 1 and meta["exposure_s"] == 0.5
    assert seen["cam"][0]["a"] == pytest.approx(0.9)  # load lags the motor by backlash/2
    counts = b.render_spectrum(0.1)
    assert counts.dtype == np.uint16 and counts[0] == 123 and seen["spec"][2] == (2048,)


def test_default_renders_respond_to_exposure_and_position():
    b = Bench.for_instrument("cornell", time_scale=1000, simulate=False)
    dim, _ = b.render_image(0.01, 8.0)
    bright, _ = b.render_image(0.04, 8.0)
    assert bright.astype(float).sum() > dim.astype(float).sum()
    s0 = b.render_spectrum(0.1).astype(float).sum()
    src = b.stage("arm")
    src.motor_on = True
    src.move_to(60.0, b.now() - 1000)
    assert b.render_spectrum(0.1).astype(float).sum() < s0
    w = b.wavelengths()  # the Cornell spectroradiometer: 1024 pixels from 385 nm
    assert w.shape == (1024,) and w[0] == pytest.approx(385.0) and np.all(np.diff(w) > 0)
    assert Bench().wavelengths()[0] == pytest.approx(339.7)  # the USB2000+ default
