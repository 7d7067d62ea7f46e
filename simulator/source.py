"""The collimated source beam and the background (stray and ambient) light of the LBL dome.

Units: photon radiometry. Irradiance in photons s⁻¹ m⁻², radiance in photons s⁻¹ m⁻² sr⁻¹
(white light, one effective wavelength); the sensor turns photons into electrons.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3: "a 3-watt quartz-halogen lamp is used with an optically precise
parabolic reflector to produce a well collimated beam"; "the finite collimation of our light
source" (limits polished surfaces); the background measurement "reduce[s] the effects of stray
and ambient light" (eq. 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Background", "Source", "cone_directions"]


def _num(value: Any, name: str, positive: bool = False, hi: float = math.inf) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0.0 or (positive and v == 0.0) or v > hi:
        want = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be finite, {want} and <= {hi}, got {value!r}")
    return v


@dataclass(frozen=True)
class Source:
    """Collimated beam of finite divergence and finite spot.

    Parameters
    ----------
    irradiance : float
        Irradiance on a surface normal to the beam, photons s⁻¹ m⁻² (before the dome's
        transmittance).
    divergence : float
        Half-angle γ of the cone of directions in the beam (radians); the source's solid
        angle is ``Ω_s = 2π (1 - cos γ)`` and its radiance ``irradiance / Ω_s``.
    spot_radius : float
        Radius of the beam cross-section (metres); its footprint on the sample is an ellipse
        stretched by ``1/cos θ_i`` along the plane of incidence.
    arm_azimuth : float
        Dome azimuth of the plane the source arm pivots in (radians, "right" = 0). The
        sample holder rotates by ``arm_azimuth - φ_i`` to set φ_i.
    """

    irradiance: float = 8.0e18
    divergence: float = math.radians(0.25)
    spot_radius: float = 0.004
    arm_azimuth: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "irradiance", _num(self.irradiance, "irradiance", True))
        object.__setattr__(
            self, "divergence", _num(self.divergence, "divergence", True, math.radians(20))
        )
        object.__setattr__(self, "spot_radius", _num(self.spot_radius, "spot_radius", True))
        a = float(self.arm_azimuth)
        if not math.isfinite(a):
            raise ValueError(f"arm_azimuth must be finite, got {self.arm_azimuth!r}")
        object.__setattr__(self, "arm_azimuth", a)

    @property
    def solid_angle(self) -> float:
        """``Ω_s = 2π(1 - cos γ)`` in sr."""
        return 2.0 * math.pi * (1.0 - math.cos(self.divergence))

    @property
    def radiance(self) -> float:
        """Radiance of the beam within its cone, ``irradiance / Ω_s``."""
        return self.irradiance / self.solid_angle

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``metadata["source"]``)."""
        return {
            "irradiance_photons_s_m2": self.irradiance,
            "divergence": self.divergence,
            "solid_angle_sr": self.solid_angle,
            "spot_radius": self.spot_radius,
            "arm_azimuth": self.arm_azimuth,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Source:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(
                d["irradiance_photons_s_m2"], d["divergence"], d["spot_radius"], d["arm_azimuth"]
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad source description: missing {exc}") from None


@dataclass(frozen=True)
class Background:
    """Light the camera sees with or without a sample (what eq. 2's V_background removes).

    Parameters
    ----------
    ambient : float
        Uniform room radiance outside the dome (photons s⁻¹ m⁻² sr⁻¹), seen through the
        dome's transmittance.
    stray : float
        Peak radiance of the glow where the beam crosses the half-silvered dome (scatter in
        the acrylic), seen by the camera as a Gaussian spot.
    stray_width : float
        Angular RMS width of that glow (radians, as seen from the lens).
    """

    ambient: float = 2.0e15
    stray: float = 2.0e16
    stray_width: float = math.radians(6.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ambient", _num(self.ambient, "ambient"))
        object.__setattr__(self, "stray", _num(self.stray, "stray"))
        object.__setattr__(self, "stray_width", _num(self.stray_width, "stray_width", True))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``metadata["background"]``)."""
        return {"ambient": self.ambient, "stray": self.stray, "stray_width": self.stray_width}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Background:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(d["ambient"], d["stray"], d["stray_width"])
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad background description: missing {exc}") from None


def cone_directions(axis: NDArray, half_angle: float, n: int) -> tuple[NDArray, NDArray]:
    """``n`` directions spread evenly (equal solid angle) over a cone, with equal weights.

    Deterministic (a Fibonacci spiral on the spherical cap); ``n = 1`` gives the axis.
    Returns ``(dirs (n, 3), weights (n,))`` with weights summing to 1.
    """
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    if n <= 1:
        return axis[None, :], np.ones(1)
    k = np.arange(n) + 0.5
    cos_t = 1.0 - (k / n) * (1.0 - math.cos(half_angle))
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    local = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)
    # rotate z onto axis
    z = axis
    t = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(t, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    dirs = local[:, :1] * x + local[:, 1:2] * y + local[:, 2:] * z
    return dirs, np.full(n, 1.0 / n)
