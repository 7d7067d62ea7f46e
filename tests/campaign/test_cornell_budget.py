"""The Cornell campaign's uncertainty budget: propagation, combination, the campaign's table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gonio.campaign.cornell import run_cornell_campaign, summary_text
from gonio.campaign.cornell_budget import combine, propagate


def test_propagate_is_the_weighted_least_squares_response():
    x = np.linspace(0.0, 1.0, 50)
    jac = np.c_[x, np.ones_like(x)]  # y = a x + b
    w = np.linspace(1.0, 2.0, 50)
    pats = np.c_[np.full(50, 0.3), 0.2 * x]  # an offset, a slope
    dp = propagate(jac, w, pats)
    np.testing.assert_allclose(dp, [[0.0, 0.2], [0.3, 0.0]], atol=1e-12)


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
