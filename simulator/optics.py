"""Dome optics of the LBL imaging gonioreflectometer: mirrors, exact ray tracing and eq. 3.

Dome frame (Ward's Figure 3): origin at the centre of the sphere (or of the ellipsoid),
``z`` up the dome axis, ``x`` to the "right" (azimuth 0), ``y = z × x``. The camera lens
centre ``C = (0, -D, 0)`` and the sample centre ``S = (0, +D, 0)`` lie on a diameter, ``2D``
apart, both looking up ``+z``; the sample surface is the plane ``z = 0``. With these
positions eq. 3's ``r_c sin φ_c sin θ_c - 2D`` is the ``y`` component of the vector from the
sample to the mirror point, so the signs of the printed equation hold as printed.

Mirrors
-------
``hemisphere``
    Sphere of radius ``R`` about the origin (upper half).
``ellipsoid``
    Prolate spheroid with foci ``C`` and ``S``: semi-major axis ``a = radius`` along ``y``,
    semi-minor ``b = sqrt(a² - D²)`` along ``x`` and ``z`` (upper half). Every ray from ``C``
    reflects exactly through ``S`` (the focal property).

Exact tracing (:meth:`Mirror.trace`): the camera ray from ``C`` meets the quadric at ``P``,
reflects about the surface normal, and meets the sample plane at ``Q``; the sample point seen
is ``Q`` and the reflected direction (away from the sample, Ward's d̂_r) is ``wo = (P - Q)/|P - Q|``.

Eq. 3 as printed (Ward 1992)::

    r_c = D sin φc sin θc + sqrt(D² sin² φc sin² θc + R² - D²)
    θ_r = acos[ r_c cos θc / sqrt(r_c² cos² φc sin² θc + (r_c sin φc sin θc - 2D)² + r_c² cos² θc) ]
    φ_r = atan[ (r_c sin φc sin θc - 2D) / (r_c cos φc sin θc) ]     (atan2, as the paper asks)

``r_c`` is the distance from the camera to a *sphere* of radius ``R``; ``(θ_r, φ_r)`` is the
direction from the sample centre ``S`` to that sphere point. That is an approximation twice
over for the hemisphere (the reflected ray does not pass through ``S``, and it leaves ``P``
along the mirror reflection, not along ``P - S``). For the ellipsoid, the direction ``P - S``
*is* the reflected ray (focal property), so eq. 3 becomes exact once ``r_c`` is the distance
to the ellipsoid, ``r_c = (a² - D²)/(a - D sin φc sin θc)`` (focal polar form of the ellipse);
with the printed sphere ``r_c`` and ``R = a`` it is not exact (its error is reported by
:func:`eq3_error` with ``form="printed"``). ``θ_r`` is computed as
``atan2(sqrt(X² + Y²), Z)``, mathematically the printed ``acos(Z/|v|)`` but accurate near
``θ_r = 0`` where ``acos`` loses half the digits.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3, Figure 3 and eq. 3 (and the note on atan2 beneath it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MIRRORS",
    "Mirror",
    "eq3_error",
    "eq3_reflection_angles",
    "traced_reflection_angles",
]

#: valid mirror kinds
MIRRORS: tuple[str, ...] = ("hemisphere", "ellipsoid")


def _check_geometry(radius: Any, half_separation: Any) -> tuple[float, float]:
    try:
        r = float(radius)
        d = float(half_separation)
    except (TypeError, ValueError):
        raise ValueError(
            f"radius and half_separation must be numbers, got {radius!r}, {half_separation!r}"
        ) from None
    if not (math.isfinite(r) and r > 0.0):
        raise ValueError(f"radius must be a finite positive length, got {radius!r}")
    if not (math.isfinite(d) and d >= 0.0):
        raise ValueError(f"half_separation must be a finite length >= 0, got {half_separation!r}")
    if d >= r:
        raise ValueError(
            f"half_separation D = {d!r} must be smaller than radius R = {r!r} "
            "(camera and sample must sit inside the dome)"
        )
    return r, d


def _check_mirror(kind: Any) -> str:
    if kind not in MIRRORS:
        raise ValueError(f"mirror {kind!r} is unknown; expected one of {', '.join(MIRRORS)}")
    return kind


def _wrap_phi(phi: NDArray) -> NDArray:
    """Map atan2's −π to +π so that φ ∈ (−π, π]."""
    return np.where(phi <= -np.pi, phi + 2.0 * np.pi, phi)


def eq3_reflection_angles(
    theta_c: ArrayLike,
    phi_c: ArrayLike,
    radius: float,
    half_separation: float,
    mirror: str = "hemisphere",
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ward's eq. 3: camera angles (θ_c, φ_c) → reflection angles (θ_r, φ_r).

    Parameters
    ----------
    theta_c, phi_c : array_like
        Polar angle from the camera axis and azimuth ("right is 0°"), radians; broadcast.
    radius : float
        ``R``: sphere radius, or the ellipsoid's semi-major axis ``a``.
    half_separation : float
        ``D``: half the distance between the camera and sample centres (``0 <= D < R``).
    mirror : {"hemisphere", "ellipsoid"}
        ``"hemisphere"`` evaluates eq. 3 exactly as printed (``r_c`` from the sphere).
        ``"ellipsoid"`` replaces ``r_c`` by the exact camera-to-ellipsoid distance
        ``(a² - D²)/(a - D sin φc sin θc)``, which makes eq. 3 exact for that mirror.

    Returns
    -------
    theta_r, phi_r : ndarray
        Polar angle from the sample normal in [0, π/2] and azimuth in (−π, π], radians.

    References
    ----------
    Ward 1992, eq. 3.

    Examples
    --------
    >>> t, p = eq3_reflection_angles(0.0, 0.0, 1.0, 0.0)
    >>> float(t), float(p)
    (0.0, 0.0)
    """
    r, d = _check_geometry(radius, half_separation)
    _check_mirror(mirror)
    tc = np.asarray(theta_c, dtype=np.float64)
    pc = np.asarray(phi_c, dtype=np.float64)
    if not (np.isfinite(tc).all() and np.isfinite(pc).all()):
        raise ValueError("theta_c and phi_c must be finite")
    if np.any(tc < 0.0) or np.any(tc > np.pi / 2):
        raise ValueError(
            f"theta_c must be in [0, pi/2] (the camera looks up the dome axis), got range "
            f"[{float(tc.min()):.6g}, {float(tc.max()):.6g}]"
        )
    st = np.sin(tc)
    sy = np.sin(pc) * st  # y component of the unit camera ray
    if mirror == "hemisphere":
        rc = d * sy + np.sqrt(d * d * sy * sy + r * r - d * d)
    else:
        rc = (r * r - d * d) / (r - d * sy)
    x = rc * np.cos(pc) * st
    y = rc * sy - 2.0 * d
    z = rc * np.cos(tc)
    theta_r = np.arctan2(np.hypot(x, y), z)
    phi_r = _wrap_phi(np.arctan2(y, x))
    return theta_r, phi_r


@dataclass(frozen=True)
class Mirror:
    """The half-silvered dome: shape, size, and its reflectance and transmittance.

    Parameters
    ----------
    kind : {"hemisphere", "ellipsoid"}
        Mirror shape (see the module docstring).
    radius : float
        Sphere radius, or the ellipsoid's semi-major axis (metres).
    half_separation : float
        ``D``, half the camera–sample distance (metres), ``0 <= D < radius``.
    reflectance, transmittance : float
        Half-silvering: fraction of light reflected (sample → camera) and transmitted
        (source beam → sample, ambient light → camera); ``reflectance + transmittance <= 1``.

    References
    ----------
    Ward 1992, §3 and Figure 3 ("half-silvered hemisphere or hemi-ellipsoid").
    """

    kind: str = "ellipsoid"
    radius: float = 0.15
    half_separation: float = 0.01
    reflectance: float = 0.5
    transmittance: float = 0.45

    def __post_init__(self) -> None:
        _check_mirror(self.kind)
        r, d = _check_geometry(self.radius, self.half_separation)
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "half_separation", d)
        for name in ("reflectance", "transmittance"):
            v = getattr(self, name)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {v!r}") from None
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"{name} must be in [0, 1], got {v!r}")
            object.__setattr__(self, name, v)
        if self.reflectance + self.transmittance > 1.0 + 1e-12:
            raise ValueError(
                f"reflectance + transmittance = {self.reflectance + self.transmittance!r} "
                "exceeds 1 (a half-silvered mirror cannot create light)"
            )

    # ------------------------------------------------------------------ shape
    @property
    def semi_axes(self) -> tuple[float, float, float]:
        """Semi-axes ``(ax, ay, az)`` of the quadric (equal for the hemisphere)."""
        if self.kind == "hemisphere":
            return (self.radius,) * 3
        b = math.sqrt(self.radius**2 - self.half_separation**2)
        return (b, self.radius, b)

    @property
    def camera_position(self) -> NDArray[np.float64]:
        """Lens centre ``C = (0, -D, 0)``."""
        return np.array([0.0, -self.half_separation, 0.0])

    @property
    def sample_position(self) -> NDArray[np.float64]:
        """Sample centre ``S = (0, +D, 0)``."""
        return np.array([0.0, self.half_separation, 0.0])

    def intersect(self, dirs: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Where camera rays from ``C`` along ``dirs`` (…, 3) meet the mirror: ``(P, t)``."""
        u = np.asarray(dirs, dtype=np.float64)
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        ax, ay, az = self.semi_axes
        inv2 = np.array([1.0 / ax**2, 1.0 / ay**2, 1.0 / az**2])
        c = self.camera_position
        qa = np.einsum("...k,k->...", u * u, inv2)
        qb = np.einsum("...k,k->...", u, c * inv2)
        qc = float(np.dot(c * c, inv2) - 1.0)  # < 0: the camera is inside
        disc = np.sqrt(qb * qb - qa * qc)
        # stable positive root of qa t² + 2 qb t + qc = 0
        t = np.where(qb > 0.0, -qc / (qb + disc), (disc - qb) / qa)
        return c + t[..., None] * u, t

    def normal(self, points: ArrayLike) -> NDArray[np.float64]:
        """Inward unit normal of the mirror at ``points`` (…, 3)."""
        p = np.asarray(points, dtype=np.float64)
        ax, ay, az = self.semi_axes
        g = p * np.array([1.0 / ax**2, 1.0 / ay**2, 1.0 / az**2])
        return -g / np.linalg.norm(g, axis=-1, keepdims=True)

    def trace(self, dirs: ArrayLike) -> dict[str, NDArray]:
        """Exact trace of camera rays (dome-frame directions from the lens centre).

        Returns
        -------
        dict
            ``point`` (P, on the mirror), ``sample_point`` (Q, on the plane z = 0),
            ``wo`` (unit reflected direction from Q towards P, Ward's d̂_r in the dome frame)
            and ``valid`` (the ray goes up, hits the dome and comes back down to the plane:
            ``wo_z > 0``). Invalid entries hold finite placeholder values.
        """
        u = np.asarray(dirs, dtype=np.float64)
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        p, _ = self.intersect(u)
        n = self.normal(p)
        refl = u - 2.0 * np.sum(u * n, axis=-1, keepdims=True) * n
        rz = refl[..., 2]
        valid = (u[..., 2] > 0.0) & (rz < 0.0)
        s = np.where(valid, -p[..., 2] / np.where(valid, rz, -1.0), 0.0)
        q = p + s[..., None] * refl
        q[..., 2] = 0.0
        wo = -refl
        wo = np.where(valid[..., None], wo, np.array([0.0, 0.0, 1.0]))
        return {"point": p, "sample_point": q, "wo": wo, "valid": valid}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``metadata["mirror"]``)."""
        return {
            "type": self.kind,
            "radius": self.radius,
            "half_separation": self.half_separation,
            "reflectance": self.reflectance,
            "transmittance": self.transmittance,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Mirror:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(
                kind=d["type"],
                radius=d["radius"],
                half_separation=d["half_separation"],
                reflectance=d.get("reflectance", 0.5),
                transmittance=d.get("transmittance", 0.45),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad mirror description {d!r}: missing {exc}") from None


def _camera_dirs(theta_c: NDArray, phi_c: NDArray) -> NDArray:
    st = np.sin(theta_c)
    return np.stack(
        np.broadcast_arrays(st * np.cos(phi_c), st * np.sin(phi_c), np.cos(theta_c)), -1
    )


def traced_reflection_angles(
    theta_c: ArrayLike,
    phi_c: ArrayLike,
    radius: float,
    half_separation: float,
    mirror: str = "hemisphere",
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The exact traced counterpart of :func:`eq3_reflection_angles`.

    Returns ``(theta_r, phi_r, offset)``: the reflected direction seen along camera direction
    (θ_c, φ_c) and the distance ``|Q - S|`` between the sample point actually seen and the
    sample centre (0 for the ellipsoid, up to rounding). Rays that do not come back down to
    the sample plane (θ_c = π/2) give ``theta_r = pi/2``.
    """
    _check_geometry(radius, half_separation)
    m = Mirror(_check_mirror(mirror), radius, half_separation, 0.5, 0.5)
    tc = np.asarray(theta_c, dtype=np.float64)
    pc = np.asarray(phi_c, dtype=np.float64)
    tr = m.trace(_camera_dirs(tc, pc))
    wo = tr["wo"]
    theta_r = np.where(
        tr["valid"], np.arctan2(np.hypot(wo[..., 0], wo[..., 1]), wo[..., 2]), np.pi / 2
    )
    phi_r = _wrap_phi(np.arctan2(wo[..., 1], wo[..., 0]))
    off = np.linalg.norm(tr["sample_point"] - m.sample_position, axis=-1)
    return theta_r, phi_r, off


def eq3_error(
    mirror: str,
    d_over_r: float,
    *,
    form: str = "auto",
    lens: Any = None,
    theta_c_max: float | None = None,
) -> dict[str, float]:
    """Angular error of eq. 3 against the exact trace over the image of a lens.

    Parameters
    ----------
    mirror : {"hemisphere", "ellipsoid"}
    d_over_r : float
        ``D / R`` in [0, 1).
    form : {"auto", "printed", "focal"}
        ``"printed"``: eq. 3 as printed (sphere ``r_c``, ``R`` = semi-major axis for the
        ellipsoid); ``"focal"``: eq. 3 with the ellipsoid's focal ``r_c``; ``"auto"``:
        printed for the hemisphere, focal for the ellipsoid.
    lens : FisheyeLens, optional
        Pixels to evaluate on; default a 512 × 512 equidistant 180° fisheye.
    theta_c_max : float, optional
        Only pixels with θ_c below this (default: the lens's field, π/2).

    Returns
    -------
    dict
        ``max``, ``p95``, ``mean`` (radians, angle between eq. 3's direction and the traced
        one), ``max_sample_offset_over_r`` (largest ``|Q - S|/R``), ``n_pixels``.

    References
    ----------
    Ward 1992, eq. 3 ("a good approximation ... as long as D is small in
    relation to R").
    """
    from gonio.simulator.lenses import make_lens

    _check_mirror(mirror)
    if form not in ("auto", "printed", "focal"):
        raise ValueError(f"form {form!r} is unknown; expected auto, printed or focal")
    dr = float(d_over_r)
    _check_geometry(1.0, dr)
    if lens is None:
        lens = make_lens("equidistant", 512, 512, fill=1.0)
    uv = lens.pixel_grid().reshape(-1, 2)
    keep = lens.in_field(uv)
    d = lens.unproject(uv[keep])
    tc = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    pc = np.arctan2(d[:, 1], d[:, 0])
    sel = tc < (np.pi / 2 if theta_c_max is None else float(theta_c_max))
    tc, pc = tc[sel], pc[sel]
    eq_mirror = {"auto": mirror, "printed": "hemisphere", "focal": "ellipsoid"}[form]
    te, pe = eq3_reflection_angles(tc, pc, 1.0, dr, eq_mirror)
    tt, pt, off = traced_reflection_angles(tc, pc, 1.0, dr, mirror)
    a = _camera_dirs(te, pe)
    b = _camera_dirs(tt, pt)
    err = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
    return {
        "max": float(err.max()),
        "p95": float(np.percentile(err, 95)),
        "mean": float(err.mean()),
        "max_sample_offset_over_r": float(off.max()),
        "n_pixels": int(err.size),
    }
