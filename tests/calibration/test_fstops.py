"""Exposure ratios of f-stop brackets from their overlaps (calibration/fstops.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.calibration import Capture
from gonio.calibration.fstops import (
    calibrate_fstops,
    correct_capture,
    overlap_ratios,
)
from gonio.calibration.radiometry import exposure_scale

sim = pytest.importorskip("gonio.simulator")

#: the engraved stop -> the true f-number of the sqrt(2) series (ISO 517)
TRUE_N = {16.0: 16.0, 11.0: 11.31, 8.0: 8.0, 5.6: 5.657, 4.0: 4.0}


def _bracket(inst, sample, ti, stops, rng, iris=0.0):
    """Frames taken at the true f-numbers (times an iris error), side-cars with the marks."""
    frames = []
    for n in stops:
        e = rng.normal(0.0, iris) if iris else 0.0
        img, meta = inst.capture(sample, ti, 0.0, f_number=TRUE_N[n] * math.exp(-e / 2),
                                 exposure=0.01, rng=int(rng.integers(2**31)))  # fmt: skip
        meta["f_number"] = n
        frames.append((img, meta))
    return Capture(frames)


@pytest.fixture(scope="module")
def inst():
    return sim.LBLInstrument(width=320, height=240)


def test_overlap_measures_the_true_ratio(inst):
    cap = _bracket(inst, "standard", 0.5, (11.0, 8.0, 5.6), np.random.default_rng(0))
    ov = overlap_ratios(cap, min_signal_dn=100)
    assert len(ov) == 2
    for o in ov:
        true = 2 * math.log(TRUE_N[o.stop_a] / TRUE_N[o.stop_b])
        assert abs(o.log_ratio - true) < 3 * o.u + 2e-4
        assert abs(o.nominal - 2 * math.log(o.stop_a / o.stop_b)) < 1e-12


def test_table_and_correction_remove_the_marked_stop_error(inst):
    rng = np.random.default_rng(1)
    caps = [_bracket(inst, s, t, (11.0, 8.0, 5.6), rng, iris=0.005)
            for s in ("standard", "rolled_brass") for t in (0.3, 0.7, 1.0)]  # fmt: skip
    ovs = [overlap_ratios(c, min_signal_dn=100) for c in caps]
    cal = calibrate_fstops([o for ol in ovs for o in ol], reference=8.0)
    # relative to f/8: f/11 is f/11.31 and f/5.6 is f/5.66
    assert cal.effective_f_number(11.0) == pytest.approx(11.31, rel=3e-3)
    assert cal.effective_f_number(5.6) == pytest.approx(5.657, rel=3e-3)
    assert 0.001 < cal.sigma_iris < 0.012  # the 0.5 % iris error (per frame, in area)
    fixed = correct_capture(caps[0], cal, ovs[0])
    for (_, m0), (_, m1) in zip(caps[0].frames, fixed.frames):
        assert m1["f_number_marked"] == m0["f_number"]
    # corrected frames agree with each other: their ratios are the measured ones
    s = [exposure_scale(m) for m in fixed.metas]
    for o in ovs[0]:
        assert math.log(s[o.b] / s[o.a]) == pytest.approx(o.log_ratio, abs=1e-12)


def test_no_overlap_and_bad_options(inst):
    cap = _bracket(inst, "standard", 0.5, (8.0,), np.random.default_rng(2))
    assert overlap_ratios(cap) == []
    assert calibrate_fstops([]).n_overlaps == 0
    with pytest.raises(ValueError, match="stride"):
        overlap_ratios(cap, stride=0)
    with pytest.raises(ValueError, match="headroom"):
        overlap_ratios(cap, headroom=1.5)
