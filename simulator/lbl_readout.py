"""The LBL instrument's camera pixels: each pixel's response to radiance, its dark current,
and the read-out of a frame's electrons into DN (noise, ADC, binning).

This part knows the lens's image (its size, its relative illumination) and the
:class:`~gonio.simulator.sensor.Sensor` — not the dome, the source or the sample: it turns
electrons into counts, and radiance at f/1 into electrons. The traced geometry it is given
only tells it which pixels are candidates (see the sample).

References
----------
.. [EMVA1288] European Machine Vision Association, "EMVA Standard 1288: Standard for
   Characterization of Image Sensors and Cameras", Release 4.0, 2021: the dark frame and
   the read-out model of Sec. 2 that :class:`~gonio.simulator.sensor.Sensor` follows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from gonio.simulator.lbl_trace import Geometry
from gonio.simulator.lenses import FisheyeLens
from gonio.simulator.sensor import Sensor
from numpy.typing import NDArray

__all__ = ["Readout"]


@dataclass(eq=False)
class Readout:
    """The pixels of the camera behind the lens (``vignetting``: the lens's relative
    illumination fall-off, 0 = none; ``geometry(rays)``: the traced geometry).

    Its caches (response, dark map) hold for one sensor and lens: a changed instrument
    builds a new ``Readout``.
    """

    lens: FisheyeLens
    sensor: Sensor
    vignetting: float
    geometry: Callable[[int], Geometry]
    _resp: tuple[NDArray, NDArray] | None = field(default=None, init=False, repr=False)
    _resp_rays: dict[int, NDArray] = field(default_factory=dict, init=False, repr=False)
    _dark_map: NDArray | None = field(default=None, init=False, repr=False)
    _resp_field: tuple[NDArray, float] | None = field(default=None, init=False, repr=False)

    # ------------------------------------------------------------------ response
    def response(self) -> tuple[NDArray, NDArray]:
        """Per-pixel electrons per (photon s⁻¹ m⁻² sr⁻¹ · s) at f/1: full image and candidates."""
        if self._resp is None:
            g = self.geometry(1)
            prnu, _ = self.sensor.maps(g.height, g.width)
            k = self.sensor.qe * (math.pi / 4.0) * self.sensor.pixel_pitch**2
            resp = (prnu * k).ravel()
            v = self.vignetting
            if v:  # the fisheye's relative illumination, 1 - v (θ / θ_max)²
                th = self.lens.field_angle(self.lens.pixel_grid().reshape(-1, 2))
                resp = resp * (1.0 - v * np.minimum(th / self.lens.theta_max, 1) ** 2)
            self._resp = (resp, np.ascontiguousarray(resp[g.idx]))
        return self._resp

    def rays_response(self, g: Geometry, rays: int) -> NDArray:
        """Per-candidate response of a supersampled geometry: each ray has 1/rays of its pixel."""
        if rays == 1:
            return self.response()[1]
        cache = self._resp_rays
        r = cache.get(rays)
        if r is None or r.size != g.idx.size:
            r = self.response()[0][g.idx] * (1.0 / rays)
            cache.clear()
            cache[rays] = r
        return r

    def candidate_response(self, g: Geometry, rays: int) -> NDArray:
        """Response of the candidates of ``g`` (the ideal geometry's is cached as before)."""
        if g is self.geometry(rays):
            return self.rays_response(g, rays)
        rc = g.__dict__.get("_rc")
        if rc is None:
            rc = np.ascontiguousarray(self.response()[0][g.idx])
            g.__dict__["_rc"] = rc
        return rc

    def field_response(self) -> tuple[NDArray, float]:
        """The response inside the image circle (0 outside) and its sum (cached)."""
        if self._resp_field is None:
            resp_field = np.zeros_like(self.response()[0])
            fi = self.geometry(1).field_idx
            resp_field[fi] = self.response()[0][fi]
            self._resp_field = (resp_field, float(resp_field.sum()))
        return self._resp_field

    def dark(self) -> NDArray:
        """Dark-current map, electrons per second (flat, cached)."""
        if self._dark_map is None:
            g = self.geometry(1)
            self._dark_map = self.sensor.dark_map(g.height, g.width).ravel()
        return self._dark_map

    # ------------------------------------------------------------------ read-out
    def finish(
        self, e: NDArray, noise: bool, rng: np.random.Generator, binning, kernel: bool = True,
        dark_e: NDArray | None = None,
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:  # fmt: skip
        """Noise, ADC and binning of expected electrons ``e`` (flat); ``dark_e``: their dark
        part (smear follows the rest; default: the instrument's dark map at no exposure)."""
        sen = self.sensor
        if not sen.ideal_readout or sen.has_charge_effects:
            return self.finish_effects(e, dark_e, noise, rng, binning)
        if noise:
            e = sen.add_noise(e, rng)
        if binning is None:
            if sen.linear and kernel:
                from gonio.simulator import _kernels

                img = np.empty(e.size, dtype=np.uint16)
                _kernels.digitise_linear(e.ravel(), *sen.linear_adc, img)
            else:
                img = sen.digitise(e)
            return img.reshape(self.lens.height, self.lens.width), self.lens
        return self.bin(e, binning, sen.full_well)

    def finish_effects(
        self,
        e: NDArray,
        dark_e: NDArray | None,
        noise: bool,
        rng: np.random.Generator | None,
        binning,
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:
        """:meth:`finish` for a sensor with effects (:attr:`Sensor.ideal_readout` false or
        charge effects on): blooming and smear of the expected charge (``dark_e``: its dark
        part, which smear does not follow; None: no dark part), then
        :meth:`Sensor.readout` (noise, full-well clip, offsets) and the ADC with no further
        clip."""
        sen = self.sensor
        h, w = self.lens.height, self.lens.width
        e = sen.spread(np.asarray(e, dtype=np.float64).reshape(h, w), dark_e)
        if binning is None:
            return sen.readout_dn(e, rng, noise=noise), self.lens
        return self.bin(sen.readout(e, rng, noise=noise), binning, math.inf)

    def bin(self, e: NDArray, binning, clip_e: float) -> tuple[NDArray[np.uint16], FisheyeLens]:
        """Area-average binning to ``binning = (width, height)`` of electrons ``e`` clipped at
        ``clip_e``, then black level, rounding and the ADC's range."""
        import cv2

        sen = self.sensor
        bw, bh = binning
        x = np.minimum(e, clip_e) * (1.0 / sen.gain)
        if not sen.linear:
            xm = sen._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** sen.response_gamma
        x = x.reshape(self.lens.height, self.lens.width) + sen.black_level
        small = cv2.resize(x, (bw, bh), interpolation=cv2.INTER_AREA)
        dn = np.clip(np.rint(small), 0, sen.max_dn).astype(np.uint16)
        return dn, self.lens.resized(bw, bh)
