"""The Cornell plan-file reader against hostile files (issue 15)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.simulator.cornell_plans import read_plan_csv
from hypothesis import given, settings
from hypothesis import strategies as st

GOOD = "theta_i,phi_i,theta_o,phi_o\n30,0,30,180\n30,0,45,170\n50,0,20,90\n"


def test_byte_order_mark_and_comments(tmp_path):
    p = tmp_path / "p.csv"
    p.write_bytes("\ufeff# a plan\n".encode() + GOOD.encode())
    assert len(read_plan_csv(p).angles) == 3


_MUTATIONS = st.lists(
    st.tuples(st.integers(0, len(GOOD) - 1), st.sampled_from(
        ["", ",", "\n", "#", "nan", "inf", "-", "1e999", "9", ".", "\ufeff", "\x00", "\"", "91"]
    )), min_size=1, max_size=6,
)  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(edits=_MUTATIONS, raw=st.binary(max_size=6))
def test_mutated_plans_give_a_plan_or_a_value_error(write_mutated, edits, raw):
    p = write_mutated(GOOD, edits, raw)
    try:
        plan = read_plan_csv(p)
    except ValueError:
        return
    assert np.isfinite(plan.angles).all()


def test_run_time_estimate_carries_its_uncertainty():
    from gonio.simulator.cornell_plans import (
        Timing,
        estimate_run_time,
        hemispherical_plan,
        order_plan,
    )

    p = order_plan(hemispherical_plan(n=5))
    t_int = np.full(len(p.measurable()), 2.0)
    e = estimate_run_time(p, Timing(), t_int)
    # integration and overheads scale directly with their relative uncertainties; the moves
    # by the change of the move time when the stages run 20 % faster
    faster = Timing(speeds=tuple(1.2 * np.asarray(Timing().speeds)),
                    acceleration=tuple(1.2 * np.asarray(Timing().acceleration)))  # fmt: skip
    du_move = e["move_s"] - estimate_run_time(p, faster, t_int)["move_s"]
    expect = np.sqrt(du_move**2 + (0.3 * e["overhead_s"]) ** 2 + (0.3 * e["integration_s"]) ** 2)
    assert 0 < du_move < e["move_s"]
    np.testing.assert_allclose(e["total_u_h"] * 3600.0, expect, rtol=1e-12)
    assert 0.1 * e["total_h"] < e["total_u_h"] < 0.5 * e["total_h"]
    exact = estimate_run_time(p, Timing(speed_u=0.0, overhead_u=0.0, integration_u=0.0), t_int)
    assert exact["total_u_h"] == 0.0 and exact["total_h"] == e["total_h"]
    with pytest.raises(ValueError, match=r"Timing\.speed_u = 1\.5"):
        Timing(speed_u=1.5)


@pytest.mark.parametrize("every", [0, 3, 4, 100])
def test_run_time_estimate_with_references_is_the_lamp_clock(every):
    """The campaign's recorded estimate (``estimate_run_time`` with ``reference_every``) ends
    where its lamp clock ends (references after every N-th geometry and after the last, each
    ``reference_seconds`` long); the references add their count times that time."""
    from gonio.simulator.cornell import CornellConfig, simulate_campaign
    from gonio.simulator.cornell_effects import realise
    from gonio.simulator.cornell_plans import (
        Timing,
        estimate_run_time,
        incidence_plane_plan,
        n_rereferences,
        order_plan,
        reference_seconds,
    )

    plan = order_plan(incidence_plane_plan((30, 60), coarse_step_deg=15.0, fine_step_deg=5.0))
    n = len(plan)
    cfg = CornellConfig(effects=realise("cornell2005", 0))
    refs: list = []
    s = simulate_campaign(plan, "garnet_red_paint", config=cfg, order=False,
                          reference_every=every, references=refs)  # fmt: skip
    m = s.metadata
    assert len(refs) == 1 + n_rereferences(n, every) == 1 + (0 if every == 0 else -(-n // every))
    assert m["estimated_run_time_h"] == pytest.approx(m["campaign_clock_h"], rel=1e-12)
    if every:  # the clock's last reference is the campaign's end
        assert refs[-1][0] / 3600.0 == pytest.approx(m["campaign_clock_h"], rel=1e-12)
    t_ref = reference_seconds(Timing(), refs[0][1].meta["t"], cfg.n_reference_reads)
    with_refs = estimate_run_time(plan, reference_every=every, reference_s=t_ref)
    no_refs = estimate_run_time(plan)
    assert with_refs["n_references"] == len(refs) - 1
    assert with_refs["total_s"] - no_refs["total_s"] == pytest.approx((len(refs) - 1) * t_ref)


def test_reference_seconds_counts_moves_and_reads():
    from gonio.simulator.cornell_plans import Timing, reference_seconds

    tm = Timing()
    move = float(tm.move_time(np.radians([[90.0, 90.0, 90.0]]))[0])
    assert reference_seconds(tm, 0.5, 16) == pytest.approx(2 * move + 16 * 4 * 0.65)
    assert reference_seconds(tm, 0.5, 1) < reference_seconds(tm, 0.5, 2)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="integration_s"):
            reference_seconds(tm, bad)
