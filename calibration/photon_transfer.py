"""The sensor's saturation level from the laboratory's own photon-transfer captures.

A side-car states the camera's nominal saturation (``saturation_dn``: black level plus the
full well over the gain), and a reduction that trusts it treats a pixel as usable while its
reading is below that value. A real sensor clips the *charge* at the full well and adds the
read noise and the pixel's own offset after the clip, so a saturated pixel reads the clip
level with a spread of about the read noise and the offset non-uniformity on either side of
it: with the realistic sensor about half of the charge-clipped readings lie below the
nominal value and pass as valid, reading the full well instead of their signal.

The laboratory measures the level where its pixels clip, as the EMVA 1288 standard's
photon-transfer set-up does (the sensor lit by an integrating sphere, R4.0 §6.1, and a dark
frame, §6.5, the saturation point of §6.4): a flat field far past the full well clips
every pixel, and the spread of those readings over the array is what a clipped reading can
be. :func:`saturation_level` puts the threshold ``z`` robust standard deviations below
their median (``z = 5``: ``Φ(−z)`` = 3·10⁻⁷ for a normal spread), and no higher than their
:data:`SATURATION_QUANTILE` quantile (the spread has tails: the realistic sensor's row and
column offsets and hot pixels put 0.2 % of the clipped readings more than 5 robust
deviations low); a genuine reading above it is within a few DN of the full well and is
lost, not misread. Measured on the realistic sensor (``Sensor.realistic()``, modern
instrument, seed 1): of a second saturated flat's readings 27 % lie below the side-car's
``saturation_dn`` (4064 DN), 0.007 % below the measured threshold (4040 DN).

References
----------
EMVA Standard 1288, Release 4.0 Linear (2021). Standard for Characterization of Image
Sensors and Cameras. European Machine Vision Association, §2 (the linear sensor model and
its saturation), §6.1 (the light source), §6.4 (saturation capacity), §6.5 (dark
measurements).
Janesick, J. R. (2007). Photon Transfer, DN → λ. SPIE Press, Bellingham, WA,
doi:10.1117/3.725073, ch. 9 (full well and the photon-transfer curve at saturation).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["SATURATION_QUANTILE", "SATURATION_Z", "saturation_level"]

#: robust standard deviations of the clipped readings between their median and the threshold
SATURATION_Z = 5.0
#: the threshold is at most this quantile of the clipped readings
SATURATION_QUANTILE = 1e-4


def saturation_level(
    flat: ArrayLike,
    flat_meta: Mapping[str, Any],
    dark: ArrayLike | None = None,
    *,
    z: float = SATURATION_Z,
) -> dict[str, Any]:
    """The saturation threshold of a sensor from a flat field past its full well.

    Parameters
    ----------
    flat : array (H, W)
        Raw DN of a flat-field capture lit far past the full well (every pixel clipped).
    flat_meta : mapping
        Its side-car (``photons_per_pixel``, ``exposure_s``, ``binning``).
    dark : array (H, W), optional
        A dark frame of the same sensor (the clip level above it is reported as the full
        well in DN).
    z : float
        The threshold lies ``z`` robust standard deviations (1.4826 × the median absolute
        deviation) below the median clipped reading, or lower at the
        :data:`SATURATION_QUANTILE` quantile of the readings; > 0.

    Returns
    -------
    dict
        ``saturation_dn`` (readings at or above it are saturated), ``clip_median_dn``,
        ``clip_sd_dn``, ``full_well_dn`` (with ``dark``), ``binning`` (of the flat; the
        threshold holds for frames read out the same way) and ``z``.
    """
    if not (math.isfinite(float(z)) and float(z) > 0):
        raise ValueError(f"z must be a finite positive number of deviations, got {z!r}")
    raw = np.asarray(flat, dtype=np.float64)
    if raw.ndim != 2 or raw.size < 100:
        raise ValueError(f"flat must be a 2-D image of at least 100 pixels, got shape {raw.shape}")
    med = float(np.median(raw))
    sd = 1.4826 * float(np.median(np.abs(raw - med)))
    out: dict[str, Any] = {
        "saturation_dn": min(med - float(z) * sd, float(np.quantile(raw, SATURATION_QUANTILE))),
        "clip_median_dn": med,
        "clip_sd_dn": sd,
        "z": float(z),
        "binning": flat_meta.get("binning"),
        "photons_per_pixel": float(flat_meta.get("photons_per_pixel", 0.0)),
    }
    if dark is not None:
        d = np.asarray(dark, dtype=np.float64)
        if d.shape != raw.shape:
            raise ValueError(f"dark has shape {d.shape}, the flat {raw.shape}")
        level = float(np.median(d))
        if not out["saturation_dn"] > level:
            raise ValueError(
                f"the flat's readings (median {med:g} DN) are not above the dark frame's "
                f"({level:g} DN): it is no saturated flat field"
            )
        out["full_well_dn"] = med - level
    return out
