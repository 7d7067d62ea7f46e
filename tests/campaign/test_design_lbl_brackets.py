"""The LBL plans' hours from the instrument's own brackets (gonio.campaign.design_lbl,
gonio.simulator.lbl_timing): a campaign keeps the brackets it took, its hours are those of
the frames it wrote, and the design's hours of a plan are those of the plan's campaign on
the design instrument."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from gonio.simulator.lbl_timing import TIMINGS, estimate_run_time

from gonio import campaign
from gonio.campaign import design_lbl
from gonio.campaign.design import DesignError

ANGLES, ROTATIONS = (20.0, 40.0, 60.0), (0.0, 90.0)


@pytest.fixture(scope="module")
def cands():
    """The candidate campaign of rolled brass at three angles and two rotations (modern
    preset, design instrument 1000)."""
    return design_lbl.lbl_candidates("rolled_brass", angles_deg=ANGLES, rotations_deg=ROTATIONS)


def _side_car_brackets(folder, angles, rotations) -> dict:
    """``{(kind, θi, rotation): [(exposure_s, f_number), ...]}`` read from the raw frames'
    side-cars a campaign wrote (what its instrument recorded of each frame)."""
    from gonio.campaign.folder import group_key

    out = {}
    for th in angles:
        for kind, rot in [("standard", None), ("background", None)] + [
            ("measured", r) for r in rotations
        ]:
            key = group_key(th, None if kind != "measured" else rot)
            cars = sorted((folder / "raw" / key).glob(f"{kind}_*.json"))
            metas = [json.loads(c.read_text()) for c in cars]
            out[(kind, th, rot)] = [(m["exposure_s"], m["f_number"]) for m in metas]
    return out


def test_a_plans_hours_are_its_campaigns_own(cands, tmp_path):
    """A plan of some candidate captures (with a re-measured standard), run as its own
    campaign on the design instrument: the brackets it keeps are the frames it wrote, and
    its hours from them are the design's hours of that plan; fewer frames than three a
    capture (rolled brass needs one f-stop for most captures)."""
    angles, rots, every = (20.0, 60.0), (0.0, 90.0), 1
    res = campaign.run(
        campaign.Plan(material="rolled_brass", plots=False, seed=1000, instrument_seed=1000,
                      theta_i_deg=angles, rotations_deg=rots, restandard_every=every),
        tmp_path / "c", workers=1,
    )  # fmt: skip
    written = _side_car_brackets(tmp_path / "c", angles, rots)
    assert res.brackets == written
    assert all(res.brackets[k] == cands.brackets[k] for k in written)  # the same instrument
    t = TIMINGS["modern"]
    own = estimate_run_time(angles, rots, written, t)
    n_anchors = len(rots) * len(angles)  # every angle re-standarded, two swaps each
    assert res.real_instrument_h() == pytest.approx(
        (own["total_s"] + 2 * t.swap_s * n_anchors) / 3600, rel=1e-12
    )
    st = design_lbl._Stack([cands])
    am, rm = np.isin(cands.angles, angles), np.isin(cands.rotations, rots)
    assert st.hours(am, rm, every) == pytest.approx(res.real_instrument_h(), rel=1e-12)
    assert own["n_frames"] < 3 * own["n_captures"]
    three = design_lbl.plan_hours(angles, rots, "modern", every, brackets=3)
    assert res.real_instrument_h() < three


def test_design_hours_are_the_mean_over_design_instruments(cands):
    """The design's hours of every plan (its schedule once, each capture's bracket parts)
    equal the mean of plan_hours over the design instruments' own brackets; a second
    instrument whose 60° captures take two more frames each at other stops lengthens them."""
    slow = {k: (v + [(0.01, 32.0), (0.01, 22.0)] if k[1] == 60.0 else v)
            for k, v in cands.brackets.items()}  # fmt: skip
    cs = [cands, dataclasses.replace(cands, brackets=slow)]
    st = design_lbl._Stack(cs)
    n = 0
    for a in range(1, 8):
        for r in range(1, 4):
            am = np.array([(a >> i) & 1 for i in range(3)], bool)
            rm = np.array([(r >> i) & 1 for i in range(2)], bool)
            for every in (0, 1, 2):
                want = [design_lbl.plan_hours(cands.angles[am], cands.rotations[rm], "modern",
                                              every, brackets=x.brackets) for x in cs]  # fmt: skip
                assert st.hours(am, rm, every) == pytest.approx(np.mean(want), rel=1e-12)
                assert (want[1] > want[0]) == bool(am[2])
                n += 1
    assert n == 63


def test_design_refuses_candidates_without_brackets(cands):
    with pytest.raises(DesignError, match="without the bracket of"):
        design_lbl._Stack([dataclasses.replace(cands, brackets={})])


def test_time_limit_check_before_the_candidates_takes_one_frame_a_capture():
    """No plan is quicker than one angle at one rotation with one frame a capture: a limit
    below it is refused before any simulation, one above it is not."""
    t = TIMINGS["ward1992"]
    one = estimate_run_time([0.0], [0.0], 1, t)["total_s"] / 3600
    assert one < estimate_run_time([0.0], [0.0], 3, t)["total_s"] / 3600
    with pytest.raises(DesignError, match="no plan can meet it"):
        design_lbl._precheck("rolled_brass", {}, "ward1992", one * 0.999)
    design_lbl._precheck("rolled_brass", {}, "ward1992", one * 1.001)


def test_plan_hours_take_the_brackets():
    with pytest.raises(TypeError, match="brackets"):
        design_lbl.plan_hours((20.0,), (0.0,), "modern")  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="no exposures for capture"):
        design_lbl.plan_hours((20.0,), (0.0,), "modern", brackets={})


def test_exchange_swaps_or_drops_an_angle_while_the_objective_falls(cands):
    """Where the forward selection stops short: one angle swapped for another, or dropped,
    while that lowers the objective (a stand-in objective here: the plans' φ given), the
    quicker plan among equals, within the time limit."""
    st = design_lbl._Stack([cands])
    rm = np.ones(2, bool)
    start = np.array([True, True, False])  # 20° and 40°
    phi = {(1, 1, 0): 1.0, (0, 1, 1): 0.0, (1, 0, 1): 0.0, (0, 1, 0): 0.5, (1, 0, 0): 2.0,
           (0, 0, 1): 3.0, (1, 1, 1): 0.7}  # fmt: skip

    def phi_of(m):
        return phi[tuple(int(x) for x in m)]

    got = design_lbl._exchange(st, start, rm, phi_of, np.inf, 0)
    # two swaps reach φ = 0; the quicker of them is chosen
    h = {k: st.hours(np.array(k, bool), rm) for k in ((0, 1, 1), (1, 0, 1))}
    assert tuple(int(x) for x in got) == min(h, key=h.get)
    # a limit below both: the drop (40° alone, φ 0.5) is the best move within it
    lim = min(h.values()) * 0.999
    got = design_lbl._exchange(st, start, rm, phi_of, lim, 0)
    assert tuple(int(x) for x in got) == (0, 1, 0)
    # φ the same everywhere: only a quicker plan is taken (here one angle dropped)
    flat = design_lbl._exchange(st, start, rm, lambda m: 1.0, np.inf, 0)
    assert flat.sum() == 1 and st.hours(flat, rm) < st.hours(start, rm)
    # nothing lowers φ nor the hours: the plan is kept
    one = np.array([True, False, False])
    kept = design_lbl._exchange(st, one, rm, lambda m: 1.0 if m[0] else 2.0, np.inf, 0)
    assert np.array_equal(kept, one)


# -- the bracket's threshold (gonio design --brackets) ------------------------------------------
@pytest.mark.parametrize("bad", [0.0, -4.0, float("nan"), float("inf"), True, "16"])
def test_plan_refuses_a_bad_bracket_threshold(bad):
    with pytest.raises(ValueError, match="bracket_min_signal_dn"):
        campaign.Plan(bracket_min_signal_dn=bad).resolved()


def test_the_threshold_in_the_plan_its_file_and_its_frames(tmp_path):
    """Unset, the plan writes what it wrote before the field (plan.json, the raw groups'
    records); set, it round-trips, a plan file sets it, and the campaign's brackets follow
    it: 64 DN takes more frames than the instrument's own 16, which an explicit 16 repeats."""
    from gonio.campaign.plan import read_plan_file

    assert "bracket_min_signal_dn" not in campaign.Plan().resolved().to_dict()
    p = campaign.Plan(bracket_min_signal_dn=64).resolved()
    assert p.bracket_min_signal_dn == 64.0
    assert campaign.Plan.from_dict(p.to_dict()) == p
    f = tmp_path / "p.json"
    f.write_text('{"instrument": "lbl", "theta_i_deg": [40], "bracket_min_signal_dn": 4}')
    assert read_plan_file(f)["bracket_min_signal_dn"] == 4.0
    f.write_text('{"instrument": "lbl", "theta_i_deg": [40], "bracket_min_signal_dn": "x"}')
    with pytest.raises(ValueError, match="expected a number of DN"):
        read_plan_file(f)
    frames = {}
    for dn in (None, 16.0, 64.0):
        res = campaign.run(
            campaign.Plan(material="rolled_brass", plots=False, theta_i_deg=(20.0, 60.0),
                          rotations_deg=(0.0,), bracket_min_signal_dn=dn), None, workers=1,
        )  # fmt: skip
        frames[dn] = res.brackets
    assert frames[16.0] == frames[None]
    n = {dn: sum(len(v) for v in b.values()) for dn, b in frames.items()}
    assert n[64.0] > n[16.0]


@pytest.fixture(scope="module")
def cands_by_dn(cands):
    """The candidate campaign of :func:`cands` at the thresholds ``brackets=True`` tries."""
    out = {16.0: [cands]}
    for dn in (4.0, 64.0):
        c = design_lbl.lbl_candidates(
            "rolled_brass", angles_deg=ANGLES, rotations_deg=ROTATIONS, min_signal_dn=dn
        )
        out[dn] = [c]
    return out


def test_bracket_search_tries_the_next_threshold(cands_by_dn, tmp_path):
    """Targets the 16 DN design meets: 4 DN is tried (fewer frames) with its own candidate
    campaign, the plan that misses fewer targets then the quicker is chosen, and its plan
    file carries the threshold."""
    from gonio.campaign.plan import read_plan_file

    r = design_lbl.design_lbl("rolled_brass", default_factor=1.5, candidates=cands_by_dn,
                              brackets=True)  # fmt: skip
    assert set(r.brackets_tried) == {"16", "4"}
    t16, t4 = r.brackets_tried["16"], r.brackets_tried["4"]
    score = {dn: (len(t["not_met"]) + len(t["unreachable"]), t["hours"]) for dn, t in
             (("16", t16), ("4", t4))}  # fmt: skip
    chosen = "4" if score["4"] < score["16"] else "16"
    assert r.bracket_min_signal_dn == (4.0 if chosen == "4" else None)
    assert r.hours == pytest.approx(r.brackets_tried[chosen]["hours"])
    path = tmp_path / "plan.json"
    design_lbl.write_lbl_plan(path, r)
    kw = read_plan_file(path)
    assert kw.get("bracket_min_signal_dn") == r.bracket_min_signal_dn


def test_a_thresholds_prediction_is_its_campaigns(cands_by_dn):
    """A plan of some candidate captures at 4 and 64 DN, run as its own campaign on the
    design instrument at that threshold: the brackets differ from the 16 DN ones, and the
    U (1 %) and hours are those predicted from that threshold's candidate campaign."""
    angles, rots = (20.0, 60.0), (0.0,)
    am, rm = np.isin(ANGLES, angles), np.isin(ROTATIONS, rots)
    for dn in (4.0, 64.0):
        c = cands_by_dn[dn][0]
        res = campaign.run(
            campaign.Plan(material="rolled_brass", plots=False, seed=1000, instrument_seed=1000,
                          theta_i_deg=angles, rotations_deg=rots, bracket_min_signal_dn=dn),
            None, workers=1,
        )  # fmt: skip
        assert res.brackets == {k: v for k, v in c.brackets.items() if k in res.brackets}
        assert (
            res.brackets[("measured", 60.0, 0.0)]
            != cands_by_dn[16.0][0].brackets[("measured", 60.0, 0.0)]
        )
        pred = 2 * np.sqrt(design_lbl._u2(c, am, rm, np.zeros(len(c.names))))
        got = [res.summary["budget"]["expanded"][p] for p in c.names]
        np.testing.assert_allclose(got, pred, rtol=0.01)
        h = design_lbl._Stack([c]).hours(am, rm)
        assert res.real_instrument_h() == pytest.approx(h, rel=1e-12)


def test_bracket_search_refuses_mismatched_candidates(cands, cands_by_dn):
    with pytest.raises(DesignError, match="go with brackets=True"):
        design_lbl.design_lbl("rolled_brass", default_factor=1.5, candidates=cands_by_dn)
    with pytest.raises(DesignError, match="go with brackets=True"):
        design_lbl.design_lbl("rolled_brass", default_factor=1.5, candidates=[cands],
                              brackets=True)  # fmt: skip
    with pytest.raises(DesignError, match="no candidate sets at the bracket threshold 4 DN"):
        design_lbl.design_lbl("rolled_brass", default_factor=1.5, candidates={16.0: [cands]},
                              brackets=True)  # fmt: skip


def test_bracket_search_tries_64_dn_where_a_reachable_target_is_missed(cands_by_dn):
    """A 16 DN design that misses a target it chased: 64 DN is tried (more frames), with the
    same targets; the plan that misses fewer targets wins even if slower."""
    d16 = design_lbl.design_lbl(
        "rolled_brass", default_factor=1.5, candidates=[cands_by_dn[16.0][0]]
    )
    missed = dataclasses.replace(d16, not_met=["alpha_x"])
    calls = []

    def sets(dn):
        calls.append(dn)
        return cands_by_dn[dn]

    r = design_lbl._design_brackets(missed, sets, None, 0.0, 0.0)
    assert calls == [64.0] and set(r.brackets_tried) == {"16", "64"}
    assert r.brackets_tried["16"]["not_met"] == ["alpha_x"]
    t64 = r.brackets_tried["64"]
    # (here 64 DN meets every target: chosen, though slower than the 16 DN plan)
    assert (
        not t64["not_met"]
        and not t64["unreachable"]
        and t64["hours"] > r.brackets_tried["16"]["hours"]
    )
    assert r.bracket_min_signal_dn == 64.0 and r.theta_i_deg == tuple(t64["theta_i_deg"])
    assert r.targets == d16.targets and r.default == d16.default
