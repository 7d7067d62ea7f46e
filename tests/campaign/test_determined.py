"""Tests of gonio.campaign.determined: undetermined is an answer, never a crash or an inf.

Each campaign here is a case of issue 35's table that crashed (or said "converged" of a fit
whose model cannot describe the data) before: on the ideal instrument with two incidence
angles, which shows the same failure at a fraction of the cost.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gonio import campaign
from gonio.campaign.budget import budget_table, effect_u
from gonio.campaign.determined import PlanError, check_plan, finite, hemisphere_geometries
from gonio.campaign.report import summary_table

TWO = dict(theta_i_deg=(20.0, 50.0), rotations_deg=(0.0,), plots=False, preset="ideal")


def _no_inf(obj):
    """Whether ``obj`` (a summary) has no non-finite float anywhere."""
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_no_inf(v) for v in obj.values())
    if isinstance(obj, list | tuple):
        return all(_no_inf(v) for v in obj)
    return True


@pytest.fixture(scope="module")
def lambert_pair(tmp_path_factory):
    out = tmp_path_factory.mktemp("ll")
    plan = campaign.Plan(**{**TWO, "plots": True}, model="lambert+lambert")
    return campaign.run(plan, out, workers=1), out


def test_an_unidentifiable_sum_is_reported_undetermined_and_every_output_written(lambert_pair):
    """`gonio campaign --model lambert+lambert` crashed after the run (inf in summary.json)
    and left its .cal behind."""
    res, out = lambert_pair
    s = json.loads((out / "summary.json").read_text())
    assert set(s["undetermined"]) == {"lambert.rho", "lambert#2.rho"}
    assert "only a combination with lambert#2.rho" in s["undetermined"]["lambert.rho"]
    assert s["budget"]["expanded"] == {"lambert.rho": None, "lambert#2.rho": None}
    # another family than the truth's: compared with its reference, but undetermined
    assert s["within_expanded"] == {"lambert.rho": None, "lambert#2.rho": None}
    for f in ("samples.csv", "fit.json", "material.rad", s["files"]["radiance_cal"],
              "plots/budget.png", "plots/residuals.png"):  # fmt: skip
        assert (out / f).is_file(), f
    assert sorted(p.name for p in out.glob("*.cal")) == [s["files"]["radiance_cal"]]
    # the pre-capture warning, then the fit's
    assert s["warnings"][0].startswith("the model's parameters lambert.rho, lambert#2.rho")
    assert any(w.startswith("not identifiable") for w in s["warnings"])
    text = summary_table(res.summary)
    assert "undetermined: lambert.rho: the samples do not constrain it" in text
    assert "warning: not identifiable" in text


@pytest.mark.parametrize(
    ("material", "model", "undetermined"),
    [
        ("garnet_red_paint", None, {"sigma", "tau"}),
        ("wall_plaster", "ward", {"alpha_x", "alpha_y"}),
    ],
)
def test_undetermined_parameters_are_null_never_inf(material, model, undetermined):
    """`--material garnet_red_paint` (a Li-Torrance material on the LBL instrument) and
    `--material wall_plaster --model ward` crashed with "Out of range float values are not
    JSON compliant: inf"."""
    kw = {"model": model} if model else {}
    res = campaign.run(campaign.Plan(**TWO, material=material, **kw), workers=1)
    s = res.summary
    assert set(s["undetermined"]) == undetermined
    assert _no_inf(s)
    json.dumps(s, allow_nan=False)  # what the campaign writes
    for k in undetermined:
        assert s["budget"]["combined"][k] is None and s["stderr"][k] is None
        assert s["within_expanded"].get(k) is None
    assert "undetermined" in budget_table(s["budget"])


def test_wall_plaster_ward_names_the_vanished_lobe():
    """A Ward lobe fitted to a diffuse material: rho_s goes to its bound 0 and takes the
    alphas' effect with it; the reason says so, the budget warns that rho_s is bounded."""
    res = campaign.run(campaign.Plan(**TWO, material="wall_plaster", model="ward"), workers=1)
    s = res.summary
    assert "rho_s fitted to 0" in s["undetermined"]["alpha_x"]
    assert any(w.startswith("rho_s: U (k=2)") for w in s["warnings"])
    assert s["fit_status"].startswith("converged, but chi2/dof")


def test_a_near_perfect_mirror_is_measured_not_lost_from_its_start():
    """`--material neumann_fig12_silver_mirror`: "converged", n = 0.37 against 5000, chi2/dof
    3e6 and no warning. The lobe (half width 0.98 deg) is resolved (0.29 deg on the modern
    instrument, 0.79 deg with Ward's digitiser); the fit had run downhill from n = 20.
    With the exponent scanned for the start (gonio.fit.core._guess_exponent) it is found."""
    res = campaign.run(campaign.Plan(**TWO, material="neumann_fig12_silver_mirror"), workers=1)
    s = res.summary
    assert abs(s["fit"]["n"] - 5000.0) / 5000.0 < 0.01
    assert s["within_expanded"] == {"n": True}
    assert s["fit_status"] == "converged" and s["warnings"] == []


def test_a_cornell_plan_of_one_repeated_geometry_is_refused_before_capture(tmp_path):
    """A Cornell plan of one geometry 50 times ran, "converged", k_fs ~ 1e-10."""
    csv = tmp_path / "plan.csv"
    csv.write_text("theta_i,phi_i,theta_o,phi_o\n" + "30,0,20,180\n" * 50)
    from gonio.campaign.cornell import run_cornell_campaign

    with pytest.raises(PlanError, match="1 distinct geometry does not separate k_dd"):
        run_cornell_campaign("garnet_red_paint", plan=str(csv), out=tmp_path / "out")
    assert not (tmp_path / "out" / "samples.csv").exists()


def test_a_plan_that_separates_part_of_the_model_runs_with_a_warning():
    wi, wo = hemisphere_geometries((30.0,))  # no rotation: Lafortune's c_y multiplies 0
    (w,) = check_plan("lafortune", wi, wo)
    assert "does not separate lobes[0].c_y (a hemispherical plan would)" in w
    with pytest.raises(PlanError, match="cannot determine the model at all"):
        check_plan("ward", np.repeat(wi[:1], 9, axis=0), np.repeat(wo[:1], 9, axis=0))


def test_finite_turns_every_non_finite_float_into_none():
    got = finite({"a": math.inf, "b": [1.0, np.float64("nan"), (2, -math.inf)], "c": "x"})
    assert got == {"a": None, "b": [1.0, None, [2, None]], "c": "x"}


def test_effect_units_are_readable():
    assert effect_u(0.00204, "1") == "0.204 %"
    assert effect_u(0.00112, "1/h") == "0.112 %/h"
    assert effect_u(0.000269, "rad") == "0.269 mrad"
    assert effect_u(4.28e-06, "rad²") == "(2.07 mrad)²"


def test_a_fit_of_another_family_is_judged_against_its_reference():
    """`--material white_sand --model ward` (Oren-Nayar data, a Ward fit): the parameters
    against the model's best approximation of the truth, and the BRDF-space inadequacy."""
    res = campaign.run(campaign.Plan(**TWO, material="white_sand", model="ward"), workers=1)
    s = res.summary
    ref = s["reference"]
    assert set(ref["params"]) == {"rho_d", "rho_s", "alpha_x", "alpha_y"}
    # with the ideal instrument the fit and its reference differ by noise only
    assert abs(s["fit"]["rho_d"] - ref["params"]["rho_d"]) < s["budget"]["expanded"]["rho_d"]
    assert s["within_expanded"]["rho_d"] is True  # coverage is against the reference
    ina = ref["inadequacy"]["fit"]
    assert 0.05 < ina["rms_relative"] < ina["worst_relative"]  # Ward cannot be Oren-Nayar
    assert "reference: ward's best approximation of the truth (oren_nayar)" in summary_table(s)
    json.dumps(s, allow_nan=False)


def test_the_plan_warnings_are_said_before_any_capture():
    import io

    class _Refusing:  # an instrument that takes nothing: any capture fails the campaign
        def shoot(self, *args):
            raise RuntimeError("no capture")

    buf = io.StringIO()
    with pytest.raises(RuntimeError, match="no capture"):
        campaign.run(campaign.Plan(**TWO, model="lambert+lambert"), quiet=False, stream=buf,
                     instrument=_Refusing())  # fmt: skip
    assert buf.getvalue().startswith("warning: the model's parameters lambert.rho")
