"""Mirror (dome) geometry from calibration captures of a front-surface mirror.

With a flat front-surface mirror in the sample holder, the source at incidence θi sends a
specular spot along the mirror direction of the beam: in the dome frame the direction at
polar angle θi, azimuth ``arm_azimuth + π``. Its image on the sensor (the spot's centroid,
:func:`spot_centroid`) is a pixel whose reflection direction a laboratory knows exactly. A
series of incidences gives a set of pixel ↔ direction pairs; :func:`fit_mirror` fits the
dome parameters the reduction's angle recovery uses (Ward's eq. 3 or the traced map of
:mod:`gonio.calibration.angles`: ``D/R``, the camera tilt) to them by least squares, with
the lens from its own calibration (:mod:`gonio.calibration.lens`). The map from camera to
reflection direction depends on ``D`` and ``R`` through ``D/R`` only, so the dome radius
stays at its nominal value.

The fit returns the parameters' covariance (from the residual scatter), which the campaign's
uncertainty budget propagates (:mod:`gonio.campaign.budget`).

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics (Proc.
SIGGRAPH '92), 26(2), 265-272. https://doi.org/10.1145/142920.134078, §3.2 and eq. 3
(reflection angles from camera angles; the mirror geometry ``R``, ``D``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gonio.calibration.angles import MirrorGeometry, reflection_directions
from numpy.typing import ArrayLike, NDArray

__all__ = ["MIRROR_PARAMETERS", "MirrorCalibration", "fit_mirror", "spot_centroid"]

#: Dome parameters :func:`fit_mirror` can fit.
MIRROR_PARAMETERS = ("d_over_r", "tilt_x", "tilt_y")


def spot_centroid(
    image: ArrayLike, black_level: float = 0.0, *, fraction: float = 0.005, radius: int = 8
) -> tuple[float, float, float]:
    """Intensity-weighted centroid ``(u, v, peak)`` of the brightest spot of a frame.

    Pixels above ``fraction`` of the peak (after removing ``black_level`` and the frame's
    median, the background) within ``radius`` pixels of the peak are weighted by their
    signal (a Gaussian spot of 1.5 px RMS: within 0.003 px). ValueError for a frame without
    a spot; the caller chooses an exposure that keeps the spot unsaturated.
    """
    a = np.asarray(image, dtype=np.float64) - float(black_level)
    if a.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {a.shape}")
    a = a - float(np.median(a))
    k = int(np.argmax(a))
    pv, pu = divmod(k, a.shape[1])
    peak = float(a[pv, pu])
    if not peak > 0:
        raise ValueError("the frame has no spot above its background")
    r = int(radius)
    v0, v1 = max(pv - r, 0), min(pv + r + 1, a.shape[0])
    u0, u1 = max(pu - r, 0), min(pu + r + 1, a.shape[1])
    win = a[v0:v1, u0:u1]
    w = np.where(win > fraction * peak, win, 0.0)
    vv, uu = np.mgrid[v0:v1, u0:u1]
    s = float(w.sum())
    return float((w * uu).sum() / s), float((w * vv).sum() / s), peak


@dataclass
class MirrorCalibration:
    """Result of :func:`fit_mirror`.

    Attributes
    ----------
    geometry : MirrorGeometry
        The calibrated dome geometry (nominal radius, fitted ``D``, tilt).
    names : list of str
        Fitted parameters (of :data:`MIRROR_PARAMETERS`).
    values, covariance : ndarray
        Their values and covariance (radians for the tilts).
    rms_deg : float
        RMS angle between the calibrated and the known directions.
    n_points : int
    """

    geometry: MirrorGeometry
    names: list[str]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    rms_deg: float
    n_points: int
    method: str = "eq3"
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def stderr(self) -> dict[str, float]:
        """Standard error of each fitted parameter."""
        return {
            n: float(math.sqrt(max(self.covariance[i, i], 0.0))) for i, n in enumerate(self.names)
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "kind": "gonio.mirror_calibration",
            "mirror": self.geometry.to_dict(),
            "method": self.method,
            "fitted": {n: float(v) for n, v in zip(self.names, self.values)},
            "stderr": self.stderr,
            "covariance": np.asarray(self.covariance).tolist(),
            "rms_deg": self.rms_deg,
            "n_points": self.n_points,
            **self.info,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> MirrorCalibration:
        """Inverse of :meth:`to_dict`."""
        names = list(d["fitted"])
        return cls(
            MirrorGeometry.from_metadata(d["mirror"]),
            names,
            np.array([d["fitted"][n] for n in names], dtype=np.float64),
            np.asarray(d["covariance"], dtype=np.float64).reshape(len(names), len(names)),
            float(d["rms_deg"]),
            int(d["n_points"]),
            str(d.get("method", "eq3")),
        )

    def perturbed(self, name: str, delta: float) -> MirrorGeometry:
        """The geometry with one fitted parameter moved by ``delta``."""
        return _apply(self.geometry, {name: _get(self.geometry, name) + float(delta)})


def _get(g: MirrorGeometry, name: str) -> float:
    if name == "d_over_r":
        return g.d_over_r
    if name == "tilt_x":
        return g.tilt[0]
    if name == "tilt_y":
        return g.tilt[1]
    raise ValueError(f"mirror parameter {name!r}; expected one of {MIRROR_PARAMETERS}")


def _apply(g: MirrorGeometry, values: Mapping[str, float]) -> MirrorGeometry:
    kw: dict[str, Any] = {}
    tilt = list(g.tilt)
    for name, v in values.items():
        if name == "d_over_r":
            kw["half_separation"] = float(v) * g.radius
        elif name == "tilt_x":
            tilt[0] = float(v)
        elif name == "tilt_y":
            tilt[1] = float(v)
        else:
            raise ValueError(f"mirror parameter {name!r}; expected one of {MIRROR_PARAMETERS}")
    return g.with_(tilt=tuple(tilt), **kw)


def fit_mirror(
    uv: ArrayLike,
    directions: ArrayLike,
    lens: Any,
    nominal: MirrorGeometry,
    *,
    method: str = "eq3",
    free: Sequence[str] = MIRROR_PARAMETERS,
) -> MirrorCalibration:
    """Fit the dome parameters to pixel ↔ known reflection direction pairs.

    Parameters
    ----------
    uv : array_like (n, 2)
        Pixel coordinates (spot centroids).
    directions : array_like (n, 3)
        The known dome-frame reflection direction of each.
    lens : FisheyeLens
        The calibrated lens.
    nominal : MirrorGeometry
        Start values (and the radius, which is not fitted).
    method : {"eq3", "exact"}
        The angle recovery the reduction will use.
    free : sequence of str
        Parameters to fit, of :data:`MIRROR_PARAMETERS`.

    Returns
    -------
    MirrorCalibration
    """
    from scipy.optimize import least_squares

    p = np.asarray(uv, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or d.shape != (p.shape[0], 3):
        raise ValueError(f"uv must be (n, 2) and directions (n, 3), got {p.shape}, {d.shape}")
    names = list(free)
    for n in names:
        _get(nominal, n)  # validates the name
    if p.shape[0] * 2 <= len(names):
        raise ValueError(f"{p.shape[0]} points cannot fit {len(names)} mirror parameters")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cam = lens.unproject(p)
    # residual: the predicted direction's components orthogonal to the known one
    e1 = np.cross(d, np.array([0.0, 0.0, 1.0]))
    bad = np.linalg.norm(e1, axis=1) < 1e-9
    e1[bad] = np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)

    def resid(x: NDArray) -> NDArray:
        try:
            g = _apply(nominal, dict(zip(names, x)))
        except ValueError:
            return np.full(2 * len(p), 1.0)
        wo, ok = reflection_directions(cam, g, method)
        r = np.concatenate([np.sum(wo * e1, 1), np.sum(wo * e2, 1)])
        return np.where(np.concatenate([ok, ok]), r, 1.0)

    x0 = np.array([_get(nominal, n) for n in names])
    sol = least_squares(resid, x0, method="lm", xtol=1e-14, ftol=1e-14)
    r = sol.fun
    dof = max(r.size - len(names), 1)
    s2 = float(r @ r) / dof
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    geo = _apply(nominal, dict(zip(names, sol.x)))
    wo, _ = reflection_directions(cam, geo, method)
    ang = np.degrees(np.arccos(np.clip(np.sum(wo * d, 1), -1.0, 1.0)))
    return MirrorCalibration(
        geo, names, sol.x, cov, float(np.sqrt(np.mean(ang**2))), int(p.shape[0]), method
    )
