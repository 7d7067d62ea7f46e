"""Calibration certificate of a diffuse reflectance standard (a file a laboratory receives).

Data only: the certified reflectance factor ``R = π f_r / ρ`` on a grid of geometries, the
standard's directional-hemispherical reflectance ``ρ`` and the expanded uncertainty (k = 2).
A reduction reads it from JSON (:meth:`Certificate.from_dict`), interpolates it
(:meth:`Certificate.factor_at`, :meth:`Certificate.brdf`) and refuses geometries it does not
cover (:meth:`Certificate.check_covers`). The simulator's true standard lives in
:mod:`gonio.simulator.standard`; this module knows nothing of it.

References
----------
JCGM 100:2008, Evaluation of measurement data - Guide to the expression of uncertainty in
measurement (GUM), §6 (expanded uncertainty, coverage factor).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Certificate", "relative_angles"]


def relative_angles(wi: NDArray, wo: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """``(θi, θo, Δφ)`` of directions (..., 3): polar angles and ``|φo - φi|`` in [0, π]
    (π: the forward, specular side)."""
    ti = np.arccos(np.clip(wi[..., 2], -1.0, 1.0))
    to = np.arccos(np.clip(wo[..., 2], -1.0, 1.0))
    dphi = np.abs(np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0])) % (
        2.0 * math.pi
    )
    dphi = np.where(dphi > math.pi, 2.0 * math.pi - dphi, dphi)
    return ti, to, dphi


@dataclass(frozen=True)
class Certificate:
    """A calibration certificate of a diffuse standard (what the laboratory knows).

    Parameters
    ----------
    rho : float
        Directional-hemispherical reflectance (the ``ρ_standard`` of eq. 2).
    theta_i_deg, theta_o_deg, dphi_deg : tuple of float
        The grid of certified geometries: incidence and viewing polar angles, and the
        azimuth between them (0 = backward, i.e. viewing on the incidence side; 180 =
        forward, the specular side), degrees, increasing.
    factor : ndarray (n_i, n_o, n_phi)
        Certified reflectance factor ``R = π f_r / ρ`` at the grid.
    expanded_uncertainty : float
        Relative expanded uncertainty ``U`` of ``R`` (and of ``ρ``), coverage factor ``k``.
    coverage_factor : float
        ``k`` (2: about 95 % coverage, GUM §6.2).
    name : str
        Label of the standard.
    """

    rho: float
    theta_i_deg: tuple[float, ...]
    theta_o_deg: tuple[float, ...]
    dphi_deg: tuple[float, ...]
    factor: NDArray[np.float64] = field(repr=False)
    expanded_uncertainty: float
    coverage_factor: float = 2.0
    name: str = "PTFE diffuse standard"

    def __post_init__(self) -> None:
        if not (0.0 < float(self.rho) <= 1.0):
            raise ValueError(f"rho must be in (0, 1], got {self.rho!r}")
        shape = []
        for name in ("theta_i_deg", "theta_o_deg", "dphi_deg"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) < 2 or any(b <= a for a, b in itertools.pairwise(v)):
                raise ValueError(f"{name} must hold at least 2 increasing angles, got {v!r}")
            object.__setattr__(self, name, v)
            shape.append(len(v))
        f = np.array(self.factor, dtype=np.float64)  # a copy, read-only: the table is fixed
        if f.shape != tuple(shape) or not np.isfinite(f).all() or (f <= 0).any():
            raise ValueError(f"factor must be positive and finite with shape {tuple(shape)}")
        f.setflags(write=False)
        object.__setattr__(self, "factor", f)
        u = float(self.expanded_uncertainty)
        if not (0.0 <= u < 1.0):
            raise ValueError(f"expanded_uncertainty must be in [0, 1), got {u!r}")
        object.__setattr__(self, "expanded_uncertainty", u)
        if not (float(self.coverage_factor) > 0.0):
            raise ValueError(f"coverage_factor must be > 0, got {self.coverage_factor!r}")

    @property
    def standard_uncertainty(self) -> float:
        """Relative standard uncertainty ``u = U / k``."""
        return self.expanded_uncertainty / float(self.coverage_factor)

    def check_covers(self, theta_i: ArrayLike, theta_o: ArrayLike | None = None) -> None:
        """Raise ``ValueError`` if an incidence (or viewing) angle, radians, lies outside the
        certified range."""
        for name, vals, grid in (
            ("theta_i", theta_i, self.theta_i_deg),
            ("theta_o", theta_o, self.theta_o_deg),
        ):
            if vals is None:
                continue
            d = np.degrees(np.asarray(vals, dtype=np.float64))
            if d.size and (d.min() < grid[0] - 1e-9 or d.max() > grid[-1] + 1e-9):
                raise ValueError(
                    f"{name} {float(d.min()):.3g}..{float(d.max()):.3g} deg is not covered by "
                    f"the certificate of {self.name!r} (range [{grid[0]:g}, {grid[-1]:g}] deg)"
                )

    def factor_at(self, theta_i: ArrayLike, theta_o: ArrayLike, dphi: ArrayLike) -> NDArray:
        """Certified ``R`` interpolated (trilinear) at angles in radians (Δφ as in the grid);
        angles outside the grid raise ``ValueError`` (:meth:`check_covers`)."""
        from gonio.numeric import grid_linear

        self.check_covers(theta_i, theta_o)
        shape = np.broadcast_shapes(np.shape(theta_i), np.shape(theta_o), np.shape(dphi))
        pts = np.stack(
            np.broadcast_arrays(
                np.degrees(np.asarray(theta_i, dtype=np.float64)),
                np.degrees(np.asarray(theta_o, dtype=np.float64)),
                np.clip(np.degrees(np.abs(np.asarray(dphi, dtype=np.float64))), 0.0, 180.0),
            ),
            axis=-1,
        )
        axes = (self.theta_i_deg, self.theta_o_deg, self.dphi_deg)
        return grid_linear(axes, self.factor, pts.reshape(-1, 3)).reshape(shape)

    def brdf(self, wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
        """Certified BRDF ``ρ R / π`` at directions in the standard's frame (..., 3)."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        ti, to, dphi = relative_angles(*np.broadcast_arrays(wi, wo))
        return self.rho / math.pi * self.factor_at(ti, to, dphi)

    @functools.cached_property
    def fingerprint(self) -> str:
        """The certificate's identity: its :meth:`to_dict` as sorted JSON (made once; every
        field, the factor table included, is read-only), e.g. a cache key."""
        import json

        return json.dumps(self.to_dict(), sort_keys=True, default=str)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (inverse of :meth:`from_dict`)."""
        return {
            "name": self.name,
            "rho": float(self.rho),
            "theta_i_deg": list(self.theta_i_deg),
            "theta_o_deg": list(self.theta_o_deg),
            "dphi_deg": list(self.dphi_deg),
            "dphi_convention": "180 = forward (specular side), 0 = backward",
            "factor": self.factor.tolist(),
            "expanded_uncertainty": self.expanded_uncertainty,
            "coverage_factor": float(self.coverage_factor),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Certificate:
        """Rebuild a certificate from :meth:`to_dict` output."""
        try:
            return cls(
                rho=d["rho"],
                theta_i_deg=tuple(d["theta_i_deg"]),
                theta_o_deg=tuple(d["theta_o_deg"]),
                dphi_deg=tuple(d["dphi_deg"]),
                factor=np.asarray(d["factor"], dtype=np.float64),
                expanded_uncertainty=d["expanded_uncertainty"],
                coverage_factor=d.get("coverage_factor", 2.0),
                name=d.get("name", "diffuse standard"),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad certificate description: missing {exc}") from None
