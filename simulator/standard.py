"""The diffuse reflectance standard: a non-Lambertian PTFE reference and its certificate.

Pressed PTFE (Halon) and sintered PTFE (Spectralon) are the white standards of reflectance
work; neither is Lambertian. Measured, their reflectance factor ``R = π f_r / ρ`` is a few
percent above 1 near the normal, falls towards grazing viewing, and grows in the forward
(specular) direction as the incidence becomes oblique (Weidner & Hsia 1981; Bhandari et al.
2011). :func:`ptfe_factor` is a smooth model of that shape:

    R(wi, wo) = (1 - a(θi)) B(θo) + a(θi) L(wi, wo) / N(θi)

with a body term ``B = (1 + β cos θo) / (1 + 2β/3)`` (unit albedo) and a broad forward lobe
``L = cos^n`` of the angle to the mirror direction (``n = 3``), normalised by ``N(θi)`` to
unit albedo over the upper hemisphere, so the directional-hemispherical reflectance is ρ at
every incidence (Spectralon's is constant to about 1 % up to 60°, Haner et al. 1998).
``β`` and the lobe weight ``a(θi)`` are set so that ``R`` is 1.04 at normal incidence and
viewing and 1.07, 1.10, 1.22 in the forward direction at 45°, 60°, 75° incidence, the
values the project's issue states, which are of the size of the published measurements
(a(θi) is a monotone cubic through those points). The model is not reciprocal (nor is a
reflectance-factor table).

:class:`Certificate` is what a laboratory receives with its standard: the reflectance factor
on a grid of in-plane and out-of-plane geometries, the directional-hemispherical
reflectance, and the expanded uncertainty (k = 2). It is data only (no simulator truth): a
reduction reads it (:meth:`Certificate.from_dict` of the campaign's side-car), interpolates
it (:meth:`Certificate.factor`) and refuses angles it does not cover (:meth:`check_covers`).
The real standard deviates from its certificate by a smooth random function within the
stated uncertainty (:func:`certificate_deviation`, drawn from the instrument seed).

References
----------
Weidner, V. R., Hsia, J. J. (1981). Reflection properties of pressed polytetrafluoroethylene
powder. J. Opt. Soc. Am. 71(7), 856-861, doi:10.1364/JOSA.71.000856.
Bhandari, A., Hamre, B., Frette, Ø., Zhao, L., Stamnes, J. J., Kildemo, M. (2011).
Bidirectional reflectance distribution function of Spectralon white reflectance standard
illuminated by incoherent unpolarized and plane-polarized light. Applied Optics 50(16),
2431-2442, doi:10.1364/AO.50.002431.
Haner, D. A., McGuckin, B. T., Menzies, R. T., Bruegge, C. J., Duval, V. (1998).
Directional-hemispherical reflectance for Spectralon by integration of its bidirectional
reflectance. Applied Optics 37(18), 3996-3999, doi:10.1364/AO.37.003996.
JCGM 100:2008, Evaluation of measurement data - Guide to the expression of uncertainty in
measurement (GUM), §6 (expanded uncertainty, coverage factor).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.io.certificate import Certificate

__all__ = [
    "PTFE_TARGETS",
    "certificate_deviation",
    "make_certificate",
    "ptfe_factor",
]

#: (θi in degrees, reflectance factor in the forward (specular) direction) the model meets
PTFE_TARGETS: tuple[tuple[float, float], ...] = (
    (0.0, 1.04),
    (45.0, 1.07),
    (60.0, 1.10),
    (75.0, 1.22),
)
_N_LOBE = 3.0
# body term: B(0) = (1 + β) / (1 + 2β/3) = 1.04
_BETA = (PTFE_TARGETS[0][1] - 1.0) / (1.0 - 2.0 * PTFE_TARGETS[0][1] / 3.0)


def _body(cos_o: NDArray) -> NDArray:
    return (1.0 + _BETA * cos_o) / (1.0 + 2.0 * _BETA / 3.0)


#: Gauss-Legendre nodes of :func:`_lobe_norms`' polar integral (3e-11 relative against 256)
_LOBE_NODES = 128


def _lobe_norms(theta_i: ArrayLike) -> NDArray[np.float64]:
    """``N(θi) = (1/π) ∫ cos^n(angle to mirror)₊ cos θo dωo`` over the upper hemisphere
    (``n = 3``), for every ``θi`` of an array in [0, π/2].

    With ``m = cos θo`` the lobe is ``(A − B cos φ)₊³``, ``A = m cos θi``,
    ``B = sin θo sin θi``; its integral over the azimuth is closed: ``2π A³ + 3π A B²``
    where the whole circle is lit (``m ≥ sin θi``: a polynomial in ``m``, integrated
    exactly), else ``2 (F(π) − F(φ₀))`` with ``cos φ₀ = A/B`` and ``F`` the antiderivative
    of the cube. The polar integral over ``[0, sin θi]`` is Gauss-Legendre; the integrand
    vanishes at its upper end to third order. Exact at the ends: ``N(0) = 2/5``,
    ``N(π/2) = 4/(15π)``; scipy's adaptive quadrature of the clipped lobe over the
    hemisphere agrees to 1e-7 (a test), a midpoint rule over (m, φ) with 2048 x 4096 nodes
    to 2e-7 (its own error).
    """
    th = np.atleast_1d(np.asarray(theta_i, dtype=np.float64))
    st, ct = np.sin(th), np.cos(th)

    def whole(m: NDArray) -> NDArray:  # ∫ m (2π ct³ m³ + 3π ct st² m (1 − m²)) dm
        return 2.0 * math.pi * ct**3 * m**5 / 5.0 + 3.0 * math.pi * ct * st**2 * (
            m**3 / 3.0 - m**5 / 5.0
        )

    upper = whole(np.ones_like(st)) - whole(st)
    x, w = np.polynomial.legendre.leggauss(_LOBE_NODES)
    m = 0.5 * st[:, None] * (x[None, :] + 1.0)
    wm = 0.5 * st[:, None] * w[None, :]
    a = ct[:, None] * m
    b = st[:, None] * np.sqrt(1.0 - m * m)
    p0 = np.arccos(np.clip(a / np.where(b > 0.0, b, 1.0), -1.0, 1.0))
    sp = np.sin(p0)

    def f(p: Any, s: Any) -> NDArray:  # antiderivative of (a − b cos p)³
        return (a**3 * p - 3.0 * a * a * b * s + 3.0 * a * b * b * (p / 2.0 + s * np.cos(p) / 2.0)
                - b**3 * (s - s**3 / 3.0))  # fmt: skip

    lit = 2.0 * (f(math.pi, 0.0) - f(p0, sp))
    return (upper + np.sum(wm * m * lit, axis=1)) / math.pi


@functools.cache
def _tables() -> tuple[Any, NDArray, NDArray]:
    """(a(θi) interpolant, θi grid, N(θi) on it), computed once."""
    from gonio.numeric import Pchip

    th = np.radians([t for t, _ in PTFE_TARGETS])
    peaks = 1.0 / _lobe_norms(th)
    a = []
    for t, (_, target), peak in zip(th, PTFE_TARGETS, peaks):
        b = float(_body(np.array(math.cos(t))))
        a.append((target - b) / (float(peak) - b))
    grid = np.radians(np.linspace(0.0, 90.0, 91))
    return Pchip(th, np.array(a)), grid, _lobe_norms(grid)


def ptfe_factor(wi: ArrayLike, wo: ArrayLike, scale: float = 1.0) -> NDArray[np.float64]:
    """Reflectance factor ``R = π f_r / ρ`` of the PTFE standard, ``1 + scale (R_ptfe - 1)``.

    Parameters
    ----------
    wi, wo : array_like (..., 3)
        Unit directions in the standard's frame (z = normal), broadcast (a single ``wi``
        against many ``wo`` costs one evaluation of the incidence terms).
    scale : float
        0 gives a Lambertian standard (R = 1), 1 the PTFE shape.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    ti = np.arccos(np.clip(wi[..., 2], -1.0, 1.0))
    weight, grid, norm = _tables()
    a = np.clip(weight(np.clip(ti, 0.0, math.pi / 2)), 0.0, 1.0)
    inv_norm = 1.0 / np.interp(ti, grid, norm)
    mirror_dot = -wi[..., 0] * wo[..., 0] - wi[..., 1] * wo[..., 1] + wi[..., 2] * wo[..., 2]
    m = np.maximum(mirror_dot, 0.0)
    lobe = m * m * m  # cos^n, n = _N_LOBE = 3
    body = _body(np.clip(wo[..., 2], 0.0, 1.0))
    r = (1.0 - a) * body + (a * inv_norm) * lobe
    return 1.0 + float(scale) * (r - 1.0)


def _raw_basis(wi: NDArray, wo: NDArray) -> NDArray:
    """``1, cos θi, cos θo, cos θi cos θo, sin θi sin θo cos Δφ, cos² θo`` of directions."""
    xi, xo = np.broadcast_arrays(wi[..., 2], wo[..., 2])
    h = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
    return np.stack(np.broadcast_arrays(np.ones_like(xo), xi, xo, xi * xo, h, xo * xo), -1)


@functools.cache
def _basis_transform() -> NDArray:
    """Matrix that makes the six raw functions orthonormal (unit RMS, uncorrelated) over
    θi, θo in [0, 85°] (uniform in cos θ) and Δφ in [0, π]."""
    c = np.cos(np.radians(85.0))
    x = c + (1.0 - c) * (np.arange(12) + 0.5) / 12
    p = (np.arange(12) + 0.5) / 12 * math.pi
    ti, to, dp = np.meshgrid(np.arccos(x), np.arccos(x), p, indexing="ij")
    wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(to) * np.cos(dp), np.sin(to) * np.sin(dp), np.cos(to)], axis=-1)
    f = _raw_basis(wi, wo).reshape(-1, 6)
    gram = f.T @ f / f.shape[0]
    return np.linalg.inv(np.linalg.cholesky(gram)).T


def certificate_deviation(
    wi: ArrayLike, wo: ArrayLike, u: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Relative deviation ``δ`` of the real standard from its certificate (``R_true = R (1 + δ)``).

    A random combination of six smooth, orthonormal functions of (θi, θo, Δφ) (polynomials
    of degree two in cos θi, cos θo and the out-of-plane term) with independent normal
    weights of variance ``u² / 6``, so ``δ`` has an expected RMS of ``u`` over the
    certified range.
    ``rng`` must be the instrument's (the same instrument gives the same δ).
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    c = rng.normal(0.0, float(u) / math.sqrt(6.0), 6)
    return _raw_basis(wi, wo) @ (_basis_transform() @ c)


def make_certificate(
    rho: float, scale: float, u: float, *, step_deg: float = 5.0, max_deg: float = 85.0
) -> Certificate:
    """The certificate of a PTFE standard of shape ``scale`` (:func:`ptfe_factor`).

    Grid: θi and θo from 0 to ``max_deg`` in ``step_deg`` steps, Δφ from 0 to 180° in 15°
    steps; values the model's ``R`` (what a calibration laboratory measured), expanded
    uncertainty ``U = 2 u`` (k = 2).
    """
    ti = np.arange(0.0, max_deg + 1e-9, step_deg)
    to = ti.copy()
    dp = np.arange(0.0, 180.0 + 1e-9, 15.0)
    T, O, P = np.meshgrid(np.radians(ti), np.radians(to), np.radians(dp), indexing="ij")
    wi = np.stack([np.sin(T), np.zeros_like(T), np.cos(T)], axis=-1)
    # wi at φ = 0, wo at φ = Δφ (180 deg: the forward, specular side)
    wo = np.stack([np.sin(O) * np.cos(P), np.sin(O) * np.sin(P), np.cos(O)], axis=-1)
    r = ptfe_factor(wi, wo, scale)
    return Certificate(float(rho), tuple(ti), tuple(to), tuple(dp), r, 2.0 * float(u))


def true_standard(rho: float, scale: float, u: float, rng: np.random.Generator | None):
    """The real standard's BRDF ``f(wi, wo) = ρ/π · R_ptfe(scale) · (1 + δ)`` as a callable.

    ``δ`` (:func:`certificate_deviation`) is drawn once here from ``rng`` (the instrument's);
    ``u = 0`` or ``rng = None`` gives ``δ = 0``.
    """
    c = None
    if u > 0.0 and rng is not None:
        c = _basis_transform() @ rng.normal(0.0, float(u) / math.sqrt(6.0), 6)
    k = float(rho) / math.pi

    def standard_brdf(wi: NDArray, wo: NDArray) -> NDArray:
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        f = ptfe_factor(wi, wo, scale)
        if c is not None:  # 1 + Σ c_k basis_k, written out (no (n, 6) matrix, no BLAS)
            xi, xo = wi[..., 2], wo[..., 2]
            h = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
            f = f * (1.0 + c[0] + c[1] * xi + (c[2] + c[3] * xi + c[5] * xo) * xo + c[4] * h)
        return k * f

    return standard_brdf
