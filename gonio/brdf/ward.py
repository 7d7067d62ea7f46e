"""Ward's isotropic and anisotropic (elliptical) Gaussian models.

References
----------
003_0632ad07325ce89d.txt (G. J. Ward, "Measuring and Modeling Anisotropic Reflection",
SIGGRAPH 1992): eq. 4 (isotropic), eq. 5a (anisotropic), eq. 5b (its "computationally
convenient approximation"), eq. 7 (sampling).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, Param, register

_WARD_PARAMS = (
    Param("rho_d", 0.1, 0.0, 1.0, "1", "diffuse reflectance"),
    Param("rho_s", 0.05, 0.0, 1.0, "1", "specular reflectance"),
    Param("alpha_x", 0.1, 1e-4, 1.0, "1", "RMS surface slope along x"),
    Param("alpha_y", 0.1, 1e-4, 1.0, "1", "RMS surface slope along y"),
)

_WARD_ISSUES = ("albedo diverges at grazing incidence (001_84a7b2661ce0a5d4.txt §7.4, eq. 38-41)",)


@register
class Ward(BRDF):
    r"""Ward's anisotropic elliptical Gaussian, eq. 5a (eq. 4 when ``alpha_x == alpha_y``).

    .. math::
        f_r = \frac{\rho_d}{\pi} + \frac{\rho_s}{\sqrt{\cos\theta_i\cos\theta_o}}
              \frac{\exp[-\tan^2\delta(\cos^2\phi/\alpha_x^2+\sin^2\phi/\alpha_y^2)]}
                   {4\pi\alpha_x\alpha_y}

    With the unnormalised half vector ``h = wi + wo``, ``tan²δ cos²φ = (h_x/h_z)²`` and
    ``tan²δ sin²φ = (h_y/h_z)²``, so eq. 5a is evaluated exactly without trigonometry.

    Parameters
    ----------
    rho_d, rho_s : float
        Diffuse and specular reflectance.
    alpha_x, alpha_y : float
        Standard deviation of the surface slope along x and y (radians ≈ slope).

    References
    ----------
    003_0632ad07325ce89d.txt eq. 4, 5a; sampling eq. 7a-7b.
    """

    name: ClassVar[str] = "ward"
    PARAMS = _WARD_PARAMS
    REFERENCE = "003_0632ad07325ce89d.txt eq. 5a (eq. 4 isotropic)"
    SUMMARY = "Ward anisotropic elliptical Gaussian"
    ENERGY_CONSERVING = False
    KNOWN_ISSUES = _WARD_ISSUES

    def _setup(self) -> None:
        p = self._params
        self._kd = p["rho_d"] / np.pi
        self._ks = p["rho_s"] / (4.0 * np.pi * p["alpha_x"] * p["alpha_y"])
        self._ax2 = 1.0 / p["alpha_x"] ** 2
        self._ay2 = 1.0 / p["alpha_y"] ** 2

    def _exponent(self, hx: NDArray, hy: NDArray, hz: NDArray) -> NDArray:
        return (hx * hx * self._ax2 + hy * hy * self._ay2) / (hz * hz)

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        ci = wi[..., 2]
        co = wo[..., 2]
        up = (ci > 0.0) & (co > 0.0)
        hx = wi[..., 0] + wo[..., 0]
        hy = wi[..., 1] + wo[..., 1]
        hz = np.where(up, ci + co, 1.0)
        cc = np.where(up, ci * co, 1.0)
        spec = self._ks * np.exp(-self._exponent(hx, hy, hz)) / np.sqrt(cc)
        return np.where(up, self._kd + spec, 0.0)


@register
class WardApprox(Ward):
    r"""Ward's eq. 5b, the "computationally convenient approximation" of eq. 5a.

    Exponent ``-2 [(ĥ·x/α_x)² + (ĥ·y/α_y)²] / (1 + ĥ·n)`` with the normalised half vector.
    It agrees with eq. 5a to second order in δ (``2/(1 + cos δ)`` replaces ``1/cos² δ``) and
    departs from it at large half-angles.

    References
    ----------
    003_0632ad07325ce89d.txt eq. 5b.
    """

    name: ClassVar[str] = "ward_approx"
    REFERENCE = "003_0632ad07325ce89d.txt eq. 5b"
    SUMMARY = "Ward eq. 5b approximation of the elliptical Gaussian"

    def _exponent(self, hx: NDArray, hy: NDArray, hz: NDArray) -> NDArray:
        n2 = hx * hx + hy * hy + hz * hz
        n = np.sqrt(n2)
        return 2.0 * (hx * hx * self._ax2 + hy * hy * self._ay2) / (n2 * (1.0 + hz / n))
