"""Bracket planning kernel: the branch-free count equals testing every stop."""

import numpy as np
from gonio.simulator import _kernels as K
from gonio.simulator.lbl import F_STOPS
from hypothesis import given, settings
from hypothesis import strategies as st


def _plan_pixel_loop(a, dk, s, inv_n2, sat_e, min_e):
    """The reference of ``_kernels._plan_pixel``: every stop tested (pure Python)."""
    bits = 0
    lead = 0
    ok = True
    for q in range(inv_n2.size):
        r = inv_n2[q]
        tot = a * r + dk
        if tot <= sat_e:
            if ok:
                lead += 1
            if s * r >= min_e:
                bits |= 1 << q
        else:
            ok = False
    return bits, lead


INV_N2 = np.array([1.0 / n**2 for n in sorted(F_STOPS, reverse=True)])


@settings(max_examples=400, deadline=None)
@given(
    a=st.floats(0.0, 1e7, allow_nan=False),
    dk=st.floats(0.0, 1e3, allow_nan=False),
    s=st.floats(1e-6, 1e7, allow_nan=False),
    sat=st.floats(1.0, 5e4, allow_nan=False),
    min_e=st.floats(0.0, 1e3, allow_nan=False),
)
def test_plan_pixel_equals_the_stop_by_stop_loop(a, dk, s, sat, min_e):
    assert K._plan_pixel(a, dk, s, INV_N2, sat, min_e) == _plan_pixel_loop(
        a, dk, s, INV_N2, sat, min_e
    )


def test_plan_pixel_at_the_exact_boundaries():
    """Totals and signals that land exactly on the thresholds at some stop."""
    rng = np.random.default_rng(0)
    for _ in range(2000):
        q = int(rng.integers(INV_N2.size))
        a = float(rng.uniform(1.0, 1e6))
        dk = float(rng.uniform(0.0, 50.0))
        s = float(rng.uniform(1.0, 1e6))
        sat = a * INV_N2[q] + dk  # stop q exactly at saturation
        min_e = s * INV_N2[int(rng.integers(INV_N2.size))]  # some stop exactly at min signal
        assert K._plan_pixel(a, dk, s, INV_N2, sat, min_e) == _plan_pixel_loop(
            a, dk, s, INV_N2, sat, min_e
        )
