"""Run-time estimate of an LBL campaign on the real instrument (Ward 1992, §3.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator.lbl_timing import TIMINGS, LBLTiming, estimate_run_time, schedule

WARD_ANGLES = tuple(np.linspace(0.0, 80.0, 21))


def test_a_complete_brdf_takes_a_few_minutes():
    """Ward: "a complete BRDF can be recorded in a few minutes, including time for manual
    rotation of the sample"."""
    old = estimate_run_time(WARD_ANGLES, (0.0,), 3, TIMINGS["ward1992"])
    new = estimate_run_time(WARD_ANGLES, (0.0,), 3, TIMINGS["modern"])
    assert 120.0 < new["total_s"] < old["total_s"] < 900.0
    for e in (old, new):
        parts = e["move_s"] + e["exposure_s"] + e["stop_change_s"] + e["manual_s"]
        assert parts == pytest.approx(e["total_s"])
        assert e["n_captures"] == 63 and e["n_frames"] == 189


def test_schedule_is_in_time_order_with_the_manual_steps_between_sweeps():
    sch = schedule((0.0, 40.0), (0.0, 90.0), 2)
    kinds = [c["kind"] for c in sch]
    assert kinds == [
        "standard", "standard", "manual", "background", "background", "manual",
        "measured", "measured", "manual", "measured", "measured",
    ]  # fmt: skip
    starts = [c["start_s"] for c in sch]
    assert starts == sorted(starts)
    # the second sweep runs back: the arm does not move between the two sweeps' ends
    assert [c["theta_i_deg"] for c in sch if c["kind"] == "background"] == [40.0, 0.0]
    t = LBLTiming()
    manual = [c["end_s"] - c["start_s"] for c in sch if c["kind"] == "manual"]
    assert manual == [t.swap_s, t.swap_s, t.rotate_sample_s]


def test_arm_move_follows_a_trapezoidal_profile():
    t = LBLTiming()
    v, a = t.arm_speed, t.arm_acceleration
    assert t.move_time(0.0) == 0.0
    assert t.move_time(math.radians(80)) == pytest.approx(math.radians(80) / v + v / a)
    small = 0.5 * v * v / a
    assert t.move_time(small) == pytest.approx(2 * math.sqrt(small / a))


def test_frames_per_capture_from_a_mapping_and_bad_input():
    frames = {("standard", 0.0, None): [0.01], ("background", 0.0, None): [0.01, 0.02],
              ("measured", 0.0, 0.0): [0.01, 0.04, 0.16]}  # fmt: skip
    e = estimate_run_time((0.0,), (0.0,), frames)
    assert e["n_frames"] == 6
    assert e["exposure_s"] == pytest.approx(0.25 + 6 * LBLTiming().readout_s)
    with pytest.raises(ValueError, match="no exposures"):
        estimate_run_time((0.0, 10.0), (0.0,), frames)
    with pytest.raises(ValueError, match="theta_i_deg"):
        schedule((95.0,))
    with pytest.raises(ValueError, match="arm_speed"):
        LBLTiming(arm_speed=0.0)
