"""The optical trace of the LBL instrument: pixel → camera ray → dome point → sample point
and reflected direction, traced once per instrument optics and cached (:class:`Geometry`).

This part knows the dome (:class:`~gonio.simulator.optics.Mirror`), the lens
(:class:`~gonio.simulator.lenses.FisheyeLens`) and the sample's radius — nothing of the
sensor, the source or the sample's BRDF. The true instrument's deviations from this ideal
trace (the dome's figure, occlusion, a raised or tilted sample) are
:mod:`gonio.simulator.lbl_pose`'s.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3 (device, Figure 2-4): the imaging path traced here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from gonio.simulator.lenses import FisheyeLens
from gonio.simulator.optics import Mirror
from numpy.typing import NDArray

__all__ = ["MAX_RAYS", "Geometry", "Optics"]


# ---------------------------------------------------------------------------- geometry cache
@dataclass
class Geometry:
    """Per-instrument traced geometry, computed once.

    Flat pixel index ``i = row * width + col``. Arrays of the candidate pixels (inside the
    image circle, ray returning to the sample plane within the sample disk) are contiguous.
    """

    height: int
    width: int
    field_idx: NDArray[np.int64]  # pixels inside the image circle
    field_dirs: NDArray[np.float64]  # their camera (= dome) directions, (n_f, 3)
    idx: NDArray[np.int64]  # candidate pixels (see the sample disk)
    wx: NDArray[np.float64]  # dome-frame reflected direction of each candidate
    wy: NDArray[np.float64]
    wz: NDArray[np.float64]
    qx: NDArray[np.float64]  # sample point seen, relative to the sample centre
    qy: NDArray[np.float64]
    isq: NDArray[np.float64]  # 1 / sqrt(cos theta_o) of each candidate
    q_max: float  # largest |Q - S| among candidates
    seconds: float  # time taken to build

    @property
    def n_pixels(self) -> int:
        """Number of pixels of the full image."""
        return self.height * self.width

    @property
    def pixel_angle(self) -> float:
        """Largest angular pitch between neighbouring candidate pixels (radians; computed
        on first use: only the mirror component's render needs it); 0 for a supersampled
        geometry, whose pixels have several entries (the mirror-component render uses the
        one-ray geometry)."""
        ang = self.__dict__.get("_pixel_angle")
        if ang is None:
            ang = self._pixel_angle = 0.0 if self.runs() is None else _pitch(self)
        return ang

    def runs(self) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
        """Runs of consecutive candidate pixels: (first pixel, first index into ``idx``) of
        each, or None when a pixel has several entries (supersampled). Cached."""
        r = self.__dict__.get("_runs", False)
        if r is False:
            idx = self.idx
            if idx.size and (np.diff(idx) <= 0).any():
                r = None
            else:
                rj = np.flatnonzero(np.diff(idx) != 1) + 1
                rj = np.concatenate([np.zeros(min(idx.size, 1), dtype=np.int64), rj])
                r = (np.ascontiguousarray(idx[rj], dtype=np.int64), rj.astype(np.int64))
            self.__dict__["_runs"] = r
        return r


#: most sub-pixel rays a supersampled geometry may hold (about 60 bytes each)
MAX_RAYS = 1 << 23


def _check_rays(rays_per_pixel: Any) -> int:
    """``rays_per_pixel`` as an int that is a perfect square in [1, 64]."""
    try:
        n = int(rays_per_pixel)
        ok = n == rays_per_pixel
    except (TypeError, ValueError):
        ok = False
    if not ok or not (1 <= n <= 64) or math.isqrt(n) ** 2 != n:
        raise ValueError(
            f"rays_per_pixel must be a square number 1, 4, 9, ..., 64 (an s x s sub-pixel "
            f"grid), got {rays_per_pixel!r}"
        )
    return n


def _trace_geometry(
    mirror: Mirror,
    lens: FisheyeLens,
    sample_radius: float,
    rays: int = 1,
    tracer: Callable[[NDArray], dict[str, NDArray]] | None = None,
    keep: Callable[[dict[str, NDArray], NDArray], NDArray] | None = None,
    field: Geometry | None = None,
) -> Geometry:
    """Trace every pixel; ``tracer`` replaces :meth:`Mirror.trace` (an imperfect dome, another
    sample plane) and ``keep(trace, q)`` further selects the candidates (occlusion); both
    only with one ray per pixel. ``field``: a geometry of the same lens whose image-circle
    pixels and camera rays are taken instead of being unprojected again."""
    t0 = time.perf_counter()
    h, w = lens.height, lens.width
    if field is not None and rays == 1:
        field_idx, dirs = field.field_idx, field.field_dirs
    else:
        uv = lens.pixel_grid().reshape(-1, 2)
        field_idx = np.flatnonzero(lens.in_field(uv))
        dirs = lens.unproject(uv[field_idx])
    if rays > 1:
        return _trace_supersampled(mirror, lens, sample_radius, rays, field_idx, dirs, t0)
    tr = mirror.trace(dirs) if tracer is None else tracer(dirs)
    q = tr["sample_point"] - mirror.sample_position
    on_sample = tr["valid"] & (q[:, 0] ** 2 + q[:, 1] ** 2 <= sample_radius**2)
    if keep is not None:
        on_sample &= keep(tr, q)
    wo = tr["wo"]
    sel = np.flatnonzero(on_sample)
    idx = field_idx[sel]
    return Geometry(
        height=h,
        width=w,
        field_idx=field_idx,
        field_dirs=dirs,
        idx=idx,
        wx=np.ascontiguousarray(wo[sel, 0]),
        wy=np.ascontiguousarray(wo[sel, 1]),
        wz=np.ascontiguousarray(wo[sel, 2]),
        qx=np.ascontiguousarray(q[sel, 0]),
        qy=np.ascontiguousarray(q[sel, 1]),
        isq=1.0 / np.sqrt(wo[sel, 2]),
        q_max=float(np.sqrt((q[sel, 0] ** 2 + q[sel, 1] ** 2).max(initial=0.0))),
        seconds=time.perf_counter() - t0,
    )


def _pitch(g: Geometry) -> float:
    """:attr:`Geometry.pixel_angle` of a one-ray geometry: the largest angle between the
    reflected directions of a candidate pixel and its right-hand or lower neighbour."""
    h, w = g.height, g.width
    full = np.zeros((h * w, 3))
    full[g.idx] = np.stack([g.wx, g.wy, g.wz], axis=-1)
    has = np.zeros(h * w, dtype=bool)
    has[g.idx] = True
    full = full.reshape(h, w, 3)
    has = has.reshape(h, w)
    ang = 0.0
    for a, b, ha, hb in (
        (full[:, 1:], full[:, :-1], has[:, 1:], has[:, :-1]),
        (full[1:], full[:-1], has[1:], has[:-1]),
    ):
        both = ha & hb
        if both.any():
            dots = np.clip(np.sum(a[both] * b[both], axis=-1), -1.0, 1.0)
            ang = max(ang, float(np.arccos(dots).max()))
    return ang


def _trace_supersampled(mirror, lens, sample_radius, rays, field_idx, dirs, t0) -> Geometry:
    """Geometry of an ``s x s`` grid of sub-pixel rays per pixel (``rays = s²``).

    Each candidate entry is one ray that sees the sample; ``idx`` repeats its pixel (sorted,
    a pixel's rays contiguous). Traced in chunks of pixels to bound the temporary memory.
    """
    h, w = lens.height, lens.width
    s = math.isqrt(rays)
    if h * w * rays > MAX_RAYS:
        raise ValueError(
            f"rays_per_pixel = {rays} on a {w} x {h} image is {h * w * rays} rays; at most "
            f"{MAX_RAYS} are traced (use fewer rays or a smaller image)"
        )
    off = (np.arange(s) + 0.5) / s - 0.5
    ou, ov = (a.ravel() for a in np.meshgrid(off, off))
    parts: dict[str, list[NDArray]] = {k: [] for k in ("idx", "wo", "q")}
    chunk = max(1, (1 << 18) // rays)
    for start in range(0, h * w, chunk):
        pix = np.arange(start, min(start + chunk, h * w))
        rows, cols = np.divmod(pix, w)
        uv = np.stack(
            [(cols[:, None] + ou[None, :]).ravel(), (rows[:, None] + ov[None, :]).ravel()],
            axis=-1,
        ).astype(np.float64)
        inf = lens.in_field(uv)
        ray_pix = np.repeat(pix, rays)
        cand = np.flatnonzero(inf)
        if cand.size == 0:
            continue
        tr = mirror.trace(lens.unproject(uv[cand]))
        q = tr["sample_point"] - mirror.sample_position
        ok = tr["valid"] & (q[:, 0] ** 2 + q[:, 1] ** 2 <= sample_radius**2)
        parts["idx"].append(ray_pix[cand[ok]])
        parts["wo"].append(tr["wo"][ok])
        parts["q"].append(q[ok, :2])
    idx = np.concatenate(parts["idx"]) if parts["idx"] else np.zeros(0, dtype=np.int64)
    wo = np.concatenate(parts["wo"]) if parts["wo"] else np.zeros((0, 3))
    q = np.concatenate(parts["q"]) if parts["q"] else np.zeros((0, 2))
    return Geometry(
        height=h,
        width=w,
        field_idx=field_idx,
        field_dirs=dirs,
        idx=idx.astype(np.int64),
        wx=np.ascontiguousarray(wo[:, 0]),
        wy=np.ascontiguousarray(wo[:, 1]),
        wz=np.ascontiguousarray(wo[:, 2]),
        qx=np.ascontiguousarray(q[:, 0]),
        qy=np.ascontiguousarray(q[:, 1]),
        isq=1.0 / np.sqrt(wo[:, 2]),
        q_max=float(np.sqrt((q[:, 0] ** 2 + q[:, 1] ** 2).max(initial=0.0))),
        seconds=time.perf_counter() - t0,
    )


_GEOMETRY_CACHE: dict[tuple, Geometry] = {}
#: most instrument geometries kept (a 1024 x 1024 one takes about 60 MB)
_GEOMETRY_CACHE_SIZE = 8


class Optics:
    """The instrument's ideal optics — dome, lens and sample disk — and what is traced
    through them: the pixel geometry (cached per optics in this module), the whole image's
    trace (the benchmark's reference without the visible-pixel skip) and the beam's point on
    the dome."""

    def __init__(self, mirror: Mirror, lens: FisheyeLens, sample_radius: float) -> None:
        self.mirror = mirror
        self.lens = lens
        self.sample_radius = sample_radius
        self._field_arrays: tuple | None = None

    def geometry(self, rays: int = 1) -> Geometry:
        """Traced geometry with ``rays`` sub-pixel rays per pixel (cached per instrument optics)."""
        key = (
            tuple(sorted(self.mirror.to_dict().items())),
            tuple(
                (k, tuple(v) if isinstance(v, list) else v) for k, v in self.lens.to_dict().items()
            ),
            self.sample_radius,
        ) + ((("rays", rays),) if rays != 1 else ())
        g = _GEOMETRY_CACHE.get(key)
        if g is None:
            g = _trace_geometry(self.mirror, self.lens, self.sample_radius, rays)
            while len(_GEOMETRY_CACHE) >= _GEOMETRY_CACHE_SIZE:  # drop the oldest
                _GEOMETRY_CACHE.pop(next(iter(_GEOMETRY_CACHE)))
            _GEOMETRY_CACHE[key] = g
        return g

    def all_field_arrays(self):
        """Traced arrays for EVERY pixel of the image (benchmark reference for the skip of
        pixels outside the image circle or seeing no illuminated sample)."""
        if self._field_arrays is None:
            g = self.geometry(1)
            uv = self.lens.pixel_grid().reshape(-1, 2)
            tr = self.mirror.trace(self.lens.unproject(uv))
            q = tr["sample_point"] - self.mirror.sample_position
            on = (
                tr["valid"]
                & self.lens.in_field(uv)
                & (q[:, 0] ** 2 + q[:, 1] ** 2 <= self.sample_radius**2)
            )
            wo = tr["wo"]
            self._field_arrays = (wo[:, 0], wo[:, 1], wo[:, 2], q[:, 0], q[:, 1], on, g.idx)
        return self._field_arrays

    def dome_crossing(self, wi_dome: NDArray) -> NDArray:
        """Point where the ray from the sample centre along ``wi_dome`` meets the dome."""
        ax, ay, az = self.mirror.semi_axes
        inv2 = np.array([1 / ax**2, 1 / ay**2, 1 / az**2])
        s = self.mirror.sample_position
        qa = float(np.dot(wi_dome * wi_dome, inv2))
        qb = float(np.dot(wi_dome, s * inv2))
        qc = float(np.dot(s * s, inv2) - 1.0)
        t = (-qb + math.sqrt(qb * qb - qa * qc)) / qa
        return s + t * wi_dome
