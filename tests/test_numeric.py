"""gonio.numeric against SciPy's own routines (the library forms it stands in for)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.interpolate import PchipInterpolator, RegularGridInterpolator
from scipy.stats import trim_mean as scipy_trim_mean

from gonio.numeric import Pchip, grid_linear, trim_mean

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(
    arrays(np.float64, st.integers(1, 400), elements=finite),
    st.sampled_from([0, 0.05, 0.2, 0.49]),
)
def test_trim_mean_is_scipys(a, p):
    assert trim_mean(a, p) == scipy_trim_mean(a, p)


def test_trim_mean_bad_input():
    with pytest.raises(ValueError, match="proportion"):
        trim_mean([1.0, 2.0], 0.5)
    with pytest.raises(ValueError, match="empty"):
        trim_mean([], 0.05)


@st.composite
def knots(draw):
    n = draw(st.integers(2, 9))
    steps = draw(arrays(np.float64, n - 1, elements=st.floats(0.05, 10.0)))
    x = np.concatenate([[draw(st.floats(-10, 10))], steps]).cumsum()
    y = draw(arrays(np.float64, n, elements=st.floats(-100, 100)))
    # flat stretches and sign changes of the secants are the slope formulas' special cases
    if draw(st.booleans()):
        y[: n // 2] = y[0]
    return x, y


@settings(max_examples=300, deadline=None)
@given(knots(), st.floats(-0.3, 1.3))
def test_pchip_is_scipys(kn, f):
    x, y = kn
    q = np.concatenate([x, x[0] + (x[-1] - x[0]) * np.array([f, 0.5 * f, -0.2, 1.2])])
    with np.errstate(over="ignore"):  # SciPy's own warning for a secant near 1e-308
        want = PchipInterpolator(x, y, extrapolate=True)(q)
    got = Pchip(x, y)(q)
    scale = max(1.0, float(np.max(np.abs(want))))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * scale)


def test_pchip_on_the_ptfe_knots():
    # the one use in gonio: the PTFE lobe's weight at four incidences, evaluated 0..90 deg
    x = np.radians([0.0, 45.0, 60.0, 75.0])
    y = np.array([0.04, 0.06, 0.11, 0.27])
    q = np.radians(np.linspace(0, 90, 901))
    np.testing.assert_allclose(Pchip(x, y)(q), PchipInterpolator(x, y)(q), rtol=1e-14, atol=0)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31))
def test_grid_linear_is_scipys(seed):
    rng = np.random.default_rng(seed)
    axes = [np.sort(rng.choice(np.arange(0.0, 91.0), size=rng.integers(2, 7), replace=False))
            for _ in range(3)]  # fmt: skip
    vals = rng.normal(1.0, 0.1, [a.size for a in axes])
    pts = np.stack([rng.uniform(a[0], a[-1], 500) for a in axes], 1)
    pts[:3] = [a[-1] for a in axes]  # the upper edges
    pts[3:6] = [a[0] for a in axes]
    want = RegularGridInterpolator(axes, vals)(pts)
    np.testing.assert_allclose(grid_linear(axes, vals, pts), want, rtol=1e-13, atol=0)


@pytest.mark.parametrize("nd", [1, 2, 3, 4])
def test_grid_linear_is_the_corner_by_corner_sum_to_the_bit(nd):
    # the gather from the flat table gives the products and sums of the plain n-d form
    import itertools

    rng = np.random.default_rng(nd)
    axes = [np.cumsum(rng.uniform(0.5, 3.0, rng.integers(2, 8))) for _ in range(nd)]
    vals = rng.normal(size=[a.size for a in axes])
    pts = np.stack([rng.uniform(a[0] - 1.0, a[-1] + 1.0, 3000) for a in axes], 1)
    idx, frac = [], []
    for d, ax in enumerate(axes):
        i = np.clip(np.searchsorted(ax, pts[:, d], side="right") - 1, 0, ax.size - 2)
        idx.append(i)
        frac.append((pts[:, d] - ax[i]) / (ax[i + 1] - ax[i]))
    want = np.zeros(len(pts))
    for corner in itertools.product((0, 1), repeat=nd):
        w = np.ones(len(pts))
        for c, t in zip(corner, frac):
            w = w * (t if c else 1.0 - t)
        want += w * vals[tuple(i + c for i, c in zip(idx, corner))]
    assert np.array_equal(grid_linear(axes, vals, pts), want)


def test_grid_linear_bad_input():
    with pytest.raises(ValueError, match="points must be"):
        grid_linear([[0.0, 1.0]], [1.0, 2.0], [0.5])
    with pytest.raises(ValueError, match="axis 0"):
        grid_linear([[1.0, 0.0]], [1.0, 2.0], [[0.5]])
