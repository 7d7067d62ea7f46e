"""Run-time estimate of an LBL campaign on the real instrument (Ward 1992, §3.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator.lbl_timing import (
    TIMINGS,
    LBLTiming,
    bracket_s,
    brackets_of,
    estimate_run_time,
    schedule,
)

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


# -- the instrument's brackets -----------------------------------------------------------------
def test_bracket_counts_each_change_of_the_iris():
    """A bracket of (exposure, f-number) frames: read-out per frame, the iris set before each
    frame whose stop differs from the one set; exposure times alone change it between frames."""
    t = LBLTiming()  # 1992: 1/30 s read-out, 3 s per iris change by hand
    two = [(0.01, 8.0), (0.02, 4.0)]
    frames = 0.03 + 2 * t.readout_s
    assert bracket_s(two, t) == (pytest.approx(frames + 3.0), 1, 4.0)  # first stop already set
    assert bracket_s(two, t, iris=8.0)[:2] == (pytest.approx(frames + 3.0), 1)
    assert bracket_s(two, t, iris=2.8)[:2] == (pytest.approx(frames + 6.0), 2)
    assert bracket_s([(0.01, 4.0)], t, iris=4.0)[:2] == (pytest.approx(0.01 + t.readout_s), 0)
    assert bracket_s([0.01, 0.02, 0.04], t, iris=2.8) == (
        pytest.approx(0.07 + 3 * t.readout_s + 6.0),
        2,
        None,
    )


def test_schedule_carries_the_iris_from_capture_to_capture():
    """Standard at f/2.8, background at f/2, the sample at f/8 and f/4 then f/4: the iris is
    changed at the background's first capture, twice for the sample's first bracket and not
    for its second: 3 changes, where a bracket of exposure times alone counts 1."""
    t = TIMINGS["ward1992"]
    br = {("standard", 0.0, None): [(0.01, 2.8)], ("standard", 40.0, None): [(0.01, 2.8)],
          ("background", 0.0, None): [(0.01, 2.0)], ("background", 40.0, None): [(0.01, 2.0)],
          ("measured", 0.0, 0.0): [(0.01, 8.0), (0.01, 4.0)],
          ("measured", 40.0, 0.0): [(0.01, 4.0)]}  # fmt: skip
    e = estimate_run_time((0.0, 40.0), (0.0,), br, t)
    one = estimate_run_time((0.0, 40.0), (0.0,), 1, t)
    assert e["stop_change_s"] == pytest.approx(3 * t.stop_change_s)
    assert e["n_frames"] == 7 and e["n_captures"] == 6
    assert e["move_s"] == pytest.approx(one["move_s"]) and e["manual_s"] == one["manual_s"]
    assert e["total_s"] == pytest.approx(
        one["move_s"] + one["manual_s"] + 0.07 + 7 * t.readout_s + 3 * t.stop_change_s
    )
    times = {k: [x for x, _ in v] for k, v in br.items()}
    assert estimate_run_time((0.0, 40.0), (0.0,), times, t)["stop_change_s"] == pytest.approx(
        t.stop_change_s
    )
    sch = schedule((0.0, 40.0), (0.0,), br, t)
    assert [c.get("stop_changes") for c in sch if c["kind"] != "manual"] == [0, 0, 1, 0, 2, 0]


def test_brackets_from_the_frames_metadata_and_bad_brackets():
    metas = {("standard", 0.0, None): [{"exposure_s": 0.01, "f_number": 2.8, "bias_adu": 64}]}
    assert brackets_of(metas) == {("standard", 0.0, None): [(0.01, 2.8)]}
    with pytest.raises(ValueError, match=r"capture \('measured', 0.0, 0.0\).*f_number"):
        brackets_of({("measured", 0.0, 0.0): [{"exposure_s": 0.01}]})
    for bad in ([(0.01, 0.0)], [(-0.01, 4.0)], [(float("nan"), 4.0)]):
        with pytest.raises(ValueError, match="expected positive finite numbers"):
            bracket_s(bad)
    with pytest.raises(ValueError, match="no exposures"):
        estimate_run_time((0.0,), (0.0,), {("standard", 0.0, None): []})
    with pytest.raises(ValueError, match="a count or a mapping"):
        schedule((0.0,), (0.0,), True)
