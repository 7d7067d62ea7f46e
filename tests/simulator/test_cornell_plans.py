"""The Cornell plan-file reader against hostile files (issue 15)."""

from __future__ import annotations

import numpy as np
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
