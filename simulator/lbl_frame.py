"""One frame of the LBL instrument: a rendered scene (the light at f/1,
:class:`~gonio.simulator.lbl_scene.Scene`) taken through the lens at an f-number, with the
lamp's output at the frame's time and the lens's point spread, then read out by the sensor
(:class:`~gonio.simulator.lbl_readout.Readout`).

This part knows the lens and its aperture, the sensor's pixel pitch and ADC (for the fused
render-and-digitise pass), the dome's radius (the working distance of the focus), the
frame effects' magnitudes and the instrument seed; not the sample or the dome's geometry.
A capture and every stop of a bracket compose from the same scene with the same
arithmetic, so a bracket's noise-free frames equal separate captures bit for bit.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3: "two or more f-stops may be used to capture the full dynamic range" — a
frame's signal and background scale with 1/N², its dark current does not.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gonio.simulator.lbl_exposure import plan_stops
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lbl_scene import Scene
from gonio.simulator.lbl_trace import Geometry
from gonio.simulator.lenses import FisheyeLens
from gonio.simulator.sensor import Sensor
from numpy.typing import NDArray

__all__ = ["FRAME_FX", "Frames"]

#: the effects on a frame: the lens's aperture, the lamp's output, the point spread
FRAME_FX = (
    "fstop_series", "fstop_error", "iris_repeatability", "lamp_warmup", "lamp_drift",
    "lamp_flicker", "pixel_fill", "diffraction_wavelength", "focus_error",
)  # fmt: skip


@dataclass(eq=False)
class Frames:
    """Frames of rendered scenes: composed at an f-number, the frame effects applied
    (``fx``: the instrument's non-zero effect magnitudes, ``frame_fx``: any of the frame
    effects on), read out by ``readout``; ``geometry(rays)``: the traced geometry (only its
    image circle is used, to bound the point spread's work)."""

    readout: Readout
    geometry: Callable[[int], Geometry]
    dome_radius: float
    fx: Mapping[str, float]
    frame_fx: bool
    seed: int
    _box: tuple[int, int, int, int] | None = field(default=None, init=False, repr=False)

    @property
    def lens(self) -> FisheyeLens:
        """The lens the frames are taken through (the read-out's)."""
        return self.readout.lens

    @property
    def sensor(self) -> Sensor:
        """The sensor that reads the frames out."""
        return self.readout.sensor

    def shoot(
        self, sc: Scene, f_number: float, noise: bool, rng, binning, skip_noise_draws=True,
        frame: tuple[str, float] = ("", 0.0),
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:  # fmt: skip
        """One frame of a scene: noise (or none), ADC, optional binning; ``frame`` = (a name
        of the frame for the per-frame effects' draws, its campaign time in seconds), see
        :meth:`electrons`."""
        sen = self.sensor
        h, w = self.lens.height, self.lens.width
        if not sen.ideal_readout or sen.has_charge_effects:
            # a sensor with effects: charge effects, readout and ADC of the composed electrons
            e = self.electrons(sc, f_number, *frame)
            dark_e = sc.dark * sc.exposure if sen.smear > 0.0 else None  # smear needs it
            return self.readout.finish_effects(e, dark_e, noise, rng, binning)
        fused = not self.frame_fx and sc.delta is None
        if not noise and skip_noise_draws and binning is None and sen.linear and fused:
            # no random draws, ADC fused into the render pass
            return self.compose(sc, f_number, digitise=True).reshape(h, w), self.lens
        if noise and binning is None and sen.linear:
            # shot + read noise and the ADC in one compiled pass over the composed electrons
            from gonio.simulator import _kernels

            e = self.electrons(sc, f_number, *frame)
            img = np.empty(h * w, dtype=np.uint16)
            _kernels.noise_u16(
                e, _kernels.seed_state(rng), sen.normal_threshold, sen.read_noise,
                *sen.linear_adc, img,
            )  # fmt: skip
            return img.reshape(h, w), self.lens
        e = self.electrons(sc, f_number, *frame)
        if noise:
            # shot + read noise drawn in place
            from gonio.simulator import _kernels

            state = _kernels.seed_state(rng)
            _kernels.noise_float(e, state, sen.normal_threshold, sen.read_noise, e)
        elif not skip_noise_draws:
            # the "no random draws when noise is off" rule switched off (benchmark): draw the
            # shot and read noise as if noise were on and add them with zero amplitude
            gen = np.random.default_rng(0)
            drawn = sen.add_noise(e, gen) - e
            e = e + 0.0 * drawn
        return self.readout.finish(e, False, None, binning)

    def plan(self, sc: Scene, f_stops, min_signal_dn, headroom, skip_stops=True) -> dict[str, Any]:
        """The f-stops a bracket of ``sc`` needs
        (:func:`~gonio.simulator.lbl_exposure.plan_stops` with this sensor, these frames'
        composition and the dark map)."""
        return plan_stops(
            sc, f_stops, min_signal_dn, headroom, skip_stops, self.sensor, self.compose,
            self.readout.dark,
        )  # fmt: skip

    def electrons(self, sc: Scene, f_number: float, key: str = "", clock_s: float = 0.0) -> NDArray:
        """Noise-free electrons of one frame: the scene at the lens's true aperture (the
        engraved series, this lens's stop error, the iris's repeatability), the lamp's
        output at the campaign time ``clock_s`` (warm-up, drift, flicker), then the
        point-spread function (pixel area, diffraction, defocus). Just :meth:`compose` when
        none is on."""
        fx = self.fx
        if not self.frame_fx:
            return self.compose(sc, f_number)
        from gonio.simulator import lbl_effects as le
        from gonio.simulator.effects import effect_rng

        n = le.true_f_number(f_number, fx.get("fstop_series", 0.0))
        area = le.fstop_area_factor(f_number, fx.get("fstop_error", 0.0), self.seed)
        t = float(clock_s)
        lamp = le.lamp_factor(t, fx.get("lamp_warmup", 0.0), fx.get("lamp_drift", 0.0))
        iris, flick = fx.get("iris_repeatability", 0.0), fx.get("lamp_flicker", 0.0)
        if iris or flick:
            rng = effect_rng(self.seed, "frame", key)
            area *= max(1.0 + iris * float(rng.normal()), 0.05)
            lamp *= max(1.0 + flick * float(rng.normal()), 0.05)
        e = self.compose(sc, n / math.sqrt(area), lamp=lamp)
        sigma = le.psf_sigma_px(
            n, fx, self.sensor.pixel_pitch, self.lens.fx, 0.5 * self.dome_radius
        )
        if sigma > 0.0:  # (the dark current is the pixel's own: not blurred)
            import cv2

            dark = sc.dark * sc.exposure
            e -= dark
            img = e.reshape(self.lens.height, self.lens.width)
            r0, r1, c0, c1 = self.light_box()
            box = img[r0:r1, c0:c1].astype(np.float32)  # (float32: 1e-7 of the signal)
            img[r0:r1, c0:c1] = cv2.GaussianBlur(box, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
            e += dark
        return e

    def light_box(self) -> tuple[int, int, int, int]:
        """Rows and columns of the image circle, with an 8-pixel margin (light falls nowhere
        else, so the point-spread function need not be applied outside)."""
        box = self._box
        if box is None:
            h, w = self.lens.height, self.lens.width
            rows, cols = np.divmod(self.geometry(1).field_idx, w)
            box = self._box = (
                max(int(rows.min()) - 8, 0), min(int(rows.max()) + 9, h),
                max(int(cols.min()) - 8, 0), min(int(cols.max()) + 9, w),
            )  # fmt: skip
        return box

    def compose(
        self, sc: Scene, f_number: float, kernel=True, digitise=False, lamp: float = 1.0
    ) -> NDArray:
        """Noise-free electrons of a scene at ``f_number`` (flat float64), or with
        ``digitise`` the flat uint16 image; ``lamp`` scales the beam's signal."""
        tk = sc.exposure / f_number**2
        k = sc.k0 * tk * lamp if lamp != 1.0 else sc.k0 * tk
        kdc, ksc = k * sc.kd0, k * sc.ks0
        sen = self.sensor
        n = self.lens.height * self.lens.width
        if kernel:
            from gonio.simulator import _kernels

            # candidates as runs (unique pixels), else the pixel index (supersampled repeats)
            runs = sc.runs is not None
            where = sc.runs if runs else (sc.idx,)
            head = (sc.bg, sc.dark, tk, sc.exposure, *where, sc.rc, sc.lit, sc.g, sc.isq, kdc, ksc)
            if digitise and sc.delta is None and sen.linear:
                img = np.empty(n, dtype=np.uint16)
                compose_u16 = _kernels.compose_u16_runs if runs else _kernels.compose_u16
                compose_u16(*head, *sen.linear_adc, img)
                return img
            out = np.empty(n)
            (_kernels.compose_float_runs if runs else _kernels.compose_float)(*head, out)
        else:
            out = sc.bg * tk + sc.dark * sc.exposure
            sig = sc.rc * sc.lit * (kdc + ksc * sc.g * sc.isq)
            if sc.rays == 1:
                out[sc.idx] += sig
            else:  # a pixel's sub-pixel rays add up
                np.add.at(out, sc.idx, sig)
        if sc.delta is not None:
            pix, val = sc.delta
            out[pix] += k * val
        if digitise:
            return sen.digitise(out)
        return out
