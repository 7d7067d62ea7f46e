"""The Cornell campaign's uncertainty budget: propagation, combination, the campaign's table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gonio.campaign.cornell import run_cornell_campaign, summary_text
from gonio.campaign.cornell_budget import combine, propagate, propagate_independent


def test_propagate_is_the_weighted_least_squares_response():
    x = np.linspace(0.0, 1.0, 50)
    jac = np.c_[x, np.ones_like(x)]  # y = a x + b
    w = np.linspace(1.0, 2.0, 50)
    pats = np.c_[np.full(50, 0.3), 0.2 * x]  # an offset, a slope
    dp = propagate(jac, w, pats)
    np.testing.assert_allclose(dp, [[0.0, 0.2], [0.3, 0.0]], atol=1e-12)


def test_independent_propagation_sums_each_geometry_alone():
    """Per-geometry independent perturbations (the stages' positioning noise): the variance
    is the sum over geometries of the squared response to that geometry's perturbation
    alone (the slow way: one propagation per geometry, every band of it together)."""
    g = np.random.default_rng(3)
    n_geo, nb = 12, 4
    jac = g.normal(size=(n_geo * nb, 3))
    w = g.uniform(0.5, 2.0, n_geo * nb)
    q = g.normal(size=(n_geo, nb))
    var = propagate_independent(jac, w, {"noise": [q, 0.5 * q]}, nb)["noise"]
    slow = np.zeros(3)
    for k in range(n_geo):
        one = np.zeros((n_geo, nb))
        one[k] = q[k]
        slow += 1.25 * propagate(jac, w, one.reshape(-1, 1))[:, 0] ** 2
    np.testing.assert_allclose(var, slow, rtol=1e-10)


def test_tilt_changes_the_irradiance_the_reduction_divides_by():
    """A Lambertian sample reads the same BRDF at any tilt, but the irradiance on the tilted
    sample is cos(θi') where the reduction divides by the nominal cos θi: the budget's tilt
    pattern about y is f (cos(θi - u) / cos θi - 1) / √2 (second order about x)."""
    from gonio import brdf
    from gonio.campaign.cornell_budget import _geometry_patterns

    th = np.radians([20.0, 60.0, 75.0])
    wi = np.c_[np.sin(th), np.zeros(3), np.cos(th)]
    wo = np.c_[-np.sin(th), np.zeros(3), np.cos(th)]
    u = 1e-3
    pats = _geometry_patterns(brdf.create("lambert", rho=0.6), wi, wo, 2, None,
                              {"sample_tilt_rad": (u, 0.0)})["sample_tilt_rad"]  # fmt: skip
    f = 0.6 / np.pi
    np.testing.assert_allclose(pats[0], f * (np.cos(u) - 1) / np.sqrt(2), rtol=1e-6)  # 2nd order
    # Rodrigues about +y by u takes (sin th, 0, cos th) to z' = cos th cos u - sin th sin u
    expect = f * ((np.cos(th) * np.cos(u) - np.sin(th) * np.sin(u)) / np.cos(th) - 1) / np.sqrt(2)
    np.testing.assert_allclose(pats[1][:, 0], expect, rtol=1e-9)
    assert abs(pats[1][2, 0]) > 10 * abs(pats[1][0, 0])  # tan 75 / tan 20


def test_combine_adds_in_quadrature_and_expands():
    b = combine(3.0, {"a": 4.0, "b": 12.0})
    assert b["combined"] == pytest.approx(13.0) and b["U"] == pytest.approx(26.0)
    assert combine(None, {})["U"] == 0.0


def test_realistic_campaign_reports_a_budget_that_covers_the_truth(tmp_path):
    s = run_cornell_campaign(
        "garnet_red_paint",
        plan="incidence",
        plan_kw={"theta_i_deg": (30.0, 60.0)},
        seed=0,
        out=tmp_path,
    )
    b = s["budget"]
    free = [k for k in s["within_3_sigma"] if k != "sigma/tau"]  # the fitted parameters
    assert set(free) <= set(b["parameters"])
    for p in free:
        e = b["parameters"][p]
        assert e["U"] == pytest.approx(2 * e["combined"])
        assert e["combined"] >= e["stat"] and math.isfinite(e["U"])
    tau = b["parameters"]["tau"]["contributions"]
    assert {"sample_tilt_rad", "stage_backlash_deg", "lamp_drift"} <= set(tau)
    assert b["parameters"]["tau"]["combined"] > 3 * b["parameters"]["tau"]["stat"]
    cov = b["coverage"]
    assert cov["n"] == len(free) + 1 and cov["n_within_U"] >= 0.9 * cov["n"]
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["budget"]["coverage"] == cov
    assert "budget tau" in summary_text(s) and "within U" in summary_text(s)
    assert "stage_noise_deg" in tau and " +- " in summary_text(s)  # the time estimate's u
    assert 0 < s["estimated_real_instrument_u_h"] < s["estimated_real_instrument_h"]
    png = tmp_path / "plots" / "budget.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and on_disk["files"]["plots"] == [
        "plots/budget.png", "plots/incidence_plane.png", "plots/residuals.png"
    ]  # fmt: skip
    assert all((tmp_path / p).is_file() for p in on_disk["files"]["plots"])
    ideal = run_cornell_campaign(
        "garnet_red_paint",
        plan="incidence",
        max_geometries=20,
        plan_kw={"theta_i_deg": (30.0,)},
        seed=0,
        effects=None,
    )
    assert all(
        not e["contributions"].get("lamp_drift") for e in ideal["budget"]["parameters"].values()
    )


def test_lag_sides_follow_the_simulated_stages_backlash():
    """The budget's side of each stage's backlash along a plan equals the lag the simulated
    stages take (gonio.simulator.cornell_physics.stage_offsets, noise off), over half the
    band."""
    from gonio.simulator.cornell_physics import stage_offsets

    from gonio.campaign.cornell_budget import lag_sides

    g = np.random.default_rng(0)
    angles = np.round(g.uniform(-1, 1, (40, 3)), 1)
    angles[5:9, 1] = angles[4, 1]  # an axis that stands still keeps its side
    lag, prev, out = np.zeros(3), np.zeros(3), []
    for a in angles:
        _off, lag = stage_offsets(a - prev, lag, 0.01, 0.0, g)
        out.append(lag / 0.005)
        prev = a
    np.testing.assert_array_equal(lag_sides(angles), np.array(out))
