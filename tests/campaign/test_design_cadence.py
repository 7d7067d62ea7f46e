"""Tests of the Cornell design's reference cadence (gonio.campaign.design): the lamp term
predicted before any reference against the one a campaign's budget evaluates from its own
references, the cadence the design picks, and the cadence in the plan file."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

import numpy as np
import pytest

from gonio.campaign import design as d


def _lamp_preset(factor: float):
    """cornell2005 with the lamp's warm-up and drift (typical and spread) times ``factor``."""
    from gonio.simulator.cornell_effects import PRESETS

    out = dict(PRESETS["cornell2005"])
    for k in ("lamp_warmup", "lamp_drift"):
        out[k] = dataclasses.replace(out[k], typical=out[k].typical * factor,
                                     spread=out[k].spread * factor)  # fmt: skip
    return out


@pytest.mark.parametrize("every", [10, 0])
def test_predicted_lamp_term_against_campaigns(every):
    """The default plan's first 80 geometries on instruments 0-2 with a lamp 5 times less
    stable than cornell2005's: the budget's lamp term (the references' leave-one-out
    residual; with none, the data sheet's over the campaign's hours) against the design's
    prediction from the laboratory's knowledge (RMS over the instruments within a factor
    1.5; measured with the whole plan on instruments 0-4: predicted / campaign 1.00-1.17,
    benchmarks/bench_design.py --lamp-table)."""
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_effects import lab_knowledge

    from gonio.campaign.cornell import _check_corrections, run_cornell_campaign
    from gonio.campaign.cornell_budget import _lamp_u

    preset = _lamp_preset(5.0)
    kn = lab_knowledge(preset)
    lab = CornellConfig().lab_view()
    plan = d.default_cornell_plan(lab, kn)
    plan = plan.subset(np.arange(80))
    truth, *_ = d._fitted("garnet_red_paint", None)
    _v, _s, t_int, ref = d._predicted_readings(truth, plan, lab, kn)
    corr = _check_corrections(None)
    pred, hours = d.plan_schedule(lab, plan, t_int, ref, every, kn, corr)
    got = []
    for seed in range(3):
        s = run_cornell_campaign("garnet_red_paint", plan=plan, seed=seed, effects=preset,
                                 reference_every=every, budget=False, fit=False)  # fmt: skip
        got.append(_lamp_u(s, kn, corr, every))
        assert s["estimated_real_instrument_h"] == pytest.approx(s["campaign_clock_h"], rel=1e-9)
    rms = math.sqrt(np.mean(np.square(got)))
    if every:
        assert len(s["reference_drift"]) == 9
        assert 1 / 1.5 < pred / rms < 1.5, (pred, rms)
    else:  # the same formula over the predicted hours (the campaign's clock)
        assert pred == pytest.approx(rms, rel=0.02)
        assert hours == pytest.approx(s["campaign_clock_h"], rel=0.05)


def test_reference_times_follow_the_campaign_clock():
    g = np.array([10.0, 20.0, 30.0, 40.0, 50.0])
    np.testing.assert_allclose(d.reference_times(g, 2, 5.0), [0, 35, 110, 165])
    np.testing.assert_allclose(d.reference_times(g, 0, 5.0), [0])
    np.testing.assert_allclose(d.reference_times(g, 5, 5.0), [0, 155])


def test_predicted_lamp_term_limits():
    """No lamp knowledge: 0; fewer than three references: the data sheet's (w + d h)/√3; the
    warm-up's curvature shrinks with a denser cadence; a drift-free lamp with a perfect
    reference: the linear interpolation leaves nothing of a pure drift."""
    g = np.full(200, 20.0)
    assert d.predicted_lamp_u({}, g, 10, 60.0) == 0.0
    kn = {"lamp_warmup": (0.005, 0.002), "lamp_drift": (0.001, 0.0005)}
    h = (200 * 20.0 + 60.0) / 3600.0
    expect = (math.hypot(0.005, 0.002) + math.hypot(0.001, 0.0005) * h) / math.sqrt(3)
    assert d.predicted_lamp_u(kn, g, 200, 60.0) == pytest.approx(expect)
    u = [d.predicted_lamp_u(kn, g, n, 60.0) for n in (80, 40, 10, 4)]
    assert all(a > b for a, b in itertools.pairwise(u))
    assert d.predicted_lamp_u({"lamp_drift": (0.01, 0.0)}, g, 10, 60.0) == pytest.approx(
        0.0, abs=1e-15
    )
    assert d.predicted_lamp_u(kn, g, 10, 60.0, drift_correction=False) == pytest.approx(
        (math.hypot(0.005, 0.002) + math.hypot(0.001, 0.0005) * (200 * 20 + 20 * 60) / 3600)
        / math.sqrt(3)
    )


@pytest.fixture(scope="module")
def cands_unstable():
    """Small candidate sets (3 x 3 directions per incidence angle and the incidence plane)
    on cornell2005 and on it with a lamp 5 times less stable."""
    return d.cornell_candidates("garnet_red_paint", n_grid=3, preset=_lamp_preset(5.0))


def test_design_re_references_only_an_unstable_lamp(cands_unstable):
    """k_dd at 2 %: the unstable lamp's data-sheet term alone (u 1.6 %) puts the target out
    of reach without references; the design measures the reference again (and predicts the
    targets met); with tau at 5 % only, the stable default lamp needs none."""
    tg = d.parse_targets(["tau=5%", "k_dd=2%"])
    r = d.design_cornell("garnet_red_paint", tg, candidates=cands_unstable,
                         preset=_lamp_preset(5.0), compare_default=False)  # fmt: skip
    assert r.reference_every > 0
    assert r.meta["cadences_tried"][0]["reference_every"] == 0
    assert r.meta["cadences_tried"][0]["targets_missed"] > 0
    assert all(r.predicted[p]["U"] <= t for p, t in r.targets.items())
    assert r.meta["lamp_u"] < 0.005
    assert "every" in r.table()
    # the references' time is in the hours: the same plan without them is quicker
    _pred, h0 = d.predict_cornell(cands_unstable, r.plan, 0, 0)
    assert r.hours > h0


def test_design_keeps_the_first_reference_only_on_the_default_lamp():
    c = d.cornell_candidates("garnet_red_paint", n_grid=3)
    r = d.design_cornell("garnet_red_paint", d.parse_targets(["tau=5%"]), candidates=c,
                         compare_default=False)  # fmt: skip
    assert r.reference_every == 0
    assert [t["reference_every"] for t in r.meta["cadences_tried"]] == [0]
    assert "first reference only" in r.table()


def _plan_with_header(tmp_path, value) -> str:
    from gonio.campaign.cornell import PLAN_HEADER

    head = {"material": "garnet_red_paint", "reference_every": value}
    rows = ["theta_i,phi_i,theta_o,phi_o"] + [f"{ti},0,{to},180" for ti in (20, 40, 60)
                                              for to in (10, 30, 50)]  # fmt: skip
    path = tmp_path / "plan.csv"
    path.write_text(f"{PLAN_HEADER} {json.dumps(head)}\n" + "\n".join(rows) + "\n")
    return str(path)


def test_plan_file_carries_the_cadence(cands_unstable, tmp_path):
    """The designed cadence written, read back as ``gonio campaign --plan`` reads it and
    applied by the campaign (its plan.json); an explicit other cadence is refused."""
    from gonio.campaign.cornell import plan_file_reference_every, run_cornell_campaign

    r = d.design_cornell("garnet_red_paint", d.parse_targets(["tau=5%", "k_dd=2%"]),
                         candidates=cands_unstable, preset=_lamp_preset(5.0),
                         compare_default=False)  # fmt: skip
    path = tmp_path / "designed.csv"
    d.write_cornell_plan(path, r)
    assert plan_file_reference_every(path) == r.reference_every > 0
    out = tmp_path / "run"
    s = run_cornell_campaign("garnet_red_paint", plan=str(path), out=out, fit=False,
                             budget=False)  # fmt: skip
    assert json.loads((out / "plan.json").read_text())["reference_every"] == r.reference_every
    assert s["n_references"] == 1 + -(-len(r.plan) // r.reference_every)
    with pytest.raises(ValueError, match="plan file's reference_every"):
        run_cornell_campaign("garnet_red_paint", plan=str(path), reference_every=7, fit=False)
    # without the field (or with the text earlier versions wrote): the campaign's default
    for v in (None, "the campaign's (not designed)"):
        assert plan_file_reference_every(_plan_with_header(tmp_path, v)) is None


@pytest.mark.parametrize("bad", [-1, 2.5, "4", True, [4]])
def test_bad_cadence_in_a_plan_file_is_refused_nothing_written(tmp_path, bad):
    from gonio.campaign.cornell import run_cornell_campaign

    path = _plan_with_header(tmp_path, bad)
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=r"reference_every = .* expected an integer >= 0"):
        run_cornell_campaign("garnet_red_paint", plan=path, out=out)
    assert not out.exists()


def test_plan_file_header_that_is_not_json_is_refused(tmp_path):
    from gonio.campaign.cornell import PLAN_HEADER, plan_file_reference_every

    path = tmp_path / "plan.csv"
    path.write_text(f"{PLAN_HEADER} {{reference_every: 4\ntheta_i,phi_i,theta_o,phi_o\n")
    with pytest.raises(ValueError, match="not a JSON object"):
        plan_file_reference_every(path)
