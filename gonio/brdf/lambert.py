"""The Lambertian (ideal diffuse) reflector.

f_r = ρ/π, the diffuse term of every model gonio implements (e.g. Ward 1992
eq. 4, first term; Oren and Nayar 1994, the σ = 0 limit of eq. 25-30).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Eq. 4, its first term ρ_d/π.
.. [OrenNayar1994] M. Oren and S. K. Nayar, "Generalization of Lambert's reflectance model",
   Proc. SIGGRAPH '94, 239-246, 1994. https://doi.org/10.1145/192161.192213
   Eq. 25-30 in the limit σ = 0.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, Param, register
from gonio.geometry import cosine_hemisphere_pdf, square_to_hemisphere


@register
class Lambert(BRDF):
    """Ideal diffuse reflection, ``f_r = rho / pi``.

    Parameters
    ----------
    rho : float
        Diffuse (directional-hemispherical) reflectance, in [0, 1].

    References
    ----------
    Ward 1992, eq. 4, term ρ_d/π.
    """

    name: ClassVar[str] = "lambert"
    PARAMS = (Param("rho", 0.5, 0.0, 1.0, "1", "diffuse reflectance"),)
    REFERENCE = "Ward 1992, eq. 4 (diffuse term)"
    SUMMARY = "ideal diffuse reflector rho/pi"

    def _setup(self) -> None:
        self._k = self._params["rho"] / np.pi

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        up = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
        return np.where(up, self._k, 0.0)

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray:
        return np.where(wi[..., 2] > 0.0, self._params["rho"], 0.0)

    def _sample(self, wo: NDArray, rng: np.random.Generator):
        u = rng.random((2,) + wo.shape[:-1])
        wi = square_to_hemisphere(u[0], u[1], cosine=True)
        return wi, cosine_hemisphere_pdf(wi)

    def _pdf(self, wo: NDArray, wi: NDArray) -> NDArray:
        return cosine_hemisphere_pdf(wi) * np.ones(np.broadcast_shapes(wo.shape, wi.shape)[:-1])
