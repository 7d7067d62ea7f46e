"""Radiometric calibration: raw counts → linear signal with errors → eq. 2 reflectance.

A raw frame from a linear CCD reads ``V = black + g⁻¹·(electrons) + noise`` ADU. A lab knows its
sensor's conversion gain ``g`` (e⁻/ADU), read noise (e⁻ rms) and black level from the camera
data sheet or a photon-transfer measurement; those are what this module uses, taken from the
image's JSON side-car (:meth:`SensorModel.from_metadata`), never from the simulator's truth.

Per pixel variance of a raw frame, in ADU² (shot + read + quantisation)::

    var(V) = max(V − black, 0) / g + (σ_read / g)² + 1/12

A dark frame ``Vd`` (same exposure, shutter closed) is subtracted when available (its own
variance adds); otherwise the black level is. The signal is then divided by the exposure scale
``t / N²`` (exposure time over f-number squared) so that frames taken at different exposures
are comparable (:func:`linearize`).

Eq. 2 (:func:`eq2`) at every pixel::

    ρ_bd = (V_measured − V_background) / (V_standard − V_background) · ρ_standard / π

with first-order error propagation including the covariance the shared background introduces.
Pixels where the standard is not significantly above the background are masked, never divided.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992 §3.2, eq. 2: calibration against a diffuse standard and a
background measurement (source on, no sample).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "VARIANCE_MODES",
    "Measurement",
    "Reflectance",
    "SensorModel",
    "eq2",
    "exposure_scale",
    "linearize",
    "neighbour_mean",
]

#: Where the noise model is evaluated for a pixel's standard error: at the pixel's own noisy
#: reading (``"own"``) or at the mean of its valid 8-neighbours (``"neighbours"``).
VARIANCE_MODES = ("own", "neighbours")

QUANTISATION_VAR = 1.0 / 12.0


def _meta_get(meta: Mapping[str, Any], keys: tuple[str, ...], default: Any = None) -> Any:
    """First present key of ``keys`` in ``meta`` or in its ``"sensor"`` / ``"camera"`` sub-dict."""
    scopes = [meta]
    for sub in ("sensor", "camera", "exposure"):
        if isinstance(meta.get(sub), Mapping):
            scopes.append(meta[sub])
    for scope in scopes:
        for k in keys:
            if k in scope and scope[k] is not None:
                return scope[k]
    return default


def _pos(value: Any, name: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        want = "≥ 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {want}, got {value!r}")
    return v


#: Upper limits of the sensor side-car fields: far beyond any real camera (EMVA 1288 data
#: sheets: gains of 0.01-100 e-/DN, read noise of 1-100 e-, ADCs of at most 32 bits, dark
#: currents below 1e6 e-/s), low enough that their squares stay finite in float64.
SENSOR_LIMITS = {
    "gain": 1e6,
    "read_noise": 1e6,
    "black_level": 2.0**32,
    "white_level": 2.0**32,
    "dark_current": 1e12,
}


@dataclass(frozen=True)
class SensorModel:
    """What a lab knows about its linear sensor (from the side-car metadata).

    Parameters
    ----------
    gain : float
        Conversion gain in electrons per ADU.
    read_noise : float
        Read noise in electrons rms (of one read-out pixel, after any binning).
    black_level : float
        ADC offset in ADU (subtracted when no dark frame is given).
    white_level : float
        Highest valid code; pixels at or above it are saturated.
    dark_current : float
        Mean dark signal in e⁻/s (used only when no dark frame is given).
    """

    gain: float
    read_noise: float
    black_level: float = 0.0
    white_level: float = 65535.0
    dark_current: float = 0.0

    def __post_init__(self) -> None:
        for name, zero_ok in (("gain", False), ("read_noise", True), ("black_level", True),
                              ("white_level", False), ("dark_current", True)):  # fmt: skip
            v = _pos(getattr(self, name), name, zero_ok)
            if v > SENSOR_LIMITS[name]:
                raise ValueError(
                    f"{name} = {v!r} is above the physical limit {SENSOR_LIMITS[name]:g} of a "
                    "sensor side-car"
                )
            object.__setattr__(self, name, v)

    @classmethod
    def from_metadata(cls, meta: Mapping[str, Any]) -> SensorModel:
        """Read gain, read noise, black and white level from a side-car dict.

        Keys looked for (top level or under ``"sensor"``; DN = ADU): ``gain_e_per_dn`` (or
        ``gain_e_per_adu``, ``gain``), ``read_noise_e``, ``black_level_dn`` (default 0),
        ``saturation_dn`` (else ``2**adc_bits − 1``), ``dark_current_e_s`` (optional, used
        only without dark frames).
        """
        if not isinstance(meta, Mapping):
            raise ValueError(f"metadata must be a mapping, got {type(meta).__name__}")
        gain = _meta_get(meta, ("gain_e_per_dn", "gain_e_per_adu", "gain"))
        read = _meta_get(meta, ("read_noise_e", "read_noise"))
        missing = [n for n, v in (("gain_e_per_adu", gain), ("read_noise_e", read)) if v is None]
        if missing:
            raise ValueError(
                f"image metadata lacks the sensor noise parameter(s) {missing}; a linear "
                "reduction needs the conversion gain (e-/ADU) and read noise (e-)"
            )
        white = _meta_get(
            meta, ("saturation_dn", "white_level_dn", "saturation_adu", "white_level")
        )
        if white is None:
            bits = _meta_get(meta, ("adc_bits", "bit_depth"), 16)
            white = 2 ** int(bits) - 1
        return cls(
            gain=gain,
            read_noise=read,
            black_level=_meta_get(
                meta, ("black_level_dn", "black_level_adu", "black_level", "bias_adu"), 0.0
            ),
            white_level=white,
            dark_current=_meta_get(
                meta, ("dark_current_e_s", "dark_current_e_per_s", "dark_current"), 0.0
            ),
        )

    def raw_variance(self, raw: ArrayLike) -> NDArray[np.float64]:
        """Variance in ADU² of raw frame values (shot + read + quantisation)."""
        raw = np.asarray(raw, dtype=np.float64)
        return (
            np.maximum(raw - self.black_level, 0.0) / self.gain
            + (self.read_noise / self.gain) ** 2
            + QUANTISATION_VAR
        )


#: Exposure times a camera can take (s): 1 ns electronic shutters to ~12 days; outside it a
#: side-car value is a unit mistake, and t² in the noise model would overflow float64.
EXPOSURE_RANGE_S = (1e-9, 1e6)

#: f-numbers a lens can have: N ≥ 0.5 in air (N = 1/(2 NA), NA ≤ 1); 1000 is a pinhole.
F_NUMBER_RANGE = (0.5, 1000.0)


def exposure_scale(meta: Mapping[str, Any]) -> float:
    """Exposure scale ``t / N²`` of a frame: exposure time (s) over f-number squared.

    Keys: ``exposure_s`` (or ``exposure_time_s``, ``exposure``) and, optionally,
    ``f_number`` (default 1). A frame's linear signal divided by this is comparable between
    exposures.
    """
    t = _meta_get(meta, ("exposure_s", "exposure_time_s", "exposure_time", "exposure"))
    if t is None:
        raise ValueError("image metadata lacks the exposure time (key 'exposure_s')")
    if isinstance(t, Mapping):
        raise ValueError(f"exposure time must be a number, got {t!r}")
    t = _pos(t, "exposure_s")
    n = _pos(_meta_get(meta, ("f_number", "fnumber"), 1.0), "f_number")
    for name, v, (lo, hi) in (("exposure_s", t, EXPOSURE_RANGE_S), ("f_number", n, F_NUMBER_RANGE)):
        if not lo <= v <= hi:
            raise ValueError(f"{name} = {v!r} is outside the physical range [{lo:g}, {hi:g}]")
    return t / (n * n)


@dataclass
class Measurement:
    """A linear, exposure-normalised signal image with its standard error.

    ``value`` and ``sigma`` are in ADU per unit exposure scale; ``valid`` is False where the
    pixel carries no usable reading (saturated, clipped at the ADC floor, or outside data).
    """

    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    valid: NDArray[np.bool_]

    def __post_init__(self) -> None:
        self.value = np.asarray(self.value, dtype=np.float64)
        self.sigma = np.asarray(self.sigma, dtype=np.float64)
        self.valid = np.asarray(self.valid, dtype=bool)
        if not (self.value.shape == self.sigma.shape == self.valid.shape):
            raise ValueError(
                f"value, sigma, valid must share a shape, got {self.value.shape}, "
                f"{self.sigma.shape}, {self.valid.shape}"
            )

    @property
    def shape(self) -> tuple[int, ...]:
        """Image shape."""
        return self.value.shape


def neighbour_mean(
    x: NDArray[np.float64], valid: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Leave-one-out local mean: the mean of each pixel's valid 8-neighbours.

    Returns the mean image and where it exists (at least one valid neighbour). The centre pixel
    is excluded, so the result is statistically independent of the pixel's own noise: a
    standard error computed from it does not correlate with the reading it belongs to.

    Why it matters: a noise model evaluated at a pixel's own reading gives bright (upward
    fluctuated) pixels larger σ, so a 1/σ² weighted fit leans towards low readings. Measured on
    rolled brass (default noise, 6 incidences × 2 rotations, all 2.09 M pixels): ρd −0.356 %
    (−72 standard errors) with own-reading σ.
    """
    import cv2

    m = valid.astype(np.float64)
    xm = np.where(valid, x, 0.0)
    k = dict(ddepth=-1, ksize=(3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    s = cv2.boxFilter(xm, **k) - xm
    c = cv2.boxFilter(m, **k) - m
    ok = c > 0.5
    return np.where(ok, s / np.where(ok, c, 1.0), 0.0), ok


def _check_variance_mode(variance: str) -> str:
    if variance not in VARIANCE_MODES:
        raise ValueError(f"variance {variance!r}; expected one of {list(VARIANCE_MODES)}")
    return variance


def _as_image(x: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric image: {exc}") from None
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains non-finite pixel values")
    return a


def linearize(
    image: ArrayLike,
    meta: Mapping[str, Any],
    dark: ArrayLike | None = None,
    *,
    sensor: SensorModel | None = None,
) -> Measurement:
    """Raw frame → dark-subtracted, exposure-normalised signal with its standard error.

    Parameters
    ----------
    image : array_like, shape (H, W)
        Raw counts (ADU) of a linear sensor.
    meta : mapping
        The frame's side-car: exposure (:func:`exposure_scale`) and sensor parameters
        (:meth:`SensorModel.from_metadata`).
    dark : array_like, optional
        A dark frame at the same exposure; its noise is propagated. Without it the black level
        and the side-car's mean dark current are subtracted.
    sensor : SensorModel, optional
        Overrides the sensor parameters of ``meta``.

    Returns
    -------
    Measurement
        ``valid`` is False where the raw value is saturated (≥ white level).
    """
    raw = _as_image(image, "image")
    sensor = sensor or SensorModel.from_metadata(meta)
    scale = exposure_scale(meta)
    var = sensor.raw_variance(raw)
    if dark is not None:
        d = _as_image(dark, "dark")
        if d.shape != raw.shape:
            raise ValueError(f"dark frame shape {d.shape} differs from image shape {raw.shape}")
        signal = raw - d
        var = var + sensor.raw_variance(d)
    else:
        t = _pos(_meta_get(meta, ("exposure_s", "exposure_time_s", "exposure")), "exposure_s")
        signal = raw - sensor.black_level - sensor.dark_current * t / sensor.gain
    valid = raw < sensor.white_level
    return Measurement(signal / scale, np.sqrt(var) / scale, valid)


@dataclass
class Reflectance:
    """Eq. 2 result per pixel: BRDF value (sr⁻¹), its standard error, and the valid mask."""

    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    mask: NDArray[np.bool_]

    @property
    def n_valid(self) -> int:
        """Number of unmasked pixels."""
        return int(np.count_nonzero(self.mask))


def eq2(
    measured: Measurement,
    standard: Measurement,
    background: Measurement,
    rho_standard: float,
    *,
    threshold: float = 5.0,
    variance: str = "own",
    ratio_at: tuple[ArrayLike, ArrayLike] | None = None,
    debias: bool = False,
) -> Reflectance:
    r"""Ward's eq. 2 at every pixel with propagated standard errors.

    .. math::
        \rho_{bd} = \frac{V_m - V_b}{V_s - V_b}\,\frac{\rho_{standard}}{\pi}

    Parameters
    ----------
    measured, standard, background : Measurement
        Linear, exposure-normalised signals (:func:`linearize` or a merge).
    rho_standard : float
        Total diffuse reflectance of the standard, in (0, 1].
    threshold : float
        A pixel is kept only if ``V_s − V_b > threshold · σ(V_s − V_b)`` (and all three
        readings are valid); the others are masked (value 0, sigma 0), never divided.
    variance : {"own", "neighbours"}
        Evaluate the error propagation's ratio ``r`` and denominator ``d`` at the pixel's own
        readings, or at the means of its unmasked neighbours (:func:`neighbour_mean`) so that
        σ does not correlate with the pixel's own noise (pass measurements merged with the
        same mode). Values are the same either way.
    ratio_at : (num, den) arrays, optional
        Estimates of ``V_m − V_b`` and ``V_s − V_b`` at which the propagation is evaluated
        instead (e.g. neighbour means computed by the caller); overrides ``variance``.
    debias : bool
        Remove the second-order bias of the ratio (see Notes), with the variances and the
        ratio taken where the error propagation is evaluated (``variance``/``ratio_at``).

    Returns
    -------
    Reflectance

    Notes
    -----
    With ``n = V_m − V_b``, ``d = V_s − V_b`` and ``r = n/d``, the background is shared by the
    numerator and denominator, so ``cov(n, d) = var(V_b)`` and::

        var(ρ) = (ρ_std/π)² / d² · [var(V_m) + var(V_b) + r² (var(V_s) + var(V_b)) − 2 r var(V_b)]

    The ratio of noisy readings is biased: to second order
    ``E[n/d] = r + (r var(d) − cov(n, d)) / d²``, a relative bias of about ``(σ_d/d)²``.
    Per pixel it is a small fraction of σ (about ``σ_d/d`` of it where the standard's noise
    dominates), but it has one sign everywhere, so a fit pooling 10⁵ pixels sees it: rolled
    brass, 21 θi × 2 rotations, default noise, selection thinning: mean ρs pull
    +1.03 ± 0.15 over 49 seeds without, −0.02 ± 0.14 over 60 seeds with ``debias``.
    ``debias=True`` subtracts ``(r var(d) − var(V_b)) / d²`` evaluated as above — with
    ``variance="neighbours"`` or ``ratio_at`` independent of the pixel's own noise. The
    noise model is that of a noisy sensor: for noise-free images the correction itself is a
    bias of relative size ``(σ_d/d)²``.

    References
    ----------
    Ward 1992, §3.2, eq. 2.
    """
    rho_standard = _pos(rho_standard, "rho_standard")
    if rho_standard > 1.0:
        raise ValueError(f"rho_standard must be in (0, 1], got {rho_standard!r}")
    threshold = _pos(threshold, "threshold", True)
    shapes = {measured.shape, standard.shape, background.shape}
    if len(shapes) != 1:
        raise ValueError(f"measured, standard and background shapes differ: {sorted(shapes)}")
    vm, vs, vb = measured.sigma**2, standard.sigma**2, background.sigma**2
    num = measured.value - background.value
    den = standard.value - background.value
    var_den = vs + vb
    mask = (
        measured.valid
        & standard.valid
        & background.valid
        & (den > threshold * np.sqrt(var_den))
        & (den > 0.0)
    )
    safe = np.where(mask, den, 1.0)
    r = np.where(mask, num / safe, 0.0)
    c = rho_standard / math.pi
    value = np.where(mask, c * r, 0.0)
    if ratio_at is not None or _check_variance_mode(variance) == "neighbours":
        if ratio_at is not None:
            n_nb = np.asarray(ratio_at[0], dtype=np.float64)
            d_nb = np.asarray(ratio_at[1], dtype=np.float64)
            if n_nb.shape != num.shape or d_nb.shape != num.shape:
                raise ValueError(f"ratio_at arrays must have shape {num.shape}")
            ok = np.isfinite(n_nb) & np.isfinite(d_nb)
        else:
            n_nb, ok = neighbour_mean(num, mask)
            d_nb, _ = neighbour_mean(den, mask)
        ok &= d_nb > 0.0
        safe = np.where(ok, d_nb, safe)
        r = np.where(ok, n_nb / np.where(ok, d_nb, 1.0), r)
    d2 = safe * safe
    var_r = (vm + vb + r * r * var_den - 2.0 * r * vb) / d2
    sigma = np.where(mask, c * np.sqrt(np.maximum(var_r, 0.0)), 0.0)
    if debias:  # E[n/d] - n/d = (r var(d) - cov(n, d)) / d², cov(n, d) = var(V_b)
        value = np.where(mask, value - c * (r * var_den - vb) / d2, 0.0)
    return Reflectance(value, sigma, mask)
