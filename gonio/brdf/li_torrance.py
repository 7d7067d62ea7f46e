"""Li & Torrance's five-component reflection model (isotropic and anisotropic).

The model sums a specular mirror-like term (eq. 3), a first-surface directional-diffuse term
(eq. 9 with the rough-surface slope distribution eq. 10), a first-surface uniform-diffuse term
(eq. 11), a subsurface uniform-diffuse term (eq. 12) and a subsurface forward-scattering term
(eq. 13-14). Fresnel reflectance and transmittance use Schlick's approximation (eq. 5), the
shadowing/masking function the paper's approximation of Smith's function (eq. 6) with the S = 1
short-cut of eq. 7, and the effective roughness eq. 8. The anisotropic extension of the appendix
(eq. 20-26) replaces τ by τ_x, τ_y.

Interpretations and corrections of the printed text (each checked numerically, see the tests):

* **eq. 7** prints the threshold ``cos θ > 1 − 0.005^(τ/σ)``. Solving ``1 − (1 − cos θ)^(τ/σ) >
  0.995`` gives ``cos θ > 1 − 0.005^(σ/τ)``: with the printed exponent the threshold is
  ``1 − 1e-23`` for τ/σ = 10 and the short-cut would never apply. We use ``σ/τ``; then each factor
  of S exceeds 0.995 and S > 0.990025 (> 0.99 as the paper states).
* **eq. 10**: with ``v̄ = 2π(L + V)/λ`` the factor ``(v̄·v̄ / v̄·N)²`` is not dimensionless. We take
  ``v̄ = L + V`` (the wavenumber cancels against the He-Torrance prefactor from which eq. 10 is
  the ``g ≫ 1`` limit). Then ``D = exp(−tan²θ_b / 4m²) / (16 m² cos⁴θ_b)`` and eq. 9 is exactly
  the Cook-Torrance form ``F S D_B / (4 cos θi cos θr)`` with a Beckmann distribution of RMS
  slope ``2m`` (``D_B = exp(−tan²θ_b/4m²)/(4π m² cos⁴θ_b)``), so ``k_dd`` is indeed the
  directional-hemispherical reflectance of the term at normal incidence (F = S = 1).
* **eq. 3** prints ``k_dd F S exp(−g) Δ / (cos θi cos θr)`` and names ``dω_i`` without using it.
  Eq. 16 (and He et al. 1991) carry ``exp(−g) Δ / (cos θi dω_i)``: the mirror part reflects the
  fraction ``ρ = k_dd F S exp(−g)`` of the incident flux (Davies, eq. 2). We expose that
  reflectance through :meth:`LiTorrance.delta`; with ``d_omega_i`` set, ``__call__`` adds it as a
  top hat ``ρ / (sqrt(cos θi cos θr) dω_i)`` over the cone of solid angle ``dω_i`` around the
  mirror direction (eq. 16; the geometric mean keeps it reciprocal and equals cos θi on axis).
* **eq. 13-14**: ``tan²θ_f`` is even about θ_f = 90°, so read literally the term would add a
  mirror-image lobe at grazing *backward* reflection. The component is called forward scattering
  (§3.5, Figure 6), and ``exp(−tan²θ_f/16m²) → 0`` as θ_f → 90°, so we set it to 0 for
  θ_f ≥ 90° (continuous). As printed, eq. 14 depends on θr but not on θi, so the term is **not
  reciprocal**; every other component is. The effective slope in eq. 13 and eq. 26 is
  ``m_e = σ_e/τ`` (``σ_e/τ_x``, ``σ_e/τ_y``), as in eq. 10; eq. 21 prints σ/τ_x without the
  subscript e.

Evaluation goes through a numba kernel (compiled on first use, cached on disk, one pass per
direction pair with the band loop inside); the vectorised numpy implementation is the reference
(``model.use_kernel = False`` or the environment variable ``GONIO_NO_NUMBA`` selects it) and the
tests check that both agree to 1e-10.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.

Li and Torrance ("A Practical, Comprehensive Light
Reflection Model", 2005): eq. 2-14 (model), eq. 16-18 (constructed models of §5.2), eq. 20-26
(anisotropic appendix), tables 1-3 (best fits; presets in
``gonio/materials/data/li_torrance.json``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_unit_directions
from gonio.brdf._jit import lazy_kernel
from gonio.brdf.base import BRDF, Param, hemisphere_integral, register

__all__ = [
    "DEFAULT_WAVELENGTHS_NM",
    "LiTorrance",
    "effective_roughness",
    "shadowing",
    "shadowing_shortcut_mask",
    "smith_shadowing",
]

#: The 31 bands of the Cornell gonioreflectometer, 400-700 nm at 10 nm (§5.1).
DEFAULT_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)

_SPECTRAL = ("k_dd", "k_udf", "k_uds", "k_fs", "wavelength_nm", "f0", "n_ior")
_FLAGS = ("specular", "shadowing", "effective_roughness", "shortcut")


# --------------------------------------------------------------------------- helpers


def shadowing(cos_theta: ArrayLike, k: ArrayLike) -> NDArray[np.float64]:
    """One factor of the shadowing/masking approximation, ``1 − (1 − cos θ)^k``.

    ``k = τ/σ`` for an isotropic surface (eq. 6), ``k_i`` / ``k_r`` of eq. 25 for an
    anisotropic one (eq. 23). S is the product of the factors of θi and θr.

    References
    ----------
    Li and Torrance 2005, eq. 6, 23.
    """
    c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    return 1.0 - (1.0 - c) ** np.asarray(k, dtype=np.float64)


def shadowing_shortcut_mask(cos_i: ArrayLike, cos_r: ArrayLike, k_i: ArrayLike, k_r: ArrayLike):
    """Where eq. 7's short-cut sets S = 1: ``cos θ > 1 − 0.005^(1/k)`` for both directions.

    The paper prints the exponent ``τ/σ`` (= k); solving ``1 − (1 − cos θ)^k > 0.995`` gives
    ``1/k = σ/τ`` (module docstring). Inside the mask each factor exceeds 0.995, so S > 0.990025.

    References
    ----------
    Li and Torrance 2005, eq. 7.
    """
    ti = 1.0 - 0.005 ** (1.0 / np.asarray(k_i, dtype=np.float64))
    tr = 1.0 - 0.005 ** (1.0 / np.asarray(k_r, dtype=np.float64))
    return (np.asarray(cos_i) > ti) & (np.asarray(cos_r) > tr)


def effective_roughness(
    sigma: float, cos_i: ArrayLike, cos_r: ArrayLike, k_i: ArrayLike, k_r: ArrayLike
) -> NDArray[np.float64]:
    """Effective roughness σ_e of eq. 8 (eq. 24 with per-direction ``k_i``, ``k_r``).

    ``σ_e = σ [1 − (1 − cos θi)^(1.6 k_i)]^(0.1 k_i) [1 − (1 − cos θr)^(1.6 k_r)]^(0.1 k_r)``.

    References
    ----------
    Li and Torrance 2005, eq. 8, 24.
    """
    ci = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    cr = np.clip(np.asarray(cos_r, dtype=np.float64), 0.0, 1.0)
    k_i = np.asarray(k_i, dtype=np.float64)
    k_r = np.asarray(k_r, dtype=np.float64)
    a = (1.0 - (1.0 - ci) ** (1.6 * k_i)) ** (0.1 * k_i)
    b = (1.0 - (1.0 - cr) ** (1.6 * k_r)) ** (0.1 * k_r)
    return sigma * a * b


def smith_shadowing(theta: ArrayLike, sigma: float, tau: float) -> NDArray[np.float64]:
    """Smith's (1967) shadowing function of one direction, the form He et al. (1991) use.

    For a Gaussian surface of RMS height σ and correlation length τ (``C = exp(−r²/τ²)``),
    with ``a = τ cot θ / (2σ)``::

        Λ = ½ [exp(−a²)/(√π a) − erfc(a)],   S(θ) = (1 − ½ erfc(a)) / (1 + Λ)

    This is the reference curve of the paper's Figure 8 for eq. 6.

    References
    ----------
    Li and Torrance 2005, eq. 6 and Figure 8 (σ = 0.5 μm, τ = 2.5 μm); B. G. Smith,
    IEEE Trans. Antennas Propag. 15 (1967) 668-671.
    """
    from scipy.special import erfc

    th = np.asarray(theta, dtype=np.float64)
    if np.any((th < 0) | (th >= np.pi / 2)):
        raise ValueError(f"theta must lie in [0, pi/2), got {theta!r}")
    with np.errstate(divide="ignore"):
        a = tau / (2.0 * sigma * np.tan(th))
    a = np.minimum(a, 1e8)
    lam = 0.5 * (np.exp(-(a**2)) / (np.sqrt(np.pi) * a) - erfc(a))
    return (1.0 - 0.5 * erfc(a)) / (1.0 + lam)


def _schlick_x(c: NDArray) -> NDArray:
    """``(1 − cos)^5`` of Schlick's approximation (eq. 5)."""
    return (1.0 - np.clip(c, 0.0, 1.0)) ** 5


# --------------------------------------------------------------------------- numba kernel
# Plain-Python body; numba.njit(cache=True) compiles it on first use (as gonio.brdf.ward does).
# Same arithmetic as LiTorrance._eval_up; the tests compare the two paths.


def _k_li_torrance(wi, wo, out, kdd, kudf, kuds, kfs, f0, lam_um, sigma, tau_x, tau_y, flags,
                   cos_box, d_omega):  # pragma: no cover - compiled by numba  # fmt: skip
    """Every component of eq. 3-14 (and 20-26) for one direction pair per iteration.

    One function on purpose (over 80 lines): a kernel that :func:`gonio.brdf._jit.lazy_kernel`
    compiles cannot call plain-Python helpers, and compiled helpers cost time (measured for
    the Li-Torrance kernel; the module docstring of :mod:`gonio.brdf._jit`).
    """
    on_dd, on_udf, on_uds, on_fs, aniso, shadow, eff, shortcut, box = flags
    thr = 1.0 - 0.005 ** (sigma / tau_x)  # eq. 7 threshold of an isotropic surface
    nb = out.shape[1]
    pi = math.pi
    for k in range(out.shape[0]):
        ix, iy, ci = wi[k, 0], wi[k, 1], wi[k, 2]
        ox, oy, co = wo[k, 0], wo[k, 1], wo[k, 2]
        for b in range(nb):
            out[k, b] = 0.0
        if not (ci > 0.0 and co > 0.0):
            continue
        ci1 = min(ci, 1.0)
        co1 = min(co, 1.0)
        if aniso:
            r2 = ix * ix + iy * iy
            c2 = ix * ix / r2 if r2 > 0.0 else 1.0
            ki = math.sqrt(c2 * tau_x * tau_x + (1.0 - c2) * tau_y * tau_y) / sigma
            r2 = ox * ox + oy * oy
            c2 = ox * ox / r2 if r2 > 0.0 else 1.0
            kr = math.sqrt(c2 * tau_x * tau_x + (1.0 - c2) * tau_y * tau_y) / sigma
        else:
            ki = tau_x / sigma
            kr = ki
        # logs of (1 - cos): x**a computed as exp(a log x), one log per direction
        li = math.log(1.0 - ci1) if ci1 < 1.0 else -math.inf
        lo = math.log(1.0 - co1) if co1 < 1.0 else -math.inf
        sig_e = sigma
        if eff:
            a = math.exp(0.1 * ki * math.log1p(-math.exp(1.6 * ki * li)))
            bb = math.exp(0.1 * kr * math.log1p(-math.exp(1.6 * kr * lo)))
            sig_e = max(sigma * a * bb, 1e-30 * sigma)
        mx = sig_e / tau_x
        my = sig_e / tau_y
        if on_dd:
            hx = ix + ox
            hy = iy + oy
            hz = ci + co
            hh = hx * hx + hy * hy + hz * hz
            ihz2 = 1.0 / (hz * hz)
            if aniso:
                expo = (hx * hx / (mx * mx) + hy * hy / (my * my)) * ihz2 * 0.25
                norm = mx * my
            else:
                expo = (hx * hx + hy * hy) * ihz2 / (4.0 * mx * mx)
                norm = mx * mx
            d = hh * hh * ihz2 * ihz2 / (16.0 * norm) * math.exp(-expo)
            s = 1.0
            if shadow:
                if aniso:
                    ti = 1.0 - 0.005 ** (1.0 / ki)
                    tr = 1.0 - 0.005 ** (1.0 / kr)
                else:
                    ti = thr
                    tr = thr
                if not (shortcut and ci > ti and co > tr):
                    s = -math.expm1(ki * li) * -math.expm1(kr * lo)
            geo = s * d / (pi * ci * co)
            cos_h = 0.5 * math.sqrt(hh)
            x5 = (1.0 - min(max(cos_h, 0.0), 1.0)) ** 5
            for b in range(nb):
                out[k, b] += kdd[b] * (f0[b] + (1.0 - f0[b]) * x5) * geo
            if box:
                refl = -ix * ox - iy * oy + ci * co
                if refl >= cos_box:
                    q = 2.0 * pi * (ci + co) * sig_e
                    scale = s / (math.sqrt(ci * co) * d_omega)
                    for b in range(nb):
                        g = (q / lam_um[b]) ** 2
                        fr = f0[b] + (1.0 - f0[b]) * x5
                        out[k, b] += kdd[b] * fr * math.exp(-g) * scale
        if on_udf:
            for b in range(nb):
                out[k, b] += kudf[b] / pi
        if on_uds or on_fs:
            yy = (1.0 - (1.0 - ci1) ** 5) * (1.0 - (1.0 - co1) ** 5)
            ang = 0.0
            if on_fs:
                lxy = math.sqrt(ix * ix + iy * iy)
                cf = -(ox * ix + oy * iy) / lxy if lxy > 0.0 else 0.0
                cf = min(cf, 1.0)
                if cf > 0.0:
                    tan2 = (1.0 - cf * cf) / (cf * cf)
                    if aniso:
                        hx = ix + ox
                        hy = iy + oy
                        r2 = hx * hx + hy * hy
                        c2 = hx * hx / r2 if r2 > 0.0 else 0.5
                        inv = c2 / (mx * mx) + (1.0 - c2) / (my * my)
                    else:
                        inv = 1.0 / (mx * mx)
                    ang = math.exp(-tan2 * inv / 16.0) * (1.0 - ci) * (1.0 - co)
            for b in range(nb):
                tt = (1.0 - f0[b]) * (1.0 - f0[b]) * yy
                if on_uds:
                    out[k, b] += kuds[b] / pi * tt
                if on_fs:
                    out[k, b] += kfs[b] / pi * tt * ang


#: the compiled kernel, or ``None`` (numba missing or ``GONIO_NO_NUMBA`` set)
_kernel = lazy_kernel(_k_li_torrance)


# --------------------------------------------------------------------------- model


@register
class LiTorrance(BRDF):
    r"""Li-Torrance five-component BRDF, eq. 3-14, anisotropic per eq. 20-26.

    .. math::
        f_r = \underbrace{k_{dd}\frac{F S D}{\pi\cos\theta_i\cos\theta_r}}_{\text{eq. 9}}
            + \frac{k_{udf}}{\pi}
            + \frac{k_{uds}}{\pi} T_i T_r
            + \frac{k_{fs}}{\pi} T_i T_r (1-\cos\theta_i)(1-\cos\theta_r)
              e^{-\tan^2\theta_f / 16 m_e^2}
            \;[+\ \text{mirror part, eq. 3 / 16}]

    Parameters
    ----------
    k_dd, k_udf, k_uds, k_fs : float or array of bands
        Scale factors of the directional-diffuse (and mirror), first-surface uniform-diffuse,
        subsurface uniform-diffuse and subsurface forward-scattering terms. A term whose
        coefficient is 0 in every band is not computed.
    sigma : float
        RMS roughness height σ in μm.
    tau : float
        Autocorrelation length τ in μm (isotropic surface).
    tau_x, tau_y : float or None
        Autocorrelation lengths along the sample x and y axes (eq. 20); setting either makes the
        model anisotropic (the other defaults to ``tau``).
    wavelength_nm : float or array of bands
        Wavelength(s) λ in nm; it enters only the mirror part through ``g`` (eq. 4).
    f0 : float, array of bands or None
        Fresnel reflectance at normal incidence ``f_λ`` (eq. 5); ``None`` derives it from
        ``n_ior`` as ``((n − 1)/(n + 1))²``. Used for F (eq. 5) and ``T = 1 − F`` (eq. 12).
    n_ior : float or array of bands
        Refractive index ``n_λ`` (used only when ``f0`` is None).
    d_omega_i : float or None
        Solid angle (sr) of the incident light. ``None``: the mirror part is only available
        through :meth:`delta`. A number: ``__call__`` includes it as eq. 16's top hat over that
        cone (as the paper fits sample #45 with ``dω_i = 0.0005``) and :meth:`delta` returns 0.
    specular, shadowing, effective_roughness, shortcut : bool
        Switch the mirror part, S (eq. 6), σ_e (eq. 8; else σ_e = σ) and eq. 7's short-cut
        (``shortcut=False`` evaluates S everywhere; used to test the short-cut).

    Notes
    -----
    Coefficient arrays of 31 entries without ``wavelength_nm`` mean the 31 bands 400-700 nm;
    other band counts need ``wavelength_nm``. Values are ``(...)`` for a grey model and
    ``(..., n_bands)`` for a spectral one; the geometric factors are computed once for all bands.

    References
    ----------
    Li and Torrance 2005, eq. 3-14 and 20-26; see the module docstring for the corrections
    to eq. 3, 7, 10 and 13-14.
    """

    name: ClassVar[str] = "li_torrance"
    PARAMS = (
        Param("k_dd", 0.5, 0.0, 1.0, "1", "directional-diffuse (and mirror) scale", spectral=True),
        Param("k_udf", 0.0, 0.0, 1.0, "1", "first-surface uniform-diffuse", spectral=True),
        Param("k_uds", 0.3, 0.0, 1.0, "1", "subsurface uniform-diffuse", spectral=True),
        Param("k_fs", 0.0, 0.0, 10.0, "1", "subsurface forward scattering", spectral=True),
        Param("sigma", 0.5, 1e-4, 100.0, "um", "RMS roughness height"),
        Param("tau", 2.5, 1e-4, 1e4, "um", "autocorrelation length"),
        Param("tau_x", None, 1e-4, 1e4, "um", "autocorrelation length along x", optional=True),
        Param("tau_y", None, 1e-4, 1e4, "um", "autocorrelation length along y", optional=True),
        Param("wavelength_nm", 550.0, 100.0, 3000.0, "nm", "wavelength(s)", spectral=True),
        Param("f0", None, 0.0, 1.0, "1", "Fresnel reflectance at normal incidence", spectral=True,
              optional=True),
        Param("n_ior", 1.5, 1.0, 10.0, "1", "refractive index", spectral=True),
        Param("d_omega_i", None, 1e-9, 0.5, "sr", "solid angle of the incident light",
              optional=True),
        Param("specular", True, kind="object", doc="include the mirror-like part (eq. 3)"),
        Param("shadowing", True, kind="object", doc="apply S (eq. 6/23)"),
        Param("effective_roughness", True, kind="object", doc="use sigma_e (eq. 8/24)"),
        Param("shortcut", True, kind="object", doc="eq. 7's S = 1 short-cut"),
    )  # fmt: skip
    REFERENCE = "Li and Torrance 2005, eq. 3-14, anisotropic eq. 20-26"
    SUMMARY = "Li-Torrance five-component model (He-Torrance based, with subsurface terms)"
    RECIPROCAL = False
    ENERGY_CONSERVING = False
    KNOWN_ISSUES = (
        "the subsurface forward-scattering term (eq. 13-14) is not reciprocal: theta_f depends "
        "on theta_r but not theta_i; the model is reciprocal when k_fs = 0",
        "k_fs may exceed 1 (tables 2-3 fit 1.0-2.0); the sum is then not energy conserving",
    )

    # ------------------------------------------------------------------ setup
    def _setup(self) -> None:
        p = self._params
        for flag in _FLAGS:
            if not isinstance(p[flag], (bool, np.bool_)):
                raise ValueError(f"{self.name}: parameter {flag} must be True or False, "
                                 f"got {p[flag]!r}")  # fmt: skip
            p[flag] = bool(p[flag])
        lengths = {
            k: p[k].shape[0] for k in _SPECTRAL if isinstance(p[k], np.ndarray) and p[k].ndim == 1
        }
        if len(set(lengths.values())) > 1:
            raise ValueError(
                f"{self.name}: per-band parameters have different lengths {lengths}; "
                "expected one band count"
            )
        nb = next(iter(lengths.values())) if lengths else None
        if nb == 0:
            raise ValueError(f"{self.name}: per-band parameters must not be empty")
        wl = p["wavelength_nm"]
        if nb is None:
            self._wl: Any = float(wl)
        elif isinstance(wl, np.ndarray):
            self._wl = wl.astype(np.float64)
        elif nb == len(DEFAULT_WAVELENGTHS_NM):
            self._wl = DEFAULT_WAVELENGTHS_NM.copy()
        else:
            raise ValueError(
                f"{self.name}: wavelength_nm = {wl!r} is a scalar but the per-band parameters "
                f"have {nb} entries; expected wavelength_nm with {nb} entries (only 31 bands "
                "default to 400..700 nm)"
            )
        self._nb = nb

        def band(v: Any) -> Any:
            return np.broadcast_to(np.asarray(v, float), (nb,)).copy() if nb else float(v)

        self._k = {k: band(p[k]) for k in ("k_dd", "k_udf", "k_uds", "k_fs")}
        f0 = p["f0"] if p["f0"] is not None else ((p["n_ior"] - 1.0) / (p["n_ior"] + 1.0)) ** 2
        self._f0 = band(f0)
        self._on = {k: bool(np.any(np.asarray(v) > 0.0)) for k, v in self._k.items()}
        self._mirror = p["specular"] and self._on["k_dd"]
        self._box = self._mirror and p["d_omega_i"] is not None
        if self._box:
            self._cos_box = 1.0 - p["d_omega_i"] / (2.0 * np.pi)
        sigma, tau = p["sigma"], p["tau"]
        self._tau_x = p["tau_x"] if p["tau_x"] is not None else tau
        self._tau_y = p["tau_y"] if p["tau_y"] is not None else tau
        self._aniso = self._tau_x != self._tau_y
        self._sigma = sigma

    #: evaluate through the numba kernel when available (False: the numpy reference path)
    use_kernel: bool = True

    def _kernel_args(self, box: bool) -> tuple:
        nb = self._nb or 1

        def arr(v: Any) -> NDArray:
            return np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), (nb,)))

        k = self._k
        flags = (
            self._on["k_dd"], self._on["k_udf"], self._on["k_uds"], self._on["k_fs"],
            self._aniso, self._params["shadowing"], self._params["effective_roughness"],
            self._params["shortcut"], bool(box and self._box),
        )  # fmt: skip
        return (
            arr(k["k_dd"]), arr(k["k_udf"]), arr(k["k_uds"]), arr(k["k_fs"]), arr(self._f0),
            arr(np.asarray(self._wl) * 1e-3), float(self._sigma), float(self._tau_x),
            float(self._tau_y), tuple(bool(f) for f in flags),
            float(getattr(self, "_cos_box", 1.0)), float(self._params["d_omega_i"] or 1.0),
        )  # fmt: skip

    # ------------------------------------------------------------------ properties
    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        """Band centres (nm) of a spectral model, ``None`` for a grey one."""
        return None if self._nb is None else self._wl.copy()

    @property
    def is_anisotropic(self) -> bool:
        """Whether τ_x ≠ τ_y (appendix, eq. 20-26)."""
        return self._aniso

    @property
    def components(self) -> tuple[str, ...]:
        """Names of the components that are computed (non-zero coefficient)."""
        names = [k for k in ("k_dd", "k_udf", "k_uds", "k_fs") if self._on[k]]
        return tuple(n[2:] for n in names) + (("mirror",) if self._mirror else ())

    # ------------------------------------------------------------------ pieces
    def _k_dir(self, w: NDArray) -> NDArray | float:
        """``k = τ/σ`` (isotropic) or eq. 25's ``k(φ)`` of direction(s) ``w``."""
        if not self._aniso:
            return self._tau_x / self._sigma
        rho2 = w[..., 0] ** 2 + w[..., 1] ** 2
        safe = np.where(rho2 > 0.0, rho2, 1.0)
        c2 = np.where(rho2 > 0.0, w[..., 0] ** 2 / safe, 1.0)
        return np.sqrt(c2 * self._tau_x**2 + (1.0 - c2) * self._tau_y**2) / self._sigma

    def _geom(self, L: NDArray, V: NDArray):
        """σ_e, S and the k's shared by the components."""
        ci, co = L[..., 2], V[..., 2]
        ki, kr = self._k_dir(L), self._k_dir(V)
        p = self._params
        if p["effective_roughness"]:
            sig_e = effective_roughness(self._sigma, ci, co, ki, kr)
            sig_e = np.maximum(sig_e, 1e-30 * self._sigma)
        else:
            sig_e = np.full(ci.shape, self._sigma)
        return ci, co, ki, kr, sig_e

    def _shadow(self, ci: NDArray, co: NDArray, ki: Any, kr: Any) -> NDArray:
        if not self._params["shadowing"]:
            return np.ones(ci.shape)
        if not self._params["shortcut"]:
            return shadowing(ci, ki) * shadowing(co, kr)
        skip = shadowing_shortcut_mask(ci, co, ki, kr)
        s = np.ones(ci.shape)
        rest = ~skip
        if rest.any():
            kis = ki[rest] if np.ndim(ki) else ki
            krs = kr[rest] if np.ndim(kr) else kr
            s[rest] = shadowing(ci[rest], kis) * shadowing(co[rest], krs)
        return s

    def _fresnel(self, c: NDArray) -> Any:
        """Schlick F (eq. 5) at cosine(s) ``c``; ``(K,)`` or ``(K, n_bands)``."""
        x = _schlick_x(c)
        if self._nb:
            return self._f0 + (1.0 - self._f0) * x[..., None]
        return self._f0 + (1.0 - self._f0) * x

    def _transmit(self, c: NDArray) -> Any:
        """``T = 1 − F`` (eq. 12, Schlick) at cosine(s) ``c``."""
        y = 1.0 - _schlick_x(c)
        if self._nb:
            return (1.0 - self._f0) * y[..., None]
        return (1.0 - self._f0) * y

    def _bands(self, g: NDArray) -> NDArray:
        return g[..., None] if self._nb else g

    def _slopes(self, sig_e: NDArray) -> tuple[NDArray, NDArray]:
        return sig_e / self._tau_x, sig_e / self._tau_y

    def _eval_up(self, L: NDArray, V: NDArray, box: bool) -> NDArray:
        """Values for directions known to be above the horizon, flattened ``(K, 3)``."""
        shape = (L.shape[0],) + ((self._nb,) if self._nb else ())
        out = np.zeros(shape)
        k = self._k
        need = self._on["k_dd"] or self._on["k_fs"]
        if need:
            ci, co, ki, kr, sig_e = self._geom(L, V)
            mx, my = self._slopes(sig_e)
        else:
            ci, co = L[:, 2], V[:, 2]
        if self._on["k_dd"]:
            hx, hy, hz = L[:, 0] + V[:, 0], L[:, 1] + V[:, 1], ci + co
            hh = hx * hx + hy * hy + hz * hz
            ihz2 = 1.0 / (hz * hz)
            if self._aniso:
                expo = (hx * hx / (mx * mx) + hy * hy / (my * my)) * ihz2 * 0.25
                norm = mx * my
            else:
                expo = (hx * hx + hy * hy) * ihz2 / (4.0 * mx * mx)
                norm = mx * mx
            d = hh * hh * ihz2 * ihz2 / (16.0 * norm) * np.exp(-expo)  # eq. 10 / 22
            s = self._shadow(ci, co, ki, kr)
            geo = s * d / (np.pi * ci * co)
            cos_h = 0.5 * np.sqrt(hh)  # cos of the angle between H and V
            out += k["k_dd"] * self._fresnel(cos_h) * self._bands(geo)  # eq. 9
            if box:
                refl = -L[:, 0] * V[:, 0] - L[:, 1] * V[:, 1] + ci * co
                inside = refl >= self._cos_box
                if inside.any():
                    idx = np.flatnonzero(inside)
                    rho = self._mirror_reflectance(ci[idx], co[idx], sig_e[idx], s[idx], cos_h[idx])
                    scale = 1.0 / (np.sqrt(ci[idx] * co[idx]) * self._params["d_omega_i"])
                    out[idx] += rho * self._bands(scale)
        if self._on["k_udf"]:
            out += k["k_udf"] / np.pi  # eq. 11
        if self._on["k_uds"] or self._on["k_fs"]:
            tt = self._transmit(ci) * self._transmit(co)
            if self._on["k_uds"]:
                out += k["k_uds"] / np.pi * tt  # eq. 12
            if self._on["k_fs"]:
                out += k["k_fs"] / np.pi * tt * self._bands(self._forward(L, V, ci, co, mx, my))
        return out

    def _forward(self, L, V, ci, co, mx, my) -> NDArray:
        """Angular factor of eq. 13 / 26 (without k_fs, T's)."""
        lxy = np.hypot(L[:, 0], L[:, 1])
        safe = np.where(lxy > 0.0, lxy, 1.0)
        cf = np.where(lxy > 0.0, -(V[:, 0] * L[:, 0] + V[:, 1] * L[:, 1]) / safe, 0.0)  # eq. 14
        cf = np.minimum(cf, 1.0)
        fwd = cf > 0.0
        cfs = np.where(fwd, cf, 1.0)
        tan2 = (1.0 - cfs * cfs) / (cfs * cfs)
        if self._aniso:
            hx, hy = L[:, 0] + V[:, 0], L[:, 1] + V[:, 1]
            r2 = hx * hx + hy * hy
            c2 = np.where(r2 > 0.0, hx * hx / np.where(r2 > 0.0, r2, 1.0), 0.5)
            inv = c2 / (mx * mx) + (1.0 - c2) / (my * my)
        else:
            inv = 1.0 / (mx * mx)
        ang = np.where(fwd, np.exp(-tan2 * inv / 16.0), 0.0)
        return ang * (1.0 - ci) * (1.0 - co)

    def _mirror_reflectance(self, ci, co, sig_e, s, cos_h) -> NDArray:
        """``ρ = k_dd F S exp(−g)`` (eq. 2-4) per band."""
        lam_um = np.asarray(self._wl) * 1e-3
        q = 2.0 * np.pi * (ci + co)
        g = (q[:, None] * sig_e[:, None] / lam_um) ** 2 if self._nb else (q * sig_e / lam_um) ** 2
        return self._k["k_dd"] * self._fresnel(cos_h) * self._bands(s) * np.exp(-g)

    # ------------------------------------------------------------------ API
    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        return self._evaluate(wi, wo, self._box)

    def _evaluate(self, wi: NDArray, wo: NDArray, box: bool) -> NDArray:
        shape = np.broadcast_shapes(wi.shape, wo.shape)[:-1]
        L = np.broadcast_to(wi, shape + (3,)).reshape(-1, 3)
        V = np.broadcast_to(wo, shape + (3,)).reshape(-1, 3)
        bands = (self._nb,) if self._nb else ()
        k = _kernel() if self.use_kernel else None
        if k is not None:
            out = np.empty((L.shape[0], self._nb or 1))
            k(np.ascontiguousarray(L), np.ascontiguousarray(V), out, *self._kernel_args(box))
            return out.reshape(shape + bands)
        up = (L[:, 2] > 0.0) & (V[:, 2] > 0.0)
        if up.all():
            out = self._eval_up(L, V, box)
        else:
            out = np.zeros((L.shape[0],) + bands)
            idx = np.flatnonzero(up)
            if idx.size:
                out[idx] = self._eval_up(L[idx], V[idx], box)
        return out.reshape(shape + bands)

    def delta(self, wi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Mirror part: ``(mirror direction, ρ = k_dd F(θi) S(θi, θi) exp(−g))`` per band.

        ``g = (4π σ_e cos θi / λ)²`` (eq. 4 at θr = θi; Davies' eq. 2). Zero below the horizon,
        when ``specular`` is off or ``k_dd = 0``, and when ``d_omega_i`` is set (the part is
        then already in ``__call__``).

        References
        ----------
        Li and Torrance 2005, eq. 2-4, 16.
        """
        wi = as_unit_directions(wi, "wi")
        d = wi * np.array([-1.0, -1.0, 1.0])
        bands = (self._nb,) if self._nb else ()
        flat = wi.reshape(-1, 3)
        rho = np.zeros((flat.shape[0],) + bands)
        if self._mirror and not self._box:
            up = flat[:, 2] > 0.0
            if up.any():
                w = flat[up]
                ci, _, ki, _, sig_e = self._geom(w, d.reshape(-1, 3)[up])
                s = self._shadow(ci, ci, ki, ki)
                rho[up] = self._mirror_reflectance(ci, ci, sig_e, s, ci)
        return d, rho.reshape(wi.shape[:-1] + bands)

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray:
        """Quadrature of the continuous part plus the analytic mirror reflectance."""
        flat = wi.reshape(-1, 3)
        bands = (self._nb,) if self._nb else ()
        out = np.zeros((flat.shape[0],) + bands)
        for j, w in enumerate(flat):
            if w[2] <= 0.0:
                continue
            prev = None
            n_s, n_phi = 16, 32
            for _ in range(8):
                est = hemisphere_integral(lambda wo, w=w: self._evaluate(w, wo, False), n_s, n_phi)
                if prev is not None:
                    diff = np.max(np.abs(est - prev))
                    if diff <= rtol * np.max(np.abs(est)) or diff <= 1e-12:
                        break
                prev = est
                n_s, n_phi = 2 * n_s, 2 * n_phi
            out[j] = est
        if self._mirror:
            up = flat[:, 2] > 0.0
            if up.any():
                w = flat[up]
                ci, _, ki, _, sig_e = self._geom(w, w * np.array([-1.0, -1.0, 1.0]))
                s = self._shadow(ci, ci, ki, ki)
                out[up] += self._mirror_reflectance(ci, ci, sig_e, s, ci)
        return out.reshape(wi.shape[:-1] + bands)
