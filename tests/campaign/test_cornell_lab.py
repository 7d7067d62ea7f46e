"""The laboratory's own Cornell models: footprint, slit deconvolution, stray-light removal,
drift correction from re-measured references — each against an independent computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator.cornell import remove_uniform_stray
from gonio.simulator.cornell_physics import lit_fraction, slit_convolve

from gonio.campaign.cornell import run_cornell_campaign
from gonio.campaign.cornell_lab import footprint_fraction, footprint_refused, slit_correction


def _dirs(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)


def test_lab_footprint_agrees_with_the_simulators_and_refuses_what_reads_low():
    g = np.random.default_rng(0)
    wi = _dirs(g.uniform(0, 85, 300), g.uniform(0, 360, 300))
    wo = _dirs(g.uniform(0, 85, 300), g.uniform(0, 360, 300))
    lab = footprint_fraction(wi, wo, 25.0, 8.0, 101.6)
    true = lit_fraction(wi, wo, 25.0, 8.0, 101.6)
    assert np.mean(true < 0.999) > 0.1  # a real share of the hemisphere reads low
    np.testing.assert_allclose(lab, true, atol=0.02)  # polar rule vs stratified points
    refused = footprint_refused(wi, wo, 25.0, 8.0, 101.6, margin=0.05)
    assert np.all(refused[true < 0.999])  # nothing that reads low survives the plan
    assert not np.any(footprint_refused(wi, wo, 25.0, 0.0, 101.6))


def test_slit_correction_removes_most_of_the_slit_bias():
    """A red-paint-like edge seen through a 5 nm slit under a halogen-like spectrum: the
    ratio of the convolved signal to the convolved reference, then corrected on the bands."""
    wl = np.linspace(380.0, 720.0, 3401)
    f = 0.05 + 0.55 / (1 + np.exp(-(wl - 600.0) / 12.0))
    k = (wl / 560.0) ** 4 * np.exp(-(((wl - 560) / 150) ** 2))
    meas = slit_convolve(k * f, wl, 5.0) / slit_convolve(k, wl, 5.0)
    bands = np.arange(400.0, 701.0, 10.0)
    m, truth, kb = (np.interp(bands, wl, v) for v in (meas, f, k))
    corr = slit_correction(m[None], kb, 5.0)[0]
    inner = slice(1, -1)
    before = np.max(np.abs(m - truth)[inner])
    after = np.max(np.abs(corr - truth)[inner])
    assert before > 5e-4 and after < 0.2 * before  # 9.2e-4 -> 7.1e-5
    with pytest.raises(ValueError, match="fwhm_nm = 12"):
        slit_correction(m[None], kb, 12.0)


def test_uniform_stray_removal_inverts_the_stray_distribution():
    r = np.random.default_rng(1).uniform(0.0, 5.0, 1024)
    m = r + 1e-3 * r.mean()
    np.testing.assert_allclose(remove_uniform_stray(m, 1e-3), r, rtol=1e-13)
    with pytest.raises(ValueError, match="stray_correction"):
        remove_uniform_stray(m, -1.0)


def test_drift_correction_from_re_measured_references():
    """A lamp drifting 20 %/h over a 40-geometry sweep in theta_o (about 4 minutes): with one
    reference at the start the ramp biases the shape (tau) and the k's; references every 8
    geometries, interpolated in time, remove it (measured: tau -2.7 % -> -0.009 %, median
    k_dd +7.9 % -> +0.04 %)."""
    kw = dict(
        plan="incidence",
        plan_kw={"theta_i_deg": (30.0,)},
        max_geometries=40,
        seed=2,
        noise=False,
        budget=False,
        effects={"lamp_drift": 0.2},
    )
    ideal = run_cornell_campaign("laser_paper", **{**kw, "effects": None})
    raw = run_cornell_campaign("laser_paper", reference_every=0, **kw)
    fixed = run_cornell_campaign("laser_paper", reference_every=8, **kw)
    k = [f"k_dd[{b}]" for b in range(31)]
    k_shift = [np.median([s["fit"][p] / ideal["fit"][p] - 1 for p in k]) for s in (raw, fixed)]
    tau_shift = [s["fit"]["tau"] / ideal["fit"]["tau"] - 1 for s in (raw, fixed)]
    assert k_shift[0] > 0.2 * raw["campaign_clock_h"] / 2  # at least the mean drift
    assert abs(tau_shift[0]) > 1e-2
    assert abs(k_shift[1]) < 0.02 * k_shift[0] and abs(tau_shift[1]) < 0.02 * abs(tau_shift[0])
    drift = fixed["reference_drift"]  # what the references saw: the 20 %/h ramp
    assert drift[-1][1] - 1 == pytest.approx(0.2 * drift[-1][0], rel=1e-3)
    assert fixed["n_references"] == 1 + math.ceil(40 / 8)
    with pytest.raises(ValueError, match="reference_every"):
        run_cornell_campaign("laser_paper", **{**kw, "reference_every": -1})
    with pytest.raises(ValueError, match="footprint"):
        run_cornell_campaign("laser_paper", **{**kw, "corrections": {"footprint": "x"}})
