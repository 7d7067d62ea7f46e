"""Exposure planning of the LBL instrument: which f-stops of a ladder a bracket needs to
cover a scene's dynamic range.

This part knows a rendered scene (:class:`~gonio.simulator.lbl_scene.Scene`, the light at
f/1), the sensor's full well and gain, and — for a scene with a mirror component — how a
frame composes it (:meth:`gonio.simulator.lbl_frame.Frames.compose`) and the dark map; not
the optics or the sample.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3: "two or more f-stops may be used to capture the full dynamic range".
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from gonio.simulator.lbl_scene import Scene
from gonio.simulator.lenses import _pos_finite as _check_positive
from gonio.simulator.sensor import Sensor
from numpy.typing import NDArray

__all__ = ["F_STOPS", "plan_stops"]

#: default f-stop ladder for bracketing (darkest first)
F_STOPS = (32.0, 22.0, 16.0, 11.0, 8.0, 5.6, 4.0, 2.8, 2.0)


def plan_stops(
    sc: Scene,
    f_stops: Sequence[float],
    min_signal_dn: float,
    headroom: float,
    skip_stops: bool,
    sensor: Sensor,
    compose: Callable[[Scene, float], NDArray],
    dark: Callable[[], NDArray],
) -> dict[str, Any]:
    """:meth:`~gonio.simulator.lbl.LBLInstrument.plan_bracket` on a rendered scene
    (electrons at f/1, rendered once); ``compose(sc, 1.0)`` and ``dark()`` are asked only
    for a scene with a mirror component."""
    stops = sorted({_check_positive(f, "f_stops") for f in f_stops}, reverse=True)
    if not stops:
        raise ValueError("f_stops must not be empty")
    if len(stops) > 62:
        raise ValueError(f"f_stops: at most 62 stops, got {len(stops)}")
    sat_e = headroom * sensor.full_well
    min_e = min_signal_dn * sensor.gain
    inv_n2 = np.array([1.0 / n**2 for n in stops], dtype=np.float64)
    masks, lead = _usability(sc, inv_n2, sat_e, min_e, compose, dark)
    n_lit = int(masks.size)
    # distinct usability patterns and how many lit pixels have each
    if len(stops) <= 16:
        cnt = np.bincount(masks, minlength=1)
        pats = np.flatnonzero(cnt)
        cnt = cnt[pats]
    else:
        pats, cnt = np.unique(masks, return_counts=True)
    pats = [int(x) for x in pats]
    cnt = [int(x) for x in cnt]
    # the widest stop before the first that saturates a lit pixel
    first = lead - 1 if lead > 0 else None
    peak_saturated = first is None
    start = 0 if first is None else first
    kept: list[float] = []
    skipped: list[float] = []
    kbits = 0  # bits of the kept stops: a pixel is covered when pattern & kbits != 0
    for i in range(start, len(stops)):
        bit = 1 << i
        new = any(p & bit and not p & kbits for p in pats)
        if new or not kept or not skip_stops:
            kept.append(stops[i])
            kbits |= bit
        else:
            skipped.append(stops[i])
        if skip_stops and n_lit and all(p & kbits for p in pats):
            break
    covered = sum(c for p, c in zip(pats, cnt) if p & kbits)
    return {
        "f_numbers": kept,
        "skipped": skipped,
        "covered_fraction": covered / n_lit if n_lit else 1.0,
        "peak_saturated": peak_saturated,
        "n_lit": n_lit,
        "exposure_s": sc.exposure,
    }


def _usability(sc, inv_n2, sat_e, min_e, compose, dark) -> tuple[NDArray[np.int64], int]:
    """Each lit pixel's usability pattern (bit ``i``: unsaturated and at least ``min_e``
    above the background at stop ``i``) and the lead: 1 + the first stop that saturates a
    lit pixel (0: none does), from one compiled pass."""
    from gonio.simulator import _kernels

    exposure = sc.exposure
    lead = np.zeros(1, dtype=np.int64)
    # all signal lies on candidate pixels (and the mirror component's pixels)
    if sc.delta is None:
        masks = np.empty(sc.idx.size, dtype=np.int64)
        k = sc.k0 * exposure
        n_lit = _kernels.plan_scene(
            sc.bg, sc.dark, exposure, sc.idx, sc.rc, sc.lit, sc.g, sc.isq, k * sc.kd0,
            k * sc.ks0, inv_n2, sat_e, min_e, masks, lead,
        )  # fmt: skip
    else:
        cp = np.unique(np.concatenate([sc.idx, sc.delta[0]]))
        e1 = compose(sc, 1.0)[cp]  # electrons at f/1: sample + background + dark
        dk = dark()[cp] * exposure
        sig = e1 - (sc.bg[cp] * exposure + dk)  # signal at f/1 (dark is not scaled by N)
        lit = sig > 0.0
        a, d, sig = e1[lit] - dk[lit], dk[lit], sig[lit]
        n_lit = int(a.size)
        masks = np.empty(max(n_lit, 1), dtype=np.int64)
        _kernels.plan_masks(a, d, sig, inv_n2, sat_e, min_e, masks, lead)
    return masks[:n_lit], int(lead[0])
