"""The physics of the Cornell instrument's imperfections (the true instrument only).

Each function implements one effect of :data:`gonio.simulator.cornell_effects.EFFECTS`;
:class:`gonio.simulator.cornell.CornellInstrument` calls them only for non-zero
magnitudes. The laboratory's own models of the same effects (nominal values, other
quadratures) live in :mod:`gonio.campaign.cornell_lab`.

References
----------
Li, H., Torrance, K. E. (2005). A practical, comprehensive light reflection model. Technical
report PCG-05-03, Program of Computer Graphics, Cornell University, §5.1.
Born, M., Wolf, E. (1999). Principles of Optics, 7th ed., Cambridge University Press, §1.5.2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "fresnel_polarisation",
    "lit_fraction",
    "slit_convolve",
    "stage_offsets",
    "taper_weights",
    "tilt_directions",
]


@lru_cache(maxsize=4)
def _disc_grid(n: int) -> NDArray[np.float64]:
    """Jittered-stratified points in the unit disc: one uniform point in each of the n x n
    squares of side 2/n, kept where inside the disc (fixed seed): (M, 2). Jitter makes the
    area error of a straight or curved cut fall as about n^-1.5 instead of the n^-1 of a
    regular raster, whose columns are all in or all out."""
    g = np.random.default_rng(20050101)
    k = np.arange(n)
    xx, yy = np.meshgrid(k, k)
    x = (xx + g.random((n, n))) / n * 2.0 - 1.0
    y = (yy + g.random((n, n))) / n * 2.0 - 1.0
    ok = x**2 + y**2 <= 1.0
    return np.c_[x[ok], y[ok]]


def _axes(w: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Unit azimuth vector of each direction's projection on the surface, its normal in the
    plane, and 1/cos(theta) (for directions near the normal the azimuth is x)."""
    xy = w[:, :2]
    r = np.linalg.norm(xy, axis=1)
    u = np.where(r[:, None] > 1e-12, xy / np.where(r > 1e-12, r, 1.0)[:, None], [1.0, 0.0])
    v = np.c_[-u[:, 1], u[:, 0]]
    return u, v, 1.0 / np.clip(w[:, 2], 1e-6, None)


def lit_fraction(
    wi: NDArray, wo: NDArray, beam_mm: float, fov_mm: float, sample_mm: float, grid: int = 128
) -> NDArray[np.float64]:
    """Fraction of the detector's field of view that lies on the lit part of the sample.

    The field of view (diameter ``fov_mm`` at normal view) is an ellipse with semi-axes
    ``fov/2/cos θo`` along the viewing azimuth and ``fov/2`` across it; the lit spot of the
    beam (diameter ``beam_mm``) an ellipse ``beam/2/cos θi`` by ``beam/2`` along the
    incidence azimuth; the sample a square of side ``sample_mm`` with its edges along x and
    y; all centred on the stage's axis. The fraction is counted on jittered-stratified
    points of the field of view (``grid`` x ``grid`` strata, equal areas). 0 means off for each
    size (infinite beam, point field of view, infinite sample).
    """
    wi, wo = np.atleast_2d(wi), np.atleast_2d(wo)
    if fov_mm <= 0:
        return np.ones(len(wi))
    phi = np.arange(72) * (2 * np.pi / 72)
    rim = _inside(np.c_[1.01 * np.cos(phi), 1.01 * np.sin(phi)], wi, wo, beam_mm, fov_mm, sample_mm)
    out = np.ones(len(wi))
    part = ~np.all(rim, axis=1)  # a rim 1 % outside the field of view (its chords' sagitta
    if part.any():  # is 1e-3) wholly lit: the field of view is (fraction 1 exactly)
        g = _disc_grid(grid)
        out[part] = _inside(g, wi[part], wo[part], beam_mm, fov_mm, sample_mm).mean(axis=1)
    return out


def _inside(
    g: NDArray, wi: NDArray, wo: NDArray, beam_mm: float, fov_mm: float, sample_mm: float
) -> NDArray[np.bool_]:
    """Which of the unit-disc points ``g`` (M, 2), mapped onto each field of view, are lit
    and on the sample: (N, M)."""
    gx, gy = g[None, :, 0], g[None, :, 1]
    uo, vo, so = _axes(wo)
    half = 0.5 * fov_mm
    ax, ay = (half * so)[:, None] * uo[:, None, 0], (half * so)[:, None] * uo[:, None, 1]
    bx, by = half * vo[:, None, 0], half * vo[:, None, 1]
    px, py = gx * ax + gy * bx, gx * ay + gy * by  # points on the sample plane (N, M)
    ok = np.ones(px.shape, bool)
    if beam_mm > 0:
        ui, vi, si = _axes(wi)
        a = (0.5 * beam_mm * si)[:, None]
        b = 0.5 * beam_mm
        x = (px * ui[:, None, 0] + py * ui[:, None, 1]) / a
        y = (px * vi[:, None, 0] + py * vi[:, None, 1]) / b
        ok &= x * x + y * y <= 1.0
    if sample_mm > 0:
        h = 0.5 * sample_mm
        ok &= (np.abs(px) <= h) & (np.abs(py) <= h)
    return ok


def taper_weights(r: NDArray, w: NDArray, alpha: float, taper: float) -> NDArray:
    """Quadrature weights of a cone whose radiance falls as ``1 - taper (r/alpha)^2``,
    renormalised to the same total (the cone average of a constant is unchanged)."""
    if taper == 0:
        return w
    prof = w * (1.0 - taper * (np.asarray(r) / alpha) ** 2)
    return prof * (w.sum() / prof.sum())


def tilt_directions(
    w: NDArray, turntable_rad: NDArray, m: Mapping[str, float], az: tuple[float, float]
) -> NDArray:
    """Directions in the true sample frame: the nominal ones turned by the sample's tilt
    (``sample_tilt_rad`` at the fixed azimuth ``az[0]``) plus the turntable's wobble
    (``sample_wobble_rad`` at lab azimuth ``az[1]``, i.e. ``az[1] - turntable`` in the sample
    frame). Rodrigues' rotation taking the nominal normal to the true one, applied inverted.
    """
    t, wb = float(m.get("sample_tilt_rad", 0.0)), float(m.get("sample_wobble_rad", 0.0))
    tt = np.broadcast_to(np.asarray(turntable_rad, float), (len(w),))
    tx = t * math.cos(az[0]) + wb * np.cos(az[1] - tt)
    ty = t * math.sin(az[0]) + wb * np.sin(az[1] - tt)
    ang = np.hypot(tx, ty)
    # the true normal n = (sin a cos b, sin a sin b, cos a); rotate w by -ang about k = z x n
    k = np.c_[-ty, tx, np.zeros_like(tx)] / np.where(ang > 0, ang, 1.0)[:, None]
    c, s = np.cos(-ang)[:, None], np.sin(-ang)[:, None]
    kw = np.sum(k * w, axis=1, keepdims=True)
    return w * c + np.cross(k, w) * s + k * kw * (1.0 - c)


def stage_offsets(
    delta_deg: NDArray, previous: NDArray, backlash: float, noise: float, rng: np.random.Generator
) -> tuple[NDArray, NDArray]:
    """True minus commanded angle (deg) of each axis after a move by ``delta_deg``: the
    backlash lag (half the band, against the direction of the move; kept from ``previous``
    for an axis that did not move) plus fresh positioning noise. Returns (offset, lag)."""
    d = np.asarray(delta_deg, float)
    lag = np.where(d != 0, -np.sign(d) * backlash / 2, previous)
    err = rng.normal(0.0, noise, d.shape) if noise > 0 else np.zeros(d.shape)
    return lag + err, lag


def slit_convolve(sig: NDArray, wl: NDArray, fwhm_nm: float) -> NDArray:
    """``sig`` (per pixel) convolved with a Gaussian slit function of ``fwhm_nm``; the pixel
    spacing is taken as its mean (the grating's dispersion varies by < 20 % over the range)."""
    from scipy.ndimage import gaussian_filter1d

    step = float(np.mean(np.diff(wl)))
    return gaussian_filter1d(
        sig, fwhm_nm / (2.0 * math.sqrt(2.0 * math.log(2.0))) / step, mode="nearest"
    )


def fresnel_polarisation(wi: NDArray, wo: NDArray, n: float) -> NDArray:
    """``(R_s - R_p) / (R_s + R_p)`` of a dielectric of index ``n`` at the half-angle of
    ``wi``, ``wo`` (the facet that reflects wi into wo; Born and Wolf §1.5.2)."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    ci = np.clip(np.sum(wi * h, -1), 1e-9, 1.0)
    st = np.sqrt(1.0 - ci**2) / n
    ct = np.sqrt(np.clip(1.0 - st**2, 0, None))
    rs = ((ci - n * ct) / (ci + n * ct)) ** 2
    rp = ((ct - n * ci) / (ct + n * ci)) ** 2
    return (rs - rp) / np.where(rs + rp > 0, rs + rp, 1.0)
