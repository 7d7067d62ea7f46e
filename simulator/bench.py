"""The simulated bench behind the fake devices.

A :class:`Bench` holds motorised :class:`Stage` objects (speed, acceleration, travel limits,
backlash, optional positioning noise) that move along trapezoidal velocity profiles on a
:class:`SimClock` whose rate can be scaled, so that a 90° move at 10 °/s need not take nine real
seconds. The fake camera and spectrometer read the bench through two pluggable render
callbacks:

``camera_render(positions, exposure_s, f_number) -> (uint16 image, metadata dict)``
``spectrum_render(positions, integration_s, wavelengths_nm) -> counts per pixel``

``positions`` maps stage names to the *true* (load-side) positions in the stage units, i.e.
including backlash and positioning noise that the controller's encoder does not see. The
built-in defaults are simple, deterministic and cheap (a Lambertian-plus-lobe spot on a dark
frame, a lamp-times-reflectance spectrum); :meth:`Bench.for_instrument` wires in the
instrument simulators (``gonio.simulator.lbl`` / ``gonio.simulator.cornell``) when they exist.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992 (seed ``ward1992``), §2: the imaging gonioreflectometer whose camera and source arm
the LBL bench models. Stage model after ophyd's ``SynAxis``: physics passed as arguments.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "CORNELL_FILTER_DEG",
    "CORNELL_PIXELS",
    "CORNELL_SHUTTER_DEG",
    "CORNELL_TARGET_MM",
    "LBL_CHANGER_MM",
    "Bench",
    "CameraRender",
    "SimClock",
    "SpectrumRender",
    "Stage",
    "StageFault",
    "cornell_positions",
    "cornell_spectrum_render",
    "default_camera_render",
    "default_spectrum_render",
    "lbl_camera_render",
    "simulator_renderers",
]

CameraRender = Callable[[Mapping[str, float], float, float], tuple[np.ndarray, dict]]
SpectrumRender = Callable[[Mapping[str, float], float, np.ndarray], np.ndarray]


class SimClock:
    """Simulated time running ``scale`` times faster than the wall clock.

    Parameters
    ----------
    scale : float
        Simulated seconds per real second (> 0). ``scale=100`` makes a 10 s move take 0.1 s.
    """

    def __init__(self, scale: float = 1.0) -> None:
        scale = float(scale)
        if not (scale > 0 and math.isfinite(scale)):
            raise ValueError(f"scale={scale!r}: expected a finite number > 0")
        self.scale = scale
        self._t0 = time.monotonic()

    def now(self) -> float:
        """Simulated seconds since the clock was created."""
        return (time.monotonic() - self._t0) * self.scale

    def real_seconds(self, sim_seconds: float) -> float:
        """Wall-clock seconds that ``sim_seconds`` of simulated time take."""
        return max(0.0, float(sim_seconds)) / self.scale

    def sleep(self, sim_seconds: float) -> None:
        """Sleep for ``sim_seconds`` of simulated time."""
        time.sleep(self.real_seconds(sim_seconds))


class StageFault(RuntimeError):
    """A stage refused a command (motor off, amplifier fault, limit)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass
class _Move:
    t0: float
    start: float
    end: float
    vmax: float
    acc: float

    def duration(self) -> float:
        d = abs(self.end - self.start)
        if d == 0:
            return 0.0
        ta = self.vmax / self.acc
        if self.acc * ta * ta >= d:  # triangular profile
            return 2.0 * math.sqrt(d / self.acc)
        return 2.0 * ta + (d - self.acc * ta * ta) / self.vmax

    def position(self, t: float) -> float:
        d = abs(self.end - self.start)
        s = math.copysign(1.0, self.end - self.start)
        tt = t - self.t0
        total = self.duration()
        if tt <= 0:
            return self.start
        if tt >= total:
            return self.end
        ta = self.vmax / self.acc
        if self.acc * ta * ta >= d:
            th = total / 2
            if tt <= th:
                x = 0.5 * self.acc * tt * tt
            else:
                r = total - tt
                x = d - 0.5 * self.acc * r * r
        else:
            if tt <= ta:
                x = 0.5 * self.acc * tt * tt
            elif tt <= total - ta:
                x = 0.5 * self.acc * ta * ta + self.vmax * (tt - ta)
            else:
                r = total - tt
                x = d - 0.5 * self.acc * r * r
        return self.start + s * x


@dataclass
class Stage:
    """One motorised stage of the bench.

    Parameters
    ----------
    name : str
        Stage name (used as the key of ``positions`` in render callbacks).
    units : str
        ``"deg"`` for rotation stages, ``"mm"`` for linear ones.
    speed, acceleration : float
        Default velocity (units/s) and acceleration (units/s²) of the trapezoidal profile.
    lower, upper : float
        Hardware travel limits: a move beyond them stalls at the limit switch.
    backlash : float
        Width of the dead band between motor (encoder) and load; the load lags the motor by
        up to ``backlash`` after a direction reversal.
    noise : float
        Standard deviation of the load position error added at the end of every move.
    home : float
        Position of the home switch (``OR`` drives there and zeroes the encoder).
    rng : int | numpy.random.Generator | None
        Random state for the positioning noise.
    """

    name: str
    units: str = "deg"
    speed: float = 20.0
    acceleration: float = 80.0
    lower: float = -180.0
    upper: float = 180.0
    backlash: float = 0.0
    noise: float = 0.0
    home: float = 0.0
    rng: Any = None
    motor_on: bool = False
    position0: float = 0.0
    _move: _Move | None = field(default=None, repr=False)
    _motor: float = field(default=0.0, repr=False)
    _load_offset: float = field(default=0.0, repr=False)
    _error: float = field(default=0.0, repr=False)
    _limit_hit: str | None = field(default=None, repr=False)
    fault: str | None = None

    def __post_init__(self) -> None:
        for arg in ("speed", "acceleration"):
            v = getattr(self, arg)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{arg}={v!r}: expected a finite number > 0")
        if not self.lower < self.upper:
            raise ValueError(f"lower={self.lower!r}, upper={self.upper!r}: expected lower < upper")
        if self.backlash < 0 or self.noise < 0:
            raise ValueError(
                f"backlash={self.backlash!r}, noise={self.noise!r}: expected values >= 0"
            )
        self._rng = np.random.default_rng(self.rng)
        self._motor = float(self.position0)
        self._lock = threading.RLock()

    # -- state at time t -------------------------------------------------------------------
    def motor_position(self, t: float) -> float:
        """Encoder (motor-side) position at simulated time ``t``."""
        with self._lock:
            self._settle(t)
            if self._move is None:
                return self._motor
            return self._move.position(t)

    def load_position(self, t: float) -> float:
        """True (load-side) position: motor position minus backlash lag plus noise."""
        with self._lock:
            m = self.motor_position(t)
            return m + self._load_offset + self._error

    def is_moving(self, t: float) -> bool:
        with self._lock:
            self._settle(t)
            return self._move is not None

    def limit_hit(self) -> str | None:
        """``"+"`` or ``"-"`` if the last move stalled at a hardware limit, else ``None``."""
        return self._limit_hit

    def _settle(self, t: float) -> None:
        mv = self._move
        if mv is not None and t >= mv.t0 + mv.duration():
            self._motor = mv.end
            self._move = None
            if self.noise > 0:
                self._error = float(self._rng.normal(0.0, self.noise))

    # -- commands -------------------------------------------------------------------------
    def move_to(
        self, target: float, t: float, speed: float | None = None, acceleration: float | None = None
    ) -> None:
        """Start a move to ``target`` at simulated time ``t``.

        A target beyond a hardware limit stalls at that limit (``limit_hit()`` tells which).
        """
        target = float(target)
        if not math.isfinite(target):
            raise ValueError(f"target={target!r}: expected a finite position")
        with self._lock:
            if self.fault:
                raise StageFault("fault", f"{self.name}: {self.fault}")
            if not self.motor_on:
                raise StageFault("motor_off", f"{self.name}: motor not enabled")
            start = self.motor_position(t)
            self._limit_hit = None
            if target > self.upper:
                target, self._limit_hit = self.upper, "+"
            elif target < self.lower:
                target, self._limit_hit = self.lower, "-"
            if target != start and self.backlash > 0:
                # the load follows the motor with a dead band of width ``backlash``: after
                # the move it trails the motor by half the band on the side it came from
                direction = math.copysign(1.0, target - start)
                self._load_offset = -direction * self.backlash / 2
            self._error = 0.0
            self._move = _Move(
                t,
                start,
                target,
                float(speed or self.speed),
                float(acceleration or self.acceleration),
            )
            if target == start:
                self._move = None

    def stop(self, t: float) -> None:
        """Stop at once (abort) wherever the stage is."""
        with self._lock:
            p = self.motor_position(t)
            self._move = None
            self._motor = p

    def define_position(self, value: float, t: float) -> None:
        """Redefine the current encoder reading as ``value`` (``DH``)."""
        with self._lock:
            p = self.motor_position(t)
            shift = float(value) - p
            self._motor = float(value)
            self.lower += shift
            self.upper += shift
            self.home += shift

    def finish_time(self, t: float) -> float:
        """Simulated time at which the current move ends (``t`` if idle)."""
        with self._lock:
            self._settle(t)
            if self._move is None:
                return t
            return self._move.t0 + self._move.duration()


# ---------------------------------------------------------------------------------------------
# default renderers
# ---------------------------------------------------------------------------------------------
def default_spectrum_render(
    positions: Mapping[str, float], integration_s: float, wavelengths_nm: np.ndarray
) -> np.ndarray:
    """Counts of a tungsten-halogen lamp (3000 K Planck shape) reflected by a grey sample.

    The reflected fraction is Lambertian in the source angle (first stage, degrees) so that
    moving the arm changes the signal; 1500 counts of dark offset; full scale 65535.
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64) * 1e-9
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    planck = 1.0 / (wl**5 * np.expm1(h * c / (wl * k * 3000.0)))
    planck /= planck.max()
    theta = math.radians(next(iter(positions.values()), 0.0)) if positions else 0.0
    geom = max(math.cos(theta), 0.0)
    counts = 1500.0 + 4.0e6 * float(integration_s) * planck * 0.5 * geom
    return np.clip(counts, 0.0, 65535.0)


def default_camera_render(
    positions: Mapping[str, float], exposure_s: float, f_number: float
) -> tuple[np.ndarray, dict]:
    """A 240×320 dark frame with a Gaussian highlight whose place follows the stages.

    Signal ∝ exposure / f_number²; 16-bit, clipped at 65535.
    """
    h, w = 240, 320
    vals = list(positions.values()) + [0.0, 0.0]
    cy = h / 2 + (h / 4) * math.sin(math.radians(vals[0]))
    cx = w / 2 + (w / 4) * math.sin(math.radians(vals[1]))
    yy, xx = np.mgrid[0:h, 0:w]
    spot = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * 12.0**2))
    gain = 2.0e5 * float(exposure_s) / float(f_number) ** 2
    img = 200.0 + gain * (0.05 + spot)
    img = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
    return img, {"renderer": "default", "positions": dict(positions)}


# ---------------------------------------------------------------------------------------------
# the bench
# ---------------------------------------------------------------------------------------------
_INSTRUMENT_STAGES: dict[str, tuple[tuple[str, dict], ...]] = {
    # LBL imaging gonioreflectometer (Ward 1992): the source arm swings in the incidence
    # plane (θ_i), the sample holder turns about its normal (ψ, φ_i = arm azimuth − ψ); the
    # third controller axis is a spare tilt stage. Names follow gonio.simulator.lbl's
    # ``camera_render(source_axis="source", sample_axis="sample")``. A fourth stage, the
    # sample changer (a linear slide on a second controller), puts the sample, the
    # reflectance standard or nothing (background) under the dome: :data:`LBL_CHANGER_MM`.
    "lbl": (
        ("source", {"lower": -5.0, "upper": 95.0, "speed": 10.0, "acceleration": 40.0}),
        ("sample", {"lower": -360.0, "upper": 360.0, "speed": 30.0, "acceleration": 90.0}),
        ("tilt", {"lower": -45.0, "upper": 45.0, "speed": 5.0, "acceleration": 20.0}),
        (
            "changer",
            {"units": "mm", "lower": -1.0, "upper": 80.0, "speed": 50.0, "acceleration": 200.0},
        ),
    ),
    # Cornell three-axis instrument (gonio.simulator.cornell axes): source arm, turntable,
    # sample tilt (speeds and accelerations of gonio.simulator.cornell.BENCH_STAGES, the ones
    # its run-time estimate assumes), then the accessories on a second controller: the
    # polariser (0° = s, 90° = p), the target slide (:data:`CORNELL_TARGET_MM`) and the
    # ND filter wheel (:data:`CORNELL_FILTER_DEG`), and on a third the rotary shutter
    # (:data:`CORNELL_SHUTTER_DEG`).
    "cornell": (
        ("arm", {"lower": -180.0, "upper": 180.0, "speed": 5.0, "acceleration": 10.0}),
        ("turntable", {"lower": -360.0, "upper": 360.0, "speed": 10.0, "acceleration": 20.0}),
        ("tilt", {"lower": -95.0, "upper": 95.0, "speed": 10.0, "acceleration": 20.0}),
        ("polarizer", {"lower": -10.0, "upper": 190.0, "speed": 90.0, "acceleration": 360.0}),
        (
            "target",
            {"units": "mm", "lower": -1.0, "upper": 80.0, "speed": 50.0, "acceleration": 200.0},
        ),
        ("filter", {"lower": -10.0, "upper": 370.0, "speed": 120.0, "acceleration": 480.0}),
        ("shutter", {"lower": -10.0, "upper": 100.0, "speed": 900.0, "acceleration": 9000.0}),
    ),
}

#: LBL sample changer stations (mm): what sits under the dome.
LBL_CHANGER_MM = {"sample": 0.0, "standard": 25.0, "empty": 50.0}
#: Cornell target slide stations (mm), in the order of ``gonio.simulator.cornell.TARGETS``.
CORNELL_TARGET_MM = {"sample": 0.0, "standard": 25.0, "beam_trap": 50.0, "direct": 75.0}
#: Cornell filter wheel stations (deg): open, ND filter in.
CORNELL_FILTER_DEG = {"open": 0.0, "nd": 60.0}
#: Cornell rotary shutter positions (deg).
CORNELL_SHUTTER_DEG = {"open": 0.0, "closed": 90.0}
#: Spectrometer pixels of the Cornell bench (its 1024-pixel spectroradiometer).
CORNELL_PIXELS = 1024


def _station(value: float, stations: Mapping[str, float], tol: float) -> str | None:
    """The station ``value`` sits at (within ``tol``), else ``None`` (between stations)."""
    for name, pos in stations.items():
        if abs(float(value) - pos) <= tol:
            return name
    return None


def cornell_positions(positions: Mapping[str, float]) -> dict[str, float]:
    """Bench stage positions → the keys ``CornellInstrument.spectrum_render`` takes.

    ``arm``, ``turntable``, ``tilt`` and ``polarizer`` pass through (degrees); the target
    slide becomes ``target`` (0 sample, 1 standard, 2 beam trap, 3 direct beam; between
    stations the beam falls on the trap), the filter wheel ``filter`` (1 with the ND filter
    in) and the rotary shutter ``shutter`` (1 only when open, within 1°).
    """
    out = {k: float(positions[k]) for k in ("arm", "turntable", "tilt") if k in positions}
    if "polarizer" in positions:
        out["polarizer"] = float(positions["polarizer"])
    if "target" in positions:
        st = _station(positions["target"], CORNELL_TARGET_MM, 0.5)
        order = list(CORNELL_TARGET_MM)
        out["target"] = float(order.index(st) if st is not None else order.index("beam_trap"))
    if "filter" in positions:
        st = _station(float(positions["filter"]) % 360.0, CORNELL_FILTER_DEG, 1.0)
        out["filter"] = 1.0 if st == "nd" else 0.0
    if "shutter" in positions:
        st = _station(positions["shutter"], CORNELL_SHUTTER_DEG, 1.0)
        out["shutter"] = 1.0 if st == "open" else 0.0
    return out


def cornell_spectrum_render(render: SpectrumRender) -> SpectrumRender:
    """Wrap a Cornell ``spectrum_render`` so that it reads the bench's accessory stages."""

    def spectrum(positions: Mapping[str, float], integration_s: float, wavelengths_nm):
        return render(cornell_positions(positions), integration_s, wavelengths_nm)

    spectrum.__wrapped__ = render  # type: ignore[attr-defined]
    return spectrum


def lbl_camera_render(renders: Mapping[str, CameraRender]) -> CameraRender:
    """A camera render that shows ``renders["sample" | "standard" | "empty"]`` according to
    the sample changer stage (``positions["changer"]``, :data:`LBL_CHANGER_MM`; between
    stations: the empty holder). Without a changer stage: the sample."""

    def camera(positions: Mapping[str, float], exposure_s: float, f_number: float):
        if "changer" in positions:
            st = _station(positions["changer"], LBL_CHANGER_MM, 0.5) or "empty"
        else:
            st = "sample"
        pos = {k: v for k, v in positions.items() if k != "changer"}
        img, meta = renders[st](pos, exposure_s, f_number)
        meta = dict(meta)
        meta["changer"] = st
        return img, meta

    return camera


def simulator_renderers(
    instrument: str,
    material: str | None = None,
    *,
    rng: int | np.random.Generator | None = None,
    noise: bool = True,
) -> tuple[CameraRender | None, SpectrumRender | None]:
    """Render callbacks from the instrument simulators, where they exist.

    ``"lbl"``: the camera is :meth:`gonio.simulator.lbl.LBLInstrument.camera_render` of the
    sample ``material`` (default: the Lambertian reflectance ``"standard"``). ``"cornell"``:
    the spectrometer is ``gonio.simulator.cornell.CornellInstrument(brdf).spectrum_render``
    (default BRDF: Lambertian; an int ``rng`` is the instrument's noise seed, so that a bench
    with ``rng=s`` reads the same noise as ``CornellInstrument(brdf, rng=s)`` in-process)
    behind :func:`cornell_spectrum_render`. The LBL camera shows the sample, the standard or
    the empty holder according to the changer stage (:func:`lbl_camera_render`). A missing
    simulator module gives ``None`` (built-in default).
    """
    import importlib

    if instrument == "lbl":
        try:
            lbl = importlib.import_module("gonio.simulator.lbl")
        except ImportError:
            return None, None
        inst = lbl.LBLInstrument()
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        kw = dict(source_axis="source", sample_axis="sample", rng=gen, noise=noise)
        cams = {
            "sample": inst.camera_render(material or "standard", **kw),
            "standard": inst.camera_render("standard", **kw),
            "empty": inst.camera_render(None, **kw),
        }
        return lbl_camera_render(cams), None
    if instrument == "cornell":
        try:
            cornell = importlib.import_module("gonio.simulator.cornell")
        except ImportError:
            return None, None
        from gonio import brdf, materials

        model = materials.get(material) if material else brdf.create("lambert")
        inst = cornell.CornellInstrument(model, noise=noise, rng=rng)
        return None, cornell_spectrum_render(inst.spectrum_render)
    raise ValueError(f"instrument={instrument!r}: expected 'lbl' or 'cornell'")


class Bench:
    """Stages plus the camera and spectrometer state, on one simulated clock.

    Parameters
    ----------
    stages : sequence of Stage, optional
        The stages, in controller-axis order (axis 1 first). Default: three rotation stages.
    time_scale : float
        Simulated seconds per real second.
    camera_render, spectrum_render : callable, optional
        Render callbacks (see the module docstring); defaults are built in.
    wavelength_coeffs : sequence of 4 floats
        Spectrometer calibration polynomial λ(p) = c0 + c1 p + c2 p² + c3 p³ (nm) for
        pixel index p, as stored in a USB2000+'s EEPROM slots 1-4.
    instrument, material : str, optional
        Labels recorded in metadata.
    n_pixels : int
        Pixels of the spectrometer's detector (2048 for a USB2000+; the Cornell bench's
        spectroradiometer has 1024). The fake USB2000+ reports and sends this many.
    """

    def __init__(
        self,
        stages: list[Stage] | None = None,
        *,
        time_scale: float = 1.0,
        camera_render: CameraRender | None = None,
        spectrum_render: SpectrumRender | None = None,
        wavelength_coeffs: tuple[float, float, float, float] = (339.7, 0.3825, -1.71e-5, -1.1e-9),
        instrument: str | None = None,
        material: str | None = None,
        n_pixels: int = 2048,
    ) -> None:
        if int(n_pixels) != n_pixels or n_pixels < 1 or n_pixels > 8192:
            raise ValueError(f"n_pixels={n_pixels!r}: expected an integer 1..8192")
        if stages is None:
            stages = [Stage(f"axis{i}") for i in (1, 2, 3)]
        names = [s.name for s in stages]
        if len(set(names)) != len(names):
            raise ValueError(f"stages={names!r}: expected unique stage names")
        self.stages: dict[str, Stage] = {s.name: s for s in stages}
        self.clock = SimClock(time_scale)
        self.camera_render: CameraRender = camera_render or default_camera_render
        self.spectrum_render: SpectrumRender = spectrum_render or default_spectrum_render
        self.wavelength_coeffs = tuple(float(c) for c in wavelength_coeffs)
        self.instrument = instrument
        self.material = material
        self.n_pixels = int(n_pixels)
        self.lock = threading.RLock()

    @classmethod
    def for_instrument(
        cls,
        instrument: str = "lbl",
        material: str | None = None,
        *,
        time_scale: float = 1.0,
        rng: int | np.random.Generator | None = None,
        simulate: bool = True,
        noise: bool = True,
        **stage_kw: Any,
    ) -> Bench:
        """A bench laid out like the ``"lbl"`` or ``"cornell"`` instrument.

        With ``simulate=True`` the camera / spectrometer render through the instrument
        simulators (:func:`simulator_renderers`; ``noise`` passed on); otherwise, or where a
        simulator is missing, through the built-in defaults. The Cornell bench's spectrometer
        has the simulator's pixel count and wavelength calibration
        (``gonio.simulator.cornell.CornellConfig``). ``stage_kw`` overrides the
        physics of every stage (e.g. ``backlash=0.01, noise=0.002``).
        """
        if instrument not in _INSTRUMENT_STAGES:
            raise ValueError(
                f"instrument={instrument!r}: expected one of {sorted(_INSTRUMENT_STAGES)}"
            )
        gen = np.random.default_rng(rng)
        stages = [
            Stage(name, **{**kw, **stage_kw}, rng=gen)
            for name, kw in _INSTRUMENT_STAGES[instrument]
        ]
        cam = spec = None
        coeffs: tuple[float, ...] = (339.7, 0.3825, -1.71e-5, -1.1e-9)
        n_pixels = 2048
        if instrument == "cornell":
            n_pixels = CORNELL_PIXELS
            try:
                from gonio.simulator.cornell import CornellConfig

                cfg = CornellConfig()
                # as the EEPROM holds them (%.6e), so the driver's wavelengths are the bench's
                coeffs = tuple(float(f"{c:.6e}") for c in cfg.wavelength_coeffs)
                n_pixels = int(cfg.n_pixels)
            except ImportError:
                pass
        if simulate:
            seed = rng if instrument == "cornell" and isinstance(rng, int | np.integer) else gen
            cam, spec = simulator_renderers(instrument, material, rng=seed, noise=noise)
        return cls(
            stages,
            time_scale=time_scale,
            camera_render=cam,
            spectrum_render=spec,
            wavelength_coeffs=coeffs,  # type: ignore[arg-type]
            instrument=instrument,
            material=material,
            n_pixels=n_pixels,
        )

    # -- stage access ---------------------------------------------------------------------
    def now(self) -> float:
        return self.clock.now()

    def stage(self, name: str) -> Stage:
        try:
            return self.stages[name]
        except KeyError:
            raise ValueError(f"stage={name!r}: expected one of {sorted(self.stages)}") from None

    def positions(self) -> dict[str, float]:
        """True (load-side) positions of every stage now."""
        t = self.now()
        return {n: s.load_position(t) for n, s in self.stages.items()}

    def encoder_positions(self) -> dict[str, float]:
        t = self.now()
        return {n: s.motor_position(t) for n, s in self.stages.items()}

    # -- detectors ------------------------------------------------------------------------
    def wavelengths(self, n_pixels: int | None = None) -> np.ndarray:
        """Wavelength (nm) of each spectrometer pixel (default: :attr:`n_pixels` of them)."""
        p = np.arange(self.n_pixels if n_pixels is None else n_pixels, dtype=np.float64)
        c = self.wavelength_coeffs
        return c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3

    def render_spectrum(self, integration_s: float, n_pixels: int | None = None) -> np.ndarray:
        """Counts per pixel (uint16 range) for the current stage positions."""
        n_pixels = self.n_pixels if n_pixels is None else int(n_pixels)
        counts = self.spectrum_render(
            self.positions(), float(integration_s), self.wavelengths(n_pixels)
        )
        counts = np.asarray(counts, dtype=np.float64)
        if counts.shape != (n_pixels,):
            raise ValueError(
                f"spectrum_render returned shape {counts.shape}: expected ({n_pixels},)"
            )
        return np.clip(np.rint(counts), 0, 65535).astype(np.uint16)

    def render_image(self, exposure_s: float, f_number: float) -> tuple[np.ndarray, dict]:
        """A raw 16-bit camera frame and metadata for the current stage positions."""
        pos = self.positions()
        img, meta = self.camera_render(pos, float(exposure_s), float(f_number))
        img = np.asarray(img)
        if img.dtype != np.uint16 or img.ndim not in (2, 3):
            raise ValueError(
                f"camera_render returned {img.dtype} with shape {img.shape}: "
                "expected a uint16 image (H, W) or (H, W, C)"
            )
        meta = dict(meta)
        meta.setdefault("positions", pos)
        meta.update(
            exposure_s=float(exposure_s),
            f_number=float(f_number),
            instrument=self.instrument,
            material=self.material,
        )
        return img, meta
