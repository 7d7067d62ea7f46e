"""The LBL design's assurance (gonio.campaign.design_lbl): the fraction of the preset's
physical instruments on which each target is to be met, through the one-sided Student
prediction bound over the design instruments."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from gonio.campaign import design_lbl
from gonio.campaign.design import DesignError

ANGLES, ROTATIONS = (20.0, 40.0, 60.0), (0.0, 90.0)
LEVELS = (0.6, 0.8, 0.95, 0.975, 0.99)


@pytest.fixture(scope="module")
def stacked():
    """Three design instruments from one candidate campaign (rolled brass, three angles, two
    rotations, design instrument 1000): itself, one whose captures carry 0.9 times the
    information and one whose exposure scatter is 1.2 times as large, so that the plans'
    U spread over the instruments."""
    c = design_lbl.lbl_candidates("rolled_brass", angles_deg=ANGLES, rotations_deg=ROTATIONS)
    return [c, dataclasses.replace(c, F=0.9 * c.F), dataclasses.replace(c, ucap=1.2 * c.ucap)]


def test_the_bound_is_the_student_prediction_bound_and_rises_with_the_level(stacked):
    """On every plan of the candidate captures: the U at level P is the mean plus
    t_P,k-1 √(1 + 1/k) times the instruments' standard deviation (t from scipy.stats, not
    the design's special function), at least the mean, and strictly higher at each higher
    level wherever the instruments differ."""
    from scipy import stats

    st = design_lbl._Stack(stacked)
    zero = np.zeros(st.P)
    k, n_plans = len(stacked), 0
    for a in range(1, 8):
        for r in range(1, 4):
            am = np.array([(a >> i) & 1 for i in range(3)], bool)
            rm = np.array([(r >> i) & 1 for i in range(2)], bool)
            U = design_lbl._U_all(st, am, rm, zero)
            m, s = U.mean(axis=0), U.std(axis=0, ddof=1)
            assert np.all(s > 0)  # the three instruments differ on every parameter
            bounds = []
            for p in LEVELS:
                got_m, got = design_lbl._U95(U, p)
                want = m + stats.t.ppf(p, k - 1) * math.sqrt(1 + 1 / k) * s
                np.testing.assert_allclose(got, want, rtol=1e-12)
                np.testing.assert_array_equal(got_m, m)
                assert np.all(got > m)
                bounds.append(got)
            assert np.all(np.diff(bounds, axis=0) > 0)
            n_plans += 1
    assert n_plans == 21


def test_the_design_at_a_higher_level(stacked, tmp_path):
    """The same targets (twice the default plan's U) designed at 0.95 and 0.99: the default
    plan's central prediction is the same, its bound higher at 0.99; each design meets every
    target at its own level, none unreachable; the 0.95 plan's bound at 0.99 misses a
    target, so the 0.99 design takes another plan, no quicker (a plan whose bound at 0.99
    meets a target meets it at 0.95; here one capture at another angle, as long). Each
    records its level, and its plan file and table say it."""
    lo = design_lbl.design_lbl("rolled_brass", default_factor=2.0, candidates=stacked)
    tg = {p: (t, False) for p, t in lo.targets.items()}
    hi = design_lbl.design_lbl("rolled_brass", tg, candidates=stacked, assurance=0.99)
    assert (lo.assurance, hi.assurance) == (design_lbl.ASSURANCE, 0.99) == (0.95, 0.99)
    assert hi.default["predicted"] == lo.default["predicted"]
    for p in lo.targets:
        assert hi.default["predicted_95"][p] > lo.default["predicted_95"][p]
    for r in (lo, hi):
        assert r.not_met == [] and r.unreachable == {}
        for p, t in r.targets.items():
            assert r.predicted[p] < r.predicted_95[p] <= t
    st = design_lbl._Stack(stacked, 0.99)
    am = np.isin(st.c.angles, lo.theta_i_deg)
    rm = np.isin(st.c.rotations, lo.rotations_deg)
    _, lo_at_99 = design_lbl._U95_of(st, am, rm, np.zeros(st.P), lo.restandard_every)
    assert any(u > lo.targets[p] for p, u in zip(st.c.names, lo_at_99))
    assert (hi.theta_i_deg, hi.rotations_deg) != (lo.theta_i_deg, lo.rotations_deg)
    assert hi.hours >= lo.hours
    path = tmp_path / "plan.json"
    design_lbl.write_lbl_plan(path, hi)
    assert json.loads(path.read_text())["assurance"] == 0.99
    assert "U (99 %)" in hi.table() and "U (95 %)" in lo.table()


@pytest.mark.parametrize("bad", [0.5, 1.0, 0.3, 1.2, -0.95, math.nan, math.inf, "high", None,
                                 True])  # fmt: skip
def test_a_bad_level_is_refused_before_any_simulation(bad):
    """Without candidates given, the refusal comes before the candidate campaign."""
    with pytest.raises(DesignError, match=r"assurance .*strictly between 0\.5 and 1"):
        design_lbl.design_lbl("rolled_brass", default_factor=1.25, assurance=bad)


def test_check_assurance_takes_a_fraction():
    assert design_lbl.check_assurance(0.975) == 0.975
    assert design_lbl.check_assurance("0.99") == 0.99
    assert design_lbl.check_assurance(np.float64(0.9)) == 0.9
