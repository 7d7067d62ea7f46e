"""Directions, frames and hemisphere sampling.

Conventions (``docs/architecture.md``): the local frame is right-handed with z the surface
normal and x the anisotropy direction; azimuth is measured from +x towards +y. Directions are
unit vectors pointing *away* from the surface, arrays of shape ``(..., 3)``. Angles in radians.

Degenerate cases are defined, never NaN:

* ``half_vector(wi, wo)`` with ``wi == -wo`` (the half vector is undefined) returns the normal
  ``(0, 0, 1)``;
* ``to_spherical`` of a direction along the z axis returns ``phi = 0``;
* ``local_frame(n, t)`` with ``t`` parallel to ``n`` picks a tangent orthogonal to ``n``
  (Frisvad / Duff et al. branchless construction);
* ``reflect`` works for any direction, including grazing (``z = 0``) and below the horizon.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Eq. 5b and its vector substitutions: the half vector.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   §5.1: the 441-position hemispherical sampling, on the map of [ShirleyChiu1997]_.
.. [ShirleyChiu1997] P. Shirley and K. Chiu, "A low distortion map between disk and square",
   Journal of Graphics Tools 2(3), 45-52, 1997. https://doi.org/10.1080/10867651.1997.10487479
   The concentric map of :func:`shirley_chiu_square_to_disk`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_directions

__all__ = [
    "cosine_hemisphere_grid",
    "cosine_hemisphere_pdf",
    "difference_half_angles",
    "from_difference_half_angles",
    "half_vector",
    "local_frame",
    "normalize",
    "reflect",
    "sample_cosine_hemisphere",
    "sample_uniform_hemisphere",
    "shirley_chiu_square_to_disk",
    "square_to_hemisphere",
    "to_local",
    "to_spherical",
    "to_vector",
    "uniform_hemisphere_grid",
]

Z = np.array([0.0, 0.0, 1.0])


def normalize(v: ArrayLike) -> NDArray[np.float64]:
    """Return ``v / |v|`` along the last axis; the zero vector maps to ``(0, 0, 1)``."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    zero = n == 0.0
    out = np.divide(v, n, out=np.zeros_like(v), where=~zero)
    if np.any(zero):
        out = np.where(zero, Z, out)
    return out


def to_vector(theta: ArrayLike, phi: ArrayLike) -> NDArray[np.float64]:
    """Unit vector from polar angle ``theta`` (from +z) and azimuth ``phi`` (from +x to +y)."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), -1)


def to_spherical(v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Polar angle in ``[0, pi]`` and azimuth in ``(-pi, pi]`` of direction(s) ``v``.

    Uses ``atan2`` for both angles so that directions near the pole keep full precision.
    A direction exactly along ±z has ``phi = 0``.
    """
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    phi = np.arctan2(y, x)
    phi = np.where(phi == -np.pi, np.pi, phi)
    return theta, phi


def half_vector(wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
    """Normalised half vector ``(wi + wo)/|wi + wo|`` (Ward 1992, eq. 5b substitutions).

    When ``wi == -wo`` the sum vanishes and the normal ``(0, 0, 1)`` is returned.
    """
    return normalize(np.asarray(wi, dtype=np.float64) + np.asarray(wo, dtype=np.float64))


def reflect(w: ArrayLike, n: ArrayLike = Z) -> NDArray[np.float64]:
    """Mirror direction of ``w`` about the normal ``n``: ``2 (w·n) n − w``."""
    w = np.asarray(w, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    return 2.0 * np.sum(w * n, axis=-1, keepdims=True) * n - w


def local_frame(normal: ArrayLike, tangent: ArrayLike | None = None) -> NDArray[np.float64]:
    """Orthonormal frame ``(x, y, z)`` as rows of a ``(..., 3, 3)`` array.

    ``z`` is ``normal``; ``x`` is ``tangent`` made orthogonal to ``normal`` (Gram-Schmidt);
    ``y = z × x``. Without a tangent, or with one parallel to the normal, a tangent is chosen
    by the branchless construction of Duff et al. (JCGT 2017).
    """
    z = normalize(normal)
    sign = np.where(z[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z[..., 2])
    b = z[..., 0] * z[..., 1] * a
    default_x = np.stack([1.0 + sign * z[..., 0] ** 2 * a, sign * b, -sign * z[..., 0]], axis=-1)
    if tangent is None:
        x = default_x
    else:
        t = np.asarray(tangent, dtype=np.float64)
        t = t - np.sum(t * z, axis=-1, keepdims=True) * z
        tn = np.linalg.norm(t, axis=-1, keepdims=True)
        bad = tn < 1e-12
        x = np.where(bad, default_x, t / np.where(bad, 1.0, tn))
    y = np.cross(z, x)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-2)


def to_local(w: ArrayLike, frame: ArrayLike) -> NDArray[np.float64]:
    """Express world direction(s) ``w`` in ``frame`` (rows x, y, z from :func:`local_frame`)."""
    return np.einsum("...ij,...j->...i", np.asarray(frame), np.asarray(w, dtype=np.float64))


def difference_half_angles(wi: ArrayLike, wo: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """Rusinkiewicz half/difference angles ``(theta_h, phi_h, theta_d, phi_d)``.

    The difference vector is ``wi`` expressed in the frame where the half vector is the
    pole: rotate by ``-phi_h`` about z, then by ``-theta_h`` about y (the MERL convention).
    ``wi == -wo`` takes the half vector as the normal: ``theta_h = 0``, ``theta_d = theta_i``.
    """
    wi = as_directions(wi, "wi")
    wo = as_directions(wo, "wo")
    h = half_vector(wi, wo)
    theta_h, phi_h = to_spherical(h)
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d, phi_d = to_spherical(d)
    return theta_h, phi_h, theta_d, phi_d


def from_difference_half_angles(
    theta_h: ArrayLike, phi_h: ArrayLike, theta_d: ArrayLike, phi_d: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`difference_half_angles`: return ``(wi, wo)``."""
    theta_h, phi_h = np.asarray(theta_h, float), np.asarray(phi_h, float)
    d = to_vector(theta_d, phi_d)
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = to_vector(theta_h, phi_h)
    wo = reflect(wi, h)
    return wi, wo


def _rot_z(v: NDArray, angle: ArrayLike) -> NDArray:
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, z), -1)


def _rot_y(v: NDArray, angle: ArrayLike) -> NDArray:
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x + s * z, y, -s * x + c * z), -1)


# --------------------------------------------------------------------------- sampling


def shirley_chiu_square_to_disk(u: ArrayLike, v: ArrayLike) -> tuple[NDArray, NDArray]:
    """Shirley-Chiu concentric map of ``[0, 1]^2`` onto the unit disk (area preserving).

    Returns ``(x, y)`` on the disk. The centre of the square maps to the origin.
    """
    a = 2.0 * np.asarray(u, dtype=np.float64) - 1.0
    b = 2.0 * np.asarray(v, dtype=np.float64) - 1.0
    a, b = np.broadcast_arrays(a, b)
    first = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0.0, 1.0, a)
    safe_b = np.where(b == 0.0, 1.0, b)
    r = np.where(first, a, b)
    phi = np.where(first, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def square_to_hemisphere(u: ArrayLike, v: ArrayLike, cosine: bool = False) -> NDArray[np.float64]:
    """Map ``[0, 1]^2`` to the upper hemisphere through the Shirley-Chiu disk.

    With ``cosine=False`` the map is uniform in solid angle (``z = 1 − r²``, Lambert
    azimuthal equal-area projection); with ``cosine=True`` it is cosine weighted
    (Malley: ``z = sqrt(1 − r²)``).
    """
    x, y = shirley_chiu_square_to_disk(u, v)
    r2 = np.clip(x * x + y * y, 0.0, 1.0)
    if cosine:
        z = np.sqrt(1.0 - r2)
        return np.stack([x, y, z], axis=-1)
    z = 1.0 - r2
    scale = np.sqrt(np.clip(2.0 - r2, 0.0, None))
    return np.stack([x * scale, y * scale, z], axis=-1)


def uniform_hemisphere_grid(n: int) -> NDArray[np.float64]:
    """``n × n`` stratified directions, uniform in solid angle, shape ``(n*n, 3)``.

    Cell centres of the square mapped by :func:`square_to_hemisphere`; each direction stands
    for a solid angle of exactly ``2π / n²``. ``n = 21`` gives Li & Torrance's 441 positions.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c, indexing="ij")
    return square_to_hemisphere(u.ravel(), v.ravel())


def cosine_hemisphere_grid(n: int) -> NDArray[np.float64]:
    """``n × n`` stratified cosine-weighted directions, shape ``(n*n, 3)``."""
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c, indexing="ij")
    return square_to_hemisphere(u.ravel(), v.ravel(), cosine=True)


def sample_uniform_hemisphere(
    n: int, rng: int | np.random.Generator | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``n`` directions uniform over the hemisphere and their pdf ``1/(2π)``."""
    g = np.random.default_rng(rng)
    u = g.random((2, n))
    w = square_to_hemisphere(u[0], u[1])
    return w, np.full(n, 1.0 / (2.0 * np.pi))


def sample_cosine_hemisphere(
    n: int, rng: int | np.random.Generator | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``n`` cosine-weighted directions and their pdf ``cos θ / π``."""
    g = np.random.default_rng(rng)
    u = g.random((2, n))
    w = square_to_hemisphere(u[0], u[1], cosine=True)
    return w, cosine_hemisphere_pdf(w)


def cosine_hemisphere_pdf(w: ArrayLike) -> NDArray[np.float64]:
    """Solid-angle pdf ``max(cos θ, 0)/π`` of :func:`sample_cosine_hemisphere`."""
    w = np.asarray(w, dtype=np.float64)
    return np.maximum(w[..., 2], 0.0) / np.pi
