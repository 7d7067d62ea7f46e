"""Angle recovery: pixel → camera direction → reflection direction → sample frame.

Ward's two steps (Ward 1992, §3.2): first the lens mapping from image points to
the lens incident direction (a calibrated fisheye model, :mod:`gonio.simulator.lenses` /
:mod:`gonio.calibration.lens`), then the reflection angles at the target from the camera
angles — by eq. 3 (an approximation for a hemisphere, exact for the hemi-ellipsoid whose foci
are the lens and sample centres), or by the exact traced map once the mirror geometry is
calibrated (:class:`MirrorGeometry`, :func:`trace`).

Frames (``docs/architecture.md`` and the simulator's notes): the dome frame has its origin at
the sphere / ellipsoid centre, ``z`` up the dome axis, ``x`` "right" (φ = 0); the lens centre
is at ``C = (0, −D, 0)`` and the sample centre at ``S = (0, +D, 0)``, both looking up ``+z``.
The nominal camera frame equals the dome frame. The sample frame is the dome frame turned by
the sample rotation about ``z``: ``w_sample = Rz(−rotation) · w_dome``.

:func:`trace` is this module's own ray tracer (sphere and prolate spheroid, plus a small
camera tilt and lens-centre offset), written from the geometry above; it is what mirror
calibration (:mod:`gonio.calibration.mirror`) fits, and a cross-check of the simulator's.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3.2, eq. 3 and Figure 3.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import check_scalar
from gonio.geometry import to_vector

__all__ = [
    "MirrorGeometry",
    "camera_directions",
    "eq3_directions",
    "reflection_directions",
    "rotation_z",
    "tilt_matrix",
    "to_sample_frame",
    "trace",
]

MIRROR_KINDS = ("hemisphere", "ellipsoid")


def _num(value: Any, name: str) -> float:
    """``value`` as a finite float (:func:`gonio._validate.check_scalar` without bounds)."""
    return check_scalar(value, name)


@dataclass(frozen=True)
class MirrorGeometry:
    """The dome geometry a reduction assumes (nominal or calibrated).

    Parameters
    ----------
    kind : {"hemisphere", "ellipsoid"}
    radius : float
        Sphere radius ``R``, or the ellipsoid's semi-major axis ``a`` (metres).
    half_separation : float
        ``D``, half the distance between lens and sample centres (``0 ≤ D < R``).
    tilt : (float, float)
        Small camera rotation about the dome ``x`` and ``y`` axes (radians): the camera-frame
        direction ``d`` is ``tilt_matrix(tilt) @ d`` in the dome frame.
    offset : (float, float, float)
        Lens-centre displacement from ``(0, −D, 0)`` (metres).
    """

    kind: str
    radius: float
    half_separation: float
    tilt: tuple[float, float] = (0.0, 0.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in MIRROR_KINDS:
            raise ValueError(
                f"mirror kind {self.kind!r} is unknown; expected one of {MIRROR_KINDS}"
            )
        r = _num(self.radius, "radius")
        d = _num(self.half_separation, "half_separation")
        if r <= 0:
            raise ValueError(f"radius must be > 0, got {r!r}")
        if not 0 <= d < r:
            raise ValueError(f"half_separation D = {d!r} must satisfy 0 ≤ D < radius = {r!r}")
        t = tuple(_num(x, "tilt") for x in np.ravel(self.tilt))
        o = tuple(_num(x, "offset") for x in np.ravel(self.offset))
        if len(t) != 2 or len(o) != 3:
            raise ValueError(f"tilt must have 2 and offset 3 components, got {t}, {o}")
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "half_separation", d)
        object.__setattr__(self, "tilt", t)
        object.__setattr__(self, "offset", o)

    @property
    def d_over_r(self) -> float:
        """``D / R``."""
        return self.half_separation / self.radius

    @classmethod
    def from_metadata(cls, meta: Mapping[str, Any]) -> MirrorGeometry:
        """From a side-car's ``mirror`` dict (``type``/``kind``, ``radius``,
        ``half_separation``; optional ``tilt``, ``offset``) or from that dict itself."""
        m = meta.get("mirror", meta) if isinstance(meta, Mapping) else None
        if not isinstance(m, Mapping):
            raise ValueError(f"mirror description must be a mapping, got {m!r}")
        kind = m.get("type", m.get("kind"))
        missing = [k for k, v in (("type", kind), ("radius", m.get("radius"))) if v is None]
        if m.get("half_separation") is None:
            missing.append("half_separation")
        if missing:
            raise ValueError(f"mirror metadata lacks {missing}; got keys {sorted(m)}")
        return cls(
            kind=str(kind),
            radius=m["radius"],
            half_separation=m["half_separation"],
            tilt=tuple(m.get("tilt", (0.0, 0.0))),
            offset=tuple(m.get("offset", (0.0, 0.0, 0.0))),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (accepted by :meth:`from_metadata`)."""
        return {
            "type": self.kind,
            "radius": self.radius,
            "half_separation": self.half_separation,
            "tilt": list(self.tilt),
            "offset": list(self.offset),
        }

    def with_(self, **kw: Any) -> MirrorGeometry:
        """A copy with some fields changed."""
        return replace(self, **kw)


def tilt_matrix(tilt: ArrayLike) -> NDArray[np.float64]:
    """Rotation ``Ry(ty) @ Rx(tx)`` for a small camera tilt ``(tx, ty)`` (radians)."""
    tx, ty = (float(x) for x in np.ravel(tilt))
    cx, sx, cy, sy = math.cos(tx), math.sin(tx), math.cos(ty), math.sin(ty)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    return ry @ rx


def rotation_z(angle: float) -> NDArray[np.float64]:
    """Rotation matrix about ``z`` by ``angle`` (radians)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def to_sample_frame(w_dome: ArrayLike, rotation: float) -> NDArray[np.float64]:
    """Dome-frame directions → sample frame of a sample rotated by ``rotation`` about ``z``."""
    w = np.asarray(w_dome, dtype=np.float64)
    c, s = math.cos(rotation), math.sin(rotation)
    out = np.empty(np.broadcast_shapes(w.shape, (3,)))
    out[..., 0] = c * w[..., 0] + s * w[..., 1]  # Rz(−rot) · w, element-wise: a (N, 3) @ (3, 3)
    out[..., 1] = c * w[..., 1] - s * w[..., 0]  # matmul is slower and BLAS-thread bound
    out[..., 2] = w[..., 2]
    return out


def camera_directions(lens: Any) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Unit camera-frame directions of every pixel centre and the in-image-circle mask.

    ``lens`` is a :class:`gonio.simulator.lenses.FisheyeLens` (or anything with
    ``pixel_grid``, ``unproject`` and ``in_field``).
    """
    uv = lens.pixel_grid()
    return lens.unproject(uv), lens.in_field(uv)


def eq3_directions(
    cam_dirs: ArrayLike, geometry: MirrorGeometry
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Reflection directions (dome frame) of camera directions by Ward's eq. 3.

    Uses :func:`gonio.simulator.optics.eq3_reflection_angles` (for the ellipsoid with the
    exact focal distance, as the simulator defines it). A camera tilt in ``geometry`` is
    applied first. Returns the unit directions and a mask of directions above the sample
    plane.
    """
    from gonio.simulator.optics import eq3_reflection_angles

    from gonio.geometry import to_spherical

    d = np.asarray(cam_dirs, dtype=np.float64)
    if any(geometry.tilt):
        d = d @ tilt_matrix(geometry.tilt).T
    theta_c, phi_c = to_spherical(d)
    up = theta_c < math.pi / 2
    theta_r, phi_r = eq3_reflection_angles(
        np.where(up, theta_c, 0.0),
        phi_c,
        geometry.radius,
        geometry.half_separation,
        mirror=geometry.kind,
    )
    ok = up & (theta_r < math.pi / 2)
    w = to_vector(np.where(ok, theta_r, 0.0), np.where(ok, phi_r, 0.0))
    return w, ok


def trace(
    cam_dirs: ArrayLike, geometry: MirrorGeometry
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Exact ray trace: camera direction → mirror → sample plane ``z = 0``.

    Parameters
    ----------
    cam_dirs : array_like (..., 3)
        Camera-frame directions (need not be unit).
    geometry : MirrorGeometry

    Returns
    -------
    wo : ndarray (..., 3)
        Unit direction from the sample-plane point towards the mirror point (dome frame).
    q : ndarray (..., 3)
        Point where the reflected ray meets the sample plane.
    valid : ndarray (...,) of bool
        The ray goes up, hits the dome and comes back down to the plane.
    """
    d = np.asarray(cam_dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    if any(geometry.tilt):
        d = d @ tilt_matrix(geometry.tilt).T
    R, D = geometry.radius, geometry.half_separation
    c = np.array([0.0, -D, 0.0]) + np.asarray(geometry.offset)
    if geometry.kind == "hemisphere":
        inv = np.array([1.0, 1.0, 1.0]) / R
    else:
        b = math.sqrt(R * R - D * D)
        inv = np.array([1.0 / b, 1.0 / R, 1.0 / b])
    # |M (c + t d)|² = 1 with M = diag(inv)
    mc = c * inv
    md = d * inv
    qa = np.sum(md * md, axis=-1)
    qb = np.sum(md * mc, axis=-1)
    qc = float(mc @ mc) - 1.0
    disc = qb * qb - qa * qc
    ok = (disc >= 0.0) & (d[..., 2] > 0.0)
    t = (-qb + np.sqrt(np.maximum(disc, 0.0))) / qa
    p = c + t[..., None] * d
    n = p * inv * inv
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    r = d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n
    down = r[..., 2] < 0.0
    ok &= down
    s = np.where(down, -p[..., 2] / np.where(down, r[..., 2], -1.0), 0.0)
    q = p + s[..., None] * r
    wo = -r
    return wo, q, ok


def reflection_directions(
    cam_dirs: ArrayLike, geometry: MirrorGeometry, method: str = "eq3"
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Dome-frame reflection directions by ``method`` ``"eq3"`` or ``"exact"`` (:func:`trace`)."""
    if method == "eq3":
        return eq3_directions(cam_dirs, geometry)
    if method == "exact":
        wo, _, ok = trace(cam_dirs, geometry)
        return wo, ok & (wo[..., 2] > 0.0)
    raise ValueError(f"angle method {method!r} is unknown; expected 'eq3' or 'exact'")
