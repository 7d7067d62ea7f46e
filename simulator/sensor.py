"""A linear CCD camera sensor (with an optional non-linear video response).

Signal chain per pixel, for an exposure of ``t`` seconds at f-number ``N``::

    photo-electrons  e_sig = QE · Φ · (1 + PRNU_map) · t / N²     (Φ: photons/s at f/1)
    dark electrons   e_dk  = dark_current · (1 + DSNU_map) · t
    noise (optional) e = Poisson(e_sig + e_dk) + Normal(0, read_noise)   (see "Noise" below)
    full well        e = min(e, full_well)
    ADC              x = e / gain (DN above black level), optional response curve on
                     x / x_max, DN = clip(round(black_level + x), 0, 2^adc_bits - 1)

The PRNU and DSNU maps are fixed patterns of the sensor (drawn once from ``pattern_seed``),
so they are present with noise on or off; noise off skips all random draws (deterministic).

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
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3 (CCD camera with fisheye lens, video capture board; two or
more f-stops to cover the dynamic range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "NORMAL_ALL_READ_NOISE_E",
    "NORMAL_MIN_READ_NOISE_E",
    "NORMAL_THRESHOLD_E",
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


@dataclass(frozen=True)
class Sensor:
    """CCD sensor parameters.

    Parameters
    ----------
    qe : float
        Quantum efficiency (electrons per photon), (0, 1].
    full_well : float
        Pixel capacity in electrons; signal clips there (saturation).
    gain : float
        Electrons per DN.
    read_noise : float
        RMS read noise, electrons.
    dark_current : float
        Mean dark current, electrons per second.
    prnu : float
        Photo-response non-uniformity, relative RMS of the gain map.
    dsnu : float
        Dark-signal non-uniformity, relative RMS of the dark-current map.
    adc_bits : int
        ADC depth, 8..16; output DN in ``[0, 2**adc_bits - 1]`` stored as uint16.
    black_level : float
        Offset added before quantisation, DN.
    response_gamma : float
        1 for a linear CCD; a video camera's response ``y = x**gamma`` on the normalised
        signal otherwise (applied above the black level).
    pattern_seed : int
        Seed of the fixed PRNU/DSNU pattern.
    pixel_pitch : float
        Pixel size in metres (photon collection area ``pixel_pitch²``).
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
        if not isinstance(self.pattern_seed, int | np.integer):
            raise ValueError(f"pattern_seed must be an integer, got {self.pattern_seed!r}")

    @property
    def max_dn(self) -> int:
        """Largest output value, ``2**adc_bits - 1``."""
        return (1 << self.adc_bits) - 1

    @property
    def saturation_dn(self) -> float:
        """DN of a full well (or the ADC maximum if that comes first)."""
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

    def maps(self, height: int, width: int) -> tuple[NDArray, NDArray]:
        """Fixed-pattern ``(1 + PRNU, 1 + DSNU)`` maps of shape ``(height, width)`` (cached)."""
        key = (int(height), int(width))
        if key not in self._maps:
            rng = np.random.default_rng(self.pattern_seed)
            prnu = 1.0 + self.prnu * rng.standard_normal(key)
            dsnu = 1.0 + self.dsnu * rng.standard_normal(key)
            np.clip(prnu, 0.0, None, out=prnu)
            np.clip(dsnu, 0.0, None, out=dsnu)
            self._maps[key] = (prnu, dsnu)
        return self._maps[key]

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

    def digitise(self, electrons: NDArray) -> NDArray[np.uint16]:
        """Full-well clip, gain, response curve, black level, rounding and ADC clip."""
        x = np.minimum(electrons, self.full_well) * (1.0 / self.gain)
        if not self.linear:
            xm = self._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** self.response_gamma
        dn = np.rint(x + self.black_level)
        np.clip(dn, 0.0, self.max_dn, out=dn)
        return dn.astype(np.uint16)

    def linearise(self, dn: NDArray) -> NDArray[np.float64]:
        """Invert the ADC: DN → electrons (before noise), for tests and calibration."""
        x = np.asarray(dn, dtype=np.float64) - self.black_level
        if not self.linear:
            xm = self._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** (1.0 / self.response_gamma)
        return x * self.gain

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``metadata["sensor"]``)."""
        return {
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

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Sensor:
        """Inverse of :meth:`to_dict`."""
        try:
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
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad sensor description: missing {exc}") from None
