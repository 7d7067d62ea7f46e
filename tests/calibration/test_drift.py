"""The lamp's drift from a re-measured standard (calibration/drift.py), its correction of a
campaign's samples (campaign/knowledge.correct_drift) and its budget terms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.calibration import Capture
from gonio.calibration.drift import drift_gain, standard_ratio

from gonio.samples import BRDFSamples

SENSOR = {"gain_e_per_dn": 10.0, "read_noise_e": 8.0, "black_level_dn": 64.0,
          "saturation_dn": 4064.0}  # fmt: skip


def _cap(signal_dn, rng):
    raw = 64.0 + signal_dn + rng.normal(0.0, 0.8, signal_dn.shape)
    meta = {"exposure_s": 0.01, "f_number": 4.0, "sensor": SENSOR}
    return Capture.single(np.clip(np.rint(raw), 0, 4095).astype(np.uint16), meta)


def test_the_standard_captured_again_follows_the_lamp():
    rng = np.random.default_rng(0)
    v, u = np.mgrid[:120, :160]
    lit = np.hypot(u - 80, v - 60) < 50
    std = np.where(lit, 2000.0, 0.0)
    bg = np.full(std.shape, 30.0)
    first, back = _cap(std + bg, rng), _cap(bg, rng)
    again = _cap(1.004 * std + bg, rng)  # the lamp 0.4 % brighter
    assert standard_ratio(again, first, back) == pytest.approx(1.004, abs=2e-4)
    with pytest.raises(ValueError, match="fraction"):
        standard_ratio(again, first, back, fraction=0.0)
    with pytest.raises(ValueError, match="share no frame"):
        standard_ratio(_cap(0.0 * std + 4100.0, rng), first, back)  # saturated


def test_drift_gain_interpolates_in_time():
    g = drift_gain([0.0, 100.0, 150.0, 300.0], [100.0, 200.0], [1.002, 1.004])
    assert np.allclose(g, [1.002, 1.002, 1.003, 1.004])
    with pytest.raises(ValueError, match="ratio"):
        drift_gain([0.0], [1.0], [-1.0])
    with pytest.raises(ValueError, match="equal-length"):
        drift_gain([0.0], [1.0, 2.0], [1.0])


def _table(n, value):
    return BRDFSamples(np.full(n, 0.3), np.zeros(n), np.full(n, 0.2), np.zeros(n),
                       np.full(n, value), np.full(n, 0.01 * value))  # fmt: skip


def test_correct_drift_divides_each_capture_by_the_lamps_change():
    from gonio.campaign.knowledge import correct_drift

    per_angle = [
        {"tables": [_table(5, 1.0)], "infos": [{"clock_s": 100.0, "n_samples": 5,
          "restandard": {"ratio": 1.01, "clock_s": 120.0, "clock_s_standard": 1.0}}]},
        {"tables": [_table(4, 2.0)], "infos": [{"clock_s": 300.0, "n_samples": 4,
          "restandard": {"ratio": 1.02, "clock_s": 320.0, "clock_s_standard": 3.0}}]},
    ]  # fmt: skip
    assert correct_drift(per_angle, ("geometry",)) == 0  # the correction off: nothing done
    assert per_angle[0]["tables"][0].value[0] == 1.0
    assert correct_drift(per_angle) == 2
    assert np.allclose(per_angle[0]["tables"][0].value, 1.0 / 1.01)  # before the first anchor
    g = 1.01 + 0.01 * (300.0 - 120.0) / (320.0 - 120.0)  # between the anchors
    assert np.allclose(per_angle[1]["tables"][0].value, 2.0 / g)
    assert np.allclose(per_angle[1]["tables"][0].sigma, 0.02 / g)
    assert per_angle[1]["infos"][0]["drift_gain"] == pytest.approx(g)


def test_the_budget_keeps_what_the_re_measured_standard_leaves():
    """Warm-up between standards (0-40 s) and samples (130-230 s): the uncorrected term is
    the lamp model's change; re-measured standards every few captures leave a fraction."""
    from gonio.campaign.budget_terms import lamp_terms

    n = 11
    ts = np.linspace(0.5, 44.0, n)
    tm = np.linspace(129.0, 227.0, n)
    s = _table(n, 1.0)
    raw = {p.name: p for p in lamp_terms(s, tm, ts, 0.005, 0.001)}
    anchors = (tm[::3] + 21.0, ts[::3])
    left = {p.name: p for p in lamp_terms(s, tm, ts, 0.005, 0.001, anchors, 5e-4)}
    tau = 600.0
    assert np.allclose(raw["lamp_warmup"].dy, np.exp(-ts / tau) - np.exp(-tm / tau))
    assert not raw["lamp_warmup"].corrected and left["lamp_warmup"].corrected
    # what remains is the lamp's change across the standard's own sweep (0.5-44 s), not the
    # 130-230 s between the standards and the samples
    sweep = math.exp(-0.5 / tau) - math.exp(-44.0 / tau)
    worst = np.max(np.abs(left["lamp_warmup"].dy))
    assert worst < 0.5 * sweep and worst < 0.15 * np.min(raw["lamp_warmup"].dy)
    flick = [p for k, p in left.items() if k.startswith("lamp_anchor")]
    assert len(flick) == 4 and flick[0].u == pytest.approx(5e-4)
    assert np.allclose(sum(-p.dy for p in flick), 1.0)  # interpolation weights sum to one
