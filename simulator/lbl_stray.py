"""Light that reaches an LBL pixel other than by the sample's one reflection into the lens:
the room's ambient light through the dome, the beam's glow where it crosses the dome,
light the dome sends back onto the sample (re-illumination), ambient light on the sample,
and the lens's veiling glare.

This part knows the optics (:class:`~gonio.simulator.lbl_trace.Optics`), the
:class:`~gonio.simulator.source.Background` and the beam's spot, the diffuse standard's
reflectance, each pixel's response (:class:`~gonio.simulator.lbl_readout.Readout`) and the
scene effects' magnitudes; of the sample only its directional-hemispherical albedo.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3, eq. 2: the background image, present with or without a sample, that the
calibration subtracts. The effects' physical sources are in :mod:`gonio.simulator.effects`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lbl_trace import Optics
from gonio.simulator.optics import Mirror
from gonio.simulator.source import Background, Source
from numpy.typing import NDArray

from gonio.brdf.base import BRDF

__all__ = ["SCENE_FX", "StrayLight"]

#: the effects that add light to a scene's background
SCENE_FX = ("veiling_glare", "reillumination", "ambient_on_sample")


@dataclass(eq=False)
class StrayLight:
    """The background and the scene effects' light. Its caches hold for one instrument."""

    optics: Optics
    background: Background
    #: the beam (its spot's size, for re-illumination)
    source: Source
    #: each pixel's response
    readout: Readout
    #: the instrument's non-zero effect magnitudes
    fx: Mapping[str, float]
    #: the diffuse standard's reflectance (its albedo)
    rho_standard: float
    _bg_cache: dict[tuple, NDArray] = field(default_factory=dict, init=False, repr=False)
    _albedo_cache: dict[tuple, tuple] = field(default_factory=dict, init=False, repr=False)
    _albedo_images: dict[tuple, NDArray] = field(default_factory=dict, init=False, repr=False)

    @property
    def mirror(self) -> Mirror:
        """The dome."""
        return self.optics.mirror

    def background_photons(self, wi_dome: NDArray) -> NDArray:
        """Background electrons per second at f/1, per pixel (cached per beam direction)."""
        key = tuple(np.round(wi_dome, 12))
        bg = self._bg_cache.get(key)
        if bg is None:
            g = self.optics.geometry(1)
            resp, _ = self.readout.response()
            rad = np.zeros(g.n_pixels)
            b = self.background
            vals = np.full(len(g.field_idx), b.ambient * self.mirror.transmittance)
            if b.stray > 0.0:
                # where the beam (from the source towards S) crosses the dome, seen from C
                cross = self.optics.dome_crossing(wi_dome)
                to = cross - self.mirror.camera_position
                to /= np.linalg.norm(to)
                cosang = np.clip(g.field_dirs @ to, -1.0, 1.0)
                ang = np.arccos(cosang)
                vals += b.stray * np.exp(-0.5 * (ang / b.stray_width) ** 2)
            rad[g.field_idx] = vals
            bg = rad * resp
            if len(self._bg_cache) > 64:
                self._bg_cache.clear()
            self._bg_cache[key] = bg
        return bg

    def albedo_fn(self, kind: str, model: BRDF) -> Callable[[NDArray], NDArray]:
        """``ρ_dh(θ)`` of the sample (interpolated over 7 polar angles at φ = 0, to 0.1 %;
        anisotropy neglected) or of the standard (``ρ_standard``: its PTFE shape keeps its
        albedo)."""
        if kind == "standard":
            rho = self.rho_standard
            return lambda th: np.full(np.shape(th), rho)
        cache = self._albedo_cache
        key = (model.name, repr(sorted(model.params.items())))
        hit = cache.get(key)
        if hit is None:
            th = np.radians(np.linspace(0.0, 89.0, 7))
            wi = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=-1)
            a = np.asarray(model.albedo(wi, rtol=1e-3), dtype=np.float64)
            if a.ndim == 2:
                a = a.mean(axis=-1)
            hit = (model, th, a)
            cache[key] = hit
        _, th, a = hit
        return lambda t: np.interp(t, th, a)

    def scene_background(self, bg, kind, model, theta_i, g, rc, lit, gv, isq, kd0, ks0, k0):
        """The scene's background electrons plus re-illumination and ambient light on the
        sample (over every candidate pixel: the whole sample disk) and the veiling glare of
        the whole image (over the image circle). A new array; ``bg`` is not changed."""
        fx = self.fx
        r = fx.get("reillumination", 0.0)
        a = fx.get("ambient_on_sample", 0.0)
        if model is not None and (r or a):
            alb = self.albedo_fn(kind, model)
            coef = 0.0
            if r:
                rs, rspot = self.optics.sample_radius, self.source.spot_radius
                lit_area = min(math.pi * rspot**2 / math.cos(theta_i), math.pi * rs**2)
                e_re = r * float(alb(np.array(theta_i))) * math.cos(theta_i) * lit_area
                coef += k0 * e_re / (math.pi * rs**2) / math.pi
            if a:
                m = self.mirror
                coef += a * m.transmittance * m.reflectance * self.background.ambient
            bg = bg + coef * self.albedo_image(kind, model, g, rc, alb)
        glare = fx.get("veiling_glare", 0.0)
        if glare:
            # the response inside the image circle (0 outside), its sum
            resp_field, resp_sum = self.readout.field_response()
            # (a plain sum, not BLAS's dot: a woken BLAS thread pool costs more than the sum)
            sig = k0 * float(np.sum(rc * lit * (kd0 + ks0 * gv * isq)))
            total = float(bg.sum()) + sig  # (the background is 0 outside the image circle)
            bg = bg + resp_field * (glare * total / resp_sum)
        return bg

    def albedo_image(self, kind, model, g, rc, alb) -> NDArray:
        """Full image of ``response x ρ_dh(θo)`` over the candidates of ``g`` (0 elsewhere):
        the pixels' electrons per unit diffuse irradiance on the sample (cached per
        geometry, holder rotation and model)."""
        cache = self._albedo_images
        key = (g.__dict__.get("_theta_o_key", id(g)), kind, model.name,
               repr(sorted(model.params.items())) if kind == "brdf" else "")  # fmt: skip
        img = cache.get(key)
        if img is None:
            if len(cache) > 8:
                cache.clear()
            img = np.zeros(g.n_pixels)
            np.add.at(img, g.idx, rc * alb(np.arccos(np.clip(g.wz, -1.0, 1.0))))
            cache[key] = img
        return img
