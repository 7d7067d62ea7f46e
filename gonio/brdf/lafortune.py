"""Lafortune's generalized cosine lobes (with Neumann's per-lobe 1/max(cos)^p).

References
----------
.. [Lafortune1997] E. P. F. Lafortune, S.-C. Foo, K. E. Torrance and D. P. Greenberg, "Non-linear
   approximation of reflectance functions", Proc. SIGGRAPH '97, 117-126, 1997.
   https://doi.org/10.1145/258734.258801
   Eq. 3-5 (the generalized lobe as a scaled cosine lobe), eq. 6 (non-Lambertian diffuse
   lobe, ``c_x = c_y = 0``), eq. 7 (mirror term), eq. 8 (sum of lobes), table 1 (blue paint).
.. [Neumann1999] L. Neumann, A. Neumann and L. Szirmay-Kalos, "New simple reflectance models for
   metals and other specular materials" (technical report; revised as "Compact metallic
   reflectance models", Computer Graphics Forum 18(3), Proc. Eurographics '99, 161-172,
   1999, https://doi.org/10.1111/1467-8659.00337). Equation numbers are the report's.
   Eq. 14-16: the p-exponent per lobe.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_unit_directions
from gonio.brdf._lobes import (
    cosine_lobe_albedo,
    cosine_lobe_pdf,
    lobe_quadrature_albedo,
    refine_nodes,
    sample_cosine_lobe,
)
from gonio.brdf.base import BRDF, Param, register
from gonio.geometry import cosine_hemisphere_pdf, square_to_hemisphere

__all__ = ["Lafortune", "classic_lobe"]

_N_MAX = 1e8


def classic_lobe(n: float, rho_s: float = 1.0) -> tuple[float, float, float, float]:
    """The lobe equal to the classical cosine lobe ``ρ_s (n+2)/(2π) cosⁿ α`` (Lafortune eq. 1).

    ``−C_x = −C_y = C_z = (ρ_s C_s)^{1/n}`` with ``C_s = (n+2)/(2π)`` (§4.2, below eq. 4).
    """
    if not (n > 0 and math.isfinite(n)):
        raise ValueError(f"classic_lobe: n must be a positive finite number, got {n!r}")
    c = (rho_s * (n + 2.0) / (2.0 * math.pi)) ** (1.0 / n)
    return (-c, -c, c, float(n))


_DEFAULT_LOBES = (classic_lobe(10.0),)


@register
class Lafortune(BRDF):
    r"""Sum of generalized cosine lobes, Lafortune eq. 8, with an optional Lambertian term.

    .. math:: f_r(u, v) = \frac{\rho_d}{\pi} + \sum_i
              \frac{[C_{x,i} u_x v_x + C_{y,i} u_y v_y + C_{z,i} u_z v_z]_+^{n_i}}
                   {\max(u_z, v_z)^{p_i}}

    A lobe whose base is ≤ 0 contributes 0. ``p_i = 0`` (default) is Lafortune's lobe;
    ``p_i > 0`` is Neumann's eq. 16 (which writes the same lobe with the mirror vector,
    ``(R·V)_M`` = Lafortune's base with ``C_x, C_y`` negated).

    Parameters
    ----------
    lobes : sequence of tuples
        ``(c_x, c_y, c_z, n)`` or ``(c_x, c_y, c_z, n, p)`` per lobe; ``n ≥ 0``,
        ``0 ≤ p ≤ 1``. The default is one classical cosine lobe (n = 10, maximum albedo 1),
        see :func:`classic_lobe`.
    rho_d : float
        Lambertian reflectance (the "Diffuse" row of table 1).
    r_m : float
        Lafortune's eq. 7 mirror fraction ``R_m``: the fraction of the power a lobe loses
        (its scaling factor minus its actual albedo) that is reflected as an ideal mirror,
        returned by :meth:`delta`. For a sum of generalized lobes the lost power of lobe i
        is ``|M_i u|^{n_i} 2π/(n_i+1) − a_i(u)``, which reduces exactly to eq. 7's
        ``ρ_s − ρ_s(u)`` for a classical lobe with ``C_s = (n+1)/(2π)``.

    Notes
    -----
    Albedo: each lobe is a scaled cosine lobe about ``u' = Mu/|Mu|`` (eq. 5), integrated
    with the azimuth in closed form (relative error < 1e-10) for ``p ∈ {0, 1}`` and by
    the lobe-frame quadrature (converged to ``rtol``) otherwise. Sampling (§7: "a probability
    density function that is a linear combination of the primitive cosine reflectance
    lobes"): lobe i is chosen with probability ∝ ``|M_i wo|^{n_i} 2π/(n_i+1)`` and the
    diffuse term with probability ∝ ``rho_d``; ``wi`` then follows ``(n+1)/(2π) cosⁿ α'``
    about ``M_i wo/|M_i wo|`` (rejected below the horizon with pdf 0). The model is
    reciprocal (M diagonal); energy conservation depends on the coefficients.

    References
    ----------
    Lafortune et al. 1997, eq. 4-8, table 1; Neumann et al. 1999, eq. 16.
    """

    name: ClassVar[str] = "lafortune"
    PARAMS = (
        Param(
            "lobes",
            _DEFAULT_LOBES,
            doc="sequence of (c_x, c_y, c_z, n[, p]) generalized cosine lobes",
            kind="object",
        ),
        Param("rho_d", 0.0, 0.0, 1.0, "1", "Lambertian reflectance"),
        Param("r_m", 0.0, 0.0, 1.0, "1", "mirror fraction R_m of the lost lobe power (eq. 7)"),
    )
    REFERENCE = "Lafortune et al. 1997, eq. 8 (+ eq. 7 mirror; Neumann eq. 16 p)"
    SUMMARY = "sum of Lafortune generalized cosine lobes (+ Lambert, + mirror)"
    ENERGY_CONSERVING = False

    def _setup(self) -> None:
        lobes = _check_lobes(self._params["lobes"])
        self._params["lobes"] = lobes
        arr = np.array([lb[:3] for lb in lobes], dtype=np.float64).reshape(-1, 3)
        self._C = arr
        self._N = np.array([lb[3] for lb in lobes], dtype=np.float64)
        self._P = np.array([lb[4] for lb in lobes], dtype=np.float64)
        self._kd = self._params["rho_d"] / np.pi

    # ------------------------------------------------------------------ values
    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci = wi[..., 2]
        co = wo[..., 2]
        up = (ci > 0.0) & (co > 0.0)
        prod = wi * wo
        cmax = np.where(up, np.maximum(ci, co), 1.0)
        total = np.zeros(np.broadcast_shapes(ci.shape, co.shape))
        for (cx, cy, cz), n, p in zip(self._C, self._N, self._P):
            b = prod[..., 0] * cx + prod[..., 1] * cy + prod[..., 2] * cz
            pos = b > 0.0
            v = np.where(pos, np.power(np.where(pos, b, 1.0), n), 0.0)
            if p == 1.0:
                v = v / cmax
            elif p != 0.0:
                v = v / np.power(cmax, p)
            total = total + v
        return np.where(up, self._kd + total, 0.0)

    # ------------------------------------------------------------------ albedo
    def _lobe_albedos(self, wi: NDArray) -> tuple[NDArray, NDArray] | None:
        """Per-lobe ``(scale·2π/(n+1), albedo)``, shape ``(..., K)``; None if some p ∉ {0,1}."""
        if np.any((self._P != 0.0) & (self._P != 1.0)):
            return None
        ci = np.clip(wi[..., 2], 0.0, 1.0)
        full, alb = [], []
        for c, n, p in zip(self._C, self._N, self._P):
            mu = wi * c
            s = np.sqrt(np.einsum("...k,...k->...", mu, mu))
            cz = np.where(s > 0.0, mu[..., 2] / np.where(s > 0.0, s, 1.0), 1.0)
            scale = np.where(s > 0.0, np.power(s, n), 0.0)
            a = cosine_lobe_albedo(n, cz, np.maximum(ci, 1e-300), int(p))
            full.append(scale * 2.0 * np.pi / (n + 1.0))
            alb.append(scale * a)
        shape = wi.shape[:-1] + (len(self._N),)
        if not full:
            return np.zeros(shape), np.zeros(shape)
        return np.stack(full, axis=-1), np.stack(alb, axis=-1)

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray | None:
        res = self._lobe_albedos(wi)
        if res is None:
            return None
        up = wi[..., 2] > 0.0
        return np.where(up, self._params["rho_d"] + res[1].sum(axis=-1), 0.0)

    def _quadrature_albedo(self, wi: NDArray, rtol: float, max_level: int = 6) -> Any:
        if wi[2] <= 0.0:
            return 0.0
        total = self._params["rho_d"]
        for c, n, p in zip(self._C, self._N, self._P):
            mu = wi * c
            s = float(np.linalg.norm(mu))
            if s == 0.0:
                continue
            one = Lafortune(lobes=[(*c, n, p)])
            total += refine_nodes(
                lambda nodes, w=wi, m=one, a=mu / s, n=n: float(
                    lobe_quadrature_albedo(
                        lambda v: m._eval(np.broadcast_to(w, v.shape), v),
                        a,
                        n,
                        float(w[2]),
                        nodes,
                    )
                ),
                rtol,
                max_level,
            )
        return total

    # ------------------------------------------------------------------ mirror (eq. 7)
    def delta(self, wi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Eq. 7 mirror part: ``(mirror of wi, R_m Σ_i [|M_i wi|^{n_i} 2π/(n_i+1) − a_i(wi)])``.

        Reflectance 0 when ``r_m = 0`` or ``wi`` is at or below the horizon.
        """
        wi = as_unit_directions(wi, "wi")
        d = wi * np.array([-1.0, -1.0, 1.0])
        r_m = self._params["r_m"]
        if r_m == 0.0 or len(self._N) == 0:
            return d, np.zeros(wi.shape[:-1])
        res = self._lobe_albedos(wi)
        if res is None:
            flat = wi.reshape(-1, 3)
            lost = []
            for w in flat:
                full = 0.0
                for c, n in zip(self._C, self._N):
                    full += float(np.linalg.norm(w * c)) ** n * 2.0 * np.pi / (n + 1.0)
                lost.append(full - (self._quadrature_albedo(w, 1e-8) - self._params["rho_d"]))
            lost_arr = np.maximum(np.asarray(lost, dtype=np.float64), 0.0).reshape(wi.shape[:-1])
        else:
            lost_arr = np.maximum(res[0] - res[1], 0.0).sum(axis=-1)
        return d, np.where(wi[..., 2] > 0.0, r_m * lost_arr, 0.0)

    # ------------------------------------------------------------------ sampling
    def _components(self, wo: NDArray) -> tuple[NDArray, NDArray]:
        """Per-lobe axes ``(..., K, 3)`` and mixture weights ``(..., K+1)`` (last: diffuse)."""
        mu = wo[..., None, :] * self._C  # (..., K, 3)
        s = np.linalg.norm(mu, axis=-1)
        axes = np.where(
            (s > 0.0)[..., None], mu / np.where(s > 0.0, s, 1.0)[..., None], [0.0, 0.0, 1.0]
        )
        w = np.where(s > 0.0, np.power(s, self._N) * 2.0 * np.pi / (self._N + 1.0), 0.0)
        wd = np.full(wo.shape[:-1] + (1,), self._params["rho_d"])
        return axes, np.concatenate([w, wd], axis=-1)

    def _sample(self, wo: NDArray, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
        shape = wo.shape[:-1]
        u = rng.random((3,) + shape)
        axes, w = self._components(wo)
        total = w.sum(axis=-1)
        cdf = np.cumsum(w, axis=-1) / np.where(total > 0.0, total, 1.0)[..., None]
        k = np.minimum((cdf <= u[2][..., None]).sum(axis=-1), w.shape[-1] - 1)
        k = np.where(total > 0.0, k, w.shape[-1] - 1)  # nothing to sample: cosine
        diffuse = k == len(self._N)
        kk = np.minimum(k, max(len(self._N) - 1, 0))
        if len(self._N):
            axis = np.take_along_axis(axes, kk[..., None, None], axis=-2)[..., 0, :]
            n = self._N[kk]
            lobe = sample_cosine_lobe(axis, n, 1.0 - u[0], u[1])
        else:
            lobe = np.broadcast_to([0.0, 0.0, 1.0], shape + (3,))
        diff = square_to_hemisphere(u[0], u[1], cosine=True)
        wi = np.where(diffuse[..., None], diff, lobe)
        return wi, self._pdf(wo, wi)

    def _pdf(self, wo: NDArray, wi: NDArray) -> NDArray:
        wo, wi = np.broadcast_arrays(wo, wi)
        axes, w = self._components(wo)
        total = w.sum(axis=-1)
        pd = cosine_hemisphere_pdf(wi)
        acc = w[..., -1] * pd
        for i in range(len(self._N)):
            acc = acc + w[..., i] * cosine_lobe_pdf(axes[..., i, :], self._N[i], wi)
        pdf = np.where(total > 0.0, acc / np.where(total > 0.0, total, 1.0), pd)
        return np.where((wi[..., 2] > 0.0) & (wo[..., 2] > 0.0), pdf, 0.0)


def _check_lobes(lobes: Any) -> tuple[tuple[float, float, float, float, float], ...]:
    """Validate ``lobes``; return a tuple of ``(c_x, c_y, c_z, n, p)`` float tuples."""
    if isinstance(lobes, (str, bytes)) or not isinstance(lobes, (Sequence, np.ndarray)):
        raise ValueError(
            f"lafortune: lobes must be a sequence of (c_x, c_y, c_z, n[, p]) tuples, got {lobes!r}"
        )
    out = []
    for i, lobe in enumerate(lobes):
        where = f"lafortune: lobes[{i}] = {lobe!r}"
        if isinstance(lobe, (str, bytes)):
            raise ValueError(f"{where} must be a tuple (c_x, c_y, c_z, n[, p])")
        try:
            vals = np.asarray(lobe, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"{where} must be a tuple of numbers (c_x, c_y, c_z, n[, p])"
            ) from None
        if vals.ndim != 1 or vals.size not in (4, 5):
            raise ValueError(f"{where} must have 4 or 5 entries (c_x, c_y, c_z, n[, p])")
        if not np.isfinite(vals).all():
            raise ValueError(f"{where} contains a non-finite value")
        n = vals[3]
        if not (0.0 <= n <= _N_MAX):
            raise ValueError(f"{where}: exponent n = {n!r} is outside [0, {_N_MAX:g}]")
        p = vals[4] if vals.size == 5 else 0.0
        if not (0.0 <= p <= 1.0):
            raise ValueError(f"{where}: p = {p!r} is outside [0, 1]")
        out.append((float(vals[0]), float(vals[1]), float(vals[2]), float(n), float(p)))
    return tuple(out)
