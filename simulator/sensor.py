"""A linear CCD camera sensor (with an optional non-linear video response), in EMVA 1288 terms.

Signal chain per pixel, for an exposure of ``t`` seconds at f-number ``N``::

    photo-electrons  e_sig = QE · Φ · (1 + PRNU_map) · t / N²     (Φ: photons/s at f/1)
    dark electrons   e_dk  = (dark_current · (1 + DSNU_map) + hot_map) · t
    charge effects   blooming (charge above the full well spills along the column), then
                     smear (a fraction of the column's photo-charge added during transfer)
    noise (optional) e = Poisson(e_sig + e_dk) + Normal(0, read_noise)   (see "Noise" below)
    full well        e = min(e, full_well)   (charge_clip: the charge is clipped BEFORE the
                     read noise, then the read noise is added)
    offsets          e += offset_map (pixel, row and column offset patterns, electrons)
    ADC              x = e / gain (DN above black level), optional response curve on
                     x / x_max, DN = clip(round(black_level + x), 0, 2^adc_bits - 1)

The PRNU, DSNU, hot-pixel and offset maps are fixed patterns of the physical pixel array
(drawn once from ``pattern_seed`` for the whole ``array_shape``; an image of another shape
reads its centred window of that array), so they are present with noise on or off; noise
off skips all random draws (deterministic).

Sensor effects
--------------
Every effect beyond today's ideal-ish sensor is a named parameter whose zero (``False`` for
:attr:`Sensor.charge_clip`, ``None`` for :attr:`Sensor.array_shape`) switches it off and skips
its work, so ``Sensor()`` gives images bit-identical to the sensor before these effects
existed. :data:`REALISTIC` holds typical magnitudes with their sources and
:meth:`Sensor.realistic` builds a sensor from them. :meth:`Sensor.emva1288` gives the
figures the standard reports for a configured sensor; :meth:`Sensor.frames` is the
sensor-level API (photons per pixel and an exposure in, ``n`` raw frames out) that a
photon-transfer measurement uses: the EMVA 1288 reference implementation (the ``emva1288``
package) analysing such frames recovers the configured system gain, dark noise, PRNU, dark
current and QE within 0.25 % (``tests/simulator/test_sensor_emva1288.py``).

With :attr:`Sensor.charge_clip` a saturated pixel no longer reads exactly
:attr:`Sensor.saturation_dn` but scatters around it by the read noise, so a reduction that
calls a pixel saturated only at ``raw >= saturation_dn`` takes half of the saturated pixels
for valid ones (``gonio bench --knob sensor_effects`` shows the fit error this gives); the
saturation threshold must come from the laboratory's own photon-transfer measurement.

Noise
-----
Shot noise is Poisson in electrons, read noise Gaussian. Drawing an exact Poisson variate
for every pixel of every frame dominated the capture time, so where it cannot be seen the
shot and read noise are drawn together from ONE standard normal ``z`` by the Cornish-Fisher
(skew-corrected) transform ``e = λ + s z + c (z² - 1)`` with ``c = λ / 6V``,
``s² = V - 2c²``, ``V = λ + σ²``: mean λ and variance V are exactly those of
``Poisson(λ) + N(0, σ²)``, the third central moment is ``λ - 4c³`` (Poisson: λ; ``c <= 1/6``),
so only the fourth cumulant and the integer lattice of the count differ. Where
(:attr:`Sensor.normal_threshold`):

* read noise σ >= 6 e⁻ (the default sensor has 8): at every λ — the read-noise variance
  (>= 36 e²) hides the Poisson shape where it is least normal;
* 2 e⁻ <= σ < 6 e⁻: for λ >= :data:`NORMAL_THRESHOLD_E` = 30 e⁻, exact Poisson below;
* σ < 2 e⁻: nowhere (exact Poisson at every λ: the count lattice would show).

Why this is statistically invisible: the total-variation distance between the DN
histograms of the exact and of the approximated draw, computed exactly (Poisson pmf
convolved with the read-noise normal and binned into DN codes by the ADC's rounding,
against the transform's CDF), for λ from 0.05 to 10 000 e⁻ and gains 1, 2.5 and 10 e⁻/DN:

==========  ==============================  ===============================
read noise  worst TV where approximated     worst TV, λ >= 30 e⁻ only
==========  ==============================  ===============================
2 e⁻        (λ >= 30 only)                  2.7e-4
4 e⁻        (λ >= 30 only)                  1.1e-4
6 e⁻        2.0e-4 (all λ)                  1.6e-4
8 e⁻        1.1e-4 (all λ; the default)     1.1e-4
10 e⁻       7.2e-5 (all λ)                  7.2e-5
==========  ==============================  ===============================

(at σ = 2-4 e⁻ the all-λ worst would be 0.45-1.8e-3, hence the exact draw below 30 e⁻ there).
Telling two distributions apart at one λ takes of the order of ``1/TV²`` samples: 10⁷-10⁸
pixels of the same mean, more than a whole campaign records (120 frames × 0.3 Mpixel), and
far beyond the count-to-count variation. A plain ``N(λ, V)`` without the skew term is
3-5e-3 off at 30-1000 e⁻ (visible with ~10⁵ pixels), hence the skew term. The ADC and
the full well only enter through the DN binning (default 12 bits at 10 e⁻/DN), included
above: a 16-bit ADC over the same 40 000 e⁻ full well (0.61 e⁻/DN) gives the same worst
values (2.7e-4, 1.1e-4, 2.0e-4, 1.1e-4 for σ = 2, 4, 6, 8 e⁻); saturation clips both draws
identically. Mean and variance of every pixel are exact
at any λ, so the radiometry (eq. 2) and the noise model the calibration uses are unchanged.
``Sensor.add_noise(..., exact=True)`` keeps numpy's exact draw for comparison, and
``benchmarks/bench_capture.py`` prints the measured moments of both.

The compiled draw takes its random numbers from a xoshiro256++ generator inside the kernel
(standard normals by numpy's 256-layer ziggurat), seeded with four 64-bit words from the
``numpy.random.Generator`` passed in, so it is reproducible from that Generator's seed and
independent of the number of threads (:mod:`gonio.simulator._kernels`; about twice as fast
as numba's ``Generator.standard_normal``, which calls the bit generator through a pointer
for every word).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078 — §3
   (CCD camera with fisheye lens, video capture board; two or more f-stops to cover the
   dynamic range).
.. [EMVA1288] EMVA Standard 1288, "Standard for characterization of image sensors and
   cameras", Release 4.0 Linear, European Machine Vision Association, 2021 — the linear
   camera model, its noise model, saturation and the absolute sensitivity threshold
   (Sec. 2), spatial nonuniformity split into column, row and pixel variances and defect
   pixels (Sec. 4), the photon transfer evaluation and its measurement conditions (Sec. 6),
   dark current (Sec. 7).
.. [Janesick2001] J. R. Janesick, "Scientific Charge-Coupled Devices", SPIE Press PM83,
   2001. https://doi.org/10.1117/3.374903 — full well and blooming along the column,
   overflow (anti-blooming) drains, smear of interline and frame-transfer CCDs, dark
   spikes (hot pixels), offsets and column patterns of the readout.
.. [Janesick2007] J. R. Janesick, "Photon Transfer DN → λ", SPIE Press PM170, 2007.
   https://doi.org/10.1117/3.725073 — the photon transfer curve, full-well saturation
   seen as the drop of the variance, fixed-pattern noise.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "NORMAL_ALL_READ_NOISE_E",
    "NORMAL_MIN_READ_NOISE_E",
    "NORMAL_THRESHOLD_E",
    "REALISTIC",
    "REALISTIC_ARRAY_SHAPE",
    "REALISTIC_SOURCES",
    "EMVA1288Warning",
    "Sensor",
]

#: Poisson means (electrons) at and above which shot + read noise are drawn from the
#: skew-corrected normal when 2 e⁻ <= read noise < 6 e⁻ (module docstring, "Noise")
NORMAL_THRESHOLD_E = 30.0
#: smallest read noise (electrons RMS) that hides the Poisson lattice; below it every pixel
#: is drawn exactly
NORMAL_MIN_READ_NOISE_E = 2.0
#: read noise (electrons RMS) from which the skew-corrected normal is used at every mean
NORMAL_ALL_READ_NOISE_E = 6.0


def _num(value: Any, name: str, lo: float = 0.0, lo_open: bool = False, hi: float = math.inf):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < lo or (lo_open and v == lo) or v > hi:
        lo_s = f"({lo}" if lo_open else f"[{lo}"
        raise ValueError(f"{name} must be a finite number in {lo_s}, {hi}], got {value!r}")
    return v


#: largest side and pixel count of a physical pixel array (bounded memory: the fixed patterns
#: are float64 maps of the whole array)
MAX_ARRAY_SIDE = 16384
MAX_ARRAY_PIXELS = 1 << 26
#: most pixels :meth:`Sensor.frames` returns at once (2 GiB of uint16)
MAX_FRAMES_PIXELS = 1 << 30

#: typical magnitudes of the sensor effects of a realistic instrument (an interline-transfer
#: CCD camera with an overflow drain, as imaging gonioreflectometers use); the source of each
#: is in :data:`REALISTIC_SOURCES` and in the parameter's description in :class:`Sensor`.
#: :meth:`Sensor.realistic` builds a sensor from them.
REALISTIC: dict[str, Any] = {
    "charge_clip": True,
    "blooming": 1e-3,
    "smear": 1e-4,
    "offset_dsnu": 1.0,
    "row_dsnu": 0.5,
    "column_dsnu": 0.5,
    "hot_pixels": 1e-4,
    "hot_pixel_dark": 2000.0,
}
#: where each :data:`REALISTIC` value comes from
REALISTIC_SOURCES: dict[str, str] = {
    "charge_clip": "physics of the pixel: the well holds at most full_well electrons and the "
    "output amplifier adds its noise after (Janesick 2007, photon transfer at full well; "
    "EMVA 1288 R4.0 Sec. 2: saturation seen as the drop of the temporal variance)",
    "blooming": "an overflow (anti-blooming) drain rated for about 1000x overexposure: a "
    "fraction 1e-3 of the excess charge is not drained (Janesick 2001, blooming and "
    "anti-blooming)",
    "smear": "interline-transfer CCD datasheets: smear about -100 dB by the 1/10 V method, "
    "i.e. 1e-4 of a fully lit column's charge per pixel (Janesick 2001, smear)",
    "offset_dsnu": "EMVA 1288 datasheets of CCD cameras: dark-signal nonuniformity of 1-3 e- "
    "at short exposure, mostly the pixel part",
    "row_dsnu": "line-clamp offsets of a CCD readout, below the pixel part (EMVA 1288 R4.0 "
    "Sec. 4, column/row/pixel split)",
    "column_dsnu": "column offsets of a CCD readout, below the pixel part (EMVA 1288 R4.0 "
    "Sec. 4, column/row/pixel split)",
    "hot_pixels": "defect pixels of the order of 0.01 % of the array in EMVA 1288 "
    "datasheets (Sec. 4, defect pixels)",
    "hot_pixel_dark": "dark spikes of 10-1000x the mean dark current (Janesick 2001, dark "
    "current spikes); 2000 e-/s is 100x the default 20 e-/s",
}
#: the physical array :meth:`Sensor.realistic` gives (rows, cols): the default LBL camera
REALISTIC_ARRAY_SHAPE = (480, 640)

#: per-effect streams of the fixed patterns (``SeedSequence(pattern_seed, spawn_key=(k,))``);
#: PRNU and DSNU keep ``default_rng(pattern_seed)`` as they always had
_STREAM_OFFSET, _STREAM_ROW, _STREAM_COLUMN, _STREAM_HOT = 1, 2, 3, 4


class EMVA1288Warning(UserWarning):
    """A sensor setting the EMVA 1288 standard does not accept for its measurements."""


@dataclass(frozen=True)
class Sensor:
    """CCD sensor parameters.

    Every effect added after the first version of the model (``array_shape`` and the
    parameters after it) is off at its default (zero, ``False`` or ``None``) and then costs
    nothing: ``Sensor()`` is the ideal-ish sensor it always was. :meth:`realistic` gives the
    typical magnitudes of :data:`REALISTIC`.

    Parameters
    ----------
    qe : float
        Quantum efficiency (electrons per photon), (0, 1].
    full_well : float
        Pixel capacity in electrons, (0, inf); signal clips there (saturation).
    gain : float
        Electrons per DN (EMVA 1288's system gain is ``K = 1 / gain`` DN/e⁻).
    read_noise : float
        RMS read noise, electrons (EMVA 1288's temporal dark noise without dark current).
    dark_current : float
        Mean dark current, electrons per second, >= 0.
    prnu : float
        Photo-response non-uniformity, relative RMS of the gain map, [0, 0.5).
    dsnu : float
        Dark-signal non-uniformity, relative RMS of the dark-current map, [0, 1).
    adc_bits : int
        ADC depth, 8..16; output DN in ``[0, 2**adc_bits - 1]`` stored as uint16.
    black_level : float
        Offset added before quantisation, DN.
    response_gamma : float
        1 for a linear CCD; a video camera's response ``y = x**gamma`` on the normalised
        signal otherwise (applied above the black level).
    pattern_seed : int
        Seed of the fixed patterns (PRNU, DSNU, offsets, hot pixels).
    pixel_pitch : float
        Pixel size in metres (photon collection area ``pixel_pitch²``).
    array_shape : (rows, cols) or None
        The physical pixel array. Its fixed patterns are drawn once for the whole array and
        an image of ``h × w`` pixels reads the centred ``h × w`` window of it (a region of
        interest), so images of different shapes see the same pixels. ``None``: the array
        has the shape of the image asked for (the patterns are drawn for that shape; an
        image of the array's own shape has the same patterns either way).
    charge_clip : bool
        True: the full well clips the pixel's charge (signal + dark + shot noise) and the
        read noise is added after it, so a saturated pixel reads ``black_level +
        full_well / gain`` with the read noise on top, up to the ADC's own ceiling
        ``max_dn`` (the physical order: Janesick 2007; EMVA 1288 R4.0 Sec. 2). False (off):
        the clip is applied after the read noise and a saturated pixel reads exactly
        :attr:`saturation_dn` with no noise.
    blooming : float
        Fraction in [0, 1] of the charge above the full well that is not removed by the
        overflow drain and spills into the neighbouring pixels of the same column (half up,
        half down), filling each to the full well before moving on (Janesick 2001,
        blooming). 1: a CCD without anti-blooming; typical :data:`REALISTIC` 1e-3 (a drain
        rated for ~1000x overexposure). Applied to the expected charge before the noise.
    smear : float
        Fraction in [0, 1) of the mean photo-charge per pixel of a column (over the whole
        array height) added to every pixel of that column: light falling on the column
        while it is transferred (interline or frame-transfer CCDs; Janesick 2001). A
        datasheet's smear of ``S`` dB by the 1/10 V method is ``10 · 10**(S/20)`` (-100 dB:
        1e-4). Independent of the exposure (valid near the datasheet's field time).
    offset_dsnu : float
        RMS of a per-pixel offset, electrons (added after the full-well clip), >= 0: the
        offset part of the dark-signal nonuniformity (EMVA 1288 R4.0 Sec. 4, pixel
        variance).
    row_dsnu, column_dsnu : float
        RMS of per-row and per-column offsets, electrons, >= 0 (EMVA 1288 R4.0 Sec. 4: row
        and column variances).
    hot_pixels : float
        Fraction in [0, 1] of pixels that are hot (dark-current spikes).
    hot_pixel_dark : float
        Mean extra dark current of a hot pixel, electrons per second (exponentially
        distributed over the hot pixels), >= 0.
    """

    qe: float = 0.5
    full_well: float = 40000.0
    gain: float = 10.0
    read_noise: float = 8.0
    dark_current: float = 20.0
    prnu: float = 0.005
    dsnu: float = 0.1
    adc_bits: int = 12
    black_level: float = 64.0
    response_gamma: float = 1.0
    pattern_seed: int = 12345
    pixel_pitch: float = 9e-6
    array_shape: tuple[int, int] | None = None
    charge_clip: bool = False
    blooming: float = 0.0
    smear: float = 0.0
    offset_dsnu: float = 0.0
    row_dsnu: float = 0.0
    column_dsnu: float = 0.0
    hot_pixels: float = 0.0
    hot_pixel_dark: float = 0.0
    _maps: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "qe", _num(self.qe, "qe", 0.0, True, 1.0))
        object.__setattr__(self, "full_well", _num(self.full_well, "full_well", 0.0, True))
        object.__setattr__(self, "gain", _num(self.gain, "gain", 0.0, True))
        for name in ("read_noise", "dark_current", "prnu", "dsnu", "black_level"):
            object.__setattr__(self, name, _num(getattr(self, name), name))
        if self.prnu >= 0.5 or self.dsnu >= 1.0:
            raise ValueError(
                f"prnu must be < 0.5 and dsnu < 1 (relative RMS), got {self.prnu}, {self.dsnu}"
            )
        g = _num(self.response_gamma, "response_gamma", 0.0, True)
        object.__setattr__(self, "response_gamma", g)
        b = self.adc_bits
        if not (isinstance(b, int | np.integer) and 8 <= int(b) <= 16):
            raise ValueError(f"adc_bits must be an integer in [8, 16], got {b!r}")
        object.__setattr__(self, "adc_bits", int(b))
        if self.black_level >= self.max_dn:
            raise ValueError(f"black_level {self.black_level} must be below {self.max_dn}")
        object.__setattr__(
            self, "pixel_pitch", _num(self.pixel_pitch, "pixel_pitch", 0.0, True, 1e-3)
        )
        ps = self.pattern_seed
        if not isinstance(ps, int | np.integer) or isinstance(ps, bool) or ps < 0:
            raise ValueError(f"pattern_seed must be a non-negative integer, got {ps!r}")
        self._check_effects()

    def _check_effects(self) -> None:
        """Validate the effect parameters (``array_shape`` and after)."""
        shape = self.array_shape
        if shape is not None:
            try:
                rows, cols = (int(x) for x in shape)
                ok = all(float(x) == int(x) for x in shape)
            except (TypeError, ValueError):
                ok = False
            if not ok or not (1 <= rows <= MAX_ARRAY_SIDE and 1 <= cols <= MAX_ARRAY_SIDE):
                raise ValueError(
                    f"array_shape must be (rows, cols), integers in [1, {MAX_ARRAY_SIDE}], "
                    f"got {shape!r}"
                )
            if rows * cols > MAX_ARRAY_PIXELS:
                raise ValueError(
                    f"array_shape {shape!r} has {rows * cols} pixels, more than the "
                    f"{MAX_ARRAY_PIXELS} allowed"
                )
            object.__setattr__(self, "array_shape", (rows, cols))
        if not isinstance(self.charge_clip, bool | np.bool_):
            raise ValueError(f"charge_clip must be True or False, got {self.charge_clip!r}")
        object.__setattr__(self, "charge_clip", bool(self.charge_clip))
        object.__setattr__(self, "blooming", _num(self.blooming, "blooming", 0.0, False, 1.0))
        smear = _num(self.smear, "smear", 0.0, False, 1.0)
        if smear >= 1.0:
            raise ValueError(f"smear must be a finite number in [0.0, 1.0), got {self.smear!r}")
        object.__setattr__(self, "smear", smear)
        for name in ("offset_dsnu", "row_dsnu", "column_dsnu"):
            v = _num(getattr(self, name), name, 0.0, False, self.full_well)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "hot_pixels", _num(self.hot_pixels, "hot_pixels", 0.0, False, 1.0))
        object.__setattr__(self, "hot_pixel_dark", _num(self.hot_pixel_dark, "hot_pixel_dark"))

    @classmethod
    def realistic(cls, **overrides: Any) -> Sensor:
        """A sensor with every effect at its typical magnitude (:data:`REALISTIC`; sources in
        :data:`REALISTIC_SOURCES`) on the physical array :data:`REALISTIC_ARRAY_SHAPE`;
        ``overrides`` replace any parameter (e.g. ``array_shape=(1024, 1024)``, ``smear=0``)."""
        kw: dict[str, Any] = {**REALISTIC, "array_shape": REALISTIC_ARRAY_SHAPE}
        kw.update(overrides)
        return cls(**kw)

    # ------------------------------------------------------------------ derived figures
    @property
    def max_dn(self) -> int:
        """Largest output value, ``2**adc_bits - 1``."""
        return (1 << self.adc_bits) - 1

    @property
    def saturation_dn(self) -> float:
        """DN of a full well (or the ADC maximum if that comes first). With
        :attr:`charge_clip` this is the mean of a saturated pixel, read noise on top."""
        x = self.full_well / self.gain
        if self.response_gamma != 1.0:
            x = self._x_max * (x / self._x_max) ** self.response_gamma
        return float(min(self.black_level + x, self.max_dn))

    @property
    def linear_adc(self) -> tuple[float, float, float, float]:
        """``(full_well, 1/gain, black_level, max_dn)``: the linear ADC as the compiled
        kernels take it (:func:`gonio.simulator._kernels.digitise_linear` and the passes that
        fuse it)."""
        return (self.full_well, 1.0 / self.gain, self.black_level, float(self.max_dn))

    @property
    def _x_max(self) -> float:
        return float(self.max_dn - self.black_level)

    @property
    def linear(self) -> bool:
        """Whether the response is linear."""
        return self.response_gamma == 1.0

    @property
    def has_offsets(self) -> bool:
        """Whether any offset pattern (pixel, row, column) is on."""
        return self.offset_dsnu > 0.0 or self.row_dsnu > 0.0 or self.column_dsnu > 0.0

    @property
    def has_charge_effects(self) -> bool:
        """Whether blooming or smear redistribute the expected charge before the noise."""
        return self.blooming > 0.0 or self.smear > 0.0

    @property
    def ideal_readout(self) -> bool:
        """True when the readout is the original one: full-well clip after the read noise
        and no offset patterns (the compiled fused passes apply)."""
        return not self.charge_clip and not self.has_offsets

    # ------------------------------------------------------------------ fixed patterns
    def _window(self, height: int, width: int) -> tuple[tuple[int, int], int, int]:
        """(array shape, first row, first column) of the centred ``height × width`` window."""
        h, w = int(height), int(width)
        if self.array_shape is None:
            return (h, w), 0, 0
        rows, cols = self.array_shape
        if h > rows or w > cols:
            raise ValueError(
                f"an image of {w} x {h} pixels does not fit the sensor's physical array "
                f"(array_shape = (rows, cols) = {self.array_shape}); give a larger array_shape"
            )
        return (rows, cols), (rows - h) // 2, (cols - w) // 2

    def _cached(self, key: tuple, make) -> Any:
        v = self._maps.get(key)
        if v is None:
            v = make()
            self._maps[key] = v
        return v

    def _full_maps(self, shape: tuple[int, int]) -> tuple[NDArray, NDArray]:
        def make():
            rng = np.random.default_rng(self.pattern_seed)
            prnu = 1.0 + self.prnu * rng.standard_normal(shape)
            dsnu = 1.0 + self.dsnu * rng.standard_normal(shape)
            np.clip(prnu, 0.0, None, out=prnu)
            np.clip(dsnu, 0.0, None, out=dsnu)
            return prnu, dsnu

        return self._cached(("full", shape), make)

    def _stream(self, k: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence(int(self.pattern_seed), spawn_key=(k,)))

    def maps(self, height: int, width: int) -> tuple[NDArray, NDArray]:
        """Fixed-pattern ``(1 + PRNU, 1 + DSNU)`` maps of shape ``(height, width)`` (cached):
        the centred window of the physical array's maps (:attr:`array_shape`)."""
        key = (int(height), int(width))

        def make():
            shape, r0, c0 = self._window(*key)
            prnu, dsnu = self._full_maps(shape)
            if shape == key:
                return prnu, dsnu
            win = (slice(r0, r0 + key[0]), slice(c0, c0 + key[1]))
            return np.ascontiguousarray(prnu[win]), np.ascontiguousarray(dsnu[win])

        return self._cached(key, make)

    def dark_map(self, height: int, width: int) -> NDArray:
        """Dark current per pixel, e⁻/s, ``(height, width)``: ``dark_current · (1 + DSNU)``
        plus the hot pixels' extra dark current (cached)."""
        key = ("dark", int(height), int(width))

        def make():
            dark = self.maps(height, width)[1] * self.dark_current
            hot = self._hot_map(int(height), int(width))
            return dark if hot is None else dark + hot

        return self._cached(key, make)

    def _hot_map(self, height: int, width: int) -> NDArray | None:
        if self.hot_pixels <= 0.0 or self.hot_pixel_dark <= 0.0:
            return None
        shape, r0, c0 = self._window(height, width)

        def make():
            rng = self._stream(_STREAM_HOT)
            hot = rng.random(shape) < self.hot_pixels
            full = np.zeros(shape)
            full[hot] = rng.exponential(self.hot_pixel_dark, size=int(hot.sum()))
            return full

        full = self._cached(("hot", shape), make)
        return full[r0 : r0 + height, c0 : c0 + width]

    def offset_map(self, height: int, width: int) -> NDArray | None:
        """Offset pattern in electrons, ``(height, width)``: pixel, row and column offsets of
        the physical array's window (cached), or None when all three are off."""
        if not self.has_offsets:
            return None
        key = ("offset", int(height), int(width))

        def make():
            shape, r0, c0 = self._window(height, width)
            full = np.zeros(shape)
            if self.offset_dsnu > 0.0:
                full += self.offset_dsnu * self._stream(_STREAM_OFFSET).standard_normal(shape)
            if self.row_dsnu > 0.0:
                rows = self.row_dsnu * self._stream(_STREAM_ROW).standard_normal(shape[0])
                full += rows[:, None]
            if self.column_dsnu > 0.0:
                cols = self.column_dsnu * self._stream(_STREAM_COLUMN).standard_normal(shape[1])
                full += cols[None, :]
            return np.ascontiguousarray(full[r0 : r0 + height, c0 : c0 + width])

        return self._cached(key, make)

    # ------------------------------------------------------------------ noise and ADC
    @property
    def normal_threshold(self) -> float:
        """Poisson mean (e⁻) from which the noise is drawn from the skew-corrected normal:
        0 when the read noise is >= 6 e⁻, 30 from 2 e⁻, ``inf`` (always exact) below 2 e⁻."""
        if self.read_noise >= NORMAL_ALL_READ_NOISE_E:
            return 0.0
        if self.read_noise >= NORMAL_MIN_READ_NOISE_E:
            return NORMAL_THRESHOLD_E
        return math.inf

    def add_noise(
        self, electrons: NDArray, rng: np.random.Generator, *, exact: bool = False
    ) -> NDArray:
        """Shot noise (Poisson) and read noise (Gaussian) on an electron image (new array).

        Negative means are treated as 0. ``exact=True``: numpy's exact Poisson for every pixel
        plus a float64 normal (the reference); default: the compiled draw of the module
        docstring (exact below :attr:`normal_threshold`, skew-corrected normal above).
        Both are reproducible for a given generator state.
        """
        lam = np.clip(np.asarray(electrons, dtype=np.float64), 0.0, None)
        if not exact:
            try:
                from gonio.simulator import _kernels
            except ImportError:  # no numba: the exact numpy draw
                exact = True
        if exact:
            e = rng.poisson(lam).astype(np.float64)
            if self.read_noise > 0.0:
                e += self.read_noise * rng.standard_normal(e.shape)
            return e
        out = np.empty(lam.shape)
        state = _kernels.seed_state(rng)
        _kernels.noise_float(
            lam.ravel(), state, self.normal_threshold, self.read_noise, out.reshape(-1)
        )
        return out

    def spread(self, electrons: NDArray, dark: NDArray | None = None) -> NDArray:
        """Blooming, then smear, on an expected-charge image ``(height, width)`` (new array).

        ``dark`` is its dark part (default: none), which smear does not follow: smear adds
        ``smear / rows`` times the column's sum of the rest (the photo-charge; ``rows``: the
        physical array's height) to every pixel of the column. Without :attr:`blooming` and
        :attr:`smear` the input is returned as is.
        """
        e = np.asarray(electrons, dtype=np.float64)
        if not self.has_charge_effects:
            return e
        if e.ndim != 2:
            raise ValueError(f"spread takes a (height, width) image, got shape {e.shape}")
        cols = None
        if self.smear > 0.0:  # the light during transfer follows the pre-blooming photo-charge
            cols = e.sum(axis=0)
            if dark is not None:
                cols -= np.asarray(dark, dtype=np.float64).reshape(e.shape).sum(axis=0)
            rows = e.shape[0] if self.array_shape is None else self.array_shape[0]
            cols = (self.smear / rows) * np.maximum(cols, 0.0)
        out = e
        if self.blooming > 0.0:
            from gonio.simulator import _kernels

            out = np.array(e, dtype=np.float64, order="C")
            _kernels.bloom_columns(out, self.full_well, self.blooming)
        if cols is not None:
            out = out + cols[None, :] if out is e else np.add(out, cols[None, :], out=out)
        return out

    def _readout_args(self, lam: NDArray) -> tuple[NDArray, NDArray]:
        """(flat float64 means, flat offsets or an empty array) for the kernels (which treat
        a negative mean as 0)."""
        flat = np.ascontiguousarray(lam, dtype=np.float64).reshape(-1)
        off = self.offset_map(*lam.shape)
        return flat, (np.empty(0) if off is None else off.reshape(-1))

    def readout(
        self,
        electrons: NDArray,
        rng: np.random.Generator | None,
        *,
        noise: bool = True,
        exact: bool = False,
    ) -> NDArray[np.float64]:
        """Electrons at the ADC's input for an expected-charge image ``(height, width)``:
        shot + read noise (``noise``), the full-well clip (before the read noise with
        :attr:`charge_clip`, after it otherwise) and the offset pattern. The ADC of the
        result (:meth:`adc`) applies no further full-well clip.

        ``exact=True`` (or no numba): numpy's exact Poisson and normal draws.
        """
        lam = np.clip(np.asarray(electrons, dtype=np.float64), 0.0, None)
        if lam.ndim != 2:
            raise ValueError(f"readout takes a (height, width) image, got shape {lam.shape}")
        off = self.offset_map(*lam.shape)
        fw = self.full_well
        if not noise:
            e = np.minimum(lam, fw)
        elif exact or not _have_kernels():
            e = rng.poisson(lam).astype(np.float64)
            if self.charge_clip:
                np.minimum(e, fw, out=e)
            if self.read_noise > 0.0:
                e += self.read_noise * rng.standard_normal(e.shape)
            if not self.charge_clip:
                np.minimum(e, fw, out=e)
        else:
            from gonio.simulator import _kernels

            e = np.empty(lam.shape)
            _kernels.readout_float(
                lam.reshape(-1), _kernels.seed_state(rng), self.normal_threshold,
                self.read_noise, self.charge_clip, fw, e.reshape(-1),
            )  # fmt: skip
        if off is not None:
            e += off
        return e

    def readout_dn(
        self, electrons: NDArray, rng: np.random.Generator | None, *, noise: bool = True
    ) -> NDArray[np.uint16]:
        """:meth:`readout` and :meth:`adc` in one compiled pass for a linear sensor (the same
        image bit for bit: the same random numbers and arithmetic); any other sensor, or no
        numba, takes the two steps."""
        lam = np.asarray(electrons, dtype=np.float64)
        if not self.linear or lam.ndim != 2 or not _have_kernels():
            return self.adc(self.readout(lam, rng, noise=noise))
        from gonio.simulator import _kernels

        flat, off = self._readout_args(lam)
        img = np.empty(flat.size, dtype=np.uint16)
        adc = (1.0 / self.gain, self.black_level, float(self.max_dn))
        if noise:
            _kernels.readout_u16(
                flat, _kernels.seed_state(rng), self.normal_threshold, self.read_noise,
                self.charge_clip, self.full_well, off, *adc, img,
            )  # fmt: skip
        else:
            _kernels.adc_charge(flat, self.full_well, off, *adc, img)
        return img.reshape(lam.shape)

    def adc(self, electrons: NDArray) -> NDArray[np.uint16]:
        """Gain, response curve, black level, rounding and the ADC's range on electrons
        already clipped by :meth:`readout` (no full-well clip here)."""
        x = np.asarray(electrons, dtype=np.float64) * (1.0 / self.gain)
        if not self.linear:
            xm = self._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** self.response_gamma
        dn = np.rint(x + self.black_level)
        np.clip(dn, 0.0, self.max_dn, out=dn)
        return dn.astype(np.uint16)

    def digitise(self, electrons: NDArray) -> NDArray[np.uint16]:
        """Full-well clip, gain, response curve, black level, rounding and ADC clip."""
        return self.adc(np.minimum(electrons, self.full_well))

    def linearise(self, dn: NDArray) -> NDArray[np.float64]:
        """Invert the ADC: DN → electrons (before noise), for tests and calibration."""
        x = np.asarray(dn, dtype=np.float64) - self.black_level
        if not self.linear:
            xm = self._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** (1.0 / self.response_gamma)
        return x * self.gain

    # ------------------------------------------------------------------ sensor-level API
    def expected_electrons(self, photons: Any, exposure: float) -> NDArray[np.float64]:
        """Expected charge per pixel before the noise: ``QE · (1 + PRNU) · photons`` plus the
        dark charge ``dark_map · exposure``, then blooming and smear (:meth:`spread`).

        ``photons`` is the mean number of photons reaching each pixel during the exposure
        (EMVA 1288's ``μ_p``), a ``(height, width)`` array or a number (then the image is the
        whole :attr:`array_shape`).
        """
        t = _num(exposure, "exposure", 0.0, True)
        p = np.asarray(photons, dtype=np.float64)
        if p.ndim == 0:
            if self.array_shape is None:
                raise ValueError(
                    "photons is a single number but the sensor has no array_shape; give a "
                    "(height, width) array of photons per pixel"
                )
            p = np.full(self.array_shape, float(p))
        if p.ndim != 2 or p.size == 0:
            raise ValueError(f"photons must be a (height, width) array, got shape {p.shape}")
        if not np.isfinite(p).all() or (p < 0.0).any():
            bad = p[~(np.isfinite(p) & (p >= 0.0))].flat[0]
            raise ValueError(f"photons must be finite and >= 0 per pixel, got {bad!r}")
        h, w = p.shape
        prnu, _ = self.maps(h, w)
        dark = self.dark_map(h, w) * t
        return self.spread(self.qe * prnu * p + dark, dark)

    def frames(
        self,
        photons: Any,
        exposure: float,
        n: int = 1,
        rng: int | np.random.Generator | None = None,
        *,
        noise: bool = True,
        exact: bool = False,
    ) -> NDArray[np.uint16]:
        """``n`` independent raw frames ``(n, height, width)`` of a sensor lit with
        ``photons`` per pixel (see :meth:`expected_electrons`) for ``exposure`` seconds.

        ``rng``: a seed or a Generator (the frames are drawn one after the other from it).
        ``photons = 0`` is a shutter-closed dark frame. ``exact``: numpy's exact draws.
        """
        if not isinstance(n, int | np.integer) or isinstance(n, bool) or not 1 <= n <= 100_000:
            raise ValueError(f"n must be an integer in [1, 100000], got {n!r}")
        shape = np.shape(photons) or self.array_shape or (1, 1)
        size = math.prod(shape)
        if int(n) * size > MAX_FRAMES_PIXELS:
            raise ValueError(
                f"n = {n} frames of {size} pixels each is {int(n) * size} pixels, more than "
                f"the {MAX_FRAMES_PIXELS} allowed at once"
            )
        lam = self.expected_electrons(photons, exposure)
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        out = np.empty((int(n), *lam.shape), dtype=np.uint16)
        for k in range(int(n)):
            if self.ideal_readout:
                e = self.add_noise(lam, gen, exact=exact) if noise else lam
                out[k] = self.digitise(e)
            elif exact:
                out[k] = self.adc(self.readout(lam, gen, noise=noise, exact=True))
            else:
                out[k] = self.readout_dn(lam, gen, noise=noise)
        return out

    # ------------------------------------------------------------------ EMVA 1288 figures
    def emva1288(self, exposure: float = 0.01, *, warn: bool = True) -> dict[str, float]:
        """The EMVA 1288 (Release 4.0 Linear) figures of this sensor at ``exposure`` seconds.

        Keys: ``quantum_efficiency`` (η), ``system_gain_dn_per_e`` (K), ``dark_noise_e``
        (σ_d: read noise and the dark current's shot noise at the exposure),
        ``saturation_capacity_e`` (μ_e.sat: the charge at which the output saturates, the
        full well or the ADC's range, less the mean dark charge), ``snr_max``
        (``sqrt(μ_e.sat)``), ``absolute_sensitivity_threshold_p`` (μ_p.min =
        ``(sqrt(σ_d² + σ_q²/K²) + 1/2) / η``, σ_q² = 1/12 DN²), ``dynamic_range``
        (μ_p.sat / μ_p.min) and ``dynamic_range_db``, ``dark_current_e_s`` (mean, hot
        pixels included), ``dsnu_e`` (spatial RMS of the dark signal at the exposure:
        dark-current nonuniformity, hot pixels and offsets), ``prnu_percent``.

        With ``warn`` each setting the standard rejects (:meth:`emva1288_problems`) is
        issued as an :class:`EMVA1288Warning`.

        References
        ----------
        EMVA Standard 1288, Release 4.0 Linear (2021), Sec. 2 (linear model, noise model,
        SNR, saturation and absolute sensitivity threshold), Sec. 4 (DSNU, PRNU), Sec. 7
        (dark current).
        """
        t = _num(exposure, "exposure", 0.0, True)
        if warn:
            for msg in self.emva1288_problems(t):
                warnings.warn(msg, EMVA1288Warning, stacklevel=2)
        k = 1.0 / self.gain
        hot_mean = self.hot_pixels * self.hot_pixel_dark
        dark_rate = self.dark_current + hot_mean
        sigma_d = math.sqrt(self.read_noise**2 + dark_rate * t)
        cap = min(self.full_well, (self.max_dn - self.black_level) * self.gain)
        mu_sat = max(cap - dark_rate * t, 0.0)
        mu_p_sat = mu_sat / self.qe
        mu_p_min = (math.sqrt(sigma_d**2 + (1.0 / 12.0) / k**2) + 0.5) / self.qe
        # spatial variance of the dark signal: DSNU of the dark current, hot pixels
        # (a fraction p with exponential extra rate of mean m: variance 2 p m² - p² m²)
        hot_var = (2.0 * self.hot_pixels - self.hot_pixels**2) * self.hot_pixel_dark**2
        dsnu_var = (
            (self.dsnu * self.dark_current * t) ** 2
            + hot_var * t * t
            + self.offset_dsnu**2
            + self.row_dsnu**2
            + self.column_dsnu**2
        )
        dr = mu_p_sat / mu_p_min
        return {
            "quantum_efficiency": self.qe,
            "system_gain_dn_per_e": k,
            "dark_noise_e": sigma_d,
            "saturation_capacity_e": mu_sat,
            "snr_max": math.sqrt(mu_sat),
            "absolute_sensitivity_threshold_p": mu_p_min,
            "dynamic_range": dr,
            "dynamic_range_db": 20.0 * math.log10(dr) if dr > 0 else -math.inf,
            "dark_current_e_s": dark_rate,
            "dsnu_e": math.sqrt(dsnu_var),
            "prnu_percent": 100.0 * self.prnu,
        }

    def emva1288_problems(self, exposure: float = 0.01) -> list[str]:
        """Settings the EMVA 1288 standard does not accept for its measurements (empty when
        none): a non-linear response (``response_gamma != 1``; Release 4.0 Linear needs a
        linear camera), a black level that clips the dark signal at 0 (the offset must keep
        the dark signal's temporal and spatial spread above zero: here black level < 3 x the
        total dark RMS in DN), and a temporal dark noise below 0.5 DN (quantisation then
        dominates and σ_d cannot be measured; the emva1288 reference code floors
        ``σ²_y.dark`` at 0.24 DN²)."""
        t = _num(exposure, "exposure", 0.0, True)
        out = []
        if not self.linear:
            out.append(
                f"response_gamma = {self.response_gamma} is not 1: EMVA 1288 Release 4.0 "
                "Linear characterises linear cameras only"
            )
        dark_rate = self.dark_current + self.hot_pixels * self.hot_pixel_dark
        temporal = math.sqrt(self.read_noise**2 + dark_rate * t) / self.gain
        spatial = (
            math.sqrt(
                (self.dsnu * self.dark_current * t) ** 2
                + self.offset_dsnu**2
                + self.row_dsnu**2
                + self.column_dsnu**2
            )
            / self.gain
        )
        total = math.sqrt(temporal**2 + spatial**2 + 1.0 / 12.0)
        if self.black_level < 3.0 * total:
            out.append(
                f"black_level = {self.black_level} DN clips the dark signal (its RMS is "
                f"{total:.3g} DN; EMVA 1288 needs the offset above 3 x that, "
                f"{3.0 * total:.3g} DN)"
            )
        if temporal < 0.5:
            out.append(
                f"the temporal dark noise is {temporal:.3g} DN, below 0.5 DN: quantisation "
                "dominates and EMVA 1288's dark noise cannot be measured (raise the gain)"
            )
        return out

    # ------------------------------------------------------------------ description
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``metadata["sensor"]``). The effect parameters appear only
        when on, so an ideal sensor's description is what it always was."""
        d = {
            "qe": self.qe,
            "full_well_e": self.full_well,
            "gain_e_per_dn": self.gain,
            "read_noise_e": self.read_noise,
            "dark_current_e_s": self.dark_current,
            "prnu": self.prnu,
            "dsnu": self.dsnu,
            "adc_bits": self.adc_bits,
            "black_level_dn": self.black_level,
            "saturation_dn": self.saturation_dn,
            "max_dn": self.max_dn,
            "response_gamma": self.response_gamma,
            "pattern_seed": int(self.pattern_seed),
            "pixel_pitch_m": self.pixel_pitch,
        }
        if self.array_shape is not None:
            d["array_shape"] = list(self.array_shape)
        if self.charge_clip:
            d["charge_clip"] = True
        for name, key in _EFFECT_KEYS:
            v = getattr(self, name)
            if v:
                d[key] = v
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Sensor:
        """Inverse of :meth:`to_dict`."""
        try:
            shape = d.get("array_shape")
            return cls(
                qe=d["qe"],
                full_well=d["full_well_e"],
                gain=d["gain_e_per_dn"],
                read_noise=d["read_noise_e"],
                dark_current=d["dark_current_e_s"],
                prnu=d["prnu"],
                dsnu=d["dsnu"],
                adc_bits=d["adc_bits"],
                black_level=d["black_level_dn"],
                response_gamma=d.get("response_gamma", 1.0),
                pattern_seed=d.get("pattern_seed", 12345),
                pixel_pitch=d.get("pixel_pitch_m", 9e-6),
                array_shape=tuple(shape) if shape is not None else None,
                charge_clip=d.get("charge_clip", False),
                **{name: d.get(key, 0.0) for name, key in _EFFECT_KEYS},
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad sensor description: missing {exc}") from None

    def with_effects_off(self) -> Sensor:
        """The same sensor with every effect parameter off (the ideal-ish sensor)."""
        return replace(
            self, array_shape=None, charge_clip=False, **{n: 0.0 for n, _ in _EFFECT_KEYS}
        )


#: (parameter, description key) of the numeric effect parameters
_EFFECT_KEYS = (
    ("blooming", "blooming"),
    ("smear", "smear"),
    ("offset_dsnu", "offset_dsnu_e"),
    ("row_dsnu", "row_dsnu_e"),
    ("column_dsnu", "column_dsnu_e"),
    ("hot_pixels", "hot_pixel_fraction"),
    ("hot_pixel_dark", "hot_pixel_dark_e_s"),
)


def _have_kernels() -> bool:
    try:
        from gonio.simulator import _kernels  # noqa: F401
    except ImportError:
        return False
    return True
