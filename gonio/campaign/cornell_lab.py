"""What the laboratory computes about its Cornell instrument: its own models, not the simulator's.

The reduction and the fit of a Cornell campaign know the instrument only through nominal
values (the source's 0.0005 sr, the detector's solid angle, the beam and field-of-view
diameters of the data sheet, the sample's 4 in) and through models written here, with other
quadratures than the simulator's (:mod:`gonio.simulator.cornell_physics`,
``gonio.simulator.cornell._cone_rule``), so a campaign is no inverse crime:

* :func:`cone_response` — the model averaged over nominal top-hat source and detector cones
  by a midpoint rule in equal-area rings (the simulator: a Gauss-Legendre product rule
  with offset azimuths), the mirror part by counting detector-cone points inside the
  source's mirror image (the simulator: the exact lens area).
* :func:`footprint_fraction` — the lit fraction of the field of view by a polar rule (the
  simulator: a raster); :func:`footprint_refused` — the plan's rule that refuses a geometry
  whose field of view (with a margin) leaves the lit spot or the sample.
* :func:`slit_correction` — second-order deconvolution of the slit function on the 31 bands.

References
----------
Li, H., Torrance, K. E. (2005). A practical, comprehensive light reflection model. Technical
report PCG-05-03, Program of Computer Graphics, Cornell University, §5.1, eq. 16.
Stearns, E. I., Stearns, R. E. (1988). An example of a method for correcting radiance data
for bandpass error. Color Research and Application 13(4), 257-259,
doi:10.1002/col.5080130410 (second-difference bandpass correction; here in its general
second-order form for a Gaussian slit of variance s^2 and a source spectrum K:
m = f + s^2 (K'/K) f' + s^2/2 f'').
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "cone_response",
    "footprint_fraction",
    "footprint_refused",
    "mirror_response",
    "slit_correction",
]


def _cap_alpha(omega: float) -> float:
    return math.acos(1.0 - omega / (2.0 * math.pi))


@lru_cache(maxsize=8)
def _ring_rule(alpha: float, rings: int = 4, nphi: int = 7) -> tuple[NDArray, NDArray, NDArray]:
    """Midpoint rule on a cap of half-angle ``alpha``: equal-area rings (midpoints in r²),
    ``nphi`` equally spaced azimuths from 0, equal weights summing to 1."""
    s = (np.arange(rings) + 0.5) / rings
    r = alpha * np.sqrt(s)
    rr = np.repeat(r, nphi)
    pp = np.tile(np.arange(nphi) * (2 * np.pi / nphi), rings)
    return rr, pp, np.full(rings * nphi, 1.0 / (rings * nphi))


def _frame(w: NDArray) -> tuple[NDArray, NDArray]:
    ref = np.where(np.abs(w[:, 2:3]) < 0.5, [[0.0, 0.0, 1.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(w, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(w, t1)


def _points(w: NDArray, r: NDArray, phi: NDArray) -> NDArray:
    t1, t2 = _frame(w)
    c, s = np.cos(r), np.sin(r)
    return (
        c[None, :, None] * w[:, None, :]
        + (s * np.cos(phi))[None, :, None] * t1[:, None, :]
        + (s * np.sin(phi))[None, :, None] * t2[:, None, :]
    )


def cone_response(
    model: Any, wi: NDArray, wo: NDArray, config: Any, taper: tuple[float, float] = (0.0, 0.0)
) -> NDArray:
    """The laboratory's model of what the instrument reads for ``model`` at ``wi``, ``wo``
    (G, 3): the BRDF averaged over nominal top-hat cones (``config.omega_nominal`` and
    ``config.detector_solid_angle``), weighted by cos θ over the source cone and divided by
    the source cone's mean cos θ; the mirror part ``ρ / (Ω_s cos θi)`` times the fraction
    of the detector cone inside the mirror image of the source cone. ``taper`` = (source,
    detector): radiance profiles ``1 - t (r/alpha)^2`` instead of top hats (the budget's
    sensitivity to them). Returns (G, n_bands).
    """
    a_s, a_d = _cap_alpha(config.omega_nominal), _cap_alpha(config.detector_solid_angle)
    rs, ps, ws = _ring_rule(a_s)
    rd, pd, wd = _ring_rule(a_d)
    if taper[0]:
        ws = ws * (1 - taper[0] * (rs / a_s) ** 2)
        ws = ws / ws.sum()
    if taper[1]:
        wd = wd * (1 - taper[1] * (rd / a_d) ** 2)
        wd = wd / wd.sum()
    pure = model
    if model.params.get("d_omega_i") is not None:
        pure = type(model)(**{**model.params, "d_omega_i": None})
    wi = np.asarray(wi, float).reshape(-1, 3)
    wo = np.asarray(wo, float).reshape(-1, 3)
    nb = len(np.atleast_1d(model.wavelengths_nm)) if model.wavelengths_nm is not None else 1
    out = np.zeros((len(wi), nb))
    ci = np.ones(len(wi))
    for chunk in np.array_split(np.arange(len(wi)), max(1, len(wi) // 128)):
        if chunk.size == 0:
            continue
        pi = _points(wi[chunk], rs, ps)
        po = _points(wo[chunk], rd, pd)
        cos_i = np.clip(pi[:, :, 2], 0, None)
        ci[chunk] = np.where(cos_i @ ws > 0, cos_i @ ws, 1.0)
        f = pure.evaluate_unchecked(pi[:, :, None, :], po[:, None, :, :])
        f = f.reshape(f.shape[:3] + (nb,))
        wgt = ws[:, None] * wd[None, :] * cos_i[:, :, None]
        out[chunk] = np.einsum("mijb,mij->mb", f, wgt) / ci[chunk, None]
    if pure.has_delta:
        out = out + mirror_response(pure, wi, wo, config, ci, wd)
    return out


def mirror_response(
    model: Any, wi: NDArray, wo: NDArray, config: Any, ci: NDArray | None = None,
    weights: NDArray | None = None,
) -> NDArray:  # fmt: skip
    """The laboratory's mirror part alone: ``ρ / (Ω_s cos θi)`` times the share of the
    detector cone's ring-rule points inside the mirror image of the nominal source cone
    (``ci``: the irradiance's cos, default the centre's; ``weights``: the detector rule's).
    Zero for a model without one. Returns (G, n_bands)."""
    wi = np.asarray(wi, float).reshape(-1, 3)
    wo = np.asarray(wo, float).reshape(-1, 3)
    nb = len(np.atleast_1d(model.wavelengths_nm)) if model.wavelengths_nm is not None else 1
    if not model.has_delta:
        return np.zeros((len(wi), nb))
    a_s, a_d = _cap_alpha(config.omega_nominal), _cap_alpha(config.detector_solid_angle)
    rd, pd, wd = _ring_rule(a_d)
    wd = wd if weights is None else weights
    ci = np.clip(wi[:, 2], 1e-12, None) if ci is None else ci
    d, rho = model.delta(wi)
    rho = np.asarray(rho, float).reshape(len(wi), -1)
    if not np.any(rho > 0):
        return np.zeros((len(wi), max(nb, rho.shape[1])))
    po = _points(wo, rd, pd)
    inside = np.einsum("nkj,nj->nk", po, d) >= math.cos(a_s)
    frac = inside.astype(float) @ wd
    return rho * (frac / (config.omega_nominal * ci))[:, None]


@lru_cache(maxsize=4)
def _polar_rule(rings: int = 24, nphi: int = 48) -> NDArray:
    """Equal-area polar points in the unit disc: (rings * nphi, 2)."""
    r = np.sqrt((np.arange(rings) + 0.5) / rings)
    phi = (np.arange(nphi) + 0.5) * (2 * np.pi / nphi)
    return np.c_[
        np.repeat(r, nphi) * np.tile(np.cos(phi), rings),
        np.repeat(r, nphi) * np.tile(np.sin(phi), rings),
    ]


def _ellipse_points(w: NDArray, diameter: float, unit: NDArray) -> NDArray:
    """Points of a unit-disc rule mapped onto the ellipse a spot of ``diameter`` seen along
    ``w`` makes on the sample plane: (N, M, 2)."""
    xy = w[:, :2]
    r = np.linalg.norm(xy, axis=1)
    u = np.where(r[:, None] > 1e-12, xy / np.where(r > 1e-12, r, 1)[:, None], [1.0, 0.0])
    v = np.c_[-u[:, 1], u[:, 0]]
    a = 0.5 * diameter / np.clip(w[:, 2], 1e-6, None)
    return (
        a[:, None, None] * unit[None, :, :1] * u[:, None, :]
        + 0.5 * diameter * unit[None, :, 1:2] * v[:, None, :]
    )


def _inside(p: NDArray, wi: NDArray, beam: float, sample: float) -> NDArray:
    ok = np.ones(p.shape[:2], bool)
    if beam > 0:
        xy = wi[:, :2]
        r = np.linalg.norm(xy, axis=1)
        u = np.where(r[:, None] > 1e-12, xy / np.where(r > 1e-12, r, 1)[:, None], [1.0, 0.0])
        v = np.c_[-u[:, 1], u[:, 0]]
        a = 0.5 * beam / np.clip(wi[:, 2], 1e-6, None)
        x = np.einsum("nmk,nk->nm", p, u) / a[:, None]
        y = np.einsum("nmk,nk->nm", p, v) / (0.5 * beam)
        ok &= x * x + y * y <= 1.0
    if sample > 0:
        ok &= np.all(np.abs(p) <= 0.5 * sample, axis=2)
    return ok


def footprint_fraction(wi: NDArray, wo: NDArray, beam: float, fov: float, sample: float) -> NDArray:
    """The laboratory's lit fraction of the field of view (nominal sizes, mm; 0 = off):
    the share of an equal-area polar rule over the field-of-view ellipse that falls in the
    lit ellipse and on the square sample."""
    wi, wo = np.atleast_2d(wi), np.atleast_2d(wo)
    if fov <= 0:
        return np.ones(len(wi))
    return _inside(_ellipse_points(wo, fov, _polar_rule()), wi, beam, sample).mean(axis=1)


def footprint_refused(
    wi: NDArray, wo: NDArray, beam: float, fov: float, sample: float, margin: float = 0.1
) -> NDArray[np.bool_]:
    """True where the plan refuses a geometry: the rim of the field of view enlarged by
    ``margin`` (relative: the sizes' uncertainty) leaves the lit spot shrunk by ``margin``
    or the sample. Tested on 72 points of the rim (and nothing refused when the field of
    view is a point)."""
    wi, wo = np.atleast_2d(wi), np.atleast_2d(wo)
    if fov <= 0:
        return np.zeros(len(wi), bool)
    phi = np.arange(72) * (2 * np.pi / 72)
    rim = np.c_[np.cos(phi), np.sin(phi)]
    p = _ellipse_points(wo, fov * (1 + margin), rim)
    return ~np.all(_inside(p, wi, beam * (1 - margin), sample), axis=1)


def slit_correction(
    values: NDArray, reference_band_rate: NDArray, fwhm_nm: float, step_nm: float = 10.0
) -> NDArray:
    """Remove a Gaussian slit function's second-order bias from band values (G, n_bands):
    ``f = m - s² (K'/K) m' - s²/2 m''`` with ``s = fwhm / 2.355``, K the reference's band rate
    (lamp x detector, known from the reference), derivatives by central differences on the
    band grid (one-sided at the ends, no curvature term there)."""
    if not (0.0 <= fwhm_nm < step_nm):
        raise ValueError(f"slit fwhm_nm = {fwhm_nm!r}: expected 0 <= fwhm < the {step_nm} nm bands")
    m = np.asarray(values, float)
    if fwhm_nm == 0:
        return m
    s2 = (fwhm_nm / (2.0 * math.sqrt(2.0 * math.log(2.0)))) ** 2
    lk = np.log(np.clip(np.asarray(reference_band_rate, float), 1e-300, None))
    dlk = np.gradient(lk, step_nm)
    d1 = np.gradient(m, step_nm, axis=-1)
    d2 = np.zeros_like(m)
    d2[..., 1:-1] = (m[..., 2:] - 2 * m[..., 1:-1] + m[..., :-2]) / step_nm**2
    return m - s2 * dlk * d1 - 0.5 * s2 * d2
