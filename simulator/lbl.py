"""The LBL imaging gonioreflectometer (Ward 1992 §3), simulated.

A collimated beam passes through the half-silvered dome and lights a spot on the sample;
light the sample reflects in direction d̂_r is reflected by the dome into a fisheye lens on
a CCD. One image therefore holds the whole hemisphere of reflected directions.

Each capture is a function of (instrument, sample, θ_i, φ_i, exposure, f-number, seed).
The per-instrument geometry — pixel → camera ray → mirror point → sample point and reflected
direction — is traced exactly once and cached (:class:`Geometry`); a capture then costs one
BRDF evaluation over the pixels that see the sample, a background fill and the ADC. Skipped
when the scene does not need them: pixels outside the image circle or seeing no sample (never
evaluated), pixels outside the beam footprint (the generic path evaluates the BRDF only on
lit pixels; the Ward kernel masks them), the beam-footprint test itself when every pixel sees
the sample centre (ellipsoid), the float image and a second pass when noise is off (the ADC
is fused into the render pass), spectral bands of a grey BRDF
(:meth:`LBLInstrument.capture_bands` evaluates once), random draws when noise is off,
f-stops adding no unsaturated pixel (:meth:`LBLInstrument.plan_bracket`), re-rendering per
f-stop (a bracket renders the noise-free scene once at f/1 and composes every stop from it:
signal and background scale with 1/N², dark current does not), and the source-cone average
when the lobe is much wider than the source. With noise on, the float electrons are
composed in one compiled pass and shot + read noise and the ADC drawn in a second
(:mod:`gonio.simulator.sensor` explains the noise draw, :mod:`gonio.simulator._kernels`
the passes).
``rays_per_pixel`` supersamples each pixel with an s × s grid of traced rays.

The instrument is a few parts, each a module with one job, and :class:`LBLInstrument` a
façade over them; a capture goes through them in the order the light does:

- :mod:`~gonio.simulator.lbl_config`: a capture's arguments checked, its side-car written;
- :mod:`~gonio.simulator.lbl_trace`: the ideal optical trace (pixel → dome → sample), cached;
- :mod:`~gonio.simulator.lbl_pose`: the beam's frames (source), the true geometry and the
  posed sample (sample, dome);
- :mod:`~gonio.simulator.lbl_scene`: the scene, the light at the lens at f/1 — the sample's
  reflection (signal and mirror terms) with :mod:`~gonio.simulator.lbl_stray`'s background
  and stray light;
- :mod:`~gonio.simulator.lbl_frame`: a frame of the scene at an f-number (lens aperture,
  lamp, point spread), read out by :mod:`~gonio.simulator.lbl_readout` (response, dark,
  noise, ADC, binning) (lens, sensor);
- :mod:`~gonio.simulator.lbl_exposure`: the bracket's f-stops;
  :mod:`~gonio.simulator.lbl_calibration`: the sensor's dark and flat-field captures.

Radiometry (photon units, see :mod:`gonio.simulator.source`): a sample point lit by the beam
(irradiance ``E`` normal to the beam, dome transmittance ``T``) reflects radiance
``L = f_r(wi, wo) T E cos θ_i``; the dome reflects ``R_m L`` into the lens; a pixel collects
``QE (1 + PRNU) (π / 4N²) p² R_m L t`` electrons (``p`` the pixel pitch). Background:
``ambient · T`` over the image circle plus the glow where the beam crosses the dome, present
with or without a sample. A mirror (delta) component of reflectance ρ_δ gives radiance
``ρ_δ T E / Ω_s`` over the image of the source cone, rendered with sub-pixel sampling.

Then eq. 2 holds: ``(V - V_bg)/(V_std - V_bg) · ρ_std/π = f_r`` at every lit pixel.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3 (device, Figure 2-4), eq. 2 (calibration against a diffuse
standard and a background image), eq. 3 (angle recovery), "reduced ... to a resolution of
108 by 80 pixels", "two or more f-stops may be used to capture the full dynamic range".
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
from gonio.simulator.lbl_calibration import calibration_capture
from gonio.simulator.lbl_config import (
    STANDARD,
    WARD_BINNING,
    Request,
    _check_angle,
    _frame_key,
    _json_value,
    _resolve_sample,
    _rng_and_seed,
    bench_incidence,
    capture_metadata,
    check_args,
    check_binning,
    check_sample,
    effect_magnitudes,
    filter_bands,
    make_camera_lens,
    make_mirror,
)
from gonio.simulator.lbl_exposure import F_STOPS
from gonio.simulator.lbl_frame import FRAME_FX, Frames
from gonio.simulator.lbl_pose import GEOMETRY_FX, SamplePose, _base_radii, _near_rim
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lbl_scene import Scene, SceneMaker, _lobe_width, _ward_kernel_params
from gonio.simulator.lbl_stray import SCENE_FX, StrayLight
from gonio.simulator.lbl_trace import (
    _GEOMETRY_CACHE,
    _GEOMETRY_CACHE_SIZE,
    MAX_RAYS,
    Geometry,
    Optics,
    _check_rays,
    _pitch,
    _trace_geometry,
    _trace_supersampled,
)
from gonio.simulator.lenses import FisheyeLens
from gonio.simulator.lenses import _pos_finite as _check_positive
from gonio.simulator.optics import Mirror
from gonio.simulator.sensor import Sensor
from gonio.simulator.source import Background, Source
from numpy.typing import NDArray

__all__ = [
    "STANDARD",
    "WARD_BINNING",
    "Geometry",
    "LBLInstrument",
    "capture",
    "default_instrument",
    "reproduce",
]

#: the scene of one capture (kept under its old name)
_Scene = Scene
#: the names the parts' modules took from this one, still importable from it
_MOVED = (
    F_STOPS, MAX_RAYS, _GEOMETRY_CACHE, _GEOMETRY_CACHE_SIZE, _base_radii, _check_angle,
    _json_value, _lobe_width, _near_rim, _pitch, _trace_geometry, _trace_supersampled,
    _ward_kernel_params,
)  # fmt: skip


# ---------------------------------------------------------------------------- the parts
@dataclass(frozen=True)
class _Parts:
    """The instrument's parts, built from its configuration (:meth:`assemble`); a changed
    configuration builds new ones, so no part keeps a cache of an old one."""

    optics: Optics
    readout: Readout
    pose: SamplePose
    scene: SceneMaker
    frames: Frames

    @classmethod
    def assemble(cls, inst: LBLInstrument) -> _Parts:
        """The parts of ``inst``, each given only what it may know."""
        fx, seed = inst._fx, inst.instrument_seed
        optics = Optics(inst.mirror, inst.lens, inst.sample_radius)
        readout = Readout(inst.lens, inst.sensor, fx.get("vignetting", 0.0), optics.geometry)
        pose = SamplePose(optics, inst.source, readout, fx, seed)
        stray = StrayLight(optics, inst.background, inst.source, readout, fx, inst.rho_standard)
        scene = SceneMaker(
            optics, inst.source, pose, stray, readout, fx, inst._scene_fx, inst.rho_standard,
            seed,
        )  # fmt: skip
        frames = Frames(readout, optics.geometry, inst.mirror.radius, fx, inst._frame_fx, seed)
        return cls(optics, readout, pose, scene, frames)


class _Forward:
    """A private name callers (tests, benchmarks, diagnostics) reach on the instrument,
    kept as the method of the part that now does the work."""

    def __init__(self, part: str, name: str) -> None:
        self.part, self.name = part, name

    def __get__(self, inst: Any, owner: type) -> Any:
        if inst is None:
            return self
        return getattr(getattr(inst._parts, self.part), self.name)


# ---------------------------------------------------------------------------- the instrument
class LBLInstrument:
    """The simulated LBL imaging gonioreflectometer.

    Parameters
    ----------
    mirror : {"ellipsoid", "hemisphere"} or Mirror
        Dome shape (a :class:`~gonio.simulator.optics.Mirror` for full control).
    radius, half_separation : float
        Dome radius ``R`` (ellipsoid: semi-major axis) and ``D`` in metres.
    lens : str or FisheyeLens
        A lens model name (:data:`~gonio.simulator.lenses.LENS_MODELS`, built with
        :func:`~gonio.simulator.lenses.make_lens` for ``width × height``) or a lens.
    width, height : int
        Sensor size in pixels (ignored when ``lens`` is a :class:`FisheyeLens`).
    sensor, source, background : optional
        :class:`Sensor`, :class:`Source`, :class:`Background` (defaults if omitted).
    sample_radius : float
        Radius of the (round) sample, metres; must be smaller than ``2D`` so the sample
        does not overlap the lens.
    rho_standard : float
        Directional-hemispherical reflectance of the diffuse standard, in (0, 1]
        (Lambertian unless the effects make it a PTFE standard).
    mirror_reflectance, mirror_transmittance : float
        Half-silvering (used when ``mirror`` is given by name).
    effects : mapping of str to float, optional
        Magnitudes of the instrument's imperfections by name
        (:data:`gonio.simulator.effects.EFFECTS`, e.g. from
        :func:`gonio.simulator.effects.realise`); missing names are 0. None or all zero is
        the ideal instrument (bit-identical images, none of the effects' work done). A
        magnitude outside its valid range is a ``ValueError``.
    instrument_seed : int
        Seed of the effects' realisation (the dome's figure map, the standard's deviation
        from its certificate, each f-stop's error, the tilt's azimuth): the same seed and
        magnitudes are the same physical instrument.

    Notes
    -----
    The side-car (:meth:`metadata`) records what a real instrument writes (the marked
    f-number, the nominal optics), not the effects: :func:`reproduce` and
    :meth:`from_metadata` rebuild the ideal instrument. The campaign's clock for the lamp's
    warm-up and drift is :attr:`clock_s` (seconds since the first capture; captures and
    brackets take ``clock_s`` too).

    The class is a façade over the parts of :mod:`gonio.simulator.lbl`'s list: it checks a
    capture's arguments, renders the scene and takes the frames, and every step of the
    light's path is a part's. It is longer than the guide's 400 lines for a class (599
    lines, 21 methods) for its public API: 190 of its lines are its docstrings and 151
    the signatures of its methods (one argument a line); :meth:`capture`'s 73 lines are
    17 of signature, 45 of docstring and 11 of code.
    """

    def __init__(
        self,
        mirror: str | Mirror = "ellipsoid",
        radius: float = 0.15,
        half_separation: float = 0.01,
        lens: str | FisheyeLens = "equidistant",
        width: int = 640,
        height: int = 480,
        *,
        sensor: Sensor | None = None,
        source: Source | None = None,
        background: Background | None = None,
        sample_radius: float = 0.008,
        rho_standard: float = 0.99,
        mirror_reflectance: float = 0.5,
        mirror_transmittance: float = 0.45,
        effects: Mapping[str, float] | None = None,
        instrument_seed: int = 0,
    ) -> None:
        self.mirror = make_mirror(
            mirror, radius, half_separation, mirror_reflectance, mirror_transmittance
        )
        self.lens = make_camera_lens(lens, width, height)
        self.sensor = sensor if sensor is not None else Sensor()
        self.source = source if source is not None else Source()
        self.background = background if background is not None else Background()
        self.sample_radius, self.rho_standard = check_sample(
            sample_radius, rho_standard, self.mirror
        )
        #: the instrument seed and every effect's magnitude (0 = off)
        self.instrument_seed, self.effects, self._fx = effect_magnitudes(effects, instrument_seed)
        self._frame_fx = any(k in self._fx for k in self._FRAME_FX)
        self._scene_fx = any(k in self._fx for k in SCENE_FX)
        #: campaign time of the next capture (s), for the lamp's warm-up and drift
        self.clock_s = 0.0

    #: attributes that describe the instrument; every part and its caches derive from them
    _CONFIG: ClassVar[frozenset[str]] = frozenset(
        {"mirror", "lens", "sensor", "source", "background", "sample_radius", "rho_standard"}
    )
    _CONFIG_TYPES: ClassVar[dict[str, type]] = {
        "sensor": Sensor,
        "source": Source,
        "background": Background,
    }
    _GEOMETRY_FX = GEOMETRY_FX
    _FRAME_FX = FRAME_FX
    _SCENE_FX = SCENE_FX

    def __setattr__(self, name: str, value: Any) -> None:
        """Reassigning a part of the instrument (``inst.sensor = Sensor(...)``) drops the
        parts built from the old one with every cache they hold, so the next capture is
        that of a fresh instrument (the parts themselves are frozen dataclasses, so
        reassignment is the only change; the traced geometry is keyed by the optics in
        :mod:`~gonio.simulator.lbl_trace`'s cache and needs no dropping)."""
        if name in self._CONFIG:
            cls = self._CONFIG_TYPES.get(name)
            if cls is not None and not isinstance(value, cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
            if name in self.__dict__ and self.__dict__[name] is not value:
                self.__dict__.pop("_assembled", None)
        object.__setattr__(self, name, value)

    @property
    def _parts(self) -> _Parts:
        """The instrument's parts (built on first use, after a change of configuration)."""
        parts = self.__dict__.get("_assembled")
        if parts is None:
            parts = self.__dict__["_assembled"] = _Parts.assemble(self)
        return parts

    # the scene of a capture: source, sample and dome (the light at the lens, at f/1)
    _scene = _Forward("scene", "render")
    # the f-stops a bracket of a rendered scene needs
    _plan = _Forward("frames", "plan")
    # names tests, benchmarks and diagnostics reach on the instrument, done by its parts
    _geometry = _Forward("optics", "geometry")
    _response = _Forward("readout", "response")
    _dark = _Forward("readout", "dark")
    _finish_effects = _Forward("readout", "finish_effects")
    _frames = _Forward("pose", "beam")
    _scene_geometry = _Forward("pose", "true_geometry")
    _posed = _Forward("pose", "posed")
    _standard_model = _Forward("scene", "standard_model")
    _signal_terms = _Forward("scene", "signal_terms")
    _compose = _Forward("frames", "compose")

    # ------------------------------------------------------------------ description
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready instrument description (the instrument part of the metadata)."""
        return {
            "instrument": "lbl",
            "mirror": self.mirror.to_dict(),
            "lens": self.lens.to_dict(),
            "sensor": self.sensor.to_dict(),
            "source": self.source.to_dict(),
            "background": self.background.to_dict(),
            "sample_radius": self.sample_radius,
            "rho_standard": self.rho_standard,
        }

    @classmethod
    def from_metadata(cls, meta: dict[str, Any]) -> LBLInstrument:
        """Rebuild the instrument a capture's metadata describes."""
        try:
            return cls(
                Mirror.from_dict(meta["mirror"]),
                lens=FisheyeLens.from_dict(
                    meta["full_lens"] if "full_lens" in meta else meta["lens"]
                ),
                sensor=Sensor.from_dict(meta["sensor"]),
                source=Source.from_dict(meta["source"]),
                background=Background.from_dict(meta["background"]),
                sample_radius=meta["sample_radius"],
                rho_standard=meta["rho_standard"],
            )
        except KeyError as exc:
            raise ValueError(f"metadata lacks {exc}; not an LBL capture") from None

    def __repr__(self) -> str:
        m = self.mirror
        return (
            f"LBLInstrument({m.kind}, R={m.radius:g}, D={m.half_separation:g}, "
            f"lens={self.lens.model} {self.lens.width}x{self.lens.height})"
        )

    @property
    def geometry(self) -> Geometry:
        """The traced per-pixel geometry (computed on first use, then cached)."""
        return self._parts.optics.geometry(1)

    def certificate(self):
        """The calibration certificate that comes with this instrument's diffuse standard
        (:class:`gonio.io.certificate.Certificate`: what the laboratory knows of it)."""
        from gonio.simulator.standard import make_certificate

        fx = self._fx
        return make_certificate(
            self.rho_standard, fx.get("standard_non_lambertian", 0.0),
            fx.get("standard_certificate_u", 0.0),
        )  # fmt: skip

    # ------------------------------------------------------------------ the path of light
    def _shoot(
        self, sc: Scene, f_number: float, noise: bool, rng, binning, skip_noise_draws=True,
        frame: tuple[str, float | None] = ("", None),
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:  # fmt: skip
        """One frame of a scene through the lens and onto the sensor (noise or none, ADC,
        optional binning); ``frame`` = (a name of the frame for the per-frame effects'
        draws, its campaign time or None for :attr:`clock_s`), see
        :meth:`gonio.simulator.lbl_frame.Frames.shoot`."""
        key, clock_s = frame
        t = self.clock_s if clock_s is None else clock_s
        frames = self._parts.frames
        return frames.shoot(sc, f_number, noise, rng, binning, skip_noise_draws, (key, t))

    def _take(self, ask: Request, sc: Scene, f_number, rng, seed, index=0, skip_noise_draws=True,
              clock_s=None) -> tuple[NDArray[np.uint16], dict[str, Any]]:  # fmt: skip
        """One frame of the scene ``sc`` at ``f_number`` through the lens onto the sensor,
        and its side-car (``ask``: what the capture was asked; ``index``: the frame's place
        in its series, for the per-frame effects' draws)."""
        key = _frame_key(ask.kind, ask.theta_i, ask.phi_i, sc.exposure, f_number, seed, index)
        frame = (key, clock_s)
        img, lens = self._shoot(sc, f_number, ask.noise, rng, ask.binning, skip_noise_draws, frame)
        return img, self.metadata(
            ask.kind, ask.model, ask.material, ask.theta_i, ask.phi_i, sc.exposure, f_number,
            seed, ask.noise, ask.binning, ask.band, ask.source_samples, lens, img, ask.rays,
        )  # fmt: skip

    def _render(
        self, kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
        kernel=True, visible_only=True, digitise=False, rays=1,
    ) -> NDArray:  # fmt: skip
        """Noise-free electrons (flat float64), or with ``digitise`` the uint16 image."""
        parts = self._parts
        sc = parts.scene.render(
            kind, model, theta_i, phi_i, exposure, band, source_samples, kernel, visible_only,
            rays,
        )  # fmt: skip
        return parts.frames.compose(sc, f_number, kernel, digitise)

    def electrons(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        band: int | None = None,
        source_samples: int | None = None,
        kernel: bool = True,
        visible_only: bool = True,
        rays_per_pixel: int = 1,
    ) -> NDArray[np.float64]:
        """Noise-free expected electrons per pixel, ``(height, width)`` float64.

        Same arguments as :meth:`capture`; ``kernel`` / ``visible_only`` switch off the
        specialised kernel and the visible-pixel skip (for benchmarks and tests).
        """
        kind, model, _ = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = check_args(theta_i, phi_i, exposure, f_number)
        return self._render(
            kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
            kernel, visible_only, False, _check_rays(rays_per_pixel),
        ).reshape(self.lens.height, self.lens.width)  # fmt: skip

    def capture(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        band: int | None = None,
        source_samples: int | None = None,
        rays_per_pixel: int = 1,
        skip_noise_draws: bool = True,
        clock_s: float | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """One raw image of ``sample`` lit from (θ_i, φ_i).

        Parameters
        ----------
        sample : BRDF, callable, str or None
            A model, a plain callable ``f(wi, wo)``, a material preset name
            (:func:`gonio.materials.get`) or model name, ``"standard"`` (the diffuse
            standard of reflectance ``rho_standard``), or ``None`` (no sample: background).
        theta_i, phi_i : float
            Incidence in the sample frame (radians), ``0 <= theta_i < pi/2``. θ_i is set by
            the source arm, φ_i by rotating the sample holder to ``arm_azimuth - phi_i``.
        exposure : float
            Exposure time, seconds (> 0).
        f_number : float
            Lens f-number (image irradiance ∝ 1/N²).
        rng : int, Generator or None
            Noise seed. An int (or None, which draws a fresh seed) is recorded in the
            metadata so the capture can be reproduced; a Generator is used as is.
        noise : bool
            False: no shot or read noise and no random draws (fixed patterns remain).
        binning : (width, height), True or None
            Reduce the image by area averaging before quantisation; ``True`` means Ward's
            108 × 80.
        band : int, optional
            Band index of a spectral BRDF (default: the mean over bands, white light).
        source_samples : int, optional
            Directions averaged over the source cone; default 1 when the model's lobe is
            at least 5× the beam divergence (or the model declares no lobe width), else 19.
        rays_per_pixel : int
            Sub-pixel supersampling: an ``s × s`` grid of rays per pixel (1, 4, 9, ..., 64),
            each traced through the mirror to the sample; the pixel averages their BRDF
            values (the background stays per pixel). Recorded in the metadata when not 1.
        skip_noise_draws : bool
            Benchmark switch of the rule "no random draws when noise is off": False draws
            the shot and read noise anyway and adds them with zero amplitude (same image).
        clock_s : float, optional
            Campaign time of the capture (s) for the lamp's warm-up and drift; default
            :attr:`clock_s`.

        Returns
        -------
        image : ndarray of uint16, shape (height, width)
        metadata : dict
            JSON-ready; see :meth:`metadata` (also written as the image side-car).
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = check_args(theta_i, phi_i, exposure, f_number)
        binning = check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        ask = Request(kind, model, material, theta_i, phi_i, noise, binning, band, source_samples,
                      rays)  # fmt: skip
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        # source, sample, dome: the light that reaches the lens, at f/1
        sc = self._scene(kind, model, theta_i, phi_i, exposure, band, source_samples, rays=rays)
        # lens, sensor: the frame at this f-number, read out, and its side-car
        return self._take(ask, sc, f_number, gen, seed, 0, skip_noise_draws, clock_s)

    def capture_series(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        settings: Sequence[Mapping[str, Any]],
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        band: int | None = None,
        source_samples: int | None = None,
        rays_per_pixel: int = 1,
        clock_s: float | None = None,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """Several raw images of one scene: ``capture(sample, theta_i, phi_i, **s)`` for each
        ``s`` of ``settings`` (keys ``exposure``, ``f_number``, ``rng``), the noise-free
        scene rendered once.

        The scene does not depend on the exposure or the f-number (:class:`_Scene`: both
        enter only when the frame is composed), so each frame equals the separate
        :meth:`capture` bit for bit (a test checks it); a calibration series such as the
        f-stop ladder (the standard at one incidence through every stop, repeated) then
        costs one BRDF evaluation instead of one per frame.
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, _, _ = check_args(theta_i, phi_i, 1.0, 1.0)
        binning = check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        bad = sorted({k for s in settings for k in s} - {"exposure", "f_number", "rng"})
        if bad:
            raise ValueError(f"settings have unknown keys {bad}; expected exposure, f_number, rng")
        ask = Request(kind, model, material, theta_i, phi_i, noise, binning, band, source_samples,
                      rays)  # fmt: skip
        sc0 = None
        out = []
        for s in settings:
            _, _, exposure, f_number = check_args(
                theta_i, phi_i, s.get("exposure", 0.01), s.get("f_number", 4.0)
            )
            gen, seed = _rng_and_seed(s.get("rng")) if noise else (None, None)
            if sc0 is None:
                sc0 = self._scene(kind, model, theta_i, phi_i, exposure, band, source_samples,
                                  rays=rays)  # fmt: skip
            sc = sc0 if exposure == sc0.exposure else replace(sc0, exposure=exposure)
            out.append(self._take(ask, sc, f_number, gen, seed, 0, True, clock_s))
        return out

    def metadata(
        self, kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise, binning,
        band, source_samples, lens, img, rays_per_pixel=1,
    ) -> dict[str, Any]:  # fmt: skip
        """The metadata dict of a capture (everything needed to reproduce it).

        ``rays_per_pixel`` is recorded (key ``"rays_per_pixel"``) only when it is not 1.
        """
        return capture_metadata(
            self.to_dict(), self.source.arm_azimuth, kind, model, material, theta_i, phi_i,
            exposure, f_number, seed, noise, binning, band, source_samples, lens, img,
            rays_per_pixel,
        )  # fmt: skip

    # ------------------------------------------------------------------ calibration captures
    def capture_dark(
        self,
        *,
        exposure: float = 0.01,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """A shutter-closed dark frame: no light reaches the sensor, only the dark current
        (with its nonuniformity and hot pixels), the offsets and the read noise — the dark
        image a laboratory records for dark subtraction and the sensor's DSNU
        (EMVA 1288 R4.0, dark measurements of Sec. 6-8).

        The side-car has ``calibration = "dark"``, ``shutter = "closed"`` and
        ``photons_per_pixel = 0``.
        """
        return calibration_capture(
            self._parts.readout, self.to_dict(), "dark", 0.0, exposure, rng, noise, binning
        )

    def capture_flat(
        self,
        photons_per_pixel: float,
        *,
        exposure: float = 0.01,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """A flat field: the lens removed and the sensor lit by an integrating sphere with
        ``photons_per_pixel`` photons per pixel during the exposure (a uniform irradiance, as
        a calibrated sphere and radiometer give it), the EMVA 1288 set-up for gain, PRNU and
        the photon transfer curve (R4.0 Sec. 6.1, 6.5).

        The side-car has ``calibration = "flat_field"``, ``shutter = "open"`` and
        ``photons_per_pixel`` (what the laboratory's radiometer reports).
        """
        p = _check_positive(photons_per_pixel, "photons_per_pixel")
        return calibration_capture(
            self._parts.readout, self.to_dict(), "flat_field", p, exposure, rng, noise, binning
        )

    # ------------------------------------------------------------------ bands
    def capture_bands(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        wavelengths_nm: Sequence[float] = (450.0, 550.0, 650.0),
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        evaluate_once: bool = True,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """One capture per colour filter (flat source spectrum, equal filter efficiency).

        A spectral BRDF is evaluated at the band nearest each filter (within 5 nm); a grey
        BRDF is evaluated once and reused for every filter (``evaluate_once=False`` forces
        one evaluation per filter, for the benchmark). Noise streams are spawned per filter
        from ``rng``.
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = check_args(theta_i, phi_i, exposure, f_number)
        wl = [float(w) for w in wavelengths_nm]
        bands = filter_bands(model, wl)
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        gens = gen.spawn(len(wl)) if noise else [None] * len(wl)
        out = []
        shared = None
        for i, w in enumerate(wl):
            grey = bands[i] is None
            if grey and evaluate_once and shared is not None:
                e = shared.copy()
            else:
                e = self._render(kind, model, theta_i, phi_i, exposure, f_number, bands[i], None)
                if grey and evaluate_once:
                    shared = e.copy()
            readout = self._parts.readout
            img, lens = readout.finish(e, noise, gens[i], None, dark_e=readout.dark() * exposure)
            meta = self.metadata(
                kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise, None,
                bands[i], None, lens, img,
            )  # fmt: skip
            meta["filter_nm"] = w
            meta["filter_index"] = i
            out.append((img, meta))
        return out

    # ------------------------------------------------------------------ bracketing
    def plan_bracket(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_stops: Sequence[float] = F_STOPS,
        min_signal_dn: float = 16.0,
        headroom: float = 0.9,
        skip_stops: bool = True,
    ) -> dict[str, Any]:
        """Choose the f-stops that cover the dynamic range of a sample's image.

        From the noise-free image: the first stop is the widest aperture at which the
        brightest lit pixel stays below ``headroom × saturation``; each wider stop is kept
        only if it brings at least one lit pixel into the usable range (unsaturated and at
        least ``min_signal_dn`` above the background) that no kept stop covered. Stops
        that add no such pixel are skipped. ``skip_stops=False`` switches the skip off
        (benchmark): every stop from the first one on is kept.

        The scene is rendered once at f/1 and every stop evaluated from it (one compiled
        pass over the lit pixels for all stops).

        Returns
        -------
        dict
            ``f_numbers`` (kept, darkest first), ``skipped`` (tried and not kept),
            ``covered_fraction`` of lit pixels, ``peak_saturated`` (even the darkest stop
            saturates the peak), ``n_lit``.
        """
        kind, model, _ = _resolve_sample(sample)
        theta_i, phi_i, exposure, _ = check_args(theta_i, phi_i, exposure, 1.0)
        sc = self._scene(kind, model, theta_i, phi_i, exposure, None, None)
        return self._plan(sc, f_stops, min_signal_dn, headroom, skip_stops)

    def bracket(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_stops: Sequence[float] = F_STOPS,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        rays_per_pixel: int = 1,
        clock_s: float | None = None,
        **plan_kw: Any,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """Capture the f-stops :meth:`plan_bracket` chooses; each metadata has ``bracket``.

        The noise-free scene is rendered once (at f/1); the plan and every stop are
        composed from it (signal and background scale with 1/N², dark current does not),
        so with noise off each frame equals ``capture(..., f_number=N)`` bit for bit.
        Noise streams are spawned per stop from ``rng``. ``plan_kw``: ``min_signal_dn``,
        ``headroom``, ``skip_stops`` (see :meth:`plan_bracket`). ``clock_s``: the campaign
        time of the bracket (lamp effects; default :attr:`clock_s`).
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, _ = check_args(theta_i, phi_i, exposure, 1.0)
        binning = check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        unknown = set(plan_kw) - {"min_signal_dn", "headroom", "skip_stops"}
        if unknown:
            raise ValueError(
                f"bracket got unexpected arguments {sorted(unknown)}; plan options are "
                "min_signal_dn, headroom, skip_stops"
            )
        ask = Request(kind, model, material, theta_i, phi_i, noise, binning, None, None, rays)
        sc = self._scene(kind, model, theta_i, phi_i, exposure, None, None, rays=rays)
        plan = self._plan(
            sc, f_stops, plan_kw.get("min_signal_dn", 16.0), plan_kw.get("headroom", 0.9),
            plan_kw.get("skip_stops", True),
        )  # fmt: skip
        nf = len(plan["f_numbers"])
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        gens = gen.spawn(nf) if noise else [None] * nf
        out = []
        for i, n in enumerate(plan["f_numbers"]):
            n = check_args(theta_i, phi_i, exposure, n)[3]
            img, meta = self._take(ask, sc, n, gens[i], seed, i, clock_s=clock_s)
            meta["bracket"] = {"index": i, **plan}
            out.append((img, meta))
        return out

    # ------------------------------------------------------------------ fake-device hook
    def camera_render(
        self,
        sample: Any,
        *,
        source_axis: str = "source",
        sample_axis: str = "sample",
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
    ) -> Callable[[dict[str, float], float, float], tuple[NDArray[np.uint16], dict[str, Any]]]:
        """A ``camera_render(positions, exposure_s, f_number)`` callable for a simulated bench.

        ``positions`` maps stage names to degrees: ``positions[source_axis]`` is θ_i (source
        arm) and ``positions[sample_axis]`` the sample-holder rotation ψ, so that
        ``φ_i = arm_azimuth - ψ``; a negative arm angle means the arm swung through the
        zenith (``θ_i = |θ|``, ``φ_i + π``). Successive calls draw fresh noise from one generator.
        """
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

        def render(positions: dict[str, float], exposure_s: float, f_number: float):
            az = self.source.arm_azimuth
            th, phi = bench_incidence(positions, source_axis, sample_axis, az)
            return self.capture(
                sample, th, phi, exposure=exposure_s, f_number=f_number, rng=gen, noise=noise
            )

        return render


# ---------------------------------------------------------------------------- module level
_DEFAULT: dict[str, LBLInstrument] = {}


def default_instrument() -> LBLInstrument:
    """The shared default instrument (ellipsoid, 640 × 480 equidistant fisheye)."""
    if "lbl" not in _DEFAULT:
        _DEFAULT["lbl"] = LBLInstrument()
    return _DEFAULT["lbl"]


def capture(
    sample: Any,
    theta_i: float,
    phi_i: float = 0.0,
    *,
    instrument: LBLInstrument | None = None,
    **kwargs: Any,
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """:meth:`LBLInstrument.capture` on ``instrument`` (default: :func:`default_instrument`)."""
    inst = instrument if instrument is not None else default_instrument()
    return inst.capture(sample, theta_i, phi_i, **kwargs)


def reproduce(
    meta: dict[str, Any], sample: Any = None
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Capture again from a capture's metadata (the BRDF is rebuilt from ``meta["brdf"]``
    unless ``sample`` is given; a plain callable cannot be rebuilt and must be passed)."""
    inst = LBLInstrument.from_metadata(meta)
    if meta.get("calibration") in ("dark", "flat_field"):
        if meta.get("seed") is None and meta.get("noise"):
            raise ValueError("the capture used a caller's Generator; its seed was not recorded")
        kw = {
            "exposure": meta["exposure_s"],
            "rng": meta.get("seed"),
            "noise": meta["noise"],
            "binning": tuple(meta["binning"]) if meta.get("binning") else None,
        }
        if meta["calibration"] == "dark":
            return inst.capture_dark(**kw)
        return inst.capture_flat(meta["photons_per_pixel"], **kw)
    if sample is None:
        if meta["sample"] == "standard":
            sample = STANDARD
        elif meta["sample"] == "brdf":
            from gonio import brdf

            b = meta["brdf"]
            if b["name"] in ("callable", "sum") or any(
                isinstance(v, dict) and "sha256" in v for v in b["params"].values()
            ):
                raise ValueError(
                    f"the capture imaged a {b['name']!r} BRDF that metadata cannot rebuild "
                    "(a callable, a sum or a large table); pass it as sample"
                )
            sample = brdf.create(b["name"], **b["params"])
    if meta.get("seed") is None and meta.get("noise"):
        raise ValueError("the capture used a caller's Generator; its seed was not recorded")
    return inst.capture(
        sample,
        meta["theta_i"],
        meta["phi_i"],
        exposure=meta["exposure_s"],
        f_number=meta["f_number"],
        rng=meta.get("seed"),
        noise=meta["noise"],
        binning=tuple(meta["binning"]) if meta.get("binning") else None,
        band=meta.get("band"),
        source_samples=meta.get("source_samples"),
        rays_per_pixel=meta.get("rays_per_pixel", 1),
    )
