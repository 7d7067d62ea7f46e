"""Oren & Nayar's rough diffuse (V-cavity) models and the Torrance-Sparrow surface term.

Four registered models, all from Oren and Nayar 1994 ("Generalization of Lambert's Reflectance
Model", SIGGRAPH 1994):

``oren_nayar``
    The functional approximation, eq. 27 (direct illumination) **plus** eq. 28 (two-bounce
    interreflection), combined by eq. 29. The paper's "model" is eq. 29 (Figure 12 compares
    "(27) and (28)" with the numerical evaluation), so the interreflection term is included;
    :meth:`OrenNayar.components` returns the two terms separately.
``oren_nayar_qualitative``
    The qualitative model, eq. 30 (no C3 term, no interreflection), with its closed-form albedo.
``oren_nayar_numeric``
    Eq. 25 evaluated by quadrature over the facet slope θa, with the single-slope radiance of
    eq. 24 (coefficients A1-A3 of Appendix B.1, eq. 45) for the direct part and eq. 49 for the
    interreflection part. This is the paper's "numerical evaluation of the model" and the
    reference against which the two approximations are tested.
``torrance_sparrow``
    The surface-reflection term of eq. 31 (used with the body term through eq. 32).

Conventions. σ is the standard deviation of the facet slope angle θa in radians (the paper
quotes degrees: σ = 30° is 0.5236 rad). The BRDF is the paper's radiance divided by
``E0 cos θi`` (text after eq. 29). ``cos(φr − φi)`` is taken as 0 when either direction is
exactly normal (the azimuth difference is undefined there, and every term it multiplies then
vanishes because β = 0).

Notes on the printed equations
------------------------------
* Eq. 25 with the normalisation constant ``c`` printed after eq. 26 integrates ``P`` over φa as
  well (a factor 2π) while eq. 25 integrates over θa only; taken literally the result would be
  ρ/(2π²) at σ → 0 instead of ρ/π. The consistent reading (eq. 8 with the φa integral done
  by eq. 23) is a *normalised* average over θa with weight ``exp(−θa²/2σ²) sin θa`` on
  [0, π/2]; this is what ``oren_nayar_numeric`` computes, and it reduces to ρ/π at σ = 0.
* The geometric attenuation factor of eq. 11/36/38 reads ``Min[1, Max[0, G_s, G_v]]`` in
  the seed text; eq. 33 defines it as the *minimum* of the illuminated and the visible
  fractions, so ``torrance_sparrow`` uses ``min(1, max(0, min(G_s, G_v)))``.
* The functional approximation (eq. 27) is not positive everywhere: in the forward direction
  (φr − φi = π) with both θi and θr close to 90° the C2 term, ``−0.45 σ²/(σ²+0.09)
  (sin α − (2β/π)³) tan β``, tends to ``−0.45 σ²/(σ²+0.09) · 6/π`` and outweighs C1.
  Measured (forward plane): with ρ → 0 (no eq. 28 to lift it) f_r < 0 once both angles exceed
  87° at σ = 0.7 rad, 72.5° at σ = 1.0, 64° at σ = 1.5; with ρ = 0.5 only for σ ≥ 1.0
  (beyond 88°) and σ = 1.5 (beyond 77°); never with ρ = 1 or σ ≤ 0.6 rad. The value is
  returned as the equation gives it (see ``KNOWN_ISSUES``); the numeric eq. 25 stays > 0.

References
----------
.. [OrenNayar1994] M. Oren and S. K. Nayar, "Generalization of Lambert's reflectance model",
   Proc. SIGGRAPH '94, 239-246, 1994. https://doi.org/10.1145/192161.192213

Oren and Nayar 1994, eq. 11, 24-31, 33, 39, 45, 49.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf._jit import lazy_kernel
from gonio.brdf._lobes import half_vector_sum
from gonio.brdf.base import BRDF, Param, register

__all__ = [
    "NUMERIC_NODES",
    "OrenNayar",
    "OrenNayarNumeric",
    "OrenNayarQualitative",
    "TorranceSparrow",
]

_RHO = Param("rho", 0.5, 0.0, 1.0, "1", "albedo of the Lambertian facets")
_SIGMA = Param("sigma", 0.3, 0.0, 1.5, "rad", "standard deviation of the facet slope angle theta_a")
_REF = "Oren and Nayar 1994"


def _angles(wi: NDArray, wo: NDArray, need_angles: bool = True):
    """Per-pair quantities shared by the Oren-Nayar forms (directions are unit vectors).

    Returns ``up, t_alpha, t_beta, alpha, beta, sin_alpha, cos_dphi, tan_half_sum`` where
    α = max(θi, θr) and β = min(θi, θr) (tangents, angles, sin α, ``tan((α+β)/2)`` by the
    identity ``(sin α + sin β)/(cos α + cos β)``), and ``cos(φr − φi)`` (0 if undefined).
    Values where a direction is below the horizon are finite garbage, masked by the caller.
    With ``need_angles=False`` the two arctangents (α, β) are skipped (returned as ``None``).
    """
    ci = wi[..., 2]
    co = wo[..., 2]
    up = (ci > 0.0) & (co > 0.0)
    ri = np.sqrt(wi[..., 0] * wi[..., 0] + wi[..., 1] * wi[..., 1])
    ro = np.sqrt(wo[..., 0] * wo[..., 0] + wo[..., 1] * wo[..., 1])
    sin_a = np.maximum(ri, ro)
    sin_b = np.minimum(ri, ro)
    cos_a = np.minimum(ci, co)  # the larger angle has the smaller cosine
    cos_b = np.maximum(ci, co)
    tiny = 1e-300
    t_alpha = sin_a / np.maximum(cos_a, tiny)
    t_beta = sin_b / np.maximum(cos_b, tiny)
    dot_xy = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
    cos_dphi = dot_xy / np.maximum(ri * ro, tiny)  # dot_xy is 0 where ri*ro is
    cos_dphi = np.clip(cos_dphi, -1.0, 1.0)
    if need_angles:
        alpha = np.arctan2(sin_a, cos_a)
        beta = np.arctan2(sin_b, cos_b)
        th = (sin_a + sin_b) / np.maximum(cos_a + cos_b, tiny)
    else:
        alpha = beta = th = None
    return up, t_alpha, t_beta, alpha, beta, sin_a, cos_dphi, th


def _ratio(s2: float, c: float) -> float:
    return s2 / (s2 + c) if s2 > 0.0 else 0.0


# --------------------------------------------------------------------------- eq. 27-29


@register
class OrenNayar(BRDF):
    r"""Oren-Nayar functional approximation, eq. 27 + eq. 28 (eq. 29).

    .. math::
        f_r = \frac{\rho}{\pi}\Big[C_1 + \cos\Delta\phi\, C_2 \tan\beta
              + (1-|\cos\Delta\phi|)\, C_3 \tan\tfrac{\alpha+\beta}{2}\Big]
              + 0.17\,\frac{\rho^2}{\pi}\frac{\sigma^2}{\sigma^2+0.13}
                \Big[1-\cos\Delta\phi\,\big(\tfrac{2\beta}{\pi}\big)^2\Big]

    with α = max(θi, θr), β = min(θi, θr), Δφ = φr − φi and C1-C3 of eq. 27. At σ = 0 it is
    exactly ρ/π (footnote 6). Reciprocal (the text after eq. 29). Albedo: the φ integral is
    done analytically and the remaining θ integral by Gauss-Legendre (split at θo = θi).

    Parameters
    ----------
    rho : float
        Albedo of the facets (ρ).
    sigma : float
        Standard deviation of the facet slope angle, radians.

    References
    ----------
    Oren and Nayar 1994, eq. 27, 28, 29 (BRDF = L_r / (E0 cos θi)).
    """

    name: ClassVar[str] = "oren_nayar"
    PARAMS = (_RHO, _SIGMA)
    REFERENCE = f"{_REF} eq. 27-29"
    SUMMARY = "Oren-Nayar functional approximation (direct eq. 27 + interreflection eq. 28)"
    KNOWN_ISSUES = (
        "negative values: eq. 27's C2 term makes f_r < 0 in the forward direction "
        "(phi_r - phi_i = pi) when theta_i and theta_r both approach 90 deg, for sigma >= 0.7 "
        "rad and small rho (rho -> 0: beyond 87 deg at sigma 0.7, 72.5 deg at 1.0, 64 deg at "
        "1.5); a property of the printed approximation (the numeric eq. 25 stays > 0)",
    )

    def _setup(self) -> None:
        s2 = self._params["sigma"] ** 2
        self._c1 = 1.0 - 0.5 * _ratio(s2, 0.33)
        self._c2 = 0.45 * _ratio(s2, 0.09)
        self._c3 = 0.125 * _ratio(s2, 0.09)
        self._k = self._params["rho"] / np.pi
        self._k2 = 0.17 * self._params["rho"] ** 2 / np.pi * _ratio(s2, 0.13)

    def components(self, wi, wo) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(direct, interreflection)``: eq. 27 and eq. 28 as BRDFs (sr⁻¹); they sum to f_r."""
        from gonio._validate import as_unit_directions

        return self._components(as_unit_directions(wi, "wi"), as_unit_directions(wo, "wo"))

    def _components(self, wi: NDArray, wo: NDArray) -> tuple[NDArray, NDArray]:
        if self._c2 == 0.0 and self._k2 == 0.0:
            up = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
            return np.where(up, self._k, 0.0), np.zeros(up.shape)
        with np.errstate(over="ignore", invalid="ignore"):
            up, _, t_beta, alpha, beta, sin_alpha, cd, tan_half = _angles(wi, wo)
            b = (2.0 / np.pi) * beta
            c2 = self._c2 * np.where(cd >= 0.0, sin_alpha, sin_alpha - b * b * b)
            ab = alpha * beta
            c3 = (self._c3 * 16.0 / np.pi**4) * ab * ab
            direct = self._c1 + cd * c2 * t_beta + (1.0 - np.abs(cd)) * c3 * tan_half
        inter = self._k2 * (1.0 - cd * b * b)
        return np.where(up, self._k * direct, 0.0), np.where(up, inter, 0.0)

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        d, i = self._components(wi, wo)
        return d + i

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray:
        rho = self._params["rho"]
        base = rho * self._c1 + np.pi * self._k2  # C1 term and the whole of eq. 28
        ci = wi[..., 2]
        up = ci > 0.0
        th_i = np.arctan2(np.hypot(wi[..., 0], wi[..., 1]), np.where(up, ci, 1.0))
        if self._c2 == 0.0:
            return np.where(up, base, 0.0)
        # phi integrals: ∫cosΔφ C2 dΔφ = 2 c2 (2β/π)³, ∫(1-|cosΔφ|) dΔφ = 2π - 4
        x, w = np.polynomial.legendre.leggauss(48)
        th_i_f = th_i.reshape(-1, 1)

        def part(lo, hi):
            t = lo + (hi - lo) * 0.5 * (x + 1.0)
            ww = (hi - lo) * 0.5 * w
            a = np.maximum(t, th_i_f)
            b = np.minimum(t, th_i_f)
            g = 2.0 * self._c2 * (2.0 * b / np.pi) ** 3 * np.tan(b) + (
                2.0 * np.pi - 4.0
            ) * self._c3 * (4.0 * a * b / np.pi**2) ** 2 * np.tan(0.5 * (a + b))
            return np.sum(ww * g * np.cos(t) * np.sin(t), axis=-1)

        extra = part(0.0 * th_i_f, th_i_f) + part(th_i_f, 0.5 * np.pi + 0.0 * th_i_f)
        out = base + rho / np.pi * extra.reshape(th_i.shape)
        return np.where(up, out, 0.0)


# --------------------------------------------------------------------------- eq. 30


@register
class OrenNayarQualitative(BRDF):
    r"""Oren-Nayar qualitative model, eq. 30.

    .. math::
        f_r = \frac{\rho}{\pi}\big(A + B \max[0, \cos\Delta\phi] \sin\alpha \tan\beta\big),\quad
        A = 1 - 0.5\frac{\sigma^2}{\sigma^2+0.33},\quad B = 0.45\frac{\sigma^2}{\sigma^2+0.09}

    Exactly ρ/π at σ = 0. Closed-form albedo:
    ``ρA + (2ρB/π)[sin θi (θi/2 − sin 2θi/4) + sin θi cos θi (1 + s + s²)/(3(1 + s))]``
    with ``s = sin θi`` (the second bracket term is ``tan θi (1 − sin³θi)/3`` written without
    cancellation at grazing incidence).

    References
    ----------
    Oren and Nayar 1994, eq. 30 (and footnote 7: 0.57 instead of 0.33 partly compensates
    for the missing interreflection; not used here).
    """

    name: ClassVar[str] = "oren_nayar_qualitative"
    PARAMS = (_RHO, _SIGMA)
    REFERENCE = f"{_REF} eq. 30"
    SUMMARY = "Oren-Nayar qualitative model (A + B max(0, cos dphi) sin alpha tan beta)"

    def _setup(self) -> None:
        s2 = self._params["sigma"] ** 2
        self._a = 1.0 - 0.5 * _ratio(s2, 0.33)
        self._b = 0.45 * _ratio(s2, 0.09)
        self._k = self._params["rho"] / np.pi

    def components(self, wi, wo) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(direct, interreflection)``; the qualitative model has no interreflection (0)."""
        v = self(wi, wo)
        return v, np.zeros_like(v)

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        if self._b == 0.0:
            return np.where((wi[..., 2] > 0.0) & (wo[..., 2] > 0.0), self._k, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            up, _, t_beta, _, _, sin_alpha, cd, _ = _angles(wi, wo, need_angles=False)
            v = (self._k * self._a) + (self._k * self._b) * np.maximum(cd, 0.0) * sin_alpha * t_beta
        return np.where(up, v, 0.0)

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray:
        rho = self._params["rho"]
        ci = wi[..., 2]
        up = ci > 0.0
        r = np.hypot(wi[..., 0], wi[..., 1])
        th = np.arctan2(r, np.where(up, ci, 1.0))
        s, c = np.sin(th), np.cos(th)
        j = s * (0.5 * th - 0.25 * np.sin(2.0 * th)) + s * c * (1.0 + s + s * s) / (3.0 * (1.0 + s))
        return np.where(up, rho * self._a + 2.0 * rho * self._b / np.pi * j, 0.0)


# --------------------------------------------------------------------------- eq. 25

#: Gauss-Legendre nodes per sub-interval of the θa quadrature of ``oren_nayar_numeric``
NUMERIC_NODES = 16

# series coefficients of h(x) = asin x - x sqrt(1 - x²) = 2 Σ C(2k,k)/4^k x^(2k+3)/(2k+3)
_H_COEF = np.array([2.0 * math.comb(2 * k, k) / 4.0**k / (2 * k + 3) for k in range(12)])


def _g(x: NDArray) -> NDArray:
    """``1 − (2φc + sin 2φc)/π`` with ``x = cos φc``, without cancellation as x → 0."""
    x = np.clip(x, 0.0, 1.0)
    direct = np.arcsin(x) - x * np.sqrt(1.0 - x * x)
    x2 = x * x
    series = np.zeros_like(x)
    for c in _H_COEF[::-1]:
        series = series * x2 + c
    series = series * x2 * x
    return (2.0 / np.pi) * np.where(x < 0.2, series, direct)


def _k_on_numeric(wi, wo, u, w, sigma, hcoef, out_d, out_i):  # pragma: no cover - numba
    """Scalar kernel of :meth:`OrenNayarNumeric._block` (same pieces, nodes and formulas).

    Returns the unscaled integrals: ``out_d`` (direct, × ρ/π) and ``out_i`` (× ρ²/π).
    One function on purpose (over 80 lines): a kernel that :func:`gonio.brdf._jit.lazy_kernel`
    compiles cannot call plain-Python helpers, and compiled helpers cost time (measured for
    the Li-Torrance kernel; the module docstring of :mod:`gonio.brdf._jit`).
    """
    half_pi = 0.5 * math.pi
    two_pi_inv = 2.0 / math.pi
    top = min(half_pi, 9.0 * sigma)
    nn = u.shape[0]
    e = np.empty(6)
    for k in range(wi.shape[0]):
        ci = wi[k, 2]
        co = wo[k, 2]
        if not (ci > 0.0 and co > 0.0):
            out_d[k] = 0.0
            out_i[k] = 0.0
            continue
        ri = math.hypot(wi[k, 0], wi[k, 1])
        ro = math.hypot(wo[k, 0], wo[k, 1])
        ti = ri / ci
        to = ro / co
        t_a = max(ti, to)
        t_b = min(ti, to)
        rr = ri * ro
        c = 0.0
        if rr > 0.0:
            c = (wi[k, 0] * wo[k, 0] + wi[k, 1] * wo[k, 1]) / rr
            c = min(1.0, max(-1.0, c))
        ac = abs(c)
        cot_a = 1.0 / t_a if t_a > 0.0 else math.inf
        cot_b = 1.0 / t_b if t_b > 0.0 else math.inf
        e[0] = 0.0
        e[1] = min(half_pi - math.atan(t_a), top)
        e[2] = min(half_pi - math.atan(t_b), top)
        e[3] = min(math.atan(math.hypot(cot_a, cot_b)), top)
        e[4] = min(3.0 * sigma, top)
        e[5] = top
        for i in range(1, 6):  # insertion sort
            v = e[i]
            j = i - 1
            while j >= 0 and e[j] > v:
                e[j + 1] = e[j]
                j -= 1
            e[j + 1] = v
        norm = 0.0
        sd = 0.0
        si = 0.0
        for piece in range(5):
            lo = e[piece]
            span = e[piece + 1] - lo
            if span <= 0.0:
                continue
            for j in range(nn):
                if piece == 0:
                    th = lo + span * u[j]
                    wt = span * w[j]
                else:
                    th = lo + span * u[j] * u[j]
                    wt = span * 2.0 * u[j] * w[j]
                q = th / sigma
                sin_a = math.sin(th)
                cos_a = math.cos(th)
                wt *= math.exp(-0.5 * q * q) * sin_a
                norm += wt
                ta = sin_a / cos_a
                p_a = ta * t_a
                p_b = ta * t_b
                if p_a > 1.0:
                    x_a = 1.0 / p_a
                    s_a = math.sqrt(1.0 - x_a * x_a)
                    asa = math.asin(x_a)
                    if x_a < 0.2:
                        x2 = x_a * x_a
                        ser = 0.0
                        for m in range(hcoef.shape[0] - 1, -1, -1):
                            ser = ser * x2 + hcoef[m]
                        g = two_pi_inv * ser * x2 * x_a
                    else:
                        g = two_pi_inv * (asa - x_a * s_a)
                else:
                    x_a = 1.0
                    s_a = 0.0
                    asa = half_pi
                    g = 1.0
                if p_b > 1.0:
                    x_b = 1.0 / p_b
                    s_b = math.sqrt(1.0 - x_b * x_b)
                    asb = math.asin(x_b)
                else:
                    x_b = 1.0
                    s_b = 0.0
                    asb = half_pi
                half_tt = 0.5 * p_a * p_b * g
                sdiff = (x_b * x_b - x_a * x_a) / (s_a + s_b + 1e-300)
                if c >= 0.0:
                    plane = 1.0 + two_pi_inv * p_b * s_a + half_tt
                else:
                    plane = two_pi_inv * (asb - p_b * sdiff) - half_tt
                a3 = 0.0
                if asa + asb < half_pi:
                    ra = math.sqrt(p_a * p_a - 1.0)
                    rb = math.sqrt(p_b * p_b - 1.0)
                    a3 = (
                        -0.5
                        + (asa + asb + rb - (1.0 + p_b * p_b) / (ra + math.hypot(p_a, p_b)))
                        / math.pi
                    )
                sd += wt * cos_a * ((1.0 - ac) * (1.0 + a3) + ac * plane)
                brk = two_pi_inv * ((half_pi - asb) + p_b * sdiff) + half_tt
                si += wt * cos_a * (1.0 - cos_a) * (1.0 - c * brk)
        if norm > 0.0:
            out_d[k] = sd / norm
            out_i[k] = si / norm
        else:
            out_d[k] = 0.0
            out_i[k] = 0.0


#: the compiled kernel, or ``None`` (numba missing or ``GONIO_NO_NUMBA`` set)
_numeric_kernel = lazy_kernel(_k_on_numeric)


def _gauss_nodes(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@register
class OrenNayarNumeric(BRDF):
    r"""Oren-Nayar model by quadrature of eq. 25 (the reference for eq. 27-30).

    .. math::
        f_r = \frac{\int_0^{\pi/2} e^{-\theta_a^2/2\sigma^2}\sin\theta_a\,
              [L^1_{rp}(\theta_a) + L^2_{rp}(\theta_a)]\,d\theta_a}
              {E_0\cos\theta_i \int_0^{\pi/2} e^{-\theta_a^2/2\sigma^2}\sin\theta_a\,d\theta_a}

    with the single-slope direct radiance ``L¹_rp`` of eq. 24 (coefficients A1, A2, A3 of
    eq. 45, critical angles eq. 39) and the interreflection ``L²_rp`` of eq. 49.

    Quadrature. For each direction pair the θa range is split at the points where the
    integrand is not smooth: θa = π/2 − α and π/2 − β (where φc^α, φc^β leave 0, eq. 39, with a
    square-root onset) and θa = atan(√(cot²θi + cot²θr)) (where φc^i + φc^r = π/2 switches A3
    on), plus θa = 3σ (so the Gaussian's bulk gets its own piece); the upper end is
    min(π/2, 9σ) (the Gaussian is below 3e-18 beyond). Each of the 5 pieces gets
    :data:`NUMERIC_NODES` (16) Gauss-Legendre nodes; pieces after the first use the
    substitution θa = b + (c − b)u², which makes the square-root onsets smooth. The
    normalisation uses the same nodes. Tolerance: against 64 nodes per piece the relative
    error is at most 1.5e-8 (σ = 0.1 rad) over θi, θr ∈ {0 … 89.9°}, Δφ ∈ {0 … 180°},
    σ ∈ {1e-3 … 1.5} rad (``test_numeric_quadrature_tolerance_stated_in_docstring`` asserts
    < 1e-7); against scipy ``quad`` of the printed eq. 45/49 it agrees to 1e-7. Cost: 80
    integrand evaluations per direction pair, ~5-10 µs per pair in the numba kernel
    (:func:`_k_on_numeric`, used when numba is available; ``use_kernel = False`` or
    ``GONIO_NO_NUMBA`` select the vectorised numpy path, 4-7× slower, equal to 1e-13).
    The 1 − (2φc + sin 2φc)/π factor, the forward in-plane bracket and the A3 square roots are
    evaluated in forms free of cancellation, so directions at 90° − 1e-12 stay accurate and
    positive. Eq. 45 itself was checked against a brute-force V-cavity integration (eq. 8 with
    the Table 1 facet radiance and the eq. 33 attenuation): equal to 2e-6 in and perpendicular
    to the plane of incidence, where it is exact; 0.2 % off-plane (the eq. 44 blend).

    References
    ----------
    Oren and Nayar 1994, eq. 23-26 (with the normalisation note in the module
    docstring), eq. 39, eq. 45 (= eq. 24), eq. 49.
    """

    name: ClassVar[str] = "oren_nayar_numeric"
    PARAMS = (_RHO, _SIGMA)
    REFERENCE = f"{_REF} eq. 25 (eq. 24/45 + eq. 49) by quadrature"
    SUMMARY = "Oren-Nayar V-cavity model by numerical integration over facet slopes"
    ALBEDO_RTOL = 1e-4
    #: pairs evaluated per vectorised block of the numpy path (memory: ~40 temporaries of
    #: block*5*nodes floats)
    BLOCK = 8192
    #: evaluate through the numba kernel when available (False: the numpy reference path;
    #: the environment variable ``GONIO_NO_NUMBA`` also selects it)
    use_kernel: bool = True

    def __init__(self, nodes: int | None = None, **params) -> None:
        n = NUMERIC_NODES if nodes is None else nodes
        if int(n) != n or n < 2:
            raise ValueError(f"nodes must be an integer >= 2, got {nodes!r}")
        self._nodes = int(n)
        super().__init__(**params)

    def _setup(self) -> None:
        self._u, self._w = _gauss_nodes(self._nodes)
        self._rho = self._params["rho"]
        self._sigma = self._params["sigma"]

    def components(self, wi, wo) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(direct, interreflection)`` BRDF terms (eq. 24 and eq. 49 integrated by eq. 25)."""
        from gonio._validate import as_unit_directions

        return self._components(as_unit_directions(wi, "wi"), as_unit_directions(wo, "wo"))

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        d, i = self._components(wi, wo)
        return d + i

    def _components(self, wi: NDArray, wo: NDArray) -> tuple[NDArray, NDArray]:
        shape = np.broadcast_shapes(wi.shape, wo.shape)
        wi = np.broadcast_to(wi, shape).reshape(-1, 3)
        wo = np.broadcast_to(wo, shape).reshape(-1, 3)
        out_d = np.zeros(len(wi))
        out_i = np.zeros(len(wi))
        k = self._rho / np.pi
        if self._sigma == 0.0:
            up = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
            out_d[up] = k
        elif self.use_kernel and _numeric_kernel() is not None and len(wi):
            _numeric_kernel()(
                np.ascontiguousarray(wi, dtype=np.float64),
                np.ascontiguousarray(wo, dtype=np.float64),
                self._u,
                self._w,
                self._sigma,
                _H_COEF,
                out_d,
                out_i,
            )
            out_d *= k
            out_i *= self._rho**2 / np.pi
        else:
            for s in range(0, len(wi), self.BLOCK):
                sl = slice(s, s + self.BLOCK)
                out_d[sl], out_i[sl] = self._block(wi[sl], wo[sl])
        return out_d.reshape(shape[:-1]), out_i.reshape(shape[:-1])

    def _block(self, wi: NDArray, wo: NDArray) -> tuple[NDArray, NDArray]:
        up, t_a, t_b, alpha, beta, _, cd, _ = _angles(wi, wo)
        sig = self._sigma
        top = min(0.5 * np.pi, 9.0 * sig)
        # break points (sorted: b1 <= b2 <= b3)
        b1 = 0.5 * np.pi - alpha
        b2 = 0.5 * np.pi - beta
        cot_a = np.where(t_a > 0.0, 1.0 / np.where(t_a > 0.0, t_a, 1.0), np.inf)
        cot_b = np.where(t_b > 0.0, 1.0 / np.where(t_b > 0.0, t_b, 1.0), np.inf)
        b3 = np.arctan(np.hypot(cot_a, cot_b))
        edges = np.stack(
            [np.zeros_like(b1), b1, b2, b3, np.full_like(b1, 3.0 * sig), np.full_like(b1, top)],
            -1,
        )
        edges = np.sort(np.minimum(edges, top), axis=-1)
        lo = edges[:, :-1, None]
        span = (edges[:, 1:] - edges[:, :-1])[:, :, None]
        u = self._u
        w = self._w
        # piece 0 plain Gauss-Legendre; pieces 1-3 with theta = lo + span*u^2
        sq = np.array([0.0, 1.0, 1.0, 1.0, 1.0])[None, :, None]
        uu = np.where(sq > 0, u * u, u)
        jac = np.where(sq > 0, 2.0 * u, 1.0) * w
        th = lo + span * uu  # (n, 5, nodes)
        wt = span * jac * np.exp(-0.5 * (th / sig) ** 2) * np.sin(th)
        th = th.reshape(len(wi), -1)
        wt = wt.reshape(len(wi), -1)
        norm = wt.sum(-1)
        cos_a = np.cos(th)
        ta = np.tan(th)
        tA = t_a[:, None]
        tB = t_b[:, None]
        c = cd[:, None]
        p_a = ta * tA  # tan θa tan α
        p_b = ta * tB
        x_a = np.where(p_a > 1.0, 1.0 / np.where(p_a > 1.0, p_a, 1.0), 1.0)  # cos φc^α
        x_b = np.where(p_b > 1.0, 1.0 / np.where(p_b > 1.0, p_b, 1.0), 1.0)
        s_a = np.sqrt(1.0 - x_a * x_a)  # sin φc^α
        s_b = np.sqrt(1.0 - x_b * x_b)
        half_tt = 0.5 * p_a * p_b * _g(x_a)  # ½ tan²θa tan α tan β (1 − (2φc^α+sin2φc^α)/π)
        sdiff = (x_b * x_b - x_a * x_a) / (s_a + s_b + 1e-300)  # sin φc^α − sin φc^β
        # eq. 45 in the plane of incidence: 1 + cos(Δφ) (A1 tan β + A2), written as
        # backward (Δφ = 0): 1 + A1 tan β; forward (Δφ = π): 1 − A1 tan β − A2 =
        # (2/π)(asin x_β − tan θa tan β (sin φc^α − sin φc^β)) − ½ tan²θa tan α tan β (…),
        # free of the cancellation of O(tan β) terms near grazing.
        asb = np.arcsin(x_b)
        back = 1.0 + (2.0 / np.pi) * p_b * s_a + half_tt
        fwd = (2.0 / np.pi) * (asb - p_b * sdiff) - half_tt
        plane = np.where(c >= 0.0, back, fwd)
        # A3 (only where φc^α + φc^β > π/2, i.e. arcsin x_a + arcsin x_b < π/2)
        asa = np.arcsin(x_a)
        on3 = (asa + asb) < 0.5 * np.pi
        pa_s = np.where(on3, p_a, 2.0)
        pb_s = np.where(on3, p_b, 2.0)
        ra = np.sqrt(pa_s * pa_s - 1.0)
        rb = np.sqrt(pb_s * pb_s - 1.0)
        a3 = -0.5 + (asa + asb + rb - (1.0 + pb_s * pb_s) / (ra + np.hypot(pa_s, pb_s))) / np.pi
        a3 = np.where(on3, a3, 0.0)
        ac = np.abs(c)
        direct = cos_a * ((1.0 - ac) * (1.0 + a3) + ac * plane)
        # eq. 49 interreflection bracket
        brk = (2.0 / np.pi) * (np.arccos(x_b) + p_b * sdiff) + half_tt
        inter = cos_a * (1.0 - cos_a) * (1.0 - c * brk)
        nrm = np.where(norm > 0.0, norm, 1.0)
        d = (self._rho / np.pi) * (wt * direct).sum(-1) / nrm
        i = (self._rho**2 / np.pi) * (wt * inter).sum(-1) / nrm
        return np.where(up, d, 0.0), np.where(up, i, 0.0)


# --------------------------------------------------------------------------- eq. 31


def fresnel_dielectric(cos_d: NDArray, n: float) -> NDArray:
    """Unpolarised Fresnel reflectance of a dielectric of index ``n`` at incidence ``cos_d``.

    ``F = ½ (g−c)²/(g+c)² [1 + ((c(g+c) − 1)/(c(g−c) + 1))²]`` with ``g = √(n² − 1 + c²)``.
    """
    c = np.clip(cos_d, 0.0, 1.0)
    g = np.sqrt(n * n - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


@register
class TorranceSparrow(BRDF):
    r"""Torrance-Sparrow surface reflection as written by Oren & Nayar, eq. 31.

    .. math::
        f_r = k_s\,\frac{F(n)\,\mathcal{GAF}\,e^{-\theta_a^2/2\sigma^2}}
                        {\cos\theta_i\cos\theta_r\cos\theta_a}

    θa is the angle of the half vector (the facet normal that mirrors wi into wo), F the
    unpolarised Fresnel reflectance at the angle between wi and the half vector (``n_ior=None``
    gives F = 1, as the paper's experiments assume), and GAF the V-cavity attenuation
    ``min(1, 2 cos θa cos θi / cos θd, 2 cos θa cos θr / cos θd)`` (eq. 33/36 with â the half
    vector). Eq. 31 is the radiance per unit E0; dividing by cos θi gives the BRDF. The
    Gaussian is not normalised: k_s is the free weight of eq. 32 (the paper prints
    k_s/k_b). Written symmetrically in wi and wo (cos θd = ``|wi + wo|/2``), so reciprocity is
    exact.

    Parameters
    ----------
    sigma : float
        Standard deviation of the facet slope angle, radians.
    n_ior : float or None
        Refractive index for the Fresnel factor; ``None`` means F = 1.
    k_s : float
        Weight of the surface term (eq. 32).

    References
    ----------
    Oren and Nayar 1994, eq. 31, 32, 33, 36.
    """

    name: ClassVar[str] = "torrance_sparrow"
    PARAMS = (
        Param("sigma", 0.1, 1e-4, 1.5, "rad", "standard deviation of the facet slope angle"),
        Param("n_ior", None, 1.0, 10.0, "1", "refractive index (None: F = 1)", optional=True),
        Param("k_s", 1.0, 0.0, math.inf, "1", "weight of the surface term (eq. 32)"),
    )
    REFERENCE = f"{_REF} eq. 31"
    SUMMARY = "Torrance-Sparrow V-cavity surface reflection (Oren-Nayar eq. 31)"
    ENERGY_CONSERVING = False
    KNOWN_ISSUES = (
        "albedo not normalised: the Gaussian of eq. 31 is unnormalised and k_s is a free "
        "weight (eq. 32), so the albedo exceeds 1 when k_s is large for the roughness "
        "(about 8 pi sigma^2 k_s at normal incidence for small sigma)",
    )

    def _setup(self) -> None:
        p = self._params
        self._inv2s2 = 0.5 / p["sigma"] ** 2
        self._n = p["n_ior"]
        self._ks = p["k_s"]

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci, co, up, hx, hy, hz = half_vector_sum(wi, wo)
        rxy = np.hypot(hx, hy)
        hn = np.hypot(rxy, hz)
        th_a = np.arctan2(rxy, hz)
        ci_s = np.where(up, ci, 1.0)
        co_s = np.where(up, co, 1.0)
        # GAF = min(1, 2 cosθa cosθ / cosθd) with cosθa = hz/|h|, cosθd = |h|/2
        gaf = np.minimum(1.0, 4.0 * hz * np.minimum(ci_s, co_s) / (hn * hn))
        v = self._ks * gaf * np.exp(-th_a * th_a * self._inv2s2) * hn / (ci_s * co_s * hz)
        if self._n is not None:
            v = v * fresnel_dielectric(0.5 * hn, self._n)
        return np.where(up, v, 0.0)


# --------------------------------------------------------------------------- accuracy report


def approximation_errors(
    sigmas,
    rho: float = 0.9,
    theta_max_deg: float = 85.0,
    theta_step_deg: float = 5.0,
    phi_step_deg: float = 15.0,
) -> list[dict]:
    """Relative errors of eq. 27-29 and eq. 30 against the numeric eq. 25, per σ.

    The grid is θi, θr in ``[0, theta_max_deg]`` by ``theta_step_deg`` and
    φr − φi in [0°, 180°] by ``phi_step_deg``. For each σ (radians) the record holds the
    maximum and RMS of ``f/f_numeric − 1`` for: ``functional`` (eq. 29 vs eq. 25 with
    interreflection), ``functional_direct`` (eq. 27 vs eq. 25 direct part only),
    ``qualitative`` (eq. 30 vs eq. 25 with interreflection) and ``qualitative_direct``
    (eq. 30 vs the direct part, the comparison the paper's eq. 30 was built for).

    References
    ----------
    Oren and Nayar 1994, Figures 12-13 (the paper's own comparisons, in the plane of
    incidence only).
    """
    from gonio.geometry import to_vector

    th = np.radians(np.arange(0.0, theta_max_deg + 1e-9, theta_step_deg))
    ph = np.radians(np.arange(0.0, 180.0 + 1e-9, phi_step_deg))
    ti, tr, dp = np.meshgrid(th, th, ph, indexing="ij")
    wi = to_vector(ti.ravel(), 0.0)
    wo = to_vector(tr.ravel(), dp.ravel())
    out = []
    for s in sigmas:
        nd, ni = OrenNayarNumeric(rho=rho, sigma=s)._components(wi, wo)
        fd, fi = OrenNayar(rho=rho, sigma=s)._components(wi, wo)
        q = OrenNayarQualitative(rho=rho, sigma=s)._eval(wi, wo)
        rec: dict = {"sigma": float(s), "sigma_deg": float(np.degrees(s)), "n": len(wi)}
        for key, a, b in (
            ("functional", fd + fi, nd + ni),
            ("functional_direct", fd, nd),
            ("qualitative", q, nd + ni),
            ("qualitative_direct", q, nd),
        ):
            r = a / b - 1.0
            k = int(np.argmax(np.abs(r)))
            rec[key] = {
                "max": float(np.max(np.abs(r))),
                "rms": float(np.sqrt(np.mean(r * r))),
                "worst_deg": [float(np.degrees(x.ravel()[k])) for x in (ti, tr, dp)],
            }
        out.append(rec)
    return out
