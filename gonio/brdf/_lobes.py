"""Shared lobe mathematics for the Phong, Blinn, Ward and Lafortune families.

* :func:`phi_integral` — ∫₀^{2π} max(0, a + b cos φ) dφ in closed form;
* :func:`cosine_lobe_albedo` — ∫_Ω [u'·v]₊ⁿ cos θ_v / max(cos θ_i, cos θ_v)^p dω_v for a cosine
  lobe of axis ``u'`` (p = 0 or 1) by closed-form azimuthal integration and a split
  Gauss-Legendre rule in the lobe angle α (relative error below 1e-10);
* :func:`lobe_quadrature_albedo` — the same integral for any callable in the lobe frame (2-D);
* :func:`half_vector_albedo` — ∫ f(wi, wo) cos θ_o dω_o for half-vector lobes (Blinn, Ward,
  Cook-Torrance) integrated over the half vector with the horizon and the
  ``cos θ_o = cos θ_i`` kink as exact azimuth limits;
* :func:`sample_cosine_lobe` / :func:`cosine_lobe_pdf` — Neumann et al. 1999, eq. 19-22;
* :func:`fresnel` — unpolarised Fresnel reflectance for a complex refractive index.

References
----------
.. [Neumann1999] L. Neumann, A. Neumann and L. Szirmay-Kalos, "New simple reflectance models for
   metals and other specular materials" (technical report; revised as "Compact metallic
   reflectance models", Computer Graphics Forum 18(3), Proc. Eurographics '99, 161-172,
   1999, https://doi.org/10.1111/1467-8659.00337). Equation numbers are the report's.
   Eq. 11, 19-22 (sampling a cosine lobe) and 26 (the grazing albedo).
.. [Lafortune1997] E. P. F. Lafortune, S.-C. Foo, K. E. Torrance and D. P. Greenberg, "Non-linear
   approximation of reflectance functions", Proc. SIGGRAPH '97, 117-126, 1997.
   https://doi.org/10.1145/258734.258801
   Eq. 5: a generalized lobe is a scaled cosine lobe around ``u' = Mu/|Mu|``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

_HALF_PI = 0.5 * np.pi


@cache
def _gl(n: int) -> tuple[NDArray, NDArray]:
    """Gauss-Legendre nodes/weights on [0, 1] after the smoothstep map ``3s² − 2s³``.

    The map has zero derivative at both ends, so integrands with square-root behaviour at
    the ends of a piece (azimuth limits, kinks) become smooth and converge spectrally.
    """
    x, w = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (x + 1.0)
    t = s * s * (3.0 - 2.0 * s)
    dt = 6.0 * s * (1.0 - s)
    return t, 0.5 * w * dt


def phi_integral(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """∫₀^{2π} max(0, a + b cos φ) dφ for ``b ≥ 0`` (closed form, broadcasting).

    With ``φ₀ = arccos(clip(−a/b, −1, 1))`` the integral is ``2 (a φ₀ + b sin φ₀)``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    safe = np.where(b > 0.0, b, 1.0)
    c = np.clip(-a / safe, -1.0, 1.0)
    phi0 = np.arccos(c)
    val = 2.0 * (a * phi0 + b * np.sqrt(np.maximum(1.0 - c * c, 0.0)))
    return np.where(b > 0.0, np.maximum(val, 0.0), 2.0 * np.pi * np.maximum(a, 0.0))


def _alpha_breaks(n: ArrayLike, cos_axis: NDArray, ci: NDArray) -> NDArray:
    """Break points in α ∈ [0, π/2] for the lobe-frame quadratures, shape ``(..., 11)``."""
    th = np.arccos(np.clip(cos_axis, -1.0, 1.0))
    ti = np.arccos(np.clip(ci, -1.0, 1.0))
    n = np.asarray(n, dtype=np.float64)
    w = 1.0 / np.sqrt(n + 1.0)
    cands = [
        np.zeros_like(th),
        np.full_like(th, _HALF_PI),
        _HALF_PI - th,
        th - _HALF_PI,
        ti - th,
        th - ti,
        th + ti,
    ] + [np.broadcast_to(k * w, th.shape) for k in (1.0, 2.0, 4.0, 8.0)]
    br = np.clip(np.stack(cands, axis=-1), 0.0, _HALF_PI)
    return np.sort(br, axis=-1)


def cosine_lobe_albedo(
    n: ArrayLike, cos_axis: ArrayLike, ci: ArrayLike, p: int = 0, nodes: int = 32
) -> NDArray[np.float64]:
    """∫_Ω [u'·v]₊ⁿ cos θ_v / max(cos θ_i, cos θ_v)^p dω_v over the upper hemisphere.

    ``u'`` is the lobe axis with ``cos θ' = cos_axis`` (it may point below the horizon),
    ``ci`` the cosine of the incident direction (used only when ``p = 1``). In the lobe frame
    ``cos θ_v = cos α cos θ' + sin α sin θ' cos φ``, so the azimuthal integral is closed-form
    (:func:`phi_integral`; for ``p = 1``, ``min(cos θ_v, cos θ_i)/cos θ_i`` is a difference of
    two of them: Neumann eq. 11). The α integral uses Gauss-Legendre pieces split at every kink
    and at multiples of the lobe width 1/√(n+1); the relative error is below 1e-10.

    References
    ----------
    Neumann et al. 1999, eq. 11; Lafortune et al. 1997, eq. 5.
    """
    if p not in (0, 1):
        raise ValueError(f"p must be 0 or 1 for the closed-form lobe albedo, got {p!r}")
    n, cos_axis, ci = np.broadcast_arrays(
        np.asarray(n, dtype=np.float64),
        np.asarray(cos_axis, dtype=np.float64),
        np.asarray(ci, dtype=np.float64),
    )
    br = _alpha_breaks(n, cos_axis, ci)
    t, wt = _gl(nodes)
    lo = br[..., :-1, None]
    hi = br[..., 1:, None]
    alpha = lo + (hi - lo) * t
    wa = (hi - lo) * wt
    ca, sa = np.cos(alpha), np.sin(alpha)
    cth = np.clip(cos_axis, -1.0, 1.0)[..., None, None]
    sth = np.sqrt(np.maximum(1.0 - cth * cth, 0.0))
    a = ca * cth
    b = sa * sth
    g = phi_integral(a, b)
    if p == 1:
        c = np.maximum(ci, 1e-300)[..., None, None]
        g = (g - phi_integral(a - c, b)) / c
    lobe = np.power(np.maximum(ca, 0.0), n[..., None, None]) * sa
    return np.einsum("...ij,...ij->...", lobe * g, wa)


def lobe_quadrature_albedo(
    f: Callable[[NDArray], NDArray],
    axis: NDArray,
    n: float,
    ci: float,
    nodes: int = 32,
) -> NDArray[np.float64]:
    """∫_Ω f(v) cos θ_v dω_v for a function concentrated around ``axis`` (a cosine lobe).

    Integrates in the lobe frame (α, φ) with α split as in :func:`cosine_lobe_albedo` and φ
    split at the horizon and at ``cos θ_v = ci`` (both in closed form), so models with
    ``1/max(cos θ_i, cos θ_v)^p`` or a Fresnel factor of Θ_min converge spectrally. ``f``
    receives directions of shape ``(A, P, 3)`` and returns ``(A, P)`` or ``(A, P, bands)``.
    """
    axis = np.asarray(axis, dtype=np.float64)
    cth = float(np.clip(axis[2], -1.0, 1.0))
    sth = float(np.sqrt(max(1.0 - cth * cth, 0.0)))
    ex, ey = _frame(axis)
    br = _alpha_breaks(np.float64(n), np.float64(cth), np.float64(ci))
    t, wt = _gl(nodes)
    alpha = (br[:-1, None] + (br[1:] - br[:-1])[:, None] * t).ravel()
    wa = ((br[1:] - br[:-1])[:, None] * wt).ravel()
    ca, sa = np.cos(alpha), np.sin(alpha)
    a, b = ca * cth, sa * sth
    # φ measured from the lobe-frame axis ex, which points "down" the slope of the axis so
    # that cos θ_v = a + b cos φ (ex has z-component sin θ' when θ' > 0).
    safe_b = np.where(b > 0.0, b, 1.0)
    phi0 = np.arccos(np.clip(-a / safe_b, -1.0, 1.0))  # horizon: v_z = 0
    phi1 = np.arccos(np.clip((ci - a) / safe_b, -1.0, 1.0))  # kink: v_z = ci
    phi0 = np.where(b > 0.0, phi0, np.where(a > 0.0, np.pi, 0.0))
    phi1 = np.minimum(np.where(b > 0.0, phi1, np.where(a > ci, np.pi, 0.0)), phi0)
    edges = np.stack([np.zeros_like(phi0), phi1, phi0], axis=-1)  # (A, 3)
    tp, wp = _gl(nodes)
    lo, hi = edges[:, :-1, None], edges[:, 1:, None]
    phi = (lo + (hi - lo) * tp).reshape(len(alpha), -1)
    wphi = ((hi - lo) * wp).reshape(len(alpha), -1)
    phi = np.concatenate([phi, -phi], axis=1)
    wphi = np.concatenate([wphi, wphi], axis=1)
    v = (
        (sa[:, None] * np.cos(phi))[..., None] * ex
        + (sa[:, None] * np.sin(phi))[..., None] * ey
        + ca[:, None, None] * axis
    )
    vz = np.maximum(v[..., 2], 0.0)
    v[..., 2] = vz
    vals = np.asarray(f(v))
    w = (wa * sa)[:, None] * wphi * vz
    if vals.ndim == 3:
        return np.einsum("apb,ap->b", vals, w)
    return np.einsum("ap,ap->", vals, w)


def _frame(axis: NDArray) -> tuple[NDArray, NDArray]:
    """Unit vectors ``ex, ey`` completing ``axis``; ``ex`` lies in the plane of axis and z.

    ``ex`` is chosen so that ``ex_z = sin θ'`` (pointing up the normal), hence
    ``v_z = cos α cos θ' + sin α sin θ' cos φ`` for
    ``v = sin α (cos φ ex + sin φ ey) + cos α axis``.
    """
    z = np.array([0.0, 0.0, 1.0])
    perp = z - axis[2] * axis
    nrm = np.linalg.norm(perp)
    if nrm < 1e-12:
        ex = np.array([1.0, 0.0, 0.0]) - axis[0] * axis
        ex = ex / np.linalg.norm(ex)
    else:
        ex = perp / nrm
    ey = np.cross(axis, ex)
    return ex, ey


def half_vector_albedo(
    f: Callable[[NDArray, NDArray], NDArray],
    wi: NDArray,
    width: float,
    tan_map: bool = False,
    nodes: int = 32,
) -> NDArray[np.float64]:
    """∫ f(wi, wo) cos θ_o dω_o for a lobe in the half vector ``h`` around the normal.

    ``dω_o = 4 (h·wi) dω_h``; in the half-vector polar angle δ the reflected direction is above
    the horizon iff ``cos φ > −cot θ_i cot 2δ`` (φ relative to the azimuth of ``wi``), and
    ``cos θ_o = cos θ_i`` where ``cos φ = cot θ_i tan δ``; both limits are used as exact
    azimuth break points and δ is split at ``π/4 ± θ_i/2``, ``θ_i`` and multiples of the lobe
    ``width`` (``1/√n`` for Blinn; the slope ``α`` for Ward and Cook-Torrance, in which case
    ``tan_map`` places the splits at ``arctan(k α)``). Gauss-Legendre on each smoothed piece.

    References
    ----------
    Neumann et al. 1999, §7 (albedos of the (N·H) models, tables 1-3, §7.2-7.4).
    """
    wi = np.asarray(wi, dtype=np.float64)
    ci = float(wi[2])
    if ci <= 0.0:
        return np.asarray(0.0)
    ti = float(np.arccos(min(ci, 1.0)))
    si = float(np.sqrt(max(1.0 - ci * ci, 0.0)))
    phi_i = float(np.arctan2(wi[1], wi[0])) if si > 0.0 else 0.0
    ks = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
    scale = [np.arctan(k * width) if tan_map else k * width for k in ks]
    br = np.clip(
        np.array([0.0, _HALF_PI, 0.25 * np.pi - 0.5 * ti, 0.25 * np.pi + 0.5 * ti, ti] + scale),
        0.0,
        _HALF_PI,
    )
    br = np.unique(br)
    t, wt = _gl(nodes)
    delta = (br[:-1, None] + np.diff(br)[:, None] * t).ravel()
    wd = (np.diff(br)[:, None] * wt).ravel()
    cd, sd = np.cos(delta), np.sin(delta)
    cos2d, sin2d = np.cos(2.0 * delta), np.sin(2.0 * delta)
    if si > 0.0:
        c0 = -ci * cos2d / np.where(sin2d > 0.0, sin2d * si, 1.0)
        c0 = np.where(sin2d > 0.0, c0, np.where(cos2d > 0.0, -2.0, 2.0))
        c1 = ci * sd / np.where(cd > 0.0, cd * si, 1.0)
    else:
        c0 = np.where(cos2d > 0.0, -2.0, 2.0)
        c1 = np.full_like(delta, 2.0)
    phi0 = np.arccos(np.clip(c0, -1.0, 1.0))
    phi1 = np.minimum(np.arccos(np.clip(c1, -1.0, 1.0)), phi0)
    edges = np.stack([np.zeros_like(phi0), phi1, phi0], axis=-1)
    tp, wp = _gl(nodes)
    lo, hi = edges[:, :-1, None], edges[:, 1:, None]
    phi = (lo + (hi - lo) * tp).reshape(len(delta), -1)
    wphi = ((hi - lo) * wp).reshape(len(delta), -1)
    phi = np.concatenate([phi, -phi], axis=1) + phi_i
    wphi = np.concatenate([wphi, wphi], axis=1)
    h = np.stack(
        [
            sd[:, None] * np.cos(phi),
            sd[:, None] * np.sin(phi),
            np.broadcast_to(cd[:, None], phi.shape),
        ],
        axis=-1,
    )
    hw = h @ wi
    wo = 2.0 * hw[..., None] * h - wi
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    vals = np.asarray(f(wi, wo))
    w = (wd * sd)[:, None] * wphi * np.maximum(wo[..., 2], 0.0) * 4.0 * np.maximum(hw, 0.0)
    if vals.ndim == 3:
        return np.einsum("apb,ap->b", vals, w)
    return np.einsum("ap,ap->", vals, w)


def refine_nodes(
    estimate: Callable[[int], Any], rtol: float, max_level: int, nodes: int = 16
) -> Any:
    """``estimate(nodes)`` with ``nodes`` doubled until two levels agree, at most ``max_level``.

    Two successive estimates agree when the largest absolute difference is at most ``rtol``
    times the largest absolute value of the newer one, or at most 1e-14; the newer one is
    returned (the last one when ``max_level`` levels do not converge).
    """
    prev = None
    for _ in range(max_level):
        est = estimate(nodes)
        if prev is not None:
            diff = np.max(np.abs(est - prev))
            if diff <= rtol * np.max(np.abs(est)) or diff <= 1e-14:
                return est
        prev, nodes = est, 2 * nodes
    return est


def half_vector_sum(
    wi: NDArray, wo: NDArray
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """``(cos θ_i, cos θ_o, up, h_x, h_y, h_z)`` of the unnormalised half vector ``wi + wo``.

    ``up`` marks pairs with both directions above the horizon; ``h_z`` is 1 elsewhere (so it
    can divide safely).
    """
    ci = wi[..., 2]
    co = wo[..., 2]
    up = (ci > 0.0) & (co > 0.0)
    hx = wi[..., 0] + wo[..., 0]
    hy = wi[..., 1] + wo[..., 1]
    hz = np.where(up, ci + co, 1.0)
    return ci, co, up, hx, hy, hz


# --------------------------------------------------------------------------- sampling


def frame_about(axis: NDArray) -> tuple[NDArray, NDArray]:
    """Orthonormal ``(i, j)`` completing unit vectors ``axis`` (..., 3); branchless (Duff 2017)."""
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    i = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    j = np.stack([b, sign + y * y * a, -y], axis=-1)
    return i, j


def sample_cosine_lobe(
    axis: NDArray, n: ArrayLike, u1: NDArray, u2: NDArray
) -> NDArray[np.float64]:
    """Directions around unit ``axis`` with density ``(n+1)/(2π) cosⁿ α`` (Neumann eq. 20-22).

    ``cos α = u1^{1/(n+1)}``, ``φ = 2π u2``; the frame is arbitrary (the density is
    rotationally symmetric), built branch-free instead of eq. 21's ``V × N``, which is
    undefined at normal incidence.
    """
    n = np.asarray(n, dtype=np.float64)
    ca = np.power(u1, 1.0 / (n + 1.0))
    sa = np.sqrt(np.maximum(1.0 - ca * ca, 0.0))
    phi = 2.0 * np.pi * u2
    i, j = frame_about(axis)
    return (
        (sa * np.cos(phi))[..., None] * i + (sa * np.sin(phi))[..., None] * j + ca[..., None] * axis
    )


def cosine_lobe_pdf(axis: NDArray, n: ArrayLike, w: NDArray) -> NDArray[np.float64]:
    """``(n+1)/(2π) [axis·w]₊ⁿ``, the solid-angle density of :func:`sample_cosine_lobe`."""
    n = np.asarray(n, dtype=np.float64)
    c = np.maximum(np.einsum("...k,...k->...", axis, w), 0.0)
    return (n + 1.0) / (2.0 * np.pi) * np.power(c, n)


# --------------------------------------------------------------------------- Fresnel


def fresnel(cos_t: ArrayLike, eta: ArrayLike) -> NDArray[np.float64]:
    """Unpolarised Fresnel reflectance from air onto a medium of complex index ``eta``.

    ``eta = n + i k`` (``k = 0`` for a dielectric); ``cos_t`` the cosine of the angle of
    incidence. Exact (not Schlick): ``F = (|r_s|² + |r_p|²)/2`` with
    ``cos θ_t = sqrt(1 − sin² θ/η²)``. ``F = 1`` at grazing incidence.
    """
    c = np.clip(np.asarray(cos_t, dtype=np.float64), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.complex128)
    s2 = 1.0 - c * c
    ct = np.sqrt(1.0 - s2 / (eta * eta) + 0j)
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)
