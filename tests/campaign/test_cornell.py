"""Cornell campaigns: in-process vs through the fake devices, fit, results directory, CLI entry."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("gonio.simulator.cornell")

from gonio.campaign.cornell import build_plan, identifiability_scan, main, run_cornell_campaign

SMALL = dict(plan="incidence", plan_kw={"theta_i_deg": (30.0,)}, max_geometries=8)


@pytest.mark.parametrize("noise", [True, False])
def test_drivers_give_the_same_samples_as_in_process(noise):
    # the ideal instrument: the realistic one's stage errors and lamp clock live in-process
    kw = dict(SMALL, seed=5, noise=noise, fit=False, effects=None)
    a = run_cornell_campaign("garnet_red_paint", **kw)
    b = run_cornell_campaign("garnet_red_paint", through_drivers=True, **kw)
    sa, sb = a["_samples"], b["_samples"]
    assert len(sa) == len(sb) == 8 * 31
    # the same geometries (directions from the encoder read-back equal the planned ones)
    np.testing.assert_array_equal(sa.wi, sb.wi)
    np.testing.assert_array_equal(sa.wo, sb.wo)
    np.testing.assert_array_equal(sa.wavelength_nm, sb.wavelength_nm)
    if noise:
        # the same values: same keyed noise; the last-digit differences come from degrees ->
        # radians round trips of the positions
        np.testing.assert_allclose(sa.value, sb.value, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(sa.sigma, sb.sigma, rtol=1e-12)
        assert not np.allclose(sa.value, run_cornell_campaign(
            "garnet_red_paint", **{**kw, "seed": 6})["_samples"].value, rtol=1e-6)  # fmt: skip
    else:
        # noise off is an ideal detector in-process (fractional counts); the device's ADC
        # still rounds every pixel to whole counts, which matters only where the signal is
        # a few hundred counts (the blue end of the lamp spectrum)
        assert np.isnan(sb.sigma).all()
        np.testing.assert_allclose(sa.value, sb.value, rtol=0.05)
        assert not np.array_equal(sa.value, sb.value)
    assert b["device_reads"] > 5 * 8 and b["device_moves"] > 8


def test_plan_angles_are_on_the_controller_grid():
    p = build_plan("incidence", resolution_deg=1e-3)
    deg = np.degrees(p.angles)
    assert np.allclose(deg * 1e3, np.round(deg * 1e3), atol=1e-6)
    assert len(p) == p.meta["n_geometries"] > 200
    with pytest.raises(ValueError, match="plan"):
        build_plan("spiral")
    with pytest.raises(ValueError, match="resolution_deg"):
        build_plan("incidence", resolution_deg=0)


def test_campaign_writes_results_and_fits(tmp_path):
    s = run_cornell_campaign(
        "laser_paper", plan="incidence", plan_kw={"theta_i_deg": (30.0, 60.0)},
        noise=True, seed=1, out=tmp_path, cone_corrections=1,
    )  # fmt: skip
    for f in ("plan.json", "samples.csv", "fit.json", "summary.json"):
        assert (tmp_path / f).is_file()
    js = json.loads((tmp_path / "summary.json").read_text())
    for k in ("material", "model", "truth", "fit", "stderr", "relative_error", "rms",
              "n_samples", "converged", "timings_s", "seed"):  # fmt: skip
        assert k in js
    assert (
        js["model"] == "li_torrance" and js["seed"] == 1 and js["n_samples"] == len(s["_samples"])
    )
    # no mirror part: sigma is held at the table value, tau (i.e. sigma/tau) fitted
    assert js["fit_mode"] == "sigma_fixed" and js["fit"]["sigma"] == js["truth"]["sigma"]
    assert 0 < js["fit"]["tau"] and js["stderr"]["tau"] > 0
    assert js["k_summary"]["n"] == 3 * 31
    assert js["estimated_real_instrument_h"] > 0
    assert js["cone_corrections"] == 1 and len(js["sigma_tau_history"]) == 2
    # the reference's noise is common to all samples of a band: reported and added to the k's
    ref = np.array(js["reference_band_rel_error"])
    assert ref.shape == (31,) and np.all((ref > 0) & (ref < 0.01))
    k = "k_dd[15]"
    assert js["stderr_with_reference"][k] > js["stderr"][k]


def test_sigma_and_tau_scaled_together_leave_a_rough_sample_unchanged():
    """Li-Torrance eq. 3-14 without the mirror part depend on sigma/tau only."""
    scan = identifiability_scan("garnet_red_paint", ratios=(0.5, 2.0))
    assert max(r["max_rel_change"] for r in scan) < 1e-9
    scan = identifiability_scan("aluminized_non_glare_glass", ratios=(0.8,))
    assert scan[0]["max_rel_change"] > 0.1  # the mirror part (eq. 4) sees sigma alone


@pytest.mark.parametrize(
    ("plan", "plan_kw", "mode"),
    [
        ("incidence", {"theta_i_deg": (60.0,)}, "both"),  # 1 deg steps: hits the mirror peak
        ("hemispherical", {"theta_i_deg": (60.0,), "n": 7}, "sigma_fixed"),  # never inside it
    ],
)
def test_auto_fits_sigma_only_where_the_plan_sees_the_mirror_part(plan, plan_kw, mode):
    s = run_cornell_campaign(
        "aluminized_non_glare_glass", plan=plan, plan_kw=plan_kw, noise=False, cone_corrections=1
    )
    assert s["fit_mode"] == mode
    assert (s["n_full_mirror_rows"] > 0) == (mode == "both")
    assert s["relative_error"]["sigma/tau"] < 0.02
    if mode == "both":
        assert max(s["relative_error"]["sigma"], s["relative_error"]["tau"]) < 0.02


def test_module_entry_point(tmp_path, capsys):
    out = tmp_path / "s.json"
    rc = main(["--material", "laser_paper", "--max-geometries", "6", "--no-fit",
               "--through-drivers", "--json", str(out), "--quiet"])  # fmt: skip
    assert rc == 0
    js = json.loads(out.read_text())
    assert js["through_drivers"] and js["n_samples"] == 6 * 31
    assert main(["--material", "no_such_material"]) == 2
    assert "no_such_material" in capsys.readouterr().err


def test_cone_response_is_the_labs_own_model_not_the_simulators():
    """The fit's cone model (nominal top hats, the laboratory's ring rule) agrees with what the
    ideal simulated instrument reads to its quadrature accuracy, but is another computation
    (no inverse crime): not equal to rounding error."""
    from gonio.simulator.cornell import CornellConfig

    from gonio import materials
    from gonio.campaign.cornell import cone_response

    for m, tol in (("aluminized_non_glare_glass", 2e-2), ("garnet_red_paint", 2e-3)):
        s = run_cornell_campaign(m, noise=False, fit=False, effects=None, **SMALL)["_samples"]
        wi, wo = s.wi[::31], s.wo[::31]
        r = cone_response(materials.get(m), wi, wo, CornellConfig())
        v = s.value.reshape(-1, 31)
        big = r > 1e-3 * r.max()
        rel = np.abs(v - r)[big] / r[big]
        assert rel.max() < tol
        assert rel.max() > 1e-9


def test_fit_recovers_the_constructed_model_from_point_values():
    """Data = the model itself at the plan's geometries: tau and the 93 k's come back."""
    from gonio import fit as _fit
    from gonio import materials
    from gonio.campaign.cornell import fit_li_torrance
    from gonio.samples import BRDFSamples

    s = run_cornell_campaign(
        "laser_paper", noise=False, fit=False, plan="incidence", plan_kw={"theta_i_deg": (30.0,)}
    )["_samples"]
    truth = materials.get("laser_paper")
    exact = BRDFSamples.from_directions(
        s.wi, s.wo, _fit.predict(truth, s), np.full(len(s), np.nan), wavelength_nm=s.wavelength_nm
    )
    res, info = fit_li_torrance(exact, "laser_paper", cone_corrections=0)
    assert info["fit_mode"] == "sigma_fixed"
    assert abs(res.params["tau"] / 5.4 - 1) < 1e-6
    for k in ("k_dd", "k_uds", "k_fs"):
        got = np.array([res.params[f"{k}[{b}]"] for b in range(31)])
        np.testing.assert_allclose(got, truth.params[k], rtol=1e-5)


def test_variable_projection_fit_equals_the_general_fit():
    """fit_li_torrance solves the 93 k's linearly per trial sigma/tau (linear=True, the
    default); the general joint least squares (linear=False) gives the same fit."""
    from gonio.campaign.cornell import fit_li_torrance

    s = run_cornell_campaign(
        "laser_paper", noise=True, seed=2, fit=False, plan="incidence",
        plan_kw={"theta_i_deg": (30.0,)},
    )["_samples"]  # fmt: skip
    fast, _ = fit_li_torrance(s, "laser_paper", cone_corrections=1)
    slow, _ = fit_li_torrance(s, "laser_paper", cone_corrections=1, linear=False)
    assert fast.free == slow.free and len(fast.free) == 1 + 3 * 31
    assert fast.converged and slow.converged
    assert fast.chi2 == pytest.approx(slow.chi2, rel=1e-9)
    for k in fast.free:
        assert fast.params[k] == pytest.approx(slow.params[k], rel=1e-6, abs=1e-10), k
        assert fast.stderr[k] == pytest.approx(slow.stderr[k], rel=1e-5, abs=1e-12), k


def test_default_cli_campaign_is_fast_and_accurate(tmp_path, capsys):
    """``gonio campaign --instrument cornell --material garnet_red_paint`` (default incidence
    plan, noise on): the full 240-geometry fit in seconds, accurate to its standard errors."""
    from gonio.cli import main as gonio_main

    out = tmp_path / "s.json"
    rc = gonio_main(["campaign", "--instrument", "cornell", "--material", "garnet_red_paint",
                     "--json", str(out)])  # fmt: skip
    assert rc == 0
    assert "garnet_red_paint (cornell" in capsys.readouterr().out
    js = json.loads(out.read_text())
    # the realistic instrument by default: geometries whose field of view leaves the lit
    # spot are refused, the rest fitted, the budget's U covers the truth
    assert js["effects"] == "cornell2005" and js["n_refused_footprint"] > 0
    assert js["n_geometries"] == 240 - js["n_refused_footprint"] and js["noise"]
    assert js["n_samples"] == js["n_geometries"] * 31
    assert js["converged"] and js["fit_mode"] == "sigma_fixed"
    assert js["relative_error"]["sigma/tau"] < 5e-3
    cov = js["budget"]["coverage"]
    assert cov["n"] == 95 and cov["n_within_U"] >= 0.9 * cov["n"]  # 93 k, tau, sigma/tau
    # was 73 s on a quiet machine (261 s loaded) with finite-difference Jacobians over 94
    # parameters; about 1 s now. Generous bound for a loaded machine.
    assert js["timings_s"]["fit"] < 30


def test_stray_offset_error_matches_the_scatter_of_the_stray_estimate():
    """The beam-trap stray-light estimate leaves a per-band additive offset common to all
    samples; its predicted standard error matches the scatter over reference measurements."""
    from gonio.simulator.cornell import BANDS_NM, CornellInstrument, _hat_projector

    from gonio.campaign.cornell import stray_offset_error

    truth = CornellInstrument("lambert", noise=False, rng=0).calibrate("standard")
    use, proj = _hat_projector(tuple(np.round(truth.wavelengths_nm, 9)), tuple(BANDS_NM))
    offsets, preds = [], []
    for seed in range(24):
        inst = CornellInstrument("lambert", noise=True, rng=seed)
        ref = inst.calibrate("standard")
        d = 0.5 * sum((ref.stray[q] - truth.stray[q]) * ref.scale / ref.rate[q] for q in "sp")
        offsets.append(proj @ d[use])
        preds.append(stray_offset_error(ref, inst.config))
    ratio = np.std(offsets, axis=0, ddof=1) / np.mean(preds, axis=0)
    assert 0.75 < np.median(ratio) < 1.25, np.median(ratio)


def test_offset_sensitivity_of_a_uniform_diffuse_k():
    """k_udf/pi alone: an offset 1/cos_eff in every sample moves k_udf by pi * mean(1/cos_eff)."""
    from gonio.simulator.cornell import BANDS_NM, CornellConfig, effective_cos

    from gonio import brdf
    from gonio.campaign.cornell import offset_sensitivity
    from gonio.geometry import to_vector
    from gonio.samples import BRDFSamples

    cfg = CornellConfig()
    m = brdf.create("li_torrance", k_dd=0.0, k_udf=np.full(31, 0.3), sigma=0.5, tau=2.5,
                    wavelength_nm=BANDS_NM)  # fmt: skip
    ti = np.radians([10.0, 35.0, 60.0, 75.0])
    wi = to_vector(ti, 0.0)
    wo = to_vector(np.radians(20.0), np.pi) * np.ones((4, 1))
    n = len(wi)
    s = BRDFSamples.from_directions(
        np.repeat(wi, 31, axis=0), np.repeat(wo, 31, axis=0), np.full(31 * n, 0.3 / np.pi),
        np.full(31 * n, 1e-3), wavelength_nm=np.tile(BANDS_NM, n),
    )  # fmt: skip
    g = offset_sensitivity(m, s, ["k_udf"], cfg)["k_udf"]
    np.testing.assert_allclose(g, np.pi * np.mean(1 / effective_cos(wi, cfg)), rtol=1e-10)
