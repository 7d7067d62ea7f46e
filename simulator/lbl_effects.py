"""How the LBL instrument realises its effects (:mod:`gonio.simulator.effects`).

Operations on the traced per-pixel geometry (the dome's figure error, occlusion by the lens
body and the sample holder, the sample's height and tilt), on the scene (veiling glare,
re-illumination, ambient light on the sample) and on each frame (the true f-number, the
lamp, the point-spread function). Each function is used only when its magnitude is not
zero; the physical sources are in :data:`gonio.simulator.effects.EFFECTS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from gonio.simulator.effects import effect_rng
from numpy.typing import NDArray

__all__ = [
    "FISHEYE_FOCAL_LENGTH_M",
    "LAMP_WARMUP_TAU_S",
    "beam_shadowed",
    "dome_frame",
    "dome_rays",
    "frame_rays",
    "fstop_area_factor",
    "lamp_factor",
    "psf_sigma_px",
    "slope_field",
    "tilt_rotation",
    "tilted_rays",
    "to_plane",
    "trace_perturbed",
    "true_f_number",
    "view_blocked",
]

#: time constant of the lamp's warm-up (s)
LAMP_WARMUP_TAU_S = 600.0
#: the fisheye's focal length used when the lens's own (fx x pixel pitch) is not known
FISHEYE_FOCAL_LENGTH_M = 1.4e-3
_N_MODES = 12


def slope_field(
    points: NDArray, magnitude: float, radius: float, seed: int
) -> tuple[NDArray, NDArray]:
    """Slope errors ``(s_x, s_y)`` (radians) of the dome at mirror points ``(n, 3)``.

    A sum of 12 plane waves across the dome's footprint (wavelengths from the dome's
    diameter down to a quarter of it, random directions and phases from ``seed``), scaled to
    unit RMS and by ``magnitude · (ρ / R)²``, ``ρ`` the distance from the dome axis: zero on
    the axis, ``magnitude`` RMS at the rim.
    """
    rng = effect_rng(seed, "dome_slope_error")
    k = rng.uniform(1.0, 4.0, _N_MODES) * (math.pi / radius)  # cycles per diameter 1..4
    ang = rng.uniform(0.0, 2.0 * math.pi, (2, _N_MODES))
    phase = rng.uniform(0.0, 2.0 * math.pi, (2, _N_MODES))
    x, y = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
    prof = magnitude * (x * x + y * y) / radius**2 * math.sqrt(2.0 / _N_MODES)
    out = []
    for c in range(2):
        kx, ky = k * np.cos(ang[c]), k * np.sin(ang[c])
        t = [np.cos(x * kx[j] + y * ky[j] + phase[c][j]) for j in range(_N_MODES)]
        # the modes summed in the order of numpy's pairwise sum over a row of 12 (eight
        # partial sums, then the rest), so the field is the same to the bit as the sum of
        # the (n, 12) array of every mode, without that array (fresh memory of that size
        # costs more here than the cosines: 0.82 s against 0.15 s on a first call)
        s = ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]))
        for j in range(8, _N_MODES):
            s += t[j]
        out.append(prof * s)
    return out[0], out[1]


def dome_rays(mirror, dirs: NDArray, slope=None) -> tuple[NDArray, NDArray, NDArray]:
    """Camera rays reflected by the dome whose normal is tilted by ``slope(points)``.

    ``slope`` maps mirror points ``(n, 3)`` to the normal's tilts ``(s_e, s_n)`` (radians)
    along the dome's local east and north tangents (:func:`slope_field`); the reflected ray
    turns by twice the tilt. Returns ``(u, p, refl)``: unit camera rays, mirror points and
    reflected directions.
    """
    if slope is not None:
        return tilted_rays(dome_frame(mirror, dirs), slope)
    u, p, n = _dome_points(mirror, dirs)
    return u, p, _reflect(u, n)


def _dome_points(mirror, dirs: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Unit camera rays, their points on the dome and the dome's normals there."""
    u = np.asarray(dirs, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    p, _ = mirror.intersect(u)
    return u, p, mirror.normal(p)


def _reflect(u: NDArray, n: NDArray) -> NDArray:
    return u - 2.0 * np.sum(u * n, axis=-1, keepdims=True) * n


def dome_frame(mirror, dirs: NDArray) -> tuple[NDArray, ...]:
    """What :func:`dome_rays` computes before a figure tilts the normal: the unit camera
    rays, their mirror points, the normals there and the local east and north tangents
    ``(u, p, n, east, north)``; many figures on the same rays (:func:`tilted_rays`) share it,
    and :func:`frame_rays` gives its rays without a figure."""
    u, p, n = _dome_points(mirror, dirs)
    up = np.array([0.0, 0.0, 1.0])
    east = np.cross(up, n)
    en = np.linalg.norm(east, axis=-1, keepdims=True)
    east = np.where(en > 1e-12, east / np.maximum(en, 1e-300), np.array([1.0, 0.0, 0.0]))
    north = np.cross(n, east)
    return u, p, n, east, north


def tilted_rays(frame: tuple[NDArray, ...], slope) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`dome_rays` of the rays of ``frame`` (:func:`dome_frame`) with the normal tilted
    by ``slope(points)``: ``(u, p, refl)``, the same values."""
    u, p, n, east, north = frame
    se, sn = slope(p)
    n = n + se[:, None] * east + sn[:, None] * north
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return u, p, _reflect(u, n)


def frame_rays(frame: tuple[NDArray, ...]) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`dome_rays` of the rays of ``frame`` (:func:`dome_frame`) without a figure:
    ``(u, p, refl)``, the same values."""
    u, p, n = frame[:3]
    return u, p, _reflect(u, n)


def to_plane(u: NDArray, p: NDArray, refl: NDArray, plane_z: float = 0.0) -> dict:
    """Where the reflected rays of :func:`dome_rays` meet the sample plane ``z = plane_z``:
    the same dict as :meth:`Mirror.trace` (``sample_point`` on that plane)."""
    rz = refl[..., 2]
    valid = (u[..., 2] > 0.0) & (rz < 0.0) & (p[..., 2] > plane_z)
    s = np.where(valid, (plane_z - p[..., 2]) / np.where(valid, rz, -1.0), 0.0)
    q = p + s[..., None] * refl
    q[..., 2] = plane_z
    wo = np.where(valid[..., None], -refl, np.array([0.0, 0.0, 1.0]))
    return {"point": p, "sample_point": q, "wo": wo, "valid": valid}


def trace_perturbed(mirror, dirs: NDArray, slope=None, plane_z: float = 0.0) -> dict:
    """:meth:`Mirror.trace` with the dome's normal tilted by ``slope(points)`` and the sample
    plane at ``z = plane_z`` (:func:`dome_rays` then :func:`to_plane`)."""
    return to_plane(*dome_rays(mirror, dirs, slope), plane_z)


def _exit_distance(qx, qy, dx, dy, cx, cy, r):
    """Parameter ``t > 0`` where the ray ``q + t d`` (horizontal parts) leaves the circle of
    radius ``r`` about ``c`` (``q`` inside), or ``inf`` for a vertical ray."""
    ox, oy = qx - cx, qy - cy
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - r * r
    disc = np.sqrt(np.maximum(b * b - a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(a > 0.0, (-b + disc) / np.where(a > 0.0, a, 1.0), np.inf)
    return t


def view_blocked(
    q: NDArray, wo: NDArray, p: NDArray, mirror, sample_radius: float, fx: Mapping[str, float]
) -> NDArray:
    """True where the ray from the sample point ``q`` along ``wo`` to the dome point ``p`` is
    blocked by the lens body or the holder's rim.

    Lens body: a vertical cylinder of radius ``2D - 1.25 r_s`` about the lens axis,
    ``lens_body_height`` above the sample plane; the holder's rim: radius ``1.25 r_s``
    about the sample centre, ``holder_rim_height`` above the sample plane (from ``fx``).
    """
    blocked = np.zeros(q.shape[0], dtype=bool)
    d = mirror.half_separation
    rim_r = 1.25 * sample_radius
    h_rim = fx.get("holder_rim_height", 0.0)
    if h_rim > 0.0:
        t = _exit_distance(q[:, 0], q[:, 1], wo[:, 0], wo[:, 1], 0.0, d, rim_r)
        blocked |= t * wo[:, 2] < h_rim
    h_lens = fx.get("lens_body_height", 0.0)
    if h_lens > 0.0:
        r = max(2.0 * d - rim_r, 0.1 * d)
        ox, oy = q[:, 0], q[:, 1] + d  # relative to the lens axis at (0, -D)
        a = wo[:, 0] ** 2 + wo[:, 1] ** 2
        b = ox * wo[:, 0] + oy * wo[:, 1]
        c = ox * ox + oy * oy - r * r
        disc = b * b - a * c
        hit = (disc > 0.0) & (a > 0.0)
        sq = np.sqrt(np.where(hit, disc, 0.0))
        safe_a = np.where(a > 0.0, a, 1.0)
        t1 = (-b - sq) / safe_a
        t2 = (-b + sq) / safe_a
        t_end = np.linalg.norm(p - q, axis=-1)
        t_in = np.maximum(t1, 0.0)
        blocked |= hit & (t2 > 0.0) & (t_in < t_end) & (t_in * wo[:, 2] < h_lens)
    return blocked


def beam_shadowed(
    qx: NDArray, qy: NDArray, wi_dome: NDArray, half_separation: float, sample_radius: float,
    h_rim: float,
) -> NDArray:  # fmt: skip
    """True where the holder's rim shadows the incident beam at the sample points."""
    t = _exit_distance(
        qx, qy + half_separation, wi_dome[0], wi_dome[1], 0.0, half_separation,
        1.25 * sample_radius,
    )  # fmt: skip
    return t * wi_dome[2] < h_rim


def tilt_rotation(tilt: float, azimuth: float) -> NDArray:
    """Rotation that maps dome-frame directions into the frame of a sample whose normal is
    tilted by ``tilt`` towards azimuth ``azimuth`` (the tilted normal goes to +z)."""
    n = np.array(
        [math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)]
    )
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    s = float(np.linalg.norm(v))
    c = float(n @ z)
    if s < 1e-15:
        return np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx * ((1.0 - c) / (s * s))


def true_f_number(marked: float, series: float) -> float:
    """The real f-number of a stop engraved ``marked``: ``2^(k/2)`` for the nearest half
    power of two (f/11 is 11.31, f/22 is 22.63), moved by the fraction ``series`` from
    the marked value. A stop that is no engraved value (off the series by > 3 %) is exact."""
    k = round(2.0 * math.log2(marked))
    true = 2.0 ** (k / 2.0)
    if abs(true / marked - 1.0) > 0.03 or series == 0.0:
        return marked
    return marked * (true / marked) ** series


def fstop_area_factor(marked: float, rms: float, seed: int) -> float:
    """This lens's fixed relative aperture-area factor at the marked stop (1 + error)."""
    if rms == 0.0:
        return 1.0
    e = effect_rng(seed, "fstop_error", f"{marked:.4g}").normal(0.0, rms)
    return max(1.0 + float(e), 0.05)


def lamp_factor(t_s: float, warmup: float, drift_per_h: float) -> float:
    """Relative lamp output at campaign time ``t_s``: ``1 - w e^(-t/τ) + d t / 3600``."""
    f = 1.0
    if warmup:
        f -= warmup * math.exp(-max(t_s, 0.0) / LAMP_WARMUP_TAU_S)
    if drift_per_h:
        f += drift_per_h * t_s / 3600.0
    return max(f, 1e-3)


def psf_sigma_px(
    f_number: float, fx: Mapping[str, float], pixel_pitch: float, focal_px: float,
    focus_distance: float,
) -> float:  # fmt: skip
    """RMS (pixels) of the Gaussian point-spread function at ``f_number``.

    Quadrature sum of the pixel's area integration ``sqrt(fill / 12)``, diffraction
    ``0.42 λ N / pitch`` and defocus ``(f / (N s_f)) · focus_error / 4`` rad times the
    lens's pixels per radian ``focal_px`` (``f = focal_px · pitch``, the focal length).
    """
    s2 = 0.0
    fill = fx.get("pixel_fill", 0.0)
    if fill:
        s2 += fill / 12.0
    lam = fx.get("diffraction_wavelength", 0.0)
    if lam:
        s2 += (0.42 * lam * 1e-9 * f_number / pixel_pitch) ** 2
    fe = fx.get("focus_error", 0.0)
    if fe:
        f_len = focal_px * pixel_pitch
        s2 += (f_len / (f_number * focus_distance) * fe / 4.0 * focal_px) ** 2
    return math.sqrt(s2)
