"""Tests of gonio.campaign.design: the inputs, the search's rank updates against the
information matrix built again, the designed plan's prediction against its targets, floors,
the time limit and the plan file."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.campaign import design as d


@pytest.fixture(scope="module")
def cands():
    """A small candidate set (3 x 3 viewing directions per incidence angle and the incidence
    plane) of garnet red paint on the cornell2005 instrument as the laboratory knows it."""
    return d.cornell_candidates("garnet_red_paint", n_grid=3)


# -- inputs -----------------------------------------------------------------------------------
def test_parse_targets():
    t = d.parse_targets(["k_fs=5%", "tau=0.01", "k_dd[3]=2%"])
    assert t == {"k_fs": (0.05, True), "tau": (0.01, False), "k_dd[3]": (0.02, True)}
    assert d.parse_targets(None) == {"all": (0.05, True)}


@pytest.mark.parametrize("bad", ["tau=0", "tau=-1%", "tau=nan", "tau", "tau=abc", "=5%"])
def test_parse_targets_rejects(bad):
    with pytest.raises(d.DesignError, match="target"):
        d.parse_targets([bad])


@pytest.mark.parametrize("bad", ["tau=9:7", "tau", "tau=a:b", "tau=1:inf"])
def test_parse_prior_rejects(bad):
    with pytest.raises(d.DesignError, match="prior"):
        d.parse_prior([bad])


def test_bad_input_is_refused_before_any_simulation():
    with pytest.raises(d.DesignError, match="'alpha_x' is not a fitted parameter"):
        d.design_cornell("garnet_red_paint", d.parse_targets(["alpha_x=1%"]))
    with pytest.raises(d.DesignError, match="outside the model's bounds"):
        d.design_cornell("garnet_red_paint", prior=d.parse_prior(["tau=0:9"]))
    with pytest.raises(d.DesignError, match="not a fitted shape parameter"):
        d.design_cornell("garnet_red_paint", prior=d.parse_prior(["sigma=0.5:0.9"]))
    with pytest.raises(d.DesignError, match="positive number of hours"):
        d.design_cornell("garnet_red_paint", time_limit_h=0.0)
    with pytest.raises(d.DesignError, match="mirror part"):
        d.design_cornell("aluminized_non_glare_glass")


# -- the search's rank updates ----------------------------------------------------------------
def test_woodbury_update_equals_the_rebuilt_information_matrix(cands):
    """u2_with (rank-31 updates on the block structure) against adding each candidate to
    the dense information matrix and inverting it again."""
    s = d._State(cands, 0, np.full(len(cands.names), 1e-4))
    s.add(np.arange(0, len(cands.plan), 5))
    probe = np.array([1, len(cands.plan) // 2, len(cands.plan) - 2])
    fast = s.u2_with(probe)
    for row, j in zip(fast, probe):
        s.add(np.array([j]))
        slow = s.u2()
        s.remove(np.array([j]))
        np.testing.assert_allclose(row, slow, rtol=1e-9)


def test_state_matches_the_budgets_jacobian(cands):
    """The search's statistical term (its block rows) equals the inverse of Jᵀ W J from the
    budget's own Jacobian over the same geometries."""
    from gonio.simulator.cornell import forward

    from gonio.campaign import cornell_budget as cb

    sel = np.arange(0, len(cands.plan), 3)
    s = d._State(cands, 0, np.zeros(len(cands.names)))
    s.add(sel)
    s.B[:] = 0.0
    wi, wo = forward(cands.plan.angles[sel], cands.lab.kinematics)
    jac = cb._jacobian(cands.model, cands.names, wi, wo, 31) / cands.sigma[sel].reshape(-1, 1)
    np.testing.assert_allclose(s.u2(), np.diag(np.linalg.inv(jac.T @ jac)), rtol=1e-8)


# -- designs ----------------------------------------------------------------------------------
def test_design_meets_its_targets_as_the_budget_predicts(cands):
    tg = d.parse_targets(["tau=2%", "k_dd=5%", "k_fs=10%"])
    r = d.design_cornell("garnet_red_paint", tg, candidates=cands)
    assert set(r.targets) == {p for p in cands.names if not p.startswith("k_uds")}
    for p, t in r.targets.items():
        assert r.predicted[p]["U"] <= t, p
    assert r.meta["not_met"] == []
    # the predicted U is the budget's (predict_cornell: cornell_budget on the predicted
    # readings of the ordered plan)
    pred, hours = d.predict_cornell(cands, r.plan, 0)
    assert pred["k_fs[15]"]["U"] == pytest.approx(r.predicted["k_fs[15]"]["U"])
    assert hours == pytest.approx(r.hours)
    # and less than the default plan needs: its k_fs misses 10 % (the sample's tilt)
    assert r.default["predicted"]["k_fs[15]"]["U"] > r.targets["k_fs[15]"]
    assert r.hours < r.default["hours"]


def test_target_below_the_floor_is_reported_not_chased(cands):
    """k_uds = 1e-6 absolute lies below the reference's noise (a scale error of every band,
    |k| x its relative error) where k_uds > 0: unreachable, with its floor and dominant term."""
    tg = d.parse_targets(["k_uds[20]=1e-6", "tau=5%"])
    r = d.design_cornell("garnet_red_paint", tg, candidates=cands)
    u = r.unreachable["k_uds[20]"]
    assert u["floor"] > u["target"] and u["dominant"] == "reference_noise"
    assert r.predicted["tau"]["U"] <= r.targets["tau"]
    assert "unreachable" in r.table()


def test_time_limit_no_plan_can_meet(cands):
    with pytest.raises(d.DesignError, match="no plan can meet it"):
        d.design_cornell("garnet_red_paint", candidates=cands, time_limit_h=1e-4)


def test_plan_file_round_trip(cands, tmp_path):
    """The written plan, read back the way ``gonio campaign --plan`` reads it, holds the
    designed motor positions."""
    from gonio.campaign.cornell import build_plan

    r = d.design_cornell("garnet_red_paint", d.parse_targets(["tau=5%"]), candidates=cands)
    path = tmp_path / "plan.csv"
    d.write_cornell_plan(path, r)
    back = build_plan(str(path), config=cands.lab)
    a = np.sort(np.round(np.degrees(back.angles), 3), axis=0)
    b = np.sort(np.round(np.degrees(r.plan.angles), 3), axis=0)
    np.testing.assert_allclose(a, b, atol=2e-3)
    assert len(back) == len(r.plan)


# -- LBL --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lbl_cands():
    """A small candidate campaign: rolled brass, three angles, two rotations (modern preset)."""
    from gonio.campaign import design_lbl

    return design_lbl.lbl_candidates(
        "rolled_brass", angles_deg=(20.0, 40.0, 60.0), rotations_deg=(0.0, 90.0)
    )


def test_lbl_full_candidate_set_is_the_campaigns_budget(lbl_cands):
    """The budget decomposed by capture and summed again over every capture equals the
    candidate campaign's own budget (gonio.campaign.budget.build_budget)."""
    from gonio.campaign import design_lbl

    c = lbl_cands
    full = design_lbl._u2(c, np.ones(3, bool), np.ones(2, bool), np.zeros(len(c.names)))
    assert np.all(np.isfinite(full)) and np.all(full > 0)
    np.testing.assert_allclose(2 * np.sqrt(full), [c.expanded[p] for p in c.names], rtol=1e-6)


def test_lbl_design_meets_the_default_u_and_writes_a_plan_file(lbl_cands, tmp_path):
    import json

    from gonio.campaign import design_lbl
    from gonio.campaign.plan import read_plan_file

    r = design_lbl.design_lbl("rolled_brass", candidates=lbl_cands, default_factor=1.5)
    assert r.not_met == [] and r.unreachable == {}
    for p, t in r.targets.items():
        assert r.predicted[p] <= r.predicted_95[p] <= t
    assert r.hours <= r.default["hours"]
    path = tmp_path / "plan.json"
    design_lbl.write_lbl_plan(path, r)
    kw = read_plan_file(path)
    assert kw["theta_i_deg"] == r.theta_i_deg and kw["rotations_deg"] == r.rotations_deg
    assert kw["restandard_every"] == r.restandard_every
    cadence = json.loads(path.read_text())["cadence"]
    assert cadence["restandard_every"] == r.restandard_every and "0" in cadence["tried"]


@pytest.mark.parametrize(
    ("angles", "rotations", "every"), [((20.0, 60.0), (0.0,), 0), ((20.0, 40.0), (0.0, 90.0), 1)]
)
def test_lbl_subset_prediction_is_the_subset_campaigns_budget(lbl_cands, angles, rotations,
                                                              every):  # fmt: skip
    """A plan of some of the candidate captures (and a re-standard cadence), run as its own
    campaign on the design instrument: its budget's U is the prediction (the plan's own
    brackets' exposure u, f-stop table u, lamp schedule and anchors, fit's χ²/dof)."""
    from gonio import campaign
    from gonio.campaign import design_lbl

    c = lbl_cands
    am, rm = np.isin(c.angles, angles), np.isin(c.rotations, rotations)
    pred = 2 * np.sqrt(design_lbl._u2(c, am, rm, np.zeros(len(c.names)), every))
    res = campaign.run(
        campaign.Plan(material="rolled_brass", plots=False, seed=1000, instrument_seed=1000,
                      theta_i_deg=angles, rotations_deg=rotations, restandard_every=every),
        None, workers=1,
    )  # fmt: skip
    got = [res.summary["budget"]["expanded"][p] for p in c.names]
    np.testing.assert_allclose(got, pred, rtol=0.01)


def test_lbl_a_drifting_lamp_gets_a_denser_cadence(lbl_cands):
    """The same targets on an instrument whose lamp is specified to warm up and drift 30
    times as much: the design re-measures the standard (the lamp's terms left by the
    interpolation between anchors against two swaps each); the stable lamp's does not."""
    import dataclasses

    from gonio.campaign import design_lbl

    c = lbl_cands
    stable = design_lbl.design_lbl("rolled_brass", candidates=c, default_factor=1.5)
    tg = {p: (t, False) for p, t in stable.targets.items()}
    lamp = {k: 30.0 * v for k, v in c.u_lamp.items()}
    drifting = design_lbl.design_lbl(
        "rolled_brass", tg, candidates=dataclasses.replace(c, u_lamp=lamp)
    )
    assert stable.restandard_every == 0
    assert drifting.restandard_every > 0 and drifting.not_met == []
    # its cadence is what meets the targets: without one they are missed
    assert not drifting.cadence["0"]["targets_met"]
    assert drifting.hours > stable.hours


def test_lbl_candidate_sets_on_two_processes_and_the_stacked_prediction():
    """The candidate campaigns of two design instruments on two forked processes (after the
    warm-up) give the arrays they give one after the other here; the prediction made on
    both instruments at once (design_lbl._Stack) is each instrument's own."""
    from gonio.campaign import design_lbl

    one = design_lbl.candidate_sets("rolled_brass", [None, None], angles_deg=(20.0, 60.0),
                                    workers=1)  # fmt: skip
    two = design_lbl.candidate_sets("rolled_brass", [None, None], angles_deg=(20.0, 60.0),
                                    workers=2)  # fmt: skip
    for a, b in zip(one, two, strict=True):
        for name in ("F", "B", "S", "chi2", "jr", "tab2", "ucap"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(one[0].F, one[1].F)  # two instruments
    am, rm, zero = np.ones(2, bool), np.array([True, False, True]), np.zeros(len(one[0].names))
    both = design_lbl._Stack(one).u2(am, rm, zero, 1)
    for k, c in enumerate(one):
        np.testing.assert_allclose(both[k], design_lbl._u2(c, am, rm, zero, 1), rtol=1e-12)


def test_lbl_bad_input_before_the_candidate_campaign():
    from gonio.campaign import design_lbl

    with pytest.raises(d.DesignError, match="'alpha_q' is not a parameter of ward"):
        design_lbl.design_lbl("rolled_brass", d.parse_targets(["alpha_q=1%"]))
    with pytest.raises(d.DesignError, match="no plan can meet it"):
        design_lbl.design_lbl("rolled_brass", time_limit_h=1e-4)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[1, 2]", "expected a JSON object with instrument 'lbl'"),
        ('{"instrument": "cornell", "theta_i_deg": [10]}', "instrument 'lbl'"),
        ('{"rotations_deg": [0]}', "missing theta_i_deg"),
        ('{"theta_i_deg": []}', "expected a list of numbers"),
        ('{"theta_i_deg": [10, "x"]}', "expected a list of numbers"),
        ('{"theta_i_deg": [10], "restandard_every": 1.5}', "expected an integer"),
        ("{not json", "not JSON"),
    ],
)
def test_lbl_plan_file_rejects(tmp_path, text, message):
    from gonio.campaign.plan import read_plan_file

    p = tmp_path / "p.json"
    p.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_plan_file(p)


# -- adaptive ---------------------------------------------------------------------------------
def test_adaptive_refuses_a_bad_target_before_the_pilot(tmp_path):
    from gonio.campaign.design_adaptive import adaptive_cornell

    with pytest.raises(d.DesignError, match="'alpha_x' is not a fitted parameter"):
        adaptive_cornell("garnet_red_paint", d.parse_targets(["alpha_x=1%"]), tmp_path / "a")
    assert not (tmp_path / "a").exists()


@pytest.mark.slow
def test_adaptive_campaign_stages(tmp_path):
    """Pilot, design from the pilot's fit (not the preset's values), main campaign: each
    stage's time in the summary, the main campaign's achieved U as the design predicted."""
    import json

    from gonio.campaign.design_adaptive import adaptive_cornell

    # the design's candidates at two incidence angles (3 x 3 viewing directions each): what is
    # checked (the prior from the pilot, the stages, achieved U against predicted) does not
    # depend on how many candidates there are; the pilot's plan is the campaign's own
    s = adaptive_cornell(
        "garnet_red_paint", d.parse_targets(["tau=2%", "k_dd=5%"]), tmp_path / "a", n_grid=3,
        theta_i_deg=(30, 60),
    )  # fmt: skip
    st = s["stages"]
    assert st["pilot"]["n_geometries"] == 21 and st["pilot"]["real_instrument_h"] > 0
    assert st["main"]["n_geometries"] == st["design"]["n_geometries"]
    lo, hi = st["design"]["prior"]["tau"]
    assert lo < 8.2 < hi and hi - lo < 1.0  # the pilot's estimate and its U, not a guess
    for p, f in s["final"].items():
        assert abs(f["achieved_U"] / f["predicted_U"] - 1) < 0.25, p
    assert json.loads((tmp_path / "a" / "adaptive.json").read_text())["n_met"] == s["n_met"]


def test_lbl_adaptive_campaign_stages(tmp_path):
    """The LBL adaptive campaign: pilot, design from the pilot's fit (its estimate, not the
    preset's values), the designed plan; each stage's hours and the final U in the summary."""
    import json

    from gonio.campaign.design_adaptive import LBL_PILOT_ANGLES, adaptive_lbl, adaptive_lbl_text
    from gonio.campaign.plan import read_plan_file

    s = adaptive_lbl("rolled_brass", d.parse_targets(["all=5%"]), tmp_path / "a",
                     n_instruments=1, candidate_angles_deg=(20.0, 40.0, 60.0),
                     assurance=0.9)  # fmt: skip
    st = s["stages"]
    assert st["design"]["assurance"] == 0.9
    assert "(90 %: " in adaptive_lbl_text(s) and "(95 %: " not in adaptive_lbl_text(s)
    assert st["pilot"]["n_angles"] == len(LBL_PILOT_ANGLES) and st["pilot"]["n_rotations"] == 2
    assert st["pilot"]["real_instrument_h"] > 0 and st["main"]["real_instrument_h"] > 0
    assert s["real_instrument_h"] == pytest.approx(
        st["pilot"]["real_instrument_h"] + st["main"]["real_instrument_h"]
    )
    prior = st["design"]["prior"][0]
    pilot = json.loads((tmp_path / "a" / "pilot" / "summary.json").read_text())["fit"]
    assert prior["alpha_x"] == pytest.approx(pilot["alpha_x"]) and prior["alpha_x"] != 0.05
    plan = read_plan_file(tmp_path / "a" / "designed_plan.json")
    main = json.loads((tmp_path / "a" / "main" / "plan.json").read_text())
    assert tuple(main["theta_i_deg"]) == plan["theta_i_deg"]
    assert main["restandard_every"] == plan["restandard_every"]
    assert json.loads((tmp_path / "a" / "designed_plan.json").read_text())["assurance"] == 0.9
    assert set(s["final"]) == {"rho_d", "rho_s", "alpha_x", "alpha_y"}
    for p, f in s["final"].items():
        assert f["met"] == (f["achieved_U"] <= f["target"]) and f["achieved_U"] > 0, p
    assert json.loads((tmp_path / "a" / "adaptive.json").read_text())["n_met"] == s["n_met"]


def test_lbl_adaptive_refuses_a_bad_target_before_the_pilot(tmp_path):
    from gonio.campaign.design_adaptive import adaptive_lbl

    with pytest.raises(d.DesignError, match="'tau' is not a parameter of ward"):
        adaptive_lbl("rolled_brass", d.parse_targets(["tau=1%"]), tmp_path / "a")
    with pytest.raises(d.DesignError, match="n_instruments 11"):
        adaptive_lbl("rolled_brass", None, tmp_path / "a", n_instruments=11)
    with pytest.raises(d.DesignError, match=r"assurance 1\.0: expected a fraction"):
        adaptive_lbl("rolled_brass", None, tmp_path / "a", assurance=1.0)
    assert not (tmp_path / "a").exists()
