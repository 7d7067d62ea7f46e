"""Kinematics of the Cornell three-axis gonioreflectometer.

Li & Torrance (Li and Torrance 2005, §5.1) describe an automated three-axis instrument whose
range covers both hemispheres to 85° except a 7° cone around retro-reflection; what is publicly
known beyond it (issue 7): the light source revolves about the sample on a motorised arm, the
sample has two rotational degrees of freedom, the detector is fixed and views the sample through
a folding mirror.

Lab frame: Z vertical (the arm's axis), the sample at the origin, ``detector`` the fixed unit
vector from the sample towards the detector (default +X, horizontal). Motor angles (radians):

* ``arm`` (axis 1): the source direction is ``Rot(Z, arm) · detector`` — so the angle between
  the incident and viewing directions is ``|arm|`` and the arm blocks the detector when
  ``|arm| < 7°`` (the retro-reflection cone);
* ``turntable`` (axis 2) and ``tilt`` (axis 3): the sample orientation is
  ``R = Rot(axis2, turntable) · Rot(axis3, tilt) · R0``, ``axis2`` fixed in the lab, ``axis3``
  carried by axis 2 (given at the zero pose), ``R0`` the zero pose (sample normal towards the
  detector, sample x axis along ``zero_x``). Defaults: ``axis2 = Z`` (turntable),
  ``axis3 = Y`` (tilt about the sample's horizontal in-plane axis). Both are configurable.

Forward kinematics gives ``wi = Rᵀ·source``, ``wo = Rᵀ·detector`` in the sample frame. Three
motors give three degrees of freedom: ``(θi, θo, φo − φi)``. The inverse therefore reproduces a
requested ``(wi, wo)`` up to a common rotation ``ψ`` about the sample normal (exact for
isotropic samples); it returns ``ψ``. It uses Paden-Kahan subproblem 2 (two rotations taking the
zero-pose normal to the required lab normal), so any ``axis2``/``axis3`` pair works.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.

Li and Torrance 2005, §5.1 (85° range, 7° retro-reflection cone); R. M. Murray, Z. Li,
S. S. Sastry, "A Mathematical Introduction to Robotic Manipulation" (1994), §3.2 (Paden-Kahan
subproblems 1 and 2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_directions, as_finite_array
from gonio.geometry import to_spherical

__all__ = ["AXES", "InverseResult", "Kinematics", "forward", "inverse", "rotation"]

#: Motor names in controller-axis order.
AXES = ("arm", "turntable", "tilt")


def rotation(axis: ArrayLike, angle: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices ``(..., 3, 3)`` about unit ``axis`` by ``angle`` (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k, axis=-1, keepdims=True)
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a)[..., None, None], np.sin(a)[..., None, None]
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    K = np.stack(
        [
            np.stack([zero, -kz, ky], -1),
            np.stack([kz, zero, -kx], -1),
            np.stack([-ky, kx, zero], -1),
        ],
        -2,
    )
    kk = k[..., :, None] * k[..., None, :]
    return c * np.eye(3) + s * K + (1.0 - c) * kk


@dataclass(frozen=True)
class Kinematics:
    """Geometry and limits of the three axes (angles in radians).

    Parameters
    ----------
    detector : 3-vector
        Lab direction from the sample towards the detector (folding mirror).
    arm_axis : 3-vector
        Axis of the source arm (vertical).
    axis2, axis3 : 3-vector
        Sample rotation axes: ``axis2`` fixed in the lab, ``axis3`` at the zero pose, carried
        by axis 2.
    zero_x : 3-vector
        Sample x axis at the zero pose (must be orthogonal to ``detector``); the sample normal
        at the zero pose is ``detector``.
    limits : ((lo, hi), (lo, hi), (lo, hi))
        Stage limits of arm, turntable, tilt.
    theta_max : float
        Largest reachable θi and θo (85°, §5.1).
    retro_cone : float
        Smallest angle between wi and wo (7°, §5.1).
    """

    detector: tuple[float, float, float] = (1.0, 0.0, 0.0)
    arm_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    axis2: tuple[float, float, float] = (0.0, 0.0, 1.0)
    axis3: tuple[float, float, float] = (0.0, 1.0, 0.0)
    zero_x: tuple[float, float, float] = (0.0, 1.0, 0.0)
    limits: tuple[tuple[float, float], ...] = field(
        default=(
            (np.radians(-180.0), np.radians(180.0)),
            (np.radians(-180.0), np.radians(180.0)),
            (np.radians(-90.0), np.radians(90.0)),
        )
    )
    theta_max: float = float(np.radians(85.0))
    retro_cone: float = float(np.radians(7.0))

    def __post_init__(self) -> None:
        for name in ("detector", "arm_axis", "axis2", "axis3", "zero_x"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
                raise ValueError(f"{name} = {getattr(self, name)!r}: expected a non-zero 3-vector")
        if abs(float(np.dot(self.d, self.x0))) > 1e-9:
            raise ValueError(f"zero_x = {self.zero_x!r} must be orthogonal to detector")
        if abs(float(np.dot(self.a2, self.a3))) > 1.0 - 1e-9:
            raise ValueError("axis2 and axis3 must not be parallel")
        lim = np.asarray(self.limits, dtype=np.float64)
        if lim.shape != (3, 2) or np.any(lim[:, 0] >= lim[:, 1]):
            raise ValueError(f"limits = {self.limits!r}: expected three (lo, hi) pairs, lo < hi")

    # unit vectors
    @property
    def d(self) -> NDArray:
        v = np.asarray(self.detector, float)
        return v / np.linalg.norm(v)

    @property
    def x0(self) -> NDArray:
        v = np.asarray(self.zero_x, float)
        return v / np.linalg.norm(v)

    @property
    def a2(self) -> NDArray:
        v = np.asarray(self.axis2, float)
        return v / np.linalg.norm(v)

    @property
    def a3(self) -> NDArray:
        v = np.asarray(self.axis3, float)
        return v / np.linalg.norm(v)

    @property
    def r0(self) -> NDArray:
        """Zero pose: columns are the sample x, y, z axes in the lab."""
        z = self.d
        x = self.x0
        return np.stack([x, np.cross(z, x), z], axis=1)

    def source(self, arm: ArrayLike) -> NDArray[np.float64]:
        """Lab direction from the sample towards the source for arm angle(s)."""
        return rotation(self.arm_axis, arm) @ self.d

    def orientation(self, turntable: ArrayLike, tilt: ArrayLike) -> NDArray[np.float64]:
        """Sample orientation matrices ``R`` (sample frame → lab)."""
        return rotation(self.a2, turntable) @ rotation(self.a3, tilt) @ self.r0

    def within_limits(self, angles: ArrayLike) -> NDArray[np.bool_]:
        a = np.asarray(angles, dtype=np.float64)
        lim = np.asarray(self.limits, dtype=np.float64)
        return np.all((a >= lim[:, 0] - 1e-12) & (a <= lim[:, 1] + 1e-12), axis=-1)

    def reachable_directions(self, wi: ArrayLike, wo: ArrayLike) -> NDArray[np.bool_]:
        """The optical limits: θi, θo ≤ ``theta_max`` and angle(wi, wo) ≥ ``retro_cone``."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        cmin = np.cos(self.theta_max)
        phase = np.sum(wi * wo, axis=-1)
        return (
            (wi[..., 2] >= cmin - 1e-12)
            & (wo[..., 2] >= cmin - 1e-12)
            & (phase <= np.cos(self.retro_cone) + 1e-12)
        )


def forward(
    angles: ArrayLike, kin: Kinematics | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Motor angles ``(..., 3)`` (arm, turntable, tilt; radians) → ``(wi, wo)`` sample frame."""
    kin = kin or Kinematics()
    a = as_finite_array(angles, "angles")
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"angles must have shape (..., 3), got {a.shape}")
    R = kin.orientation(a[..., 1], a[..., 2])
    s = kin.source(a[..., 0])
    wi = np.einsum("...ji,...j->...i", R, s)
    wo = np.einsum("...ji,j->...i", R, kin.d)
    return wi, wo


def _subproblem1(w: NDArray, p: NDArray, q: NDArray) -> NDArray:
    """Angle of the rotation about unit ``w`` taking ``p`` to ``q`` (Paden-Kahan 1)."""
    up = p - np.sum(w * p, -1, keepdims=True) * w
    vq = q - np.sum(w * q, -1, keepdims=True) * w
    return np.arctan2(np.sum(w * np.cross(up, vq), -1), np.sum(up * vq, -1))


def _subproblem2(w1: NDArray, w2: NDArray, p: NDArray, q: NDArray, sign: float):
    """Angles ``(t1, t2)`` with ``Rot(w1, t1) Rot(w2, t2) p = q`` (Paden-Kahan 2)."""
    c12 = float(np.dot(w1, w2))
    den = c12 * c12 - 1.0
    alpha = (c12 * (p @ w2) - q @ w1) / den
    beta = (c12 * (q @ w1) - p @ w2) / den
    cr = np.cross(w1, w2)
    g2 = (np.sum(p * p, -1) - alpha**2 - beta**2 - 2 * alpha * beta * c12) / float(cr @ cr)
    ok = g2 >= -1e-12
    gamma = sign * np.sqrt(np.clip(g2, 0.0, None))
    c = alpha[..., None] * w1 + beta[..., None] * w2 + gamma[..., None] * cr
    t2 = _subproblem1(w2, p, c)
    t1 = _subproblem1(w1, c, q)
    return t1, t2, ok


@dataclass
class InverseResult:
    """What :func:`inverse` returns.

    ``angles`` (N, 3) radians; ``reachable`` (N,) bool (optics and stage limits); ``psi`` (N,)
    the rotation about the sample normal between the requested and the reached directions
    (reached = Rz(psi) · requested); ``wi``, ``wo`` the reached directions.
    """

    angles: NDArray[np.float64]
    reachable: NDArray[np.bool_]
    psi: NDArray[np.float64]
    wi: NDArray[np.float64]
    wo: NDArray[np.float64]


def _wrap(a: NDArray) -> NDArray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def inverse(
    wi: ArrayLike,
    wo: ArrayLike,
    kin: Kinematics | None = None,
    *,
    current: ArrayLike | None = None,
    speeds: ArrayLike = (1.0, 1.0, 1.0),
) -> InverseResult:
    """Motor angles that put the sample at ``(wi, wo)`` (up to a rotation about its normal).

    Up to four solutions exist (two arm signs × two branches of subproblem 2); the one within
    the stage limits that is quickest to reach from ``current`` (default: all zeros) with the
    given axis ``speeds`` is returned.

    Parameters
    ----------
    wi, wo : array_like, shape (..., 3)
        Requested unit directions in the sample frame.
    kin : Kinematics, optional
    current : array_like, shape (3,) or (..., 3), optional
        Present motor angles (radians).
    speeds : 3 floats
        Relative axis speeds used to rank the solutions.
    """
    kin = kin or Kinematics()
    wi = as_directions(wi, "wi")
    wo = as_directions(wo, "wo")
    wi, wo = np.broadcast_arrays(wi, wo)
    shape = wi.shape[:-1]
    a_i = wi.reshape(-1, 3) / np.linalg.norm(wi.reshape(-1, 3), axis=-1, keepdims=True)
    a_o = wo.reshape(-1, 3) / np.linalg.norm(wo.reshape(-1, 3), axis=-1, keepdims=True)
    n = a_i.shape[0]
    cur = (
        np.zeros((n, 3))
        if current is None
        else np.broadcast_to(as_finite_array(current, "current"), (n, 3))
    )
    spd = np.asarray(speeds, dtype=np.float64)
    phase = np.arccos(np.clip(np.sum(a_i * a_o, -1), -1.0, 1.0))
    optical = kin.reachable_directions(a_i, a_o)
    # orthonormal triads in the sample frame and the lab, for each arm sign
    best = np.full((n, 3), np.nan)
    best_cost = np.full(n, np.inf)
    e_s = _triad(a_o, a_i)  # rows: wo, u, v in the sample frame
    for arm_sign in (1.0, -1.0):
        arm = arm_sign * phase
        src = kin.source(arm)  # (n, 3)
        e_l = _triad(np.broadcast_to(kin.d, (n, 3)), src)
        # R* maps sample-frame triad to lab triad: R* = E_l^T E_s
        rstar = np.einsum("nki,nkj->nij", e_l, e_s)
        normal = rstar[:, :, 2]  # lab image of the sample z axis
        p0 = kin.r0[:, 2]
        for branch in (1.0, -1.0):
            t2, t3, ok = _subproblem2(kin.a2, kin.a3, np.broadcast_to(p0, (n, 3)), normal, branch)
            ang = np.stack([arm, _wrap(t2), _wrap(t3)], -1)
            good = ok & kin.within_limits(ang)
            cost = np.max(np.abs(ang - cur) / spd, axis=-1)
            take = good & (cost < best_cost - 1e-12)
            best[take] = ang[take]
            best_cost[take] = cost[take]
    found = np.isfinite(best_cost)
    best[~found] = 0.0
    rwi, rwo = forward(best, kin)
    _, phi_req = to_spherical(a_i)
    _, phi_got = to_spherical(rwi)
    psi = np.where(found, _wrap(phi_got - phi_req), 0.0)
    return InverseResult(
        angles=best.reshape(shape + (3,)),
        reachable=(found & optical).reshape(shape),
        psi=psi.reshape(shape),
        wi=rwi.reshape(shape + (3,)),
        wo=rwo.reshape(shape + (3,)),
    )


def _triad(a: NDArray, b: NDArray) -> NDArray:
    """Rows ``(a, u, v)``: ``a``, the part of ``b`` orthogonal to it, and their cross product."""
    u = b - np.sum(a * b, -1, keepdims=True) * a
    un = np.linalg.norm(u, axis=-1, keepdims=True)
    # b parallel to a (phase 0): any orthogonal u; such targets are unreachable anyway
    alt = np.cross(a, np.array([0.0, 0.0, 1.0]))
    alt_n = np.linalg.norm(alt, axis=-1, keepdims=True)
    alt = np.where(alt_n > 1e-9, alt / np.where(alt_n > 0, alt_n, 1), np.array([1.0, 0, 0]))
    u = np.where(un > 1e-12, u / np.where(un > 0, un, 1.0), alt)
    return np.stack([a, u, np.cross(a, u)], axis=-2)
