"""Neumann, Neumann & Szirmay-Kalos's compact metallic reflectance models (and relatives).

The reciprocal Phong model and its 1/max(cos) correction (the "new model" for metals), the
p-model, the retro-reflective variant, the metal and plastic forms, the Blinn model and its
correction, the corrected (anisotropic) Ward model and the Cook-Torrance model.

All models here are reciprocal. Values are 0 when either direction is at or below the horizon.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Eq. 5a and 7: the Ward model that eq. 34-35 of [Neumann1999]_ correct, and its sampling.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Eq. 5: Schlick's Fresnel approximation, used by :class:`CookTorrance` when ``f0`` is given.
.. [Neumann1999] L. Neumann, A. Neumann and L. Szirmay-Kalos, "New simple reflectance models for
   metals and other specular materials" (technical report; revised as "Compact metallic
   reflectance models", Computer Graphics Forum 18(3), Proc. Eurographics '99, 161-172,
   1999, https://doi.org/10.1111/1467-8659.00337). Equation numbers are the report's.
   Eq. 5-7 and 9-10 (Phong and the corrected model), eq. 12 (p-model), eq. 13
   (retro-reflection), eq. 19-25 (importance sampling), eq. 26 (grazing albedo), eq. 27-30
   (metals and plastics), eq. 32-33 (Blinn), eq. 34-35 (Ward), eq. 36-37 (Cook-Torrance),
   tables 1-3.
"""

from __future__ import annotations

import itertools
import math
from functools import lru_cache
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf._lobes import (
    cosine_lobe_albedo,
    cosine_lobe_pdf,
    fresnel,
    half_vector_albedo,
    half_vector_sum,
    lobe_quadrature_albedo,
    refine_nodes,
    sample_cosine_lobe,
)
from gonio.brdf.base import BRDF, Param, register
from gonio.brdf.ward import Ward
from gonio.geometry import cosine_hemisphere_pdf, square_to_hemisphere

__all__ = [
    "BlinnNeumann",
    "BlinnPhong",
    "CookTorrance",
    "MetalNeumann",
    "Phong",
    "PhongNeumann",
    "PhongRetro",
    "PlasticNeumann",
    "WardNeumann",
    "blinn_max_c_n",
    "mean_albedo",
]

_N_MAX = 1e8  # Neumann §2.4.2 uses n = 1e4 ... 1e8 for glossy mirrors

_P_N = Param("n", 10.0, 0.0, _N_MAX, "1", "Phong exponent")
_P_CN = Param(
    "c_n", None, 0.0, math.inf, "sr^-1", "lobe scale; None = maximum (n+2)/(2π)", optional=True
)
_P_RHOD = Param("rho_d", 0.0, 0.0, 1.0, "1", "Lambertian (diffuse) reflectance")
_P_P = Param("p", 1.0, 0.0, 1.0, "1", "exponent of 1/max(cos θ_i, cos θ_o), eq. 12")


def _up(wi: NDArray, wo: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    ci = wi[..., 2]
    co = wo[..., 2]
    return ci, co, (ci > 0.0) & (co > 0.0)


def _pow_pos(base: NDArray, n: float) -> NDArray:
    """``base**n`` where ``base > 0``, else 0 (a lobe whose base is ≤ 0 contributes 0)."""
    pos = base > 0.0
    return np.where(pos, np.power(np.where(pos, base, 1.0), n), 0.0)


def _dot(a: NDArray, b: NDArray) -> NDArray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _mirror(w: NDArray) -> NDArray:
    return w * np.array([-1.0, -1.0, 1.0])


def _sample_mixture(
    wo: NDArray,
    rng: np.random.Generator,
    w_diffuse: float | NDArray,
    w_lobe: float | NDArray,
    axis: NDArray,
    n: float,
) -> NDArray:
    """Draw from ``(w_d cos θ/π + w_l · lobe)/(w_d + w_l)`` (lobe: Neumann eq. 19-22)."""
    shape = wo.shape[:-1]
    u = rng.random((3,) + shape)
    total = np.asarray(w_diffuse + w_lobe, dtype=np.float64)
    frac_d = np.where(total > 0.0, w_diffuse / np.where(total > 0.0, total, 1.0), 1.0)
    lobe = sample_cosine_lobe(axis, n, 1.0 - u[0], u[1])
    diff = square_to_hemisphere(u[0], u[1], cosine=True)
    return np.where((u[2] < frac_d)[..., None], diff, lobe)


def _mixture_pdf(
    wi: NDArray,
    w_diffuse: float | NDArray,
    w_lobe: float | NDArray,
    axis: NDArray,
    n: float,
) -> NDArray:
    total = np.asarray(w_diffuse + w_lobe, dtype=np.float64)
    safe = np.where(total > 0.0, total, 1.0)
    pd = cosine_hemisphere_pdf(wi)
    pl = cosine_lobe_pdf(axis, n, wi)
    return np.where(total > 0.0, (w_diffuse * pd + w_lobe * pl) / safe, pd)


# =========================================================================== Phong family


class _PhongLobe(BRDF):
    """``rho_d/π + c · [cos α]₊ⁿ · F / max(cos θ_i, cos θ_o)^p`` with α about the mirror."""

    RETRO: ClassVar[bool] = False
    KNOWN_ISSUES: ClassVar[tuple[str, ...]] = (
        "albedo exceeds 1 slightly with the maximum c_n: by 0.0003 near 13 deg at n = 1 and "
        "by 0.01 near 30 deg at n = 0.5, more as n -> 0 (Neumann et al. 1999, §2.2: "
        "eq. 6 is energy conserving only for the reciprocal Phong model, n >= 1)",
    )

    # -- parameters the subclasses map onto the common form
    def _lobe_params(self) -> tuple[float, float, float, float]:
        """``(n, c, p, rho_d)``."""
        p = self._params
        n = p["n"]
        c = p["c_n"] if p.get("c_n") is not None else (n + 2.0) / (2.0 * np.pi)
        return n, c, float(p.get("p", 0.0)), p.get("rho_d", 0.0)

    def _setup(self) -> None:
        self._n, self._c, self._p, self._rho_d = self._lobe_params()
        self._kd = self._rho_d / np.pi

    def _cos_alpha(self, wi: NDArray, wo: NDArray, ci: NDArray, co: NDArray) -> NDArray:
        if self.RETRO:
            return _dot(wi, wo)
        return 2.0 * ci * co - _dot(wi, wo)  # eq. 9

    def _fresnel(self, wi: NDArray, wo: NDArray, cmax: NDArray) -> NDArray | float:
        return 1.0

    def _diffuse(self) -> NDArray | float:
        return self._kd

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        return self._eval_parts(wi, wo, True)

    def _eval_parts(self, wi: NDArray, wo: NDArray, diffuse: bool) -> NDArray:
        ci, co, up = _up(wi, wo)
        ca = self._cos_alpha(wi, wo, ci, co)
        cmax = np.where(up, np.maximum(ci, co), 1.0)
        spec = self._c * _pow_pos(ca, self._n)
        if self._p == 1.0:
            spec = spec / cmax
        elif self._p != 0.0:
            spec = spec / np.power(cmax, self._p)
        spec = np.where(up, spec, 0.0)
        fr = self._fresnel(wi, wo, cmax)
        kd = self._diffuse() if diffuse else 0.0
        if self.n_bands:
            spec = spec[..., None] * fr  # fr: (..., n_bands) or (n_bands,)
            return np.where(up[..., None], kd + spec, 0.0)
        return np.where(up, kd + spec * fr, 0.0)

    # -- albedo
    def _albedo(self, wi: NDArray, rtol: float) -> NDArray | None:
        if self._p not in (0.0, 1.0) or self._has_fresnel():
            return None
        ci = wi[..., 2]
        c = np.clip(ci, 0.0, 1.0)
        lobe = cosine_lobe_albedo(self._n, c, np.maximum(c, 1e-300), int(self._p))
        spec = np.where(ci > 0.0, self._c * lobe, 0.0)
        rd = self._diffuse_albedo()
        if np.ndim(rd):
            return np.where(ci[..., None] > 0.0, np.asarray(rd) + spec[..., None], 0.0)
        return np.where(ci > 0.0, rd + spec, 0.0)

    def _diffuse_albedo(self) -> NDArray | float:
        return self._rho_d

    def _has_fresnel(self) -> bool:
        return False

    def _quadrature_albedo(self, wi: NDArray, rtol: float, max_level: int = 6) -> Any:
        bands = self.n_bands
        if wi[2] <= 0.0:
            return np.zeros(bands) if bands else 0.0
        axis = wi if self.RETRO else _mirror(wi)
        # the lobe frame covers only the lobe's half-space: integrate the lobe, add diffuse
        return refine_nodes(
            lambda nodes: (
                lobe_quadrature_albedo(
                    lambda v, w=wi: self._eval_parts(np.broadcast_to(w, v.shape), v, False),
                    axis,
                    self._n,
                    float(wi[2]),
                    nodes,
                )
                + np.asarray(self._diffuse_albedo())
            ),
            rtol,
            max_level,
        )

    # -- sampling (Neumann §4, eq. 19-22)
    def _lobe_weight(self) -> float:
        """∫ over the sphere of ``c cosⁿ α`` (no cosine): ``2π c/(n+1)``; eq. 23."""
        return 2.0 * np.pi * self._c / (self._n + 1.0)

    def _diffuse_weight(self) -> float:
        return float(np.max(self._diffuse_albedo()))

    def _axis(self, wo: NDArray) -> NDArray:
        return wo.copy() if self.RETRO else _mirror(wo)

    def _sample(self, wo: NDArray, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
        axis = self._axis(wo)
        wi = _sample_mixture(wo, rng, self._diffuse_weight(), self._lobe_weight(), axis, self._n)
        return wi, self._pdf(wo, wi)

    def _pdf(self, wo: NDArray, wi: NDArray) -> NDArray:
        wo, wi = np.broadcast_arrays(wo, wi)
        pdf = _mixture_pdf(wi, self._diffuse_weight(), self._lobe_weight(), self._axis(wo), self._n)
        return np.where((wi[..., 2] > 0.0) & (wo[..., 2] > 0.0), pdf, 0.0)


@register
class Phong(_PhongLobe):
    r"""The reciprocal Phong model, Neumann eq. 5, plus an optional Lambertian term.

    .. math:: f_r = \rho_d/\pi + c_n \cos^n\alpha, \qquad
              \cos\alpha = (\mathbf R\cdot\mathbf V)^+ = [2(N·L)(N·V) − L·V]^+ \;(eq.\ 9)

    Parameters
    ----------
    n : float
        Phong exponent (≥ 0).
    c_n : float or None
        Lobe scale in sr⁻¹; ``None`` gives the maximum energy-conserving ``(n+2)/(2π)``
        (eq. 6), for which the albedo at normal incidence is exactly 1.
    rho_d : float
        Lambertian reflectance added to the lobe (energy is conserved when
        ``rho_d + 2π c_n/(n+2) ≤ 1``).

    Notes
    -----
    The albedo is evaluated with the azimuth integrated in closed form and a split
    Gauss-Legendre rule in the lobe angle (relative error < 1e-10). Unlike the corrected
    model (eq. 26), the plain Phong albedo at grazing incidence goes to 0 as n → ∞ (§2.1).
    Sampling follows eq. 19-22 (density ``(n+1)/(2π) cosⁿ α`` about the mirror direction of
    ``wo``, samples below the horizon rejected with pdf 0), mixed with cosine-weighted
    sampling of the diffuse term.

    References
    ----------
    Neumann et al. 1999, eq. 5, 6, 9, 19-22.
    """

    name: ClassVar[str] = "phong"
    KNOWN_ISSUES: ClassVar[tuple[str, ...]] = ()  # eq. 6 bound holds for eq. 5 itself
    PARAMS = (_P_N, _P_CN, _P_RHOD)
    REFERENCE = "Neumann et al. 1999, eq. 5-6 (reciprocal Phong)"
    SUMMARY = "reciprocal Phong lobe c_n cos^n(alpha) (+ Lambert)"


@register
class PhongNeumann(_PhongLobe):
    r"""Neumann's p-model, eq. 12 (the corrected "new" metal model eq. 7/10 at ``p = 1``).

    .. math:: f_r = \rho_d/\pi + c_n \frac{\cos^n\alpha}{\max(\cos\theta_i,\cos\theta_o)^p}

    Parameters
    ----------
    n : float
        Phong exponent.
    c_n : float or None
        Lobe scale; ``None`` = ``(n+2)/(2π)`` (eq. 6, valid for every p when n ≥ 1).
    p : float
        Transition parameter in [0, 1]: 0 = reciprocal Phong (eq. 5), 1 = eq. 7.
    rho_d : float
        Lambertian reflectance.

    Notes
    -----
    Albedo: closed-form azimuth (Neumann eq. 11 split into ``cos θ_o ≷ cos θ_i``) for
    ``p ∈ {0, 1}``, relative error < 1e-10; otherwise the lobe-frame quadrature with exact
    azimuth limits, converged to ``rtol``. At grazing incidence the ``p = 1`` albedo with the
    maximum ``c_n`` tends to ``(n+2)/(2(n+1))`` (eq. 26).

    References
    ----------
    Neumann et al. 1999, eq. 7, 10-12, 25-26.
    """

    name: ClassVar[str] = "phong_neumann"
    PARAMS = (_P_N, _P_CN, _P_P, _P_RHOD)
    REFERENCE = "Neumann et al. 1999, eq. 12 (eq. 7 at p = 1)"
    SUMMARY = "Neumann p-model c_n cos^n(alpha)/max(cos)^p (corrected metal Phong)"


@register
class PhongRetro(_PhongLobe):
    r"""Neumann's retro-reflective model, eq. 13.

    .. math:: f_r = \rho_d/\pi + c_n \frac{[(L\cdot V)^+]^n}{\max(\cos\theta_i,\cos\theta_o)}

    Parameters
    ----------
    n, c_n, rho_d
        As for :class:`Phong`; ``c_n=None`` = ``(n+2)/(2π)`` ("as defined in eq. 6").

    Notes
    -----
    The lobe about ``L`` makes the same angle with the normal as the mirror lobe, so the
    albedo equals that of ``phong_neumann`` (p = 1) with the same n and c_n. Sampling draws
    ``wi`` from ``(n+1)/(2π) [wi·wo]ⁿ`` (eq. 19-22 with R replaced by L).

    References
    ----------
    Neumann et al. 1999, eq. 13.
    """

    name: ClassVar[str] = "phong_retro"
    PARAMS = (_P_N, _P_CN, _P_RHOD)
    REFERENCE = "Neumann et al. 1999, eq. 13 (retro-reflective)"
    SUMMARY = "retro-reflective corrected Phong lobe about L"
    RETRO = True

    def _lobe_params(self) -> tuple[float, float, float, float]:
        n, c, _, rho_d = super()._lobe_params()
        return n, c, 1.0, rho_d


_KAPPA_DOC = "real part of the complex refractive index κ = n + ik (None: F = 1)"


@register
class MetalNeumann(_PhongLobe):
    r"""Neumann's metal model, eq. 27 / eq. 28.

    .. math:: f_r(λ) = \frac{n+2}{2\pi}\frac{\cos^n\alpha}{\cos\Theta_{min}}
              F(\kappa(\lambda), \Theta)

    with ``Θ = Θ_min`` (eq. 28, ``fresnel_angle="min"``) or the angle between L and the
    halfway vector (eq. 27's "straightforward selection", ``fresnel_angle="half"``); both are
    symmetric in L and V, so the model stays reciprocal.

    Parameters
    ----------
    n : float
        Phong exponent.
    kappa_re, kappa_im : float or 1-D array or None
        Real and imaginary parts of the complex refractive index κ(λ) (per band). ``None``
        gives F = 1 (Neumann §2.4: "for silver this is practically true").
    fresnel_angle : {"min", "half"}
        Angle at which F is evaluated.
    wavelength_nm : 1-D array or None
        Band centres (labels only) when κ is spectral.

    Notes
    -----
    The Fresnel factor is the exact unpolarised Fresnel reflectance (not Schlick's). With
    ``F = 1`` the albedo is the closed form of :class:`PhongNeumann` (p = 1); otherwise the
    lobe-frame quadrature converged to ``rtol``.

    References
    ----------
    Neumann et al. 1999, eq. 27-28.
    """

    name: ClassVar[str] = "metal_neumann"
    PARAMS = (
        Param("n", 20.0, 0.0, _N_MAX, "1", "Phong exponent"),
        Param("kappa_re", None, 1e-3, 100.0, "1", _KAPPA_DOC, spectral=True, optional=True),
        Param(
            "kappa_im", None, 0.0, 100.0, "1", "imaginary part of κ", spectral=True, optional=True
        ),
        Param("fresnel_angle", "min", doc="'min' (eq. 28) or 'half' (eq. 27)", kind="object"),
        Param("wavelength_nm", None, doc="band centres in nm", kind="object", optional=True),
    )
    REFERENCE = "Neumann et al. 1999, eq. 27-28 (metal)"
    SUMMARY = "Neumann metal: corrected Phong times Fresnel F(kappa, Theta_min)"

    def _lobe_params(self) -> tuple[float, float, float, float]:
        n = self._params["n"]
        return n, (n + 2.0) / (2.0 * np.pi), 1.0, 0.0

    def _setup(self) -> None:
        super()._setup()
        p = self._params
        if p["fresnel_angle"] not in ("min", "half"):
            raise ValueError(
                f"metal_neumann: fresnel_angle must be 'min' or 'half', got {p['fresnel_angle']!r}"
            )
        kr, ki = p["kappa_re"], p["kappa_im"]
        if kr is None and ki is not None:
            raise ValueError("metal_neumann: kappa_im given without kappa_re")
        self._eta = None
        if kr is not None:
            ki = 0.0 if ki is None else ki
            try:
                kr_b, ki_b = np.broadcast_arrays(np.asarray(kr), np.asarray(ki))
            except ValueError:
                raise ValueError(
                    f"metal_neumann: kappa_re (shape {np.shape(kr)}) and kappa_im "
                    f"(shape {np.shape(ki)}) have different band counts"
                ) from None
            self._eta = kr_b + 1j * ki_b
        self._wl = _check_wavelengths(p["wavelength_nm"], self._eta, self.name, "kappa_re")

    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        if self._eta is None or np.ndim(self._eta) == 0:
            return None
        if self._wl is not None:
            return self._wl
        return np.arange(np.size(self._eta), dtype=np.float64)

    def _has_fresnel(self) -> bool:
        return self._eta is not None

    def _fresnel(self, wi: NDArray, wo: NDArray, cmax: NDArray) -> NDArray | float:
        if self._eta is None:
            return 1.0
        if self._params["fresnel_angle"] == "min":
            c = cmax
        else:
            h = wi + wo
            nrm = np.sqrt(_dot(h, h))
            c = _dot(wi, h) / np.where(nrm > 0.0, nrm, 1.0)
        eta = self._eta
        if np.ndim(eta):
            return fresnel(c[..., None], eta)
        return fresnel(c, eta)


@register
class PlasticNeumann(_PhongLobe):
    r"""Neumann's plastic model, eq. 29 (eq. 30 when ``kappa`` is None, i.e. F = 1).

    .. math:: f_r(λ) = \frac{a_d(λ)}{\pi} + a_s \frac{n+2}{2\pi}
              \frac{\cos^n\alpha}{\cos\Theta_{min}} F(\kappa, \Theta_{min})

    Parameters
    ----------
    n : float
        Phong exponent.
    a_d : float or 1-D array
        Albedo of the diffuse component (per band, e.g. the (r, g, b) of eq. 30).
    a_s : float
        Size of the specular part; the paper requires ``a_s ≤ 1 − max(a_d)`` (checked).
    kappa : float or None
        Real refractive index for F (eq. 29); ``None`` = F ≡ 1 (eq. 30).
    wavelength_nm : 1-D array or None
        Band centres (labels only) when ``a_d`` is spectral.

    References
    ----------
    Neumann et al. 1999, eq. 29-30; figure 13 (a_s, n) sequence.
    """

    name: ClassVar[str] = "plastic_neumann"
    PARAMS = (
        Param("n", 20.0, 0.0, _N_MAX, "1", "Phong exponent"),
        Param("a_d", 0.5, 0.0, 1.0, "1", "diffuse albedo (per band)", spectral=True),
        Param("a_s", 0.05, 0.0, 1.0, "1", "specular size"),
        Param("kappa", None, 1.0, 10.0, "1", "real refractive index (None: F = 1)", optional=True),
        Param("wavelength_nm", None, doc="band centres in nm", kind="object", optional=True),
    )
    REFERENCE = "Neumann et al. 1999, eq. 29-30 (plastic)"
    SUMMARY = "Neumann plastic: a_d/pi + a_s x corrected Phong (x Fresnel)"

    def _lobe_params(self) -> tuple[float, float, float, float]:
        p = self._params
        n = p["n"]
        return n, p["a_s"] * (n + 2.0) / (2.0 * np.pi), 1.0, 0.0

    def _setup(self) -> None:
        super()._setup()
        p = self._params
        a_d = p["a_d"]
        if p["a_s"] + np.max(a_d) > 1.0 + 1e-12:
            raise ValueError(
                f"plastic_neumann: a_s + max(a_d) = {p['a_s'] + np.max(a_d)!r} exceeds 1 "
                "(eq. 30 requires a_s <= 1 - max(r, g, b))"
            )
        self._kd_arr = np.asarray(a_d) / np.pi if np.ndim(a_d) else a_d / np.pi
        self._wl = _check_wavelengths(p["wavelength_nm"], a_d, self.name, "a_d")

    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        a_d = self._params["a_d"]
        if np.ndim(a_d) == 0:
            return None
        return self._wl if self._wl is not None else np.arange(np.size(a_d), dtype=np.float64)

    def _diffuse(self) -> NDArray | float:
        return self._kd_arr

    def _diffuse_albedo(self) -> NDArray | float:
        return self._params["a_d"]

    def _has_fresnel(self) -> bool:
        return self._params["kappa"] is not None

    def _fresnel(self, wi: NDArray, wo: NDArray, cmax: NDArray) -> NDArray | float:
        k = self._params["kappa"]
        if k is None:
            return 1.0 if np.ndim(self._kd_arr) == 0 else np.ones(np.size(self._kd_arr))
        f = fresnel(cmax, k)
        return f[..., None] if np.ndim(self._kd_arr) else f


def _check_wavelengths(wl: Any, values: Any, model: str, what: str) -> NDArray | None:
    if wl is None:
        return None
    arr = np.asarray(wl, dtype=np.float64)
    if arr.ndim != 1 or not np.isfinite(arr).all() or np.any(arr <= 0):
        raise ValueError(f"{model}: wavelength_nm must be a 1-D array of positive nm, got {wl!r}")
    if values is None or np.size(values) != arr.size or np.ndim(values) != 1:
        raise ValueError(
            f"{model}: wavelength_nm has {arr.size} entries but {what} has shape {np.shape(values)}"
        )
    return arr


# =========================================================================== Blinn family


class _HalfLobe(BRDF):
    """Common evaluation of ``rho_d/π + D(h) · K(wi, wo)`` models in the half vector."""

    P: ClassVar[float] = 0.0  # exponent of 1/max(cos θ_i, cos θ_o)

    def _width(self) -> tuple[float, bool]:
        """Lobe width for the half-vector quadrature and whether it is a slope (tan map)."""
        return 0.1, False

    def _quadrature_albedo(self, wi: NDArray, rtol: float, max_level: int = 5) -> Any:
        if wi[2] <= 0.0:
            return 0.0
        width, tan_map = self._width()
        return float(
            refine_nodes(
                lambda n: half_vector_albedo(self._eval, wi, width, tan_map, n), rtol, max_level
            )
        )


class _Blinn(_HalfLobe):
    PARAMS = (
        Param("n", 10.0, 0.0, _N_MAX, "1", "Blinn exponent"),
        Param(
            "c_n",
            None,
            0.0,
            math.inf,
            "sr^-1",
            "scale; None = maximum C_n (table 1)",
            optional=True,
        ),
        _P_RHOD,
    )

    def _setup(self) -> None:
        p = self._params
        self._n = p["n"]
        c = p["c_n"]
        self._c = blinn_max_c_n(self._n, self.P == 1.0) if c is None else c
        self._kd = p["rho_d"] / np.pi

    def _width(self) -> tuple[float, bool]:
        return 1.0 / math.sqrt(self._n + 1.0), False

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci, co, up = _up(wi, wo)
        h = wi + wo
        hn = np.sqrt(_dot(h, h))
        nh = (ci + co) / np.where(up, hn, 1.0)
        spec = self._c * _pow_pos(nh, self._n)
        if self.P == 1.0:
            spec = spec / np.where(up, np.maximum(ci, co), 1.0)
        return np.where(up, self._kd + spec, 0.0)


@register
class BlinnPhong(_Blinn):
    r"""The Blinn model, Neumann eq. 32, plus an optional Lambertian term.

    .. math:: f_r = \rho_d/\pi + C_n (\mathbf N\cdot\mathbf H)^n

    Parameters
    ----------
    n : float
        Exponent.
    c_n : float or None
        Scale in sr⁻¹; ``None`` = the maximum energy-conserving C_n (Neumann table 1), i.e.
        ``1 / max_θ a(θ)`` of the model with C_n = 1, computed numerically
        (:func:`blinn_max_c_n`, cached per n).
    rho_d : float
        Lambertian reflectance.

    Notes
    -----
    Albedo by the half-vector quadrature (exact horizon limits), converged to ``rtol``.

    References
    ----------
    Neumann et al. 1999, eq. 32, table 1.
    """

    name: ClassVar[str] = "blinn_phong"
    REFERENCE = "Neumann et al. 1999, eq. 32 (Blinn)"
    SUMMARY = "Blinn lobe C_n (N.H)^n (+ Lambert)"


@register
class BlinnNeumann(_Blinn):
    r"""Neumann's corrected Blinn model, eq. 33.

    .. math:: f_r = \rho_d/\pi + C_n \frac{(\mathbf N\cdot\mathbf H)^n}
              {\max(\cos\theta_i, \cos\theta_o)}

    Parameters
    ----------
    n, c_n, rho_d
        As for :class:`BlinnPhong`; ``c_n=None`` = the corrected column of table 1.

    References
    ----------
    Neumann et al. 1999, eq. 33, table 1.
    """

    name: ClassVar[str] = "blinn_neumann"
    REFERENCE = "Neumann et al. 1999, eq. 33 (corrected Blinn)"
    SUMMARY = "corrected Blinn C_n (N.H)^n / max(cos)"
    P = 1.0


def _blinn_unit_albedo(n: float, corrected: bool, theta: float, nodes: int = 32) -> float:
    c = math.cos(theta)
    wi = np.array([math.sqrt(max(1.0 - c * c, 0.0)), 0.0, c])
    model = (BlinnNeumann if corrected else BlinnPhong)(n=n, c_n=1.0)
    return float(half_vector_albedo(model._eval, wi, 1.0 / math.sqrt(n + 1.0), False, nodes))


@lru_cache(maxsize=256)
def blinn_max_c_n(n: float, corrected: bool = False) -> float:
    """Maximum energy-conserving ``C_n`` of the Blinn model (Neumann table 1).

    ``C_n = 1 / max_θ a₁(θ)`` where ``a₁`` is the albedo with ``C_n = 1``. The albedo is
    computed by the half-vector quadrature on a 41-point grid of incidence angles
    (θ = 0 … 90° − 1e-6) and the maximum refined by a bounded scalar search (absolute
    tolerance 1e-7 rad). Cached per ``(n, corrected)``.

    References
    ----------
    Neumann et al. 1999, §7.1, table 1.
    """
    from scipy.optimize import minimize_scalar

    n = float(n)
    thetas = np.linspace(0.0, 0.5 * np.pi - 1e-6, 41)
    vals = np.array([_blinn_unit_albedo(n, corrected, t) for t in thetas])
    k = int(np.argmax(vals))
    best = vals[k]
    if 0 < k < len(thetas) - 1:
        res = minimize_scalar(
            lambda t: -_blinn_unit_albedo(n, corrected, t),
            bounds=(thetas[k - 1], thetas[k + 1]),
            method="bounded",
            options={"xatol": 1e-7},
        )
        best = max(best, -float(res.fun))
    elif k == len(thetas) - 1:
        best = max(best, _blinn_unit_albedo(n, corrected, 0.5 * np.pi - 1e-9))
    return 1.0 / best


# =========================================================================== Ward / Cook-Torrance


@register
class WardNeumann(Ward):
    r"""Neumann's corrected Ward model, eq. 35, with the anisotropic extension.

    .. math:: f_r = \frac{\rho_d}{\pi} + \frac{\rho_s}{4\pi\alpha_x\alpha_y}
              \frac{\exp[-\tan^2\delta(\cos^2\phi/\alpha_x^2+\sin^2\phi/\alpha_y^2)]}
                   {\max(\cos\theta_i, \cos\theta_o)}

    ``rho_s`` is Neumann's ``C_max``; table 2 gives its maximum energy-conserving value
    (≥ 1 for every printed m, so ``rho_s ≤ 1`` conserves energy for ``m ≤ 0.4``). The
    paper states the anisotropic extension in words ("a similar method can be applied to
    the anisotropic Ward model"): the denominator of Ward's eq. 5a is replaced in the same
    way.

    Parameters
    ----------
    rho_d, rho_s, alpha_x, alpha_y : float
        As for ``ward`` (Ward eq. 5a).

    Notes
    -----
    Sampling uses Ward's eq. 7 half-vector distribution (as ``ward``). The albedo is the
    half-vector quadrature converged to ``rtol``.

    References
    ----------
    Neumann et al. 1999, eq. 34-35, table 2; Ward 1992, eq. 5a, 7.
    """

    name: ClassVar[str] = "ward_neumann"
    REFERENCE = "Neumann et al. 1999, eq. 35 (corrected Ward, anisotropic)"
    SUMMARY = "Ward elliptical Gaussian with 1/max(cos) (Neumann-corrected)"
    ENERGY_CONSERVING = True
    KNOWN_ISSUES = ()
    _KERNEL = "ward_neumann"

    def _eval_numpy(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci, co, up, hx, hy, hz = half_vector_sum(wi, wo)
        cm = np.where(up, np.maximum(ci, co), 1.0)
        spec = self._ks * np.exp(-self._exponent(hx, hy, hz)) / cm
        return np.where(up, self._kd + spec, 0.0)


@register
class CookTorrance(_HalfLobe):
    r"""The Cook-Torrance model as written by Neumann, eq. 36-37 (F = 1 unless ``f0``).

    .. math:: f_r = \frac{\rho_d}{\pi} + k_s F \frac{\exp(-\tan^2\delta/m^2)}
              {4\pi m^2\cos^4\delta}\frac{G}{(N\cdot L)(N\cdot V)},\quad
              G = \min\{1, \tfrac{2(N·H)(N·V)}{V·H}, \tfrac{2(N·H)(N·L)}{L·H}\}

    Parameters
    ----------
    m : float
        RMS slope of the facets.
    f0 : float or None
        Normal-incidence reflectance for Schlick's approximation at the half angle,
        ``F = f0 + (1 − f0)(1 − cos θ_h)^5`` with ``cos θ_h = H·V`` (Li-Torrance eq. 5);
        ``None`` = F ≡ 1 as in Neumann's eq. 36.
    k_s : float
        Scale of the specular term.
    rho_d : float
        Lambertian reflectance.

    Notes
    -----
    Albedo by the half-vector quadrature converged to ``rtol``.

    Neumann §7.3 prints albedos 2.1, 9.3 and 91 at θ_L = 89.9°, 89.99°, 89.999° for
    m = 0.1 and §7.4 "proves" divergence by assuming G = 1 near grazing (eq. 39). With G of
    eq. 37 that assumption fails: ``G ≤ 2(N·H)(N·L)/(L·H)`` cancels the ``1/(N·L)``, and
    the computed albedo stays bounded — 0.99834, 0.99983, 0.99998 at those angles (it
    tends to 1). Without the geometry factor (G ≡ 1) the albedo does diverge, as
    ``1/cos θ_L`` (16.67, 162.1, 1617 at the same angles), but not with the printed
    values either. The tests check these computed values; ``ENERGY_CONSERVING`` stays
    False because the model has no energy bound by construction.

    References
    ----------
    Neumann et al. 1999, eq. 36-37, §7.3-7.4; Li and Torrance 2005, eq. 5.
    """

    name: ClassVar[str] = "cook_torrance"
    PARAMS = (
        Param("m", 0.1, 1e-3, 1.0, "1", "RMS facet slope"),
        Param("f0", None, 0.0, 1.0, "1", "Schlick normal reflectance (None: F = 1)", optional=True),
        Param("k_s", 1.0, 0.0, 1.0, "1", "specular scale"),
        _P_RHOD,
    )
    REFERENCE = "Neumann et al. 1999, eq. 36-37 (Cook-Torrance)"
    SUMMARY = "Cook-Torrance with Beckmann D and V-groove G (F = 1 or Schlick)"
    ENERGY_CONSERVING = False
    KNOWN_ISSUES = (
        "Neumann et al. 1999, §7.3-7.4 claims the albedo diverges at grazing incidence; "
        "with eq. 37's G it stays bounded (the masking term cancels 1/(N.L)), see the notes",
    )

    def _setup(self) -> None:
        p = self._params
        m = p["m"]
        self._m2 = m * m
        self._ks = p["k_s"] / (4.0 * np.pi * m * m)
        self._kd = p["rho_d"] / np.pi
        self._f0 = p["f0"]

    def _width(self) -> tuple[float, bool]:
        return self._params["m"], True

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci, co, up = _up(wi, wo)
        h = wi + wo
        hn = np.sqrt(_dot(h, h))
        hn = np.where(up, hn, 1.0)
        nh = np.where(up, (ci + co) / hn, 1.0)
        vh = np.where(up, 0.5 * (_dot(wo, h) + _dot(wi, h)) / hn, 1.0)  # = L·H = V·H
        nh2 = nh * nh
        tan2 = (1.0 - nh2) / nh2
        d = self._ks * np.exp(-tan2 / self._m2) / (nh2 * nh2)
        g = np.minimum(1.0, 2.0 * nh * np.minimum(co, ci) / vh)
        cc = np.where(up, ci * co, 1.0)
        spec = d * g / cc
        if self._f0 is not None:
            # clip: non-unit (e.g. float32-rounded) inputs can give v·h a hair above 1
            spec = spec * (self._f0 + (1.0 - self._f0) * np.clip(1.0 - vh, 0.0, 1.0) ** 5)
        return np.where(up, self._kd + spec, 0.0)


# =========================================================================== mean albedo


def mean_albedo(model: BRDF, nodes: int = 48, rtol: float = 1e-7) -> float:
    """Mean albedo ``(1/π) ∫ a(L) cos θ_L dω_L`` (Neumann eq. 43) of an isotropic model.

    ``a(θ)`` is :meth:`BRDF.albedo` at azimuth 0; the θ integral is Gauss-Legendre in
    ``cos² θ`` (``2 cos θ sin θ dθ = d(cos² θ)``) split at 45°, 70° and 85°.

    References
    ----------
    Neumann et al. 1999, eq. 43, table 3.
    """
    x, w = np.polynomial.legendre.leggauss(nodes)
    edges = np.cos(np.radians([90.0, 85.0, 70.0, 45.0, 0.0])) ** 2
    total = 0.0
    for lo, hi in itertools.pairwise(edges):
        mu2 = lo + (hi - lo) * 0.5 * (x + 1.0)
        mu = np.sqrt(mu2)
        wi = np.stack([np.sqrt(1.0 - mu2), np.zeros_like(mu), mu], axis=-1)
        a = np.asarray(model.albedo(wi, rtol=rtol), dtype=np.float64)
        total += float(np.sum(0.5 * (hi - lo) * w * a))
    return total
