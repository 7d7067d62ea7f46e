"""Spectral ingredients of the Cornell instrument: lamp, detector, polarisation, standard.

* Source: quartz-halogen lamp as a Planck curve at 3000-3200 K (default 3100 K), relative
  spectral radiance normalised to 1 at 560 nm.
* Detector: a grating spectroradiometer with a silicon array; its relative responsivity is a
  smooth curve (peak near 550 nm, falling towards 385 and 710 nm) and its grating efficiency
  depends on polarisation (``s`` rising, ``p`` falling with wavelength by ±15 % across the
  range) — the reason the instrument measures two polarisations and combines them.
* Standard: a Spectralon-like diffuse reflector, reflectance 0.99 at 700 nm falling linearly to
  0.975 at 400 nm (typical of pressed PTFE), treated as Lambertian.

These shapes are instrument-plausible assumptions, not measured data; each ratio used in the
reduction cancels them, so they only shape the raw spectra and the noise.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.

Li and Torrance 2005, §5.1 (31 bands 400-700 nm, RGB conversion); issue 7 (quartz-halogen
source, ~1024-pixel spectroradiometer over 385-710 nm, two polarisations, Spectralon standard).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["detector_response", "halogen_spectrum", "planck", "spectralon_reflectance"]

_H, _C, _K = 6.62607015e-34, 2.99792458e8, 1.380649e-23


def planck(wavelength_nm: ArrayLike, temperature_k: float) -> NDArray[np.float64]:
    """Black-body spectral radiance (W sr⁻¹ m⁻³) at ``wavelength_nm``."""
    if not (temperature_k > 0):
        raise ValueError(f"temperature_k must be positive, got {temperature_k!r}")
    lam = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    return 2 * _H * _C**2 / lam**5 / np.expm1(_H * _C / (lam * _K * temperature_k))


def halogen_spectrum(wavelength_nm: ArrayLike, temperature_k: float = 3100.0) -> NDArray:
    """Relative spectral radiance of a quartz-halogen lamp (Planck shape), 1 at 560 nm."""
    if not (2500.0 <= temperature_k <= 3500.0):
        raise ValueError(f"temperature_k = {temperature_k!r}: expected a halogen 2500-3500 K")
    return planck(wavelength_nm, temperature_k) / planck(560.0, temperature_k)


def detector_response(wavelength_nm: ArrayLike, polarization: str | None = None) -> NDArray:
    """Relative responsivity of the spectroradiometer (1 at its 550 nm peak).

    ``polarization``: ``"s"``, ``"p"`` or ``None`` (mean of the two, i.e. unpolarised light).
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    base = np.exp(-(((lam - 550.0) / 190.0) ** 2)) + 1e-3
    tilt = 0.15 * np.clip((lam - 550.0) / 150.0, -2.0, 2.0)
    if polarization is None:
        return base
    if polarization == "s":
        return base * (1.0 + tilt)
    if polarization == "p":
        return base * (1.0 - tilt)
    raise ValueError(f"polarization = {polarization!r}: expected 's', 'p' or None")


def spectralon_reflectance(wavelength_nm: ArrayLike) -> NDArray:
    """Directional-hemispherical reflectance of the diffuse standard (0.975 → 0.99)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return 0.975 + 0.015 * np.clip((lam - 400.0) / 300.0, 0.0, 1.0)
