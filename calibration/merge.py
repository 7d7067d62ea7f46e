"""Merging bracketed exposures into one signal image with its standard error.

Two cases, as a lab would meet them:

* **Linear sensor** (:func:`merge_linear`): every frame is linearised (dark frame or black
  level subtracted, divided by its exposure scale ``t/N²``); the merged value is the
  inverse-variance weighted mean over the frames where the pixel is neither saturated nor
  clipped at the ADC floor. The weights come from the sensor noise model evaluated at the
  current merged estimate (not at each frame's own noisy reading, which would bias the mean
  towards low readings), iterated twice. The result is the minimum-variance unbiased
  combination; its standard error is ``(Σ w_k)^-½``.
* **Non-linear (video) camera** (:func:`calibrate_response`, :func:`merge_debevec`): the camera
  response is recovered with OpenCV's ``createCalibrateDebevec`` from the bracket itself and
  the radiance map made with ``createMergeDebevec``; codes at 0 and at the top code are
  excluded. The standard error is propagated through the recovered response's slope.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992 §3.2: "two or more f-stops may be used to capture the full
dynamic range of the BRDF, there is often redundant information where the useful ranges of
exposures overlap". P. Debevec and J. Malik, "Recovering High Dynamic Range Radiance Maps from
Photographs", SIGGRAPH 1997 (OpenCV's ``CalibrateDebevec`` / ``MergeDebevec``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gonio.calibration.radiometry import (
    Measurement,
    SensorModel,
    _as_image,
    _check_variance_mode,
    exposure_scale,
    neighbour_mean,
)
from numpy.typing import ArrayLike, NDArray

__all__ = ["calibrate_response", "merge_debevec", "merge_linear", "merge_measurements"]


def merge_linear(
    images: Sequence[ArrayLike],
    metas: Sequence[Mapping[str, Any]],
    darks: Sequence[ArrayLike | None] | None = None,
    *,
    sensor: SensorModel | None = None,
    iterations: int = 2,
    variance: str = "own",
    variance_at: ArrayLike | None = None,
) -> Measurement:
    """Noise-optimal merge of bracketed frames of a linear sensor.

    Parameters
    ----------
    images : sequence of (H, W) arrays
        Raw frames (ADU) of the same scene at different exposures.
    metas : sequence of mappings
        Their side-cars (exposure ``exposure_s``, ``f_number``; sensor gain, read noise,
        black and white level).
    darks : sequence of arrays or None, optional
        Dark frame per exposure (or ``None`` entries); the black level and mean dark current
        are used where none is given.
    sensor : SensorModel, optional
        Overrides the sensor parameters read from the first side-car.
    iterations : int
        Re-weighting passes with the model variance at the current estimate.
    variance : {"own", "neighbours"}
        Evaluate the noise model (weights and standard error) at the pixel's own merged
        estimate, or at the mean of its valid 8-neighbours' estimates
        (:func:`~gonio.calibration.radiometry.neighbour_mean`), which is independent of the
        pixel's own noise: the weights then carry no bias towards low readings.
    variance_at : array_like, optional
        An estimate of the signal (per unit exposure scale, the images' shape) at which the
        noise model is evaluated instead — e.g. neighbour means computed by the caller when
        only some pixels are merged. Overrides ``variance``.

    Returns
    -------
    Measurement
        Merged value and standard error per unit exposure scale. A pixel saturated in every
        frame is invalid. A pixel clipped at the ADC floor in every frame keeps the reading
        of the longest exposure.
    """
    images = list(images)
    metas = list(metas)
    if not images:
        raise ValueError("images must hold at least one frame, got none")
    if len(metas) != len(images):
        raise ValueError(f"got {len(images)} images but {len(metas)} metadata dicts")
    if darks is None:
        darks = [None] * len(images)
    darks = list(darks)
    if len(darks) != len(images):
        raise ValueError(f"got {len(images)} images but {len(darks)} dark frames")
    sensor = sensor or SensorModel.from_metadata(metas[0])
    fr = _Frames(images, metas, darks, sensor)
    shape = fr.shape
    order = np.argsort(fr.scales)[::-1]  # longest exposure first
    # initial estimate: the longest exposure that is usable at each pixel
    x = np.zeros(shape)
    have = np.zeros(shape, bool)
    for k in order:
        take = fr.ok[k] & ~have
        x[take] = fr.xs[k][take]
        have |= take

    nb = _check_variance_mode(variance) == "neighbours"
    fixed = None
    if variance_at is not None:
        fixed = np.asarray(variance_at, dtype=np.float64)
        if fixed.shape != shape:
            raise ValueError(f"variance_at has shape {fixed.shape}, expected {shape}")
    for _ in range(max(1, int(iterations))):  # inverse-variance weights at the estimate
        est = x
        if fixed is not None:
            est = np.where(np.isfinite(fixed), fixed, x)
        elif nb:
            xn, okn = neighbour_mean(x, have)
            est = np.where(okn, xn, x)
        wsum = np.zeros(shape)
        xsum = np.zeros(shape)
        for k in range(len(fr.raws)):
            w = np.where(fr.ok[k], 1.0 / fr.variance(k, est), 0.0)
            wsum += w
            xsum += w * fr.xs[k]
        x = np.where(have, xsum / np.where(have, wsum, 1.0), x)

    sigma = np.where(have, 1.0 / np.sqrt(np.where(have, wsum, 1.0)), 0.0)

    # pixels without any usable frame: clipped at the floor everywhere → keep the longest
    # exposure's reading (with its noise); saturated everywhere → invalid
    k0 = order[0]
    raws, white = fr.raws, sensor.white_level
    floor_only = ~have & np.logical_or.reduce([raws[k] <= 0.0 for k in range(len(raws))])
    floor_only &= np.logical_and.reduce([raws[k] < white for k in range(len(raws))])
    if floor_only.any():
        x = np.where(floor_only, fr.xs[k0], x)
        sigma = np.where(floor_only, np.sqrt(fr.variance(k0, np.zeros(shape))), sigma)
    valid = have | floor_only
    return Measurement(x, sigma, valid)


class _Frames:
    """The bracketed frames of :func:`merge_linear`, checked and linearised: per frame the
    raw reading, its exposure scale, the offset removed (dark frame or black level plus mean
    dark current), the signal-independent variance (read noise, quantisation, dark), the
    per-unit-scale estimate ``xs`` and the usable-pixel mask ``ok`` (neither saturated nor
    clipped at the floor)."""

    def __init__(self, images: list, metas: list, darks: list, sensor: SensorModel) -> None:
        g = self.gain = sensor.gain
        rn2 = (sensor.read_noise / g) ** 2 + 1.0 / 12.0
        self.raws, self.scales, offs, self.base = [], [], [], []
        self.shape = None
        for k, (img, meta, dark) in enumerate(zip(images, metas, darks)):
            raw = _as_image(img, f"images[{k}]")
            if self.shape is None:
                self.shape = raw.shape
            elif raw.shape != self.shape:
                raise ValueError(f"images[{k}] has shape {raw.shape}, expected {self.shape}")
            self.scales.append(exposure_scale(meta))
            if dark is not None:
                d = _as_image(dark, f"darks[{k}]")
                if d.shape != self.shape:
                    raise ValueError(f"darks[{k}] has shape {d.shape}, expected {self.shape}")
                dark_adu = np.maximum(d - sensor.black_level, 0.0)
                off = d
                # the dark electrons' shot noise and read noise, in the frame and in the dark
                b = 2.0 * (dark_adu / g + rn2)
            else:
                t = _exposure_time(meta)
                dark_adu = np.full(self.shape, sensor.dark_current * t / g)
                off = sensor.black_level + dark_adu
                b = dark_adu / g + rn2
            self.raws.append(raw)
            offs.append(off)
            self.base.append(b)
        n = len(self.raws)
        self.xs = [(self.raws[k] - offs[k]) / self.scales[k] for k in range(n)]
        self.ok = [(self.raws[k] < sensor.white_level) & (self.raws[k] > 0.0) for k in range(n)]

    def variance(self, k: int, est: NDArray) -> NDArray:
        """Frame ``k``'s variance per unit exposure scale² at the signal estimate ``est``."""
        s = self.scales[k]
        return (np.maximum(est * s, 0.0) / self.gain + self.base[k]) / s**2


def _exposure_time(meta: Mapping[str, Any]) -> float:
    for key in ("exposure_s", "exposure_time_s", "exposure_time", "exposure"):
        v = meta.get(key)
        if v is not None and not isinstance(v, Mapping):
            return float(v)
    return 0.0


def merge_measurements(measurements: Sequence[Measurement]) -> Measurement:
    """Inverse-variance weighted mean of already linearised frames (valid pixels only).

    Uses each frame's own standard error; prefer :func:`merge_linear` on raw frames, which
    weights by the noise model at the merged estimate.
    """
    ms = list(measurements)
    if not ms:
        raise ValueError("measurements must hold at least one Measurement, got none")
    shape = ms[0].shape
    wsum = np.zeros(shape)
    xsum = np.zeros(shape)
    for k, m in enumerate(ms):
        if m.shape != shape:
            raise ValueError(f"measurements[{k}] has shape {m.shape}, expected {shape}")
        ok = m.valid & (m.sigma > 0)
        w = np.where(ok, 1.0 / np.where(ok, m.sigma, 1.0) ** 2, 0.0)
        wsum += w
        xsum += w * m.value
    valid = wsum > 0
    x = np.where(valid, xsum / np.where(valid, wsum, 1.0), 0.0)
    s = np.where(valid, 1.0 / np.sqrt(np.where(valid, wsum, 1.0)), 0.0)
    return Measurement(x, s, valid)


def _as_u8_stack(images: Sequence[ArrayLike]) -> list[NDArray[np.uint8]]:
    out = []
    for k, img in enumerate(images):
        a = np.asarray(img)
        if a.ndim != 2:
            raise ValueError(f"images[{k}] must be a 2-D image, got shape {a.shape}")
        if a.dtype != np.uint8:
            if a.size and (a.min() < 0 or a.max() > 255):
                raise ValueError(
                    f"images[{k}] must be 8-bit codes (0..255) for the Debevec merge, "
                    f"got range [{a.min()}, {a.max()}]"
                )
            a = a.astype(np.uint8)
        out.append(np.ascontiguousarray(a))
    if len({a.shape for a in out}) != 1:
        raise ValueError("images must all have the same shape")
    return out


def _times(metas_or_times: Sequence[Any], n: int) -> NDArray[np.float32]:
    if len(metas_or_times) != n:
        raise ValueError(f"got {n} images but {len(metas_or_times)} exposures")
    t = [exposure_scale(m) if isinstance(m, Mapping) else float(m) for m in metas_or_times]
    t = np.asarray(t, dtype=np.float64)
    if not (np.isfinite(t).all() and (t > 0).all()):
        raise ValueError(f"exposures must be finite and > 0, got {t.tolist()}")
    return t.astype(np.float32)


def calibrate_response(
    images: Sequence[ArrayLike],
    exposures: Sequence[Any],
    *,
    samples: int = 200,
    lambda_: float = 10.0,
    rng: int | np.random.Generator | None = 0,
) -> NDArray[np.float64]:
    """Recover a camera's response with OpenCV's Debevec-Malik method.

    Parameters
    ----------
    images : sequence of (H, W) uint8 arrays
        A bracket of the same scene.
    exposures : sequence
        Exposure times (s), or side-car dicts (their ``t/N²``).
    samples, lambda_ : int, float
        ``createCalibrateDebevec`` parameters.
    rng : int, Generator or None
        OpenCV's sample picking is random; this seeds ``cv2.setRNGSeed`` for reproducibility.

    Returns
    -------
    ndarray, shape (256,)
        Relative irradiance·time for each code (OpenCV's ``exp(g(Z))``).
    """
    import cv2

    imgs = _as_u8_stack(images)
    t = _times(exposures, len(imgs))
    seed = rng if isinstance(rng, int) else np.random.default_rng(rng).integers(2**31)
    cv2.setRNGSeed(int(seed))
    cal = cv2.createCalibrateDebevec(samples=int(samples), lambda_=float(lambda_), random=False)
    resp = cal.process(imgs, t)
    return np.asarray(resp, dtype=np.float64).reshape(256)


def merge_debevec(
    images: Sequence[ArrayLike],
    exposures: Sequence[Any],
    response: ArrayLike,
    *,
    read_noise_codes: float = 0.5,
) -> Measurement:
    """Radiance map of a non-linear camera's bracket (OpenCV ``createMergeDebevec``).

    Parameters
    ----------
    images : sequence of (H, W) uint8 arrays
    exposures : sequence
        Exposure times (s) or side-car dicts.
    response : array_like, shape (256,)
        From :func:`calibrate_response` (recover it once, use it for the measured, standard
        and background brackets alike so that eq. 2's ratio is consistent).
    read_noise_codes : float
        Temporal noise of one reading in output codes (plus quantisation), used for the
        standard error through the response slope.

    Returns
    -------
    Measurement
        Relative radiance (arbitrary but consistent units), its standard error, and
        ``valid`` False where every frame is at code 0 or 255.
    """
    import cv2

    imgs = _as_u8_stack(images)
    t = _times(exposures, len(imgs))
    resp = np.asarray(response, dtype=np.float64).reshape(256)
    if not (np.isfinite(resp).all() and (resp > 0).all()):
        raise ValueError("response must be 256 finite positive values")
    merged = cv2.createMergeDebevec().process(
        [cv2.merge([a, a, a]) for a in imgs],
        t,
        np.repeat(resp.astype(np.float32).reshape(256, 1, 1), 3, axis=2),
    )
    value = np.asarray(merged[..., 0], dtype=np.float64)

    # error propagation: ln E_k = ln resp(Z_k) − ln t_k; σ(ln E_k) ≈ |d ln resp / dZ| σ_Z
    lnr = np.log(resp)
    slope = np.gradient(lnr)
    sz2 = float(read_noise_codes) ** 2 + 1.0 / 12.0
    z = np.arange(256)
    hat = np.minimum(z, 255 - z).astype(np.float64)  # Debevec's triangle weights
    wsum = np.zeros(value.shape)
    vsum = np.zeros(value.shape)
    for a in imgs:
        w = hat[a]
        wsum += w
        vsum += (w * slope[a]) ** 2 * sz2
    valid = wsum > 0
    var_ln = np.where(valid, vsum / np.where(valid, wsum, 1.0) ** 2, 0.0)
    sigma = np.abs(value) * np.sqrt(var_ln)
    return Measurement(np.where(valid, value, 0.0), np.where(valid, sigma, 0.0), valid)
