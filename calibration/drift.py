"""The lamp's drift from a re-measured standard.

Eq. 2 divides each sample capture by the standard's capture of the same incidence, taken
minutes earlier in the standard's sweep; a lamp that warms up or drifts in between scales
the sample's BRDF by ``L(t_m)/L(t_s)``. The laboratory re-measures the standard during the
sample sweeps (:attr:`gonio.campaign.plan.Plan.restandard_every`): the ratio
:func:`standard_ratio` of the standard captured again at ``t_k`` to its first capture at
``t_s,k`` is the lamp's change ``L(t_k)/L(t_s,k)``, and :func:`drift_gain` interpolates
those ratios linearly in time (constant beyond the first and last) to each sample capture's
time stamp. Eq. 2's result is divided by the gain. What remains is the lamp's change across
the standard's own sweep and between the re-measurements (budgeted from the lamp model at
the specification's magnitudes) and the scatter of each ratio: the iris setting and the
lamp's flicker of its frames, in the re-measured and in the first capture.

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics (Proc.
SIGGRAPH '92), 26(2), 265-272. https://doi.org/10.1145/142920.134078, §3.2 (eq. 2: the
sample's image over the standard's, taken under the same source).
JCGM 100:2008, Evaluation of measurement data — Guide to the expression of uncertainty in
measurement (GUM), §3.2.4 (a recognised systematic effect corrected, the correction's
uncertainty kept).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["drift_gain", "standard_ratio"]


def standard_ratio(again: Any, first: Any, background: Any, *, fraction: float = 0.25) -> float:
    """``L(t_k)/L(t_s)``: the standard captured again over its first capture (both minus the
    background, per unit exposure scale, summed over the pixels it lights — signal above
    ``fraction`` of its median — and unsaturated in both), the mean over the brackets'
    frames of equal exposure scale (each frame's iris setting scatters on its own: with
    the modern instrument's 0.3 % a single frame's ratio is 0.4 % off).

    Parameters
    ----------
    again, first, background : Capture
        The re-measured and the first standard capture of one incidence and its background.
    fraction : float
        In (0, 1).
    """
    if not (0.0 < fraction < 1.0):
        raise ValueError(f"fraction must be in (0, 1), got {fraction!r}")
    sa, sf, sb = (_frame_signals(c) for c in (again, first, background))
    ratios = []
    for (a, ok_a, ka), (f, ok_f, kf) in zip(sa, sf):
        b, ok_b, _ = min(sb, key=lambda x: abs(math.log(x[2] / kf)))
        if not (a.shape == f.shape == b.shape):
            raise ValueError(f"the captures' images differ in size: {a.shape}, {f.shape}")
        if abs(math.log(ka / kf)) > 1e-6:
            continue
        d_f, d_a = f - b, a - b
        ok = ok_a & ok_f & ok_b
        if not ok.any():
            continue
        lit = ok & (d_f > fraction * float(np.median(d_f[ok])))
        den = float(d_f[lit].sum())
        if lit.sum() >= 100 and den > 0:
            ratios.append(float(d_a[lit].sum()) / den)
    if not ratios:
        raise ValueError(
            "the two standard captures share no frame of equal exposure with 100 lit, "
            "unsaturated pixels"
        )
    return float(np.mean(ratios))


def _frame_signals(capture: Any) -> list[tuple[NDArray, NDArray, float]]:
    """Per frame: the linear signal per unit exposure scale (flat), where it is neither
    saturated nor at the floor, and the exposure scale."""
    from gonio.calibration.radiometry import SensorModel, exposure_scale

    out = []
    for img, meta in zip(capture.images, capture.metas):
        sensor = SensorModel.from_metadata(meta)
        raw = np.asarray(img, dtype=np.float64).ravel()
        k = exposure_scale(meta)
        t = float(meta.get("exposure_s", 0.0))
        sig = (raw - sensor.black_level - sensor.dark_current * t / sensor.gain) / k
        out.append((sig, (raw < sensor.white_level) & (raw > 0), k))
    return out


def drift_gain(
    t: ArrayLike, t_anchor: Sequence[float], ratio: Sequence[float]
) -> NDArray[np.float64]:
    """The lamp's change at times ``t``: the anchors' ratios interpolated linearly in time
    (constant before the first and after the last anchor)."""
    ta = np.asarray(t_anchor, dtype=np.float64)
    ra = np.asarray(ratio, dtype=np.float64)
    if ta.ndim != 1 or ta.shape != ra.shape or ta.size == 0:
        raise ValueError(f"t_anchor and ratio must be equal-length 1-D, got {ta.shape}, {ra.shape}")
    if not (np.all(np.isfinite(ra)) and np.all(ra > 0)):
        raise ValueError(f"ratio must be finite and > 0, got {ra.tolist()}")
    order = np.argsort(ta, kind="stable")
    return np.interp(np.asarray(t, dtype=np.float64), ta[order], ra[order])
