"""The Cornell instrument's effects: presets, the ideal instrument bit for bit, every effect
changes the reading, the footprint against an independent geometric calculation, bad input."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest
from gonio.simulator.cornell import CornellConfig, CornellInstrument, inverse
from gonio.simulator.cornell_effects import EFFECTS, PRESETS, check_magnitudes, realise

from gonio.campaign.cornell import run_cornell_campaign

TINY = dict(plan="incidence", plan_kw={"theta_i_deg": (30.0,)}, max_geometries=8, fit=False)
SHORT = {**TINY, "max_geometries": 4}
NO_CORRECTION = {"footprint": "none", "stray": False, "slit": False, "drift": False}


def _fingerprint(s) -> str:
    data = np.ascontiguousarray(s.value).tobytes() + np.ascontiguousarray(s.sigma).tobytes()
    return hashlib.sha256(data).hexdigest()[:16]


#: the samples of the instrument before the effects existed (the code before issue 18's
#: effects, commit c9cd0d7's parent, seed 3, the TINY plan): their fingerprints on the
#: platforms where that code was run, and the values it gave on the second (value, sigma)
PRE_EFFECTS = {
    "garnet_red_paint": {"9d9d6110b3c91f4c", "5c2730cd1ed88a75"},
    "aluminized_non_glare_glass": {"402839ef99ffeb55", "81d355139dae8bc4"},
}
PRE_EFFECTS_VALUES = Path(__file__).parent / "data" / "cornell_pre_effects.npz"


def test_every_effect_at_zero_is_the_ideal_instrument_bit_for_bit():
    """None, the ideal preset and every effect at zero give the same samples to the bit,
    and those of the instrument before the effects existed: to the bit on a platform where
    that code was run (:data:`PRE_EFFECTS`), else to 1e-12 of its values there. The last
    bits are the platform's: the same code on another machine (its CPU, libm, libraries)
    gave other fingerprints (9d9d... and 402839... were recorded on one machine; the code
    before the effects itself gives 5c2730... and 81d355... on an AVX-512 EPYC)."""
    ref = np.load(PRE_EFFECTS_VALUES)
    zeros = {name: 0.0 for name in EFFECTS}
    for m, known in PRE_EFFECTS.items():
        runs = [run_cornell_campaign(m, seed=3, effects=fx, **TINY)["_samples"]
                for fx in (None, "ideal", zeros)]  # fmt: skip
        fps = {_fingerprint(s) for s in runs}
        assert len(fps) == 1, (m, fps)  # zero = off: the same bits whichever way it is said
        got = np.stack([runs[0].value, runs[0].sigma])
        if fps.isdisjoint(known):  # a platform the code before the effects never ran on
            np.testing.assert_allclose(got, ref[m], rtol=1e-12, atol=0.0, err_msg=m)


def test_presets_realise_different_instruments_within_range():
    assert all(v == 0 for v in realise("ideal", 4).values())
    a, b = realise("cornell2005", 1), realise("cornell2005", 2)
    assert a == realise("cornell2005", 1) and a != b
    for m in (a, b):
        for name, v in m.items():
            assert EFFECTS[name].contains(v), name
        assert m["sample_size_mm"] == 101.6 and m["fov_diameter_mm"] > 0
    assert set(PRESETS["cornell2005"]) == set(EFFECTS)


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"fov_diameter_mm": 50.0, "sample_size_mm": 40.0}, "fov_diameter_mm = 50.0 is larger"),
        ({"lamp_drift": -1.5}, r"lamp_drift = -1.5 is outside its valid range \[-0.2, 0.2\]"),
        ({"slit_fwhm_nm": 12.0}, r"slit_fwhm_nm = 12.0 is outside its valid range \[0, 10\)"),
        ({"slit_fwhm_nm": 10.0}, "slit_fwhm_nm"),
        ({"stray_light_fraction": -1e-3}, "stray_light_fraction"),
        ({"no_such_effect": 1.0}, "unknown"),
    ],
)
def test_bad_magnitudes_are_value_errors_naming_them(bad, match):
    with pytest.raises(ValueError, match=match):
        check_magnitudes(bad)
    with pytest.raises(ValueError, match=match):
        CornellConfig(effects=bad)


def test_every_effect_changes_what_the_instrument_reads():
    m = realise("cornell2005", 0)
    base = run_cornell_campaign("garnet_red_paint", seed=1, effects=None, noise=False, **SHORT)
    v0 = base["_samples"].value
    for name in EFFECTS:
        if name in (
            "beam_diameter_mm",
            "sample_size_mm",
            "polariser_error_deg",
            "sample_polarisation",
        ):
            continue  # with a field of view / a polariser error only (below)
        one = {name: m[name] or 0.5 * EFFECTS[name].valid[1]}
        if name == "fov_diameter_mm":
            one = {"fov_diameter_mm": 60.0, "sample_size_mm": 101.6, "beam_diameter_mm": 25.0}
        s = run_cornell_campaign(
            "garnet_red_paint",
            seed=1,
            effects=one,
            noise=False,
            reference_every=2,
            corrections=NO_CORRECTION,
            **SHORT,
        )
        assert not np.allclose(s["_samples"].value, v0, rtol=1e-7, atol=0), name
    # a polarising sample: the s/p average is exact with orthogonal polariser positions, and
    # no longer with the p position 3 deg off
    kw = dict(seed=1, noise=False, corrections=NO_CORRECTION, **SHORT)
    pol = run_cornell_campaign("garnet_red_paint", effects={"sample_polarisation": 1.0}, **kw)
    np.testing.assert_allclose(pol["_samples"].value, v0, rtol=1e-9)
    off = {"sample_polarisation": 1.0, "polariser_error_deg": 3.0}
    v = run_cornell_campaign("garnet_red_paint", effects=off, **kw)["_samples"].value
    assert not np.allclose(v, v0, rtol=1e-7, atol=0)


def _signal(inst: CornellInstrument, angles) -> np.ndarray:
    inst.move_to(angles)
    sig = inst.expected_counts(inst._pos(), 1.0)
    trap = inst.expected_counts({**inst._pos(), "target": 2.0}, 1.0)
    return sig - trap


def test_footprint_bias_matches_an_independent_geometric_calculation():
    """Field of view 20 mm viewed at 80 deg: an ellipse of semi-axes 57.6 x 10 mm, cut by the
    edges of the 101.6 mm sample (an infinite beam): the reading falls to the share of the
    ellipse with |x| <= 50.8 mm, (2/pi) (asin u + u sqrt(1 - u^2)), u = 50.8 / 57.6."""
    t_o = math.radians(80.0)
    wi = np.array([[math.sin(math.radians(20)), 0.0, math.cos(math.radians(20))]])
    wo = np.array([[-math.sin(t_o), 0.0, math.cos(t_o)]])
    ang = inverse(wi[0], wo[0]).angles
    fx = {"fov_diameter_mm": 20.0, "sample_size_mm": 101.6}
    real = CornellInstrument("garnet_red_paint", noise=False, config=CornellConfig(effects=fx))
    ideal = CornellInstrument("garnet_red_paint", noise=False)
    ratio = _signal(real, ang) / _signal(ideal, ang)
    u = 50.8 / (10.0 / math.cos(t_o))
    expect = 2 / math.pi * (math.asin(u) + u * math.sqrt(1 - u * u))
    assert 0.9 < expect < 0.99
    np.testing.assert_allclose(ratio, expect, rtol=1e-3)  # the simulator's stratified points
