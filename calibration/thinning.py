"""Data thinning (Ward 1992 §3.2): adaptive binning of per-pixel BRDF values on the hemisphere.

An imaging gonioreflectometer returns far more pixels than a fit needs, crowded where the
fisheye/mirror mapping is dense and duplicated where exposures overlap. Ward applies "a program
to eliminate crowding of data points and insure that the peak is recorded at a high enough
angular resolution while the rest of the usable distribution is recorded at a uniform
density". :func:`thin` does this with a quadtree on an *equal-area* map of the hemisphere:

1. each direction ``ω = (θ, φ)`` goes to the unit disk by Lambert's azimuthal equal-area map
   ``ρ = √(1 − cos θ)`` and then to the square ``[-1, 1]²`` by the inverse Shirley-Chiu
   concentric map; both preserve area, so square cells of one level hold equal solid angle
   (``2π / 4^L``) — a uniform density on the hemisphere;
2. every cell of ``base_level`` is kept as one sample unless it is split; a cell is split into
   its four children when the children's mean values differ by more than ``rel_tol`` of the
   cell mean *and* by more than ``z`` standard errors (a real gradient, not noise), or when it
   lies in the peak (its mean above ``peak_fraction`` of the largest value) and is coarser
   than ``peak_level``;
3. each leaf cell becomes one sample: the mean of its pixels' values, its standard error
   ``√(Σσ²)/n``, and the normalised mean direction of its pixels.

:class:`ThinningResult` reports the counts before and after, and the within-bin spread that
bounds the error thinning introduces (the benchmark measures that error against the truth).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992 §3.2, last paragraph (thinning before fitting).
P. Shirley, K. Chiu, "A low distortion map between disk and square", JGT 2(3), 1997.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_directions, as_finite_array

__all__ = ["ThinningResult", "hemisphere_to_square", "thin"]


def hemisphere_to_square(w: ArrayLike) -> NDArray[np.float64]:
    """Equal-area map of upper-hemisphere directions ``(..., 3)`` to ``[-1, 1]²``.

    Lambert azimuthal equal-area to the unit disk, then the inverse concentric (Shirley-Chiu)
    map to the square. Equal solid angles map to equal areas (``2π`` ↔ 4).
    """
    w = np.asarray(w, dtype=np.float64)
    z = np.clip(w[..., 2], -1.0, 1.0)
    r = np.sqrt(np.maximum(1.0 - z, 0.0))  # in [0, 1] on the upper hemisphere
    phi = np.arctan2(w[..., 1], w[..., 0])
    phi = np.where(phi < -math.pi / 4, phi + 2 * math.pi, phi)  # in [-π/4, 7π/4)
    q = math.pi / 4
    a = np.empty_like(r)
    b = np.empty_like(r)
    s0 = phi < q
    s1 = (phi >= q) & (phi < 3 * q)
    s2 = (phi >= 3 * q) & (phi < 5 * q)
    s3 = phi >= 5 * q
    a[s0] = r[s0]
    b[s0] = phi[s0] / q * r[s0]
    b[s1] = r[s1]
    a[s1] = -(phi[s1] - 2 * q) / q * r[s1]
    a[s2] = -r[s2]
    b[s2] = -(phi[s2] - 4 * q) / q * r[s2]
    b[s3] = -r[s3]
    a[s3] = (phi[s3] - 6 * q) / q * r[s3]
    return np.stack([a, b], axis=-1)


@dataclass
class ThinningResult:
    """Thinned samples and bookkeeping.

    Attributes
    ----------
    wo : ndarray (M, 3)
        Mean direction of each bin (unit vectors).
    value, sigma : ndarray (M,)
        Mean of the bin's pixel values and its standard error ``√(Σσ²)/n``.
    n_pixels : ndarray (M,) of int
        Pixels in each bin.
    level : ndarray (M,) of int
        Quadtree level of each bin (cell solid angle ``2π / 4^level``).
    n_before, n_after : int
        Counts before and after thinning.
    spread : ndarray (M,)
        Relative rms spread of the pixel values within each bin, noise removed
        (``√max(var − mean σ², 0) / |mean|``): how much the BRDF varies inside a bin.
    """

    wo: NDArray[np.float64]
    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    n_pixels: NDArray[np.int64]
    level: NDArray[np.int64]
    n_before: int
    n_after: int
    spread: NDArray[np.float64]
    settings: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-ready counts and spread statistics."""
        sp = self.spread[np.isfinite(self.spread)]
        return {
            "n_before": self.n_before,
            "n_after": self.n_after,
            "ratio": self.n_before / max(self.n_after, 1),
            "levels": {int(k): int(v) for k, v in zip(*np.unique(self.level, return_counts=True))},
            "median_within_bin_spread": float(np.median(sp)) if sp.size else 0.0,
            "p95_within_bin_spread": float(np.percentile(sp, 95)) if sp.size else 0.0,
            **self.settings,
        }


def _group_stats(keys: NDArray, value: NDArray, var: NDArray, w: NDArray):
    uniq, inv = np.unique(keys, return_inverse=True)
    n = np.bincount(inv).astype(np.float64)
    s = np.bincount(inv, weights=value)
    s2 = np.bincount(inv, weights=value * value)
    sv = np.bincount(inv, weights=var)
    sw = np.stack([np.bincount(inv, weights=w[:, j]) for j in range(3)], axis=1)
    return uniq, inv, n, s, s2, sv, sw


def thin(
    wo: ArrayLike,
    value: ArrayLike,
    sigma: ArrayLike,
    *,
    base_level: int = 4,
    max_level: int = 9,
    peak_level: int = 7,
    peak_fraction: float = 0.1,
    rel_tol: float = 0.01,
    z: float = 3.0,
    min_split: int = 2,
) -> ThinningResult:
    """Adaptive equal-solid-angle binning of per-pixel samples on the hemisphere.

    Parameters
    ----------
    wo : array_like (N, 3)
        Outgoing directions of the pixels (unit, upper hemisphere), in the sample frame.
    value, sigma : array_like (N,)
        Per-pixel BRDF values and standard errors (eq. 2).
    base_level : int
        Coarsest level: ``4^L`` cells of ``2π/4^L`` sr each on the hemisphere; sets the
        uniform density away from the peak.
    max_level : int
        Finest level a bin can be split to.
    peak_level : int
        Bins whose mean exceeds ``peak_fraction × max`` are split at least to this level.
    peak_fraction : float
        Fraction of the largest bin value that marks the specular peak.
    rel_tol : float
        Split when the four children's means differ from the cell mean by more than this
        fraction (rms) — and significantly: their χ² about the cell mean exceeds its degrees
        of freedom by ``z`` standard deviations.
    z : float
        Significance of a gradient (see ``rel_tol``).
    min_split : int
        Cells with fewer pixels are never split.

    Returns
    -------
    ThinningResult
    """
    w, v, s = _thin_inputs(wo, value, sigma, base_level, max_level)
    settings = {
        "base_level": int(base_level),
        "max_level": int(max_level),
        "peak_level": int(peak_level),
        "peak_fraction": float(peak_fraction),
        "rel_tol": float(rel_tol),
        "z": float(z),
    }
    n_before = int(v.size)
    empty = np.zeros(0)
    if n_before == 0:
        return ThinningResult(
            np.zeros((0, 3)), empty, empty, empty.astype(np.int64), empty.astype(np.int64), 0, 0,
            empty, settings,
        )  # fmt: skip

    wn = w / np.linalg.norm(w, axis=1, keepdims=True)
    sq = hemisphere_to_square(wn)
    m = int(max_level)
    cells = 1 << m
    ij = np.clip(((sq + 1.0) * 0.5 * cells).astype(np.int64), 0, cells - 1)
    var = s * s
    vmax = None

    leaves: list[tuple] = []
    active = np.arange(n_before)
    for level in range(int(base_level), m + 1):
        if active.size == 0:
            break
        shift = m - level
        ai, aj = ij[active, 0] >> shift, ij[active, 1] >> shift
        key = (ai << 16) | aj
        uniq, inv, n, sv_, s2, svar, sw = _group_stats(key, v[active], var[active], wn[active])
        mean = sv_ / n
        if vmax is None:
            vmax = float(np.max(np.abs(mean)))
        split = np.zeros(uniq.size, bool)
        if level < m:
            # children statistics: bits of the next level's cell inside this one
            bi = (ij[active, 0] >> (shift - 1)) & 1
            bj = (ij[active, 1] >> (shift - 1)) & 1
            ck = inv * 4 + ((bi << 1) | bj)
            gradient, nchild = _significant_gradient(ck, uniq.size, v[active], var[active],
                                                     mean, rel_tol, z)  # fmt: skip
            peak = (np.abs(mean) > peak_fraction * vmax) & (level < peak_level)
            split = (n >= min_split) & (nchild > 1) & (gradient | peak)
        leaf = ~split
        if leaf.any():
            leaves.append(_leaf_rows(level, n[leaf], mean[leaf], sw[leaf], s2[leaf], svar[leaf]))
        active = active[split[inv]]

    cols = [np.concatenate(c) for c in zip(*leaves)]
    wo_out = cols[0]
    return ThinningResult(
        wo=wo_out,
        value=cols[1],
        sigma=cols[2],
        n_pixels=cols[3],
        level=cols[4],
        n_before=n_before,
        n_after=int(wo_out.shape[0]),
        spread=cols[5],
        settings=settings,
    )


def _thin_inputs(
    wo: ArrayLike, value: ArrayLike, sigma: ArrayLike, base_level: Any, max_level: Any
) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`thin`'s inputs checked: directions (N, 3) on the upper hemisphere, values and
    errors (N,) finite, σ >= 0, levels integers in [0, 15] with max >= base."""
    w = as_directions(wo, "wo").reshape(-1, 3)
    v = as_finite_array(value, "value").ravel()
    s = as_finite_array(sigma, "sigma").ravel()
    if not (w.shape[0] == v.shape[0] == s.shape[0]):
        raise ValueError(
            f"wo, value and sigma must have the same length, got {w.shape[0]}, {v.shape[0]}, "
            f"{s.shape[0]}"
        )
    if (s < 0).any():
        raise ValueError("sigma must be ≥ 0")
    for name, lev in (("base_level", base_level), ("max_level", max_level)):
        if not (isinstance(lev, int | np.integer) and 0 <= lev <= 15):
            raise ValueError(f"{name} must be an integer in [0, 15], got {lev!r}")
    if max_level < base_level:
        raise ValueError(f"max_level = {max_level} must be ≥ base_level = {base_level}")
    up = w[:, 2] >= 0.0
    if not up.all():
        raise ValueError(f"wo has {int((~up).sum())} direction(s) below the horizon")
    return w, v, s


def _significant_gradient(
    ck: NDArray, n_cells: int, v: NDArray, var: NDArray, mean: NDArray, rel_tol: float,
    z: float,
) -> tuple[NDArray, NDArray]:  # fmt: skip
    """Per cell: do its four children's means differ from the cell mean by more than
    ``rel_tol`` (rms), and significantly (χ² about the mean above its degrees of freedom by
    ``z`` standard deviations, or no error known)? ``ck`` is each pixel's cell·4 + child.
    Also returns each cell's number of non-empty children."""
    cn = np.bincount(ck, minlength=4 * n_cells).reshape(-1, 4)
    cs = np.bincount(ck, weights=v, minlength=4 * n_cells).reshape(-1, 4)
    cv = np.bincount(ck, weights=var, minlength=4 * n_cells).reshape(-1, 4)
    has = cn > 0
    cmean = np.where(has, cs / np.where(has, cn, 1), 0.0)
    cse2 = np.where(has, cv / np.where(has, cn, 1) ** 2, 0.0)
    dev = np.where(has, cmean - mean[:, None], 0.0)
    nchild = has.sum(axis=1)
    rms_dev = np.sqrt((dev**2).sum(axis=1) / np.maximum(nchild, 1))
    chi2 = np.where(has, dev**2 / np.where(cse2 > 0, cse2, np.inf), 0.0).sum(axis=1)
    dof = np.maximum(nchild - 1, 1)
    significant = chi2 > dof + z * np.sqrt(2.0 * dof)
    gradient = (rms_dev > rel_tol * np.abs(mean)) & (significant | (cse2.sum(1) == 0))
    return gradient, nchild


def _leaf_rows(
    level: int, nl: NDArray, mu: NDArray, wsum: NDArray, s2: NDArray, svar: NDArray
) -> tuple:
    """The output rows of the cells that stay whole at ``level``: direction (the normalised
    sum of their pixels' directions), mean, its standard error, pixel count, level, and the
    relative spread of the values within the cell beyond their noise."""
    within = np.maximum(s2 / nl - mu * mu - svar / nl, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(mu != 0, np.sqrt(within) / np.abs(mu), np.nan)
    return (
        wsum / np.linalg.norm(wsum, axis=1, keepdims=True),
        mu,
        np.sqrt(svar) / nl,
        nl.astype(np.int64),
        np.full(nl.size, level, np.int64),
        spread,
    )
