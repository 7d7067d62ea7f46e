"""Three small numerical routines of SciPy, written here because importing their SciPy
modules costs a campaign more than their work does.

A realistic LBL campaign used ``scipy.stats.trim_mean`` (the veiling glare's offset),
``scipy.interpolate.PchipInterpolator`` (the PTFE standard's forward lobe) and
``scipy.interpolate.RegularGridInterpolator`` (the standard's certificate) on a few
thousand numbers each; importing ``scipy.stats`` and ``scipy.interpolate`` took 0.32 s and
0.47 s of the campaign's main process on the 2-core development machine (``python -X
importtime``), together 15 % of the whole ideal campaign that the realistic one is measured
against. Each routine here follows SciPy's algorithm and is tested against SciPy itself
(``tests/test_numeric.py``): equal to the last bit for :func:`trim_mean`, to a few units in
the last place for the two interpolants (the same formulas, summed in another order).

References
----------
Fritsch, F. N. and Carlson, R. E. (1980). Monotone piecewise cubic interpolation. SIAM
Journal on Numerical Analysis, 17(2), 238-246. https://doi.org/10.1137/0717021 (the
interior slopes, as weighted harmonic means of the neighbouring secants).

Moler, C. (2004). Numerical Computing with MATLAB, §3.6 "Shape-preserving piecewise cubic",
SIAM. https://doi.org/10.1137/1.9780898717952 (the one-sided, shape-preserving end slopes
SciPy's ``PchipInterpolator`` uses).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Pchip", "grid_linear", "trim_mean"]


def trim_mean(a: ArrayLike, proportion: float) -> float:
    """Mean of ``a`` (1-d) after cutting ``int(proportion · n)`` values from each end of its
    sorted order (``scipy.stats.trim_mean`` on a 1-d array, the same partition and sum)."""
    x = np.asarray(a, dtype=np.float64).ravel()
    if x.size == 0:
        raise ValueError("trim_mean needs at least one value, got an empty array")
    if not (0.0 <= proportion < 0.5):
        raise ValueError(f"proportion must be in [0, 0.5), got {proportion!r}")
    lo = int(proportion * x.size)
    hi = x.size - lo
    return float(np.mean(np.partition(x, (lo, hi - 1))[lo:hi]))


def _pchip_slopes(h: NDArray, m: NDArray) -> NDArray:
    """Slopes at the knots: Fritsch-Carlson inside, the three-point shape-preserving
    formula at both ends (SciPy's ``PchipInterpolator._find_derivatives``)."""
    d = np.zeros(m.size + 1)
    if m.size == 1:
        d[:] = m[0]
        return d
    w1, w2 = 2.0 * h[1:] + h[:-1], h[1:] + 2.0 * h[:-1]
    same = (np.sign(m[1:]) == np.sign(m[:-1])) & (m[1:] != 0.0) & (m[:-1] != 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # a tiny secant:
        whmean = (w1 / m[:-1] + w2 / m[1:]) / (w1 + w2)  # inf, so its knot's slope is 0
    d[1:-1] = np.where(same, 1.0 / np.where(same, whmean, 1.0), 0.0)
    for k, (h0, h1, m0, m1) in ((0, (h[0], h[1], m[0], m[1])), (-1, (h[-1], h[-2], m[-1], m[-2]))):
        e = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        if np.sign(e) != np.sign(m0):
            e = 0.0
        elif np.sign(m0) != np.sign(m1) and abs(e) > 3.0 * abs(m0):
            e = 3.0 * m0
        d[k] = e
    return d


class Pchip:
    """Piecewise cubic Hermite interpolant with shape-preserving slopes (SciPy's
    ``PchipInterpolator(x, y, extrapolate=True)`` for 1-d ``y``): beyond the knots the end
    pieces' cubics continue.

    Parameters
    ----------
    x : array_like (n,)
        Strictly increasing knots, n ≥ 2.
    y : array_like (n,)
        Values at the knots.
    """

    def __init__(self, x: ArrayLike, y: ArrayLike) -> None:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if x.ndim != 1 or x.shape != y.shape or x.size < 2:
            raise ValueError(
                f"x and y must be 1-d of the same length >= 2, got {x.shape} and {y.shape}"
            )
        h = np.diff(x)
        if not np.all(h > 0):
            raise ValueError("x must be strictly increasing")
        m = np.diff(y) / h
        d = _pchip_slopes(h, m)
        t = (d[:-1] + d[1:] - 2.0 * m) / h
        # c3 s³ + c2 s² + c1 s + c0 on each piece, s = x - x[i]
        self._x, self._c = x, np.stack([y[:-1], d[:-1], (m - d[:-1]) / h - t, t / h])

    def __call__(self, xq: ArrayLike) -> NDArray[np.float64]:
        xq = np.asarray(xq, dtype=np.float64)
        i = np.clip(np.searchsorted(self._x, xq, side="right") - 1, 0, self._x.size - 2)
        s = xq - self._x[i]
        c0, c1, c2, c3 = (c[i] for c in self._c)
        return c0 + s * (c1 + s * (c2 + s * c3))


def grid_linear(axes: Sequence[ArrayLike], values: ArrayLike, points: ArrayLike) -> NDArray:
    """Multilinear interpolation of ``values`` on the rectilinear grid ``axes`` at
    ``points`` (m, ndim) (SciPy's ``RegularGridInterpolator(axes, values)(points)``, method
    ``"linear"``; points outside the grid extend its edge cells linearly — check the range
    first where that matters)."""
    vals = np.asarray(values, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != len(axes) or vals.ndim != len(axes):
        raise ValueError(
            f"points must be (m, {vals.ndim}) for a {vals.ndim}-d grid, got {pts.shape} "
            f"for {len(axes)} axes"
        )
    # the corners read from the flat table (a gather, not an n-d fancy index), each axis's
    # weights t and 1 - t made once: the same products and sums as corner by corner
    flat = np.ascontiguousarray(vals).ravel()
    step = np.cumprod((1,) + vals.shape[:0:-1])[::-1]  # elements per step along each axis
    base = np.zeros(pts.shape[0], dtype=np.int64)
    frac = []
    for d, ax in enumerate(axes):
        ax = np.asarray(ax, dtype=np.float64)
        if ax.ndim != 1 or ax.size < 2 or ax.size != vals.shape[d] or not np.all(np.diff(ax) > 0):
            raise ValueError(
                f"axis {d} must be strictly increasing with {vals.shape[d]} >= 2 points, got "
                f"{ax.size}"
            )
        i = np.clip(np.searchsorted(ax, pts[:, d], side="right") - 1, 0, ax.size - 2)
        base += i * int(step[d])
        t = (pts[:, d] - ax[i]) / (ax[i + 1] - ax[i])
        frac.append((1.0 - t, t))
    out = np.zeros(pts.shape[0])
    for corner in itertools.product((0, 1), repeat=len(axes)):
        w = frac[0][corner[0]]  # (1 x the first weight: the same number)
        for c, f in zip(corner[1:], frac[1:]):
            w = w * f[c]
        out += w * flat[base + int(sum(c * int(k) for c, k in zip(corner, step)))]
    return out
