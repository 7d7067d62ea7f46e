"""Veiling glare measured in a known-dark region of the image and removed before eq. 2.

A lens scatters a small fraction of the light it images into a veil over the whole image
(ISO 9358): every pixel of the image circle gains about ``g`` times the mean image
irradiance. Eq. 2 does not remove it: the background capture (no sample) carries only the
veil of the background's own light, while the sample and standard images carry the veils of
their reflections, so a dark part of the BRDF reads high by the veil over the standard's
signal (1-5 % of a glossy sample's mean level in the dim parts of the lobe's image).

Pixels of the image circle that see no sample light at all — blocked by the lens body or
the holder's rim, the same pixels in every image — show the veil alone. :func:`dark_region`
finds them in the standard capture (signal below ``fraction`` of its median over the image
circle), and :func:`glare_offset` measures a capture's veil there: the mean of the capture's
linear signal minus the background's over those pixels (per unit exposure scale, with its
standard error from the pixels' scatter). :func:`gonio.calibration.reduce.reduce_selected`
subtracts the offsets from the sample and standard signals (``glare=``). Without a dark
region (a dome that images every pixel onto the sample) there is nothing to measure and
nothing is removed.

References
----------
ISO 9358:1994, Optics and optical instruments — Veiling glare of image forming systems —
Definitions and methods of measurement (the veiling glare index: the light in the image of a
black patch against a bright field). McCann, J. J. and Rizzi, A. (2007). Veiling glare: the
dynamic range limit of HDR images. Proc. SPIE 6492, 649213.
https://doi.org/10.1117/12.703694
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gonio.calibration.radiometry import SensorModel, exposure_scale
from numpy.typing import NDArray

from gonio.numeric import trim_mean

__all__ = ["GlareOffset", "binned_limits", "dark_region", "glare_offset", "veil", "veil_shape"]

#: fewest dark pixels a glare estimate uses
MIN_DARK_PIXELS = 200

#: how far (pixels) a usable dark pixel lies from the nearest lit one. Measured on the modern
#: instrument (seed 1, rolled brass at 40 deg incidence, no veil): the sample's own mean
#: signal over dark pixels within 1 px of a lit pixel is 6.5 x the veil, within 3 px 2.1 x,
#: between 3 and 5 px 4 % of it, beyond 5 px zero within its noise; with every dark pixel
#: the veil read 7 % high and the corrected fit's alpha_y moved by -0.19 %.
DARK_MARGIN_PX = 6

#: sectors of azimuth per ring of the veil's shape (:func:`veil_shape`)
SHAPE_SECTORS = 16
#: fewest pixels of a ring's sector whose mean enters the ring's median
SHAPE_MIN_PIXELS = 8


def _longest_signal(
    capture: Any, at: NDArray[np.int64] | None = None
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The capture's longest-exposure frame: linear signal per unit exposure scale (flat)
    and where it is unsaturated; with ``at`` (flat indices) at those pixels only (the
    same values: a sample capture's veil is read at the dark pixels alone)."""
    got = capture.__dict__.get("_longest")
    if got is not None:  # cached on the capture (dark region, veils, shape use it)
        return got if at is None else (got[0][at], got[1][at])
    scales = [exposure_scale(m) for m in capture.metas]
    k = int(np.argmax(scales))
    meta = capture.metas[k]
    sensor = SensorModel.from_metadata(meta)
    raw = np.asarray(capture.images[k]).ravel()
    raw = (raw if at is None else raw[at]).astype(np.float64)
    t = float(meta.get("exposure_s", 0.0))
    sig = (raw - sensor.black_level - sensor.dark_current * t / sensor.gain) / scales[k]
    got = (sig, raw < sensor.white_level)
    if at is None:  # (a subset is not kept: the whole frame is what the cache holds)
        capture.__dict__["_longest"] = got
    return got


def dark_region(
    standard: Any,
    background: Any,
    in_field: NDArray[np.bool_],
    *,
    fraction: float = 0.25,
    margin: int = DARK_MARGIN_PX,
    min_pixels: int = MIN_DARK_PIXELS,
) -> NDArray[np.int64] | None:
    """Flat indices of the image-circle pixels that see no standard light, or None.

    Parameters
    ----------
    standard, background : Capture
        The standard and background captures of one incidence.
    in_field : ndarray of bool (H, W)
        The image circle (from the calibrated lens).
    fraction : float
        A pixel is dark when the standard's signal over the background is below this
        fraction of its median over the image circle (the veil is a few per cent of it).
    margin : int
        Dark pixels closer than this (pixels, Euclidean) to a lit one are left out: the
        occluder's edge is blurred by the point-spread function and cut by pixels that
        straddle it, so a bright lobe next to it lights the first few pixels beyond it
        (:data:`DARK_MARGIN_PX`). 0 keeps them.
    min_pixels : int
        Fewest dark pixels an estimate uses (:data:`MIN_DARK_PIXELS`).

    Returns
    -------
    ndarray of int or None
        None when fewer than ``min_pixels`` pixels are dark.

    Notes
    -----
    Both pixel counts are the camera's. For a digitised image (Ward's 108 × 80 from a
    640 × 480 camera, Ward 1992 §3) :func:`binned_limits` converts them: a margin of six
    camera pixels is two digitised ones, and 200 camera pixels' area is six; with the camera's
    figures the margin alone ate the lens body's shadow and on some instruments no dark
    region was left (the veil then went uncorrected).
    """
    if not (0.0 < fraction < 1.0):
        raise ValueError(f"fraction must be in (0, 1), got {fraction!r}")
    if not (isinstance(margin, int | np.integer) and 0 <= margin <= 64):
        raise ValueError(f"margin must be an integer number of pixels in [0, 64], got {margin!r}")
    if not (isinstance(min_pixels, int | np.integer) and min_pixels >= 1):
        raise ValueError(f"min_pixels must be a positive integer, got {min_pixels!r}")
    s, ok_s = _longest_signal(standard)
    b, ok_b = _longest_signal(background)
    field = np.asarray(in_field, dtype=bool).ravel()
    if field.shape != s.shape:
        raise ValueError(f"in_field has {field.size} pixels, the images {s.size}")
    d = s - b
    lit = field & ok_s & ok_b
    if not lit.any():
        return None
    level = float(np.median(d[lit]))
    is_dark = lit & (d < fraction * level)
    if margin > 0 and is_dark.any():  # away from every lit pixel: a dilation by a disk
        import cv2

        shape = np.asarray(in_field).shape
        bright = (field & ~is_dark).reshape(shape).astype(np.uint8)
        y, x = np.mgrid[-margin : margin + 1, -margin : margin + 1]
        disk = (x * x + y * y <= margin * margin).astype(np.uint8)
        is_dark &= cv2.dilate(bright, disk).ravel() == 0
    dark = np.flatnonzero(is_dark)
    return dark if dark.size >= min_pixels else None


#: fewest dark pixels of a digitised image (:func:`binned_limits`): a trimmed mean and its
#: scatter need a few tens
MIN_BINNED_PIXELS = 20


def binned_limits(
    camera_width: int, camera_height: int, width: int, height: int
) -> tuple[int, int]:
    """:func:`dark_region`'s ``margin`` and ``min_pixels`` for an image of ``width × height``
    pixels digitised from a ``camera_width × camera_height`` camera (each pixel the area mean
    of a box of camera pixels; Ward 1992 §3): the camera's :data:`DARK_MARGIN_PX` in digitised
    pixels, plus one for the box that straddles the occluder's edge, and
    :data:`MIN_DARK_PIXELS`' area (at least :data:`MIN_BINNED_PIXELS`). The camera's own
    figures for a full-resolution image.

    Examples
    --------
    >>> binned_limits(640, 480, 640, 480)
    (6, 200)
    >>> binned_limits(640, 480, 108, 80)
    (2, 20)

    References
    ----------
    .. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer
       Graphics (Proc. SIGGRAPH '92) 26(2), 265-272, 1992, §3 (the 108 × 80 images).
    """
    bx, by = camera_width / float(width), camera_height / float(height)
    if not (bx > 1.0 or by > 1.0):
        return DARK_MARGIN_PX, MIN_DARK_PIXELS
    b = max(bx, by)
    margin = math.ceil(DARK_MARGIN_PX / b) + 1
    return margin, max(MIN_BINNED_PIXELS, math.ceil(MIN_DARK_PIXELS / (bx * by)))


@dataclass(frozen=True)
class GlareOffset:
    """A capture's veil: ``value`` per unit exposure scale (ADU s⁻¹ f²), ``sigma`` its
    standard error, ``n`` dark pixels used."""

    value: float
    sigma: float
    n: int


def glare_offset(capture: Any, background: Any, dark: NDArray[np.int64]) -> GlareOffset:
    """The veil of ``capture``: mean signal over the dark pixels above the background's.

    Saturated pixels (in either image) are left out; a dark region without a usable pixel
    gives a zero offset with ``n = 0``.
    """
    idx = np.asarray(dark, dtype=np.int64)
    c, ok_c = _longest_signal(capture, idx)
    b, ok_b = _longest_signal(background, idx)
    use = ok_c & ok_b
    d = (c - b)[use]
    if d.size == 0:
        return GlareOffset(0.0, 0.0, 0)
    # a mean trimmed by 5 % at each end: a dark pixel that the sample does light (a footprint
    # moved by the sample's height) is an outlier, not part of the veil; a median would be
    # biased by the readings' quantisation (the veil is about 1 DN in a frame)
    return GlareOffset(trim_mean(d, 0.05), float(d.std() / math.sqrt(d.size)), int(d.size))


def veil_shape(
    background: Any,
    in_field: NDArray[np.bool_],
    field_angle: NDArray[np.float64],
    rings: int = 48,
    sectors: int = SHAPE_SECTORS,
    *,
    standard: Any = None,
    factor: NDArray[np.float64] | None = None,
    stride: int = 2,
) -> NDArray[np.float64]:
    """The veil's relative distribution over the image (flat, mean 1 over the image circle).

    A veil is spread like the camera's response (the fisheye's relative illumination falls
    towards the edge of the field); the background image — the room's uniform ambient light
    through the dome — shows that response. Each ring of equal field angle is cut into
    ``sectors`` sectors of azimuth about the image circle's centre; the ring's level is the
    median over its sectors of the sector's mean reading. The means are not quantised (a
    median of single readings of a background of a few DN is a staircase of whole DN: on the
    modern instrument it put 8 % steps into the veil), and the median over sectors rejects
    the beam's glow on the dome, which is local in azimuth (a trimmed mean over a ring does
    not: near normal incidence the glow fills much of the central rings, and the inflated
    veil there raised the corrected specular peak of rolled brass by 5 %).

    With ``standard`` (its capture of the same incidence) the response is read from the
    standard's light instead, ``standard − background`` divided by the standard's
    ``factor`` (its certified reflectance factor at each pixel, flat; 1 if not given; NaN
    leaves a pixel out) over the pixels it lights: a uniform radiance hundreds of times the
    background, without the beam's glow (which the background holds, and which near normal
    incidence covers whole central rings: there the background's shape was 5.7 times too
    high and the corrected specular peak of rolled brass 5 % too high). Every
    ``stride``-th usable pixel enters the means (a sector of a ring needs tens of pixels,
    not thousands).
    """
    b, ok = _longest_signal(background)
    mask = np.asarray(in_field, dtype=bool)
    field = mask.ravel()
    th = np.asarray(field_angle, dtype=np.float64).ravel()
    use = field & ok
    # the readings are taken at the usable pixels only (with a certificate every
    # SHAPE_STRIDE-th lit pixel has a factor: an eighth of the image)
    if standard is not None:
        s_sig, ok_s = _longest_signal(standard)
        fac = None if factor is None else np.asarray(factor, dtype=np.float64).ravel()
        if fac is not None:
            use = use & np.isfinite(fac)
        pix = np.flatnonzero(use & ok_s)
        vals = s_sig[pix] - b[pix]
        if fac is not None:
            f = fac[pix]
            vals = vals / np.where(f > 0, f, 1.0)
        if pix.size:  # the lit pixels (not the occluded ones, which hold only the veil)
            lit = vals > 0.25 * float(np.median(vals))
            pix, vals = pix[lit], vals[lit]
    else:
        pix = np.flatnonzero(use)
        vals = b[pix]
    out = np.zeros(b.shape)
    if not pix.size:
        return out
    edges = np.linspace(0.0, float(th[pix].max()) + 1e-9, rings + 1)
    pix, vals = pix[::stride], vals[::stride]
    ring = np.clip(np.searchsorted(edges, th[pix], side="right") - 1, 0, rings - 1)
    v, u = np.divmod(pix, mask.shape[1])
    cv, cu = _centre(mask)
    az = np.arctan2(v - cv, u - cu)
    sector = np.minimum(((az + math.pi) / (2.0 * math.pi) * sectors).astype(np.int64), sectors - 1)
    cell = ring * sectors + sector
    n_cells = rings * sectors
    cnt = np.bincount(cell, minlength=n_cells).reshape(rings, sectors)
    tot = np.bincount(cell, weights=vals, minlength=n_cells).reshape(rings, sectors)
    means = np.where(cnt >= SHAPE_MIN_PIXELS, tot / np.maximum(cnt, 1), np.nan)
    have = np.isfinite(means).any(axis=1)
    n_ring = cnt.sum(axis=1)  # a ring too small for sectors: its plain mean
    med = np.where(n_ring > 0, tot.sum(axis=1) / np.maximum(n_ring, 1), np.nan)
    med[have] = np.nanmedian(means[have], axis=1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    good = np.isfinite(med) & (med > 0)
    if not good.any():
        out[field] = 1.0
        return out
    out[field] = np.interp(th[field], centres[good], med[good])
    return out / float(out[field].mean())


def _centre(mask: NDArray[np.bool_]) -> tuple[float, float]:
    """Mean row and column of the true pixels of ``mask`` (H, W): the sums of whole
    indices are exact, so these are the means of the pixels' indices to the bit."""
    rows, cols = mask.sum(axis=1), mask.sum(axis=0)
    n = int(rows.sum())
    return (float(rows @ np.arange(rows.size)) / n, float(cols @ np.arange(cols.size)) / n)


def veil(offset: GlareOffset, shape: NDArray[np.float64], dark: NDArray[np.int64]) -> NDArray:
    """The per-pixel veil (flat) whose mean over the dark pixels is the measured offset."""
    m = float(shape[np.asarray(dark)].mean())
    return shape * (offset.value / m if m > 0 else 0.0)
