"""Exposure ratios of an f-stop bracket from the frames' overlaps.

A bracket's frames are merged by dividing each by its exposure scale ``t / N²``
(:func:`gonio.calibration.radiometry.exposure_scale`) with the *marked* f-number ``N``. Real
lenses are marked with rounded values of the series ``√2^k`` (f/11 is f/11.31, f/5.6 is
f/5.66, f/22 is f/22.6) and their irises do not return to exactly the same opening twice, so
the marked ratios are wrong by a few per cent. Ward noticed the way out: "there is often
redundant information where the useful ranges of exposures overlap" — a pixel usable in two
frames measures their true exposure ratio.

:func:`overlap_ratios` measures the ratio of every pair of consecutive frames of a capture
(the ratio of the signal sums over the pixels usable in both, with its standard error from
the pixels' scatter); :func:`calibrate_fstops` combines all overlaps of a campaign by least
squares into one relative exposure per marked stop (:class:`FStopCalibration`, the stop most
often used fixed at its marked value) and estimates the iris repeatability from the
residual scatter; :func:`correct_capture` rewrites a capture's side-cars with effective
f-numbers: each frame's ratio to the capture's other frames is its measured one, and the
capture as a whole is placed on the table (least squares over its frames), so what is left
is the mean of the capture's own iris errors (standard uncertainty ``σ_iris / √m`` for ``m``
frames, :meth:`FStopCalibration.capture_uncertainty`).

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics (Proc.
SIGGRAPH '92), 26(2), 265-272. https://doi.org/10.1145/142920.134078, §3.2 ("two or more
f-stops may be used to capture the full dynamic range ... redundant information where the
useful ranges of exposures overlap").
ISO 517:2008, Photography — Apertures and related properties pertaining to photographic
lenses — Designations and measurements (the marked f-number series and its tolerances).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gonio.calibration.radiometry import SensorModel, exposure_scale

__all__ = [
    "FStopCalibration",
    "Overlap",
    "calibrate_fstops",
    "correct_capture",
    "overlap_ratios",
]


@dataclass(frozen=True)
class Overlap:
    """The measured exposure ratio of two frames of one capture.

    ``log_ratio`` is ``ln(scale_b / scale_a)`` measured (frames ``a``, ``b`` by index in the
    capture, ``b`` the longer exposure), ``u`` its standard uncertainty, ``n`` the pixels
    usable in both, ``stop_a``/``stop_b`` the marked f-numbers, ``nominal`` the marked
    ``ln(scale_b / scale_a)``.
    """

    a: int
    b: int
    stop_a: float
    stop_b: float
    log_ratio: float
    u: float
    n: int
    nominal: float


def _signal(img: Any, meta: Mapping[str, Any], sensor: SensorModel, idx: np.ndarray):
    raw = np.asarray(img).ravel()[idx].astype(np.float64)
    t = float(meta.get("exposure_s", 0.0))
    return raw, raw - sensor.black_level - sensor.dark_current * t / sensor.gain


def overlap_ratios(
    capture: Any,
    *,
    min_signal_dn: float = 200.0,
    headroom: float = 0.85,
    stride: int = 3,
    min_pixels: int = 50,
) -> list[Overlap]:
    """Measured exposure ratios of consecutive frames of a capture's bracket.

    Parameters
    ----------
    capture : Capture
        Its frames (the same scene at several f-numbers or exposure times).
    min_signal_dn : float
        A pixel is usable in a frame when its signal is at least this many DN above black
        (keeps the ratio's noise and the ADC's rounding small) ...
    headroom : float
        ... and its raw value below ``headroom`` times the white level (away from
        saturation and any non-linearity before it).
    stride : int
        Every ``stride``-th pixel is used (the ratio needs thousands of pixels, not all).
    min_pixels : int
        Pairs with fewer usable pixels are not reported.

    Returns
    -------
    list of Overlap
    """
    if not (isinstance(stride, int) and stride >= 1):
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    if not (0.0 < headroom <= 1.0):
        raise ValueError(f"headroom must be in (0, 1], got {headroom!r}")
    if not (math.isfinite(min_signal_dn) and min_signal_dn > 0):
        raise ValueError(f"min_signal_dn must be > 0, got {min_signal_dn!r}")
    frames = capture.frames
    if len(frames) < 2:
        return []
    scales = [exposure_scale(m) for _, m in frames]
    order = np.argsort(scales)
    n_pix = np.asarray(frames[0][0]).size
    idx = np.arange(0, n_pix, stride)
    sensor = SensorModel.from_metadata(frames[0][1])
    top = headroom * sensor.white_level
    out = []
    prev = None
    for k in order:
        raw, sig = _signal(frames[k][0], frames[k][1], sensor, idx)
        cur = (int(k), raw, sig)
        if prev is not None:
            a, raw_a, sig_a = prev
            b, raw_b, sig_b = cur
            use = (
                (sig_a >= min_signal_dn) & (raw_a < top) & (sig_b >= min_signal_dn) & (raw_b < top)
            )
            n = int(np.count_nonzero(use))
            if n >= min_pixels:
                sa, sb = sig_a[use], sig_b[use]
                ratio = float(sb.sum() / sa.sum())
                lr = np.log(sb / sa)
                u = float(np.std(lr) / math.sqrt(n))
                out.append(
                    Overlap(a, b, _stop(frames[a][1]), _stop(frames[b][1]), math.log(ratio),
                            u, n, math.log(scales[b] / scales[a]))
                )  # fmt: skip
        prev = cur
    return out


def _stop(meta: Mapping[str, Any]) -> float:
    return float(meta.get("f_number", 1.0))


@dataclass
class FStopCalibration:
    """Relative exposure of each marked stop, from a campaign's overlaps.

    Attributes
    ----------
    log_gain : dict
        Marked f-number -> ``ln`` of (true exposure scale / marked exposure scale) relative
        to the reference stop (0 there).
    u_log_gain : dict
        Their standard uncertainties (the reference stop's is 0 by definition).
    reference : float
        The stop held at its marked value.
    sigma_iris : float
        Iris repeatability: standard deviation of one frame's ``ln`` exposure about its
        stop's value, from the fit's residuals (0 when it cannot be estimated).
    n_overlaps : int
    """

    log_gain: dict[float, float]
    u_log_gain: dict[float, float]
    reference: float
    sigma_iris: float
    n_overlaps: int
    residual_rms: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    def effective_f_number(self, marked: float) -> float:
        """The f-number whose ``1/N²`` is the stop's true relative exposure."""
        g = self.log_gain.get(float(marked), 0.0)
        return float(marked) * math.exp(-0.5 * g)

    def capture_uncertainty(self, n_frames: int) -> float:
        """Standard uncertainty of a corrected capture's exposure scale (relative)."""
        return self.sigma_iris / math.sqrt(max(int(n_frames), 1))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> FStopCalibration:
        """Inverse of :meth:`to_dict`."""
        return cls(
            {float(k): float(v) for k, v in d["log_gain"].items()},
            {float(k): float(v) for k, v in d["u_log_gain"].items()},
            float(d["reference_stop"]),
            float(d["sigma_iris"]),
            int(d["n_overlaps"]),
            float(d.get("residual_rms", 0.0)),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (stops as strings)."""
        return {
            "reference_stop": self.reference,
            "log_gain": {f"{k:g}": v for k, v in sorted(self.log_gain.items())},
            "u_log_gain": {f"{k:g}": v for k, v in sorted(self.u_log_gain.items())},
            "effective_f_number": {
                f"{k:g}": self.effective_f_number(k) for k in sorted(self.log_gain)
            },
            "sigma_iris": self.sigma_iris,
            "n_overlaps": self.n_overlaps,
            "residual_rms": self.residual_rms,
        }


def calibrate_fstops(
    overlaps: Iterable[Overlap], reference: float | None = None
) -> FStopCalibration:
    """Least-squares relative exposure of every marked stop from measured overlaps.

    Each overlap says ``ln r_ab − nominal_ab = g(stop_b) − g(stop_a) + e_b − e_a`` with
    ``g`` the stop's log gain and ``e`` each frame's iris error. Solved with ``g`` of the
    reference stop (default: the stop in most overlaps) fixed at 0, every overlap weighted
    equally (the iris errors, not the pixel noise, dominate); ``σ_iris`` is then
    ``rms(residual) / √2 · √(n / (n − n_g))``.

    Returns
    -------
    FStopCalibration
        Empty (every gain 0) without overlaps.
    """
    ov = list(overlaps)
    stops = sorted({o.stop_a for o in ov} | {o.stop_b for o in ov})
    if not ov:
        return FStopCalibration({}, {}, float(reference or 0.0), 0.0, 0)
    count = {s: 0 for s in stops}
    for o in ov:
        count[o.stop_a] += 1
        count[o.stop_b] += 1
    ref = float(reference) if reference is not None else max(stops, key=lambda s: (count[s], -s))
    if ref not in count:
        raise ValueError(f"reference stop f/{ref:g} is in no overlap; stops seen: {stops}")
    unknown = [s for s in stops if s != ref]
    col = {s: j for j, s in enumerate(unknown)}
    A = np.zeros((len(ov), len(unknown)))
    b = np.array([o.log_ratio - o.nominal for o in ov])
    for i, o in enumerate(ov):
        if o.stop_b in col:
            A[i, col[o.stop_b]] += 1.0
        if o.stop_a in col:
            A[i, col[o.stop_a]] -= 1.0
    g, *_ = np.linalg.lstsq(A, b, rcond=None) if unknown else (np.zeros(0),)
    res = b - A @ g if unknown else b
    dof = len(ov) - np.linalg.matrix_rank(A) if unknown else len(ov)
    rms = float(np.sqrt(np.mean(res**2)))
    s_pair = float(np.sqrt(np.sum(res**2) / dof)) if dof > 0 else 0.0
    stat = float(np.sqrt(np.mean([o.u**2 for o in ov])))
    sigma_iris = math.sqrt(max(s_pair**2 - stat**2, 0.0) / 2.0)
    log_gain = {ref: 0.0}
    u_gain = {ref: 0.0}
    if unknown:
        cov = np.linalg.pinv(A.T @ A) * max(s_pair**2, stat**2)
        for s, j in col.items():
            log_gain[s] = float(g[j])
            u_gain[s] = float(math.sqrt(max(cov[j, j], 0.0)))
    return FStopCalibration(log_gain, u_gain, ref, sigma_iris, len(ov), rms)


def correct_capture(capture: Any, cal: FStopCalibration, overlaps: list[Overlap] | None = None):
    """A copy of ``capture`` whose side-cars carry effective f-numbers.

    Each frame's log exposure is its stop's table value; with the capture's own
    ``overlaps`` (:func:`overlap_ratios`) the frames' ratios to each other are the measured
    ones instead, and the capture is placed on the table by the mean over its frames. The
    marked value stays in ``f_number_marked``. A single-frame capture takes the table value.
    """
    from gonio.calibration.reduce import Capture

    metas = [dict(m) for m in capture.metas]
    n = len(metas)
    table = np.array([cal.log_gain.get(_stop(m), 0.0) for m in metas])
    scales = np.array([exposure_scale(m) for m in metas])
    logs = np.log(scales) + table
    if overlaps:
        # measured chain: ln s_b − ln s_a = log_ratio; anchor by the mean over the frames
        chain = np.full(n, np.nan)
        first = overlaps[0].a
        chain[first] = 0.0
        for o in overlaps:
            if math.isfinite(chain[o.a]):
                chain[o.b] = chain[o.a] + o.log_ratio
        have = np.isfinite(chain)
        off = float(np.mean(logs[have] - chain[have]))
        logs = np.where(have, chain + off, logs)
    for m, s0, lg in zip(metas, scales, logs):
        marked = _stop(m)
        m.setdefault("f_number_marked", marked)
        # exposure_scale = t / N²: keep t, move the change into N
        m["f_number"] = marked * math.exp(-0.5 * (lg - math.log(s0)))
    return Capture(list(zip(capture.images, metas)), capture.darks)
