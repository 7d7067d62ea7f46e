"""The campaign's reduction as a laboratory makes it: calibrated, corrected, truth-free.

:func:`laboratory_view` is the boundary between the simulated instrument and the
laboratory: it keeps of each side-car only the fields a real instrument writes (exposure,
marked f-number, the camera's read-out parameters, the commanded incidence and rotation, the
campaign clock) and drops the simulator's description of itself (its true lens, mirror,
source, sample BRDF, effect magnitudes). :func:`reduce_incidence` reduces one incidence's
captures with the laboratory's calibration
(:class:`~gonio.calibration.laboratory.LabCalibration`) and the corrections of
:data:`CORRECTIONS`, each of which can be switched off (ablation):

``geometry``
    the calibrated lens and dome geometry instead of the nominal design;
``standard``
    eq. 2 with the standard's certified BRDF instead of a Lambertian one;
``exposure``
    effective f-numbers from the f-stop ladder and each bracket's own overlaps instead of
    the marked ones;
``glare``
    the veil measured in the image's known-dark region subtracted from the sample's and the
    standard's signals;
``drift``
    the lamp's drift from the standard re-measured during the sample sweeps
    (:attr:`gonio.campaign.plan.Plan.restandard_every`, :mod:`gonio.calibration.drift`):
    each sample capture divided by the lamp's change since its standard's capture
    (:func:`correct_drift`); without re-measurements there is nothing to correct;
``saturation``
    the saturation threshold measured on the laboratory's own saturated flat field
    (:mod:`gonio.calibration.photon_transfer`) instead of the side-car's nominal
    ``saturation_dn``, below which half of the realistic sensor's charge-clipped readings
    lie; in a digitised frame also the pixels that may hold a clipped camera pixel
    (:func:`digitised_clipping`).

:func:`campaign_budget` then builds the fit's uncertainty budget from the same knowledge
(:mod:`gonio.campaign.budget`, :mod:`gonio.campaign.budget_terms`); the
:class:`CampaignBudget` it returns keeps its inputs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from gonio.campaign.budget import Budget, Perturbation

__all__ = [
    "CORRECTIONS",
    "SENSOR_FIELDS",
    "SIDECAR_FIELDS",
    "CampaignBudget",
    "budget_fields",
    "campaign_budget",
    "check_corrections",
    "correct_drift",
    "field_angle",
    "laboratory_view",
    "reduce_incidence",
]

#: the corrections a laboratory applies (each ablatable)
CORRECTIONS = ("geometry", "standard", "exposure", "glare", "saturation", "drift")

#: side-car fields a real instrument writes (everything else is the simulator's truth):
#: the exposure and the marked f-number, the commanded incidence and rotation, the campaign
#: clock, the nominal optics (``lens``, ``mirror``: the design, which the simulator's
#: side-car records instead of its imperfect instrument) and the standard's certified ρ
SIDECAR_FIELDS = frozenset({
    "exposure_s", "f_number", "theta_i", "phi_i", "sample_rotation", "sample", "seed",
    "noise", "binning", "band", "shape", "dtype", "units", "frame", "instrument", "bracket",
    "filter_nm", "filter_index", "time_s", "clock_s", "rho_standard", "lens", "mirror",
})  # fmt: skip

#: the camera's read-out parameters a side-car carries (data sheet / EMVA 1288 figures)
SENSOR_FIELDS = frozenset({
    "gain_e_per_dn", "read_noise_e", "black_level_dn", "saturation_dn", "adc_bits", "max_dn",
    "response_gamma", "dark_current_e_s", "pixel_pitch_m",
})  # fmt: skip


def check_corrections(corrections: Iterable[str] | None) -> tuple[str, ...]:
    """The corrections as a tuple (None: all of :data:`CORRECTIONS`); unknown ones raise."""
    if corrections is None:
        return CORRECTIONS
    got = tuple(dict.fromkeys(str(c) for c in corrections))
    bad = sorted(set(got) - set(CORRECTIONS))
    if bad:
        raise ValueError(f"corrections {bad} are unknown; expected some of {list(CORRECTIONS)}")
    return got


def laboratory_view(
    frames: Sequence[tuple[Any, Mapping[str, Any]]], sensor: Mapping[str, Any] | None = None
) -> list[tuple[Any, dict]]:
    """The frames with side-cars cut down to what a real instrument records.

    ``sensor``: the laboratory's photon-transfer record
    (:func:`gonio.calibration.photon_transfer.saturation_level`); its ``saturation_dn``
    replaces the side-car's in frames read out as its flat field was (same binning).
    """
    out = []
    for img, meta in frames:  # only the kept fields are read (a test guards the others)
        m = {k: meta[k] for k in meta if k in SIDECAR_FIELDS}
        if "sensor" in meta and isinstance(meta["sensor"], Mapping):
            s = meta["sensor"]
            m["sensor"] = {k: s[k] for k in s if k in SENSOR_FIELDS}
            if sensor is not None and _same_binning(meta.get("binning"), sensor.get("binning")):
                m["sensor"]["saturation_dn"] = float(sensor["saturation_dn"])
            if sensor is not None and not _same_binning(meta.get("binning"), None):
                img = digitised_clipping(img, m["sensor"].get("saturation_dn"))
        out.append((img, m))
    return out


#: a digitised pixel (the mean of a box of camera pixels: Ward's 108 x 80 from 640 x 480,
#: Ward 1992 §3) above this fraction of the saturation level, on a slope of more than
#: :data:`DIGITISED_SLOPE` across its 3 x 3 neighbourhood, may hold a clipped camera pixel
#: and is treated as saturated. A flat field saturates a whole box at once; a lobe's peak
#: does not, and its box reads below the top code. Measured on a ward1992 instrument (seed
#: 0, rolled brass, 21 θi x 3 rotations, every effect off): 986 digitised pixels held a
#: clipped camera pixel, at 0.08-0.99 of the top code (10th percentile 0.64, median 0.94),
#: none next to a pixel at the top code; taken as they read, they moved rho_s by -0.9 % and
#: alpha_y by +0.5 %
DIGITISED_USABLE = 0.6
#: the relative range (max - min over 3 x 3, over the pixel's reading) above which a
#: digitised pixel is on a slope (the standard's smooth image stays below it)
DIGITISED_SLOPE = 0.1


def digitised_clipping(img: Any, saturation_dn: float | None) -> Any:
    """``img`` (a digitised frame) with every pixel that may hold a clipped camera pixel
    (:data:`DIGITISED_USABLE`, :data:`DIGITISED_SLOPE`) set to ``saturation_dn``, so that the
    merge leaves it out of this exposure; unchanged without a saturation level."""
    if saturation_dn is None or not np.isfinite(saturation_dn) or saturation_dn <= 0:
        return img
    import cv2

    a = np.asarray(img, dtype=np.float32)
    if a.ndim != 2:
        return img
    high = a > DIGITISED_USABLE * float(saturation_dn)
    if not high.any():
        return img
    k = np.ones((3, 3), np.uint8)
    spread = cv2.dilate(a, k) - cv2.erode(a, k)
    suspect = high & (spread > DIGITISED_SLOPE * a)
    if not suspect.any():
        return img
    out = np.array(img, copy=True)
    out[suspect] = min(float(saturation_dn), float(np.iinfo(out.dtype).max)
                       if out.dtype.kind in "ui" else float(saturation_dn))  # fmt: skip
    return out


def _same_binning(a: Any, b: Any) -> bool:
    def norm(x: Any) -> Any:
        return None if not x or tuple(x) == (0, 0) else tuple(int(v) for v in x)

    return norm(a) == norm(b)


def _fstop_corrected(cap: Any, cal: Any) -> tuple[Any, int]:
    from gonio.calibration.fstops import correct_capture, overlap_ratios

    if cal is None:
        return cap, len(cap.frames)
    ov = overlap_ratios(cap) if len(cap.frames) > 1 else []
    return correct_capture(cap, cal, ov), len(cap.frames)


def reduce_incidence(
    standard: Sequence[Any],
    background: Sequence[Any],
    measured: Mapping[float, Sequence[Any]],
    cal: Any,
    *,
    nominal: Mapping[str, Any] | None = None,
    corrections: Iterable[str] | None = None,
    seeds: Mapping[float, int] | None = None,
    debias: bool = False,
    select: Mapping[str, Any] | None = None,
    restandard: Mapping[float, Sequence[Any]] | None = None,
) -> list[tuple[Any, dict[str, Any]]]:
    """Reduce one incidence: the standard, background and sample brackets (frames) of each
    sample rotation -> one :class:`~gonio.samples.BRDFSamples` per rotation with what the
    budget needs to know of it (frames used, the veil measured).

    Parameters
    ----------
    standard, background : sequence of (image, side-car)
    measured : mapping
        Sample rotation (degrees) -> its frames.
    cal : LabCalibration or None
        None: no calibration (the nominal design is used).
    nominal : mapping, optional
        The instrument's design: ``lens`` (a lens dict or FisheyeLens) and ``mirror`` (a
        mirror dict); used where a correction is off or ``cal`` lacks the knowledge.
        Default: the nominal optics the standard's side-car records.
    corrections : iterable of str, optional
        Of :data:`CORRECTIONS` (default all); those whose knowledge ``cal`` lacks are skipped.
    seeds : mapping, optional
        Rotation -> the selection's seed.
    debias : bool
        Eq. 2's second-order debias.
    select : mapping, optional
        ``reduce_selected``'s thinning options.
    restandard : mapping, optional
        Sample rotation -> the standard's frames captured again after that rotation's
        capture: the lamp's ratio to the first standard capture goes into the rotation's
        info (``restandard``) for :func:`correct_drift`.
    """
    from gonio.calibration.glare import (
        binned_limits,
        dark_region,
        glare_offset,
        veil,
        veil_shape,
    )
    from gonio.calibration.reduce import Capture, load_lens, pixel_geometry, reduce_selected

    corr = set(check_corrections(corrections))
    sat = cal.sensor if cal is not None and "saturation" in corr else None
    std = Capture(laboratory_view(standard, sat))
    bg = Capture(laboratory_view(background, sat))
    opts: dict[str, Any] = dict(select or {})
    if nominal is None:
        nominal = {"lens": std.meta.get("lens"), "mirror": std.meta.get("mirror")}
    opts["lens"], opts["mirror"] = nominal["lens"], nominal["mirror"]
    if cal is not None and "geometry" in corr:
        geo = cal.reduction_options()
        opts.update({k: geo[k] for k in ("lens", "mirror", "method") if k in geo})
    if cal is not None and "standard" in corr and cal.certificate is not None:
        opts["certificate"] = cal.certificate
    fst = cal.fstops if cal is not None and "exposure" in corr else None
    std, n_std = _fstop_corrected(std, fst)
    bg, _ = _fstop_corrected(bg, fst)  # the background too: eq. 2 and the veil subtract it
    dark = None
    if "glare" in corr and cal is not None:
        h, w = np.asarray(std.images[0]).shape
        cam = load_lens(opts["lens"])  # the camera's pixels (a digitiser averages boxes)
        lens = load_lens(cam, w, h)
        _, gvalid = pixel_geometry(lens, opts["mirror"], opts.get("method", "eq3"))
        margin, least = binned_limits(cam.width, cam.height, w, h)
        dark = dark_region(std, bg, gvalid, margin=margin, min_pixels=least)
    g_s = None
    if dark is not None:
        fac = None
        if "certificate" in opts:  # the standard's certified factor at each pixel
            wo_dome, _ = pixel_geometry(lens, opts["mirror"], opts.get("method", "eq3"))
            fac = _certified_image(opts["certificate"], std, wo_dome, gvalid)
        shape = veil_shape(bg, gvalid, field_angle(lens), standard=std, factor=fac,
                           stride=1 if fac is not None else SHAPE_STRIDE)  # fmt: skip
        g_s = glare_offset(std, bg, dark)
        v_s = veil(g_s, shape, dark)  # (the standard's veil: the same for every rotation)
    out = []
    for rot, frames in measured.items():
        meas, n_meas = _fstop_corrected(Capture(laboratory_view(frames, sat)), fst)
        kw = dict(opts)
        info: dict[str, Any] = {
            "rotation_deg": float(rot),
            "n_frames": n_meas,
            "n_frames_standard": n_std,
            "stops": [float(m["f_number"]) for _, m in frames],
            "stops_standard": [float(m["f_number"]) for _, m in standard],
        }
        if g_s is not None:
            g_m = glare_offset(meas, bg, dark)
            kw["glare"] = (veil(g_m, shape, dark), v_s)
            info["glare"] = {"measured": g_m.value, "standard": g_s.value, "n_dark": g_m.n}
        seed = None if seeds is None else seeds.get(rot)
        red = reduce_selected(meas, std, bg, rng=seed, debias=debias, **kw)
        info["n_before"] = int(red.stats.get("n_before", len(red.samples)))
        info["n_samples"] = len(red.samples)
        info["image_shape"] = list(np.asarray(frames[0][0]).shape)  # (a digitiser's binning)
        if restandard and rot in restandard and "drift" in corr:
            info["restandard"] = _restandard(restandard[rot], std, bg, fst, sat)
        clocks = _clocks(meas), _clocks(std)
        if clocks[0] is not None and clocks[1] is not None:  # the captures' time stamps
            info["clock_s"], info["clock_s_standard"] = clocks
        out.append((red.samples, info))
    return out


def _restandard(frames: Sequence[Any], std: Any, bg: Any, fst: Any, sat: Any) -> dict:
    """The lamp's ratio from the re-measured standard and its time stamps."""
    from gonio.calibration.drift import standard_ratio
    from gonio.calibration.reduce import Capture

    again, _ = _fstop_corrected(Capture(laboratory_view(frames, sat)), fst)
    out = {"ratio": standard_ratio(again, std, bg)}
    t_a, t_s = _clocks(again), _clocks(std)
    if t_a is not None and t_s is not None:
        out["clock_s"], out["clock_s_standard"] = t_a, t_s
    return out


def correct_drift(per_angle: Sequence[Mapping[str, Any]], corrections: Any = None) -> int:
    """Divide each sample capture of a campaign by the lamp's change since its standard's
    capture, from the re-measured standards (:mod:`gonio.calibration.drift`), in place.

    ``per_angle``: the capture stage's results (``tables``, ``infos``, optionally
    ``csv_rows``, which are formatted again). Returns the number of anchors used (0: no
    re-measurement with time stamps, or the ``drift`` correction is off; nothing changed).
    """
    from dataclasses import replace

    from gonio.calibration.drift import drift_gain

    if "drift" not in set(check_corrections(corrections)):
        return 0
    infos = [i for r in per_angle for i in r.get("infos", [])]
    anchors = [i["restandard"] for i in infos if "clock_s" in i.get("restandard", {})]
    if not anchors or any("clock_s" not in i for i in infos):
        return 0
    t_k = [a["clock_s"] for a in anchors]
    r_k = [a["ratio"] for a in anchors]
    for r in per_angle:
        for j, (table, info) in enumerate(zip(r["tables"], r["infos"])):
            g = float(drift_gain(info["clock_s"], t_k, r_k))
            info["drift_gain"] = g
            r["tables"][j] = replace(table, value=table.value / g, sigma=table.sigma / g)
            if "csv_rows" in r:
                from gonio.io.samples_table import csv_rows

                r["csv_rows"][j] = csv_rows(r["tables"][j])
    for i in infos:
        i["drift_anchors"] = {"clock_s": t_k, "ratio": r_k}
    return len(anchors)


def _clocks(cap: Any) -> float | None:
    """Mean time stamp (``clock_s``, s) of a capture's frames, or None without one."""
    t = [m.get("clock_s") for m in cap.metas]
    return None if any(x is None for x in t) else float(np.mean(t))


#: the veil the glare correction leaves, as a fraction of the veil: measured on the modern
#: instrument (seed 1, rolled brass, every incidence) against the same instrument without
#: glare, the corrected samples differ by +0.08 % in the lobe and -0.1 % in its tails where
#: the uncorrected ones differ by -1.3 % and +2.3 % (4-6 %); the veil's shape from the
#: standard's light is within 3-6 % of the simulator's own veil over the image circle
GLARE_RESIDUAL = 0.06
#: the same for digitised images (Ward's 108 × 80, each pixel the mean of about 6 × 6 camera
#: pixels; Ward 1992 §3): measured on seven ``ward1992`` instruments (seeds 0-6, rolled
#: brass, θi 5-75°, rotation 0) against the same instruments without glare, the corrected
#: fit's rho_d moved by -0.4 % to -2.3 % where the uncorrected one moved by +3.2 % to +10.1 %:
#: the correction overshoots by 8-33 % of the veil (median 12 %, rms 17 %), where at full
#: resolution it leaves 1-2 %. The coarse image's veil shape and dark-pixel level are the
#: correction's limit; the budget carries the rms
GLARE_RESIDUAL_DIGITISED = 0.17

_CERTIFIED: dict[tuple, np.ndarray] = {}

#: every how many pixels of the sample's image the veil shape reads the standard
SHAPE_STRIDE = 8


def _certified_image(cert: Any, std: Any, wo_dome: np.ndarray, gvalid: np.ndarray) -> np.ndarray:
    """The standard's certified reflectance factor at every :data:`SHAPE_STRIDE`-th pixel
    that sees the sample (flat; NaN at the others; 1 where the certificate does not reach),
    cached per pixel geometry, incidence and certificate."""
    from gonio.calibration.consistency import sidecar_angle
    from gonio.calibration.reduce import standard_factor

    theta_i = sidecar_angle(std.meta, "theta_i", "standard metadata")
    rot = std.meta.get("sample_rotation", 0.0), std.meta.get("phi_i", 0.0)
    key = (id(wo_dome), theta_i, rot, cert.fingerprint)
    got = _CERTIFIED.get(key)
    if got is not None and got.size == np.asarray(gvalid).size:
        return got
    idx = np.flatnonzero(np.asarray(gvalid).ravel())[::SHAPE_STRIDE]
    out = np.full(np.asarray(gvalid).size, np.nan)
    out[idx] = standard_factor(cert, std, theta_i, wo_dome.reshape(-1, 3)[idx])[0]
    out.setflags(write=False)
    if len(_CERTIFIED) > 64:
        _CERTIFIED.clear()
    _CERTIFIED[key] = out
    return out


def field_angle(lens: Any) -> np.ndarray:
    """Field angle of every pixel (flat, read-only), cached per lens with the lens's pixel
    rays (:func:`gonio.calibration.reduce.grid_field_angle`: the Kannala-Brandt inverse of
    a 640 x 480 grid, made once for both)."""
    from gonio.calibration.reduce import grid_field_angle

    return grid_field_angle(lens).ravel()


def campaign_budget(
    result: Any,
    samples: Any,
    cal: Any,
    *,
    corrections: Iterable[str] | None = None,
    infos: Sequence[Mapping[str, Any]] = (),
    k: float = 2.0,
    fields: list | None = None,
):
    """The GUM budget of a fit (a :class:`CampaignBudget`) from the laboratory's knowledge
    (see the module docstring of :mod:`gonio.campaign.budget_terms` for each term).

    With ``cal`` None (the ideal, uncalibrated instrument) only the statistical term is
    there. ``fields``: :func:`budget_fields` of ``cal`` and ``corrections`` if computed
    before (in a campaign, by an idle worker during the fit); else computed here. Runs
    with every OpenBLAS on one thread (:class:`~gonio.campaign.blas.SingleThreadBLAS`),
    as inside a campaign's executor: the
    terms' products of (n, 3) and (n, 6) arrays gain nothing from a second thread, and
    called on its own next to a busy process the budget took twice as long with two (the
    tilt terms 0.3 s instead of 0.016 s, measured on the default modern campaign).
    """
    from gonio.campaign.blas import SingleThreadBLAS

    with SingleThreadBLAS():
        return _campaign_budget(result, samples, cal, corrections, infos, k, fields)


@dataclasses.dataclass
class CampaignBudget(Budget):
    """A campaign's :class:`~gonio.campaign.budget.Budget` with what it was built from: the
    fitted samples (as the budget saw them) and every term's
    :class:`~gonio.campaign.budget.Perturbation` (the fit result is the campaign's); the
    LBL measurement design decomposes them by capture (:mod:`gonio.campaign.design_lbl`),
    with the captures' ``infos`` (frames, stops, time stamps) and the calibration ``cal``."""

    samples: Any = None
    perturbations: tuple[Perturbation, ...] = ()
    infos: tuple[Mapping[str, Any], ...] = ()
    cal: Any = None


def budget_fields(cal: Any, corrections: Iterable[str] | None = None) -> list:
    """The part of :func:`campaign_budget` that depends on the calibration alone: the
    geometric terms' direction fields (:func:`gonio.campaign.budget_terms.direction_fields`;
    none without a calibration or without the ``geometry`` correction)."""
    if cal is None or "geometry" not in set(check_corrections(corrections)):
        return []
    from gonio.campaign import budget_terms as bt
    from gonio.campaign.blas import SingleThreadBLAS

    with SingleThreadBLAS():
        return bt.direction_fields(cal)


def _campaign_budget(
    result: Any, samples: Any, cal: Any, corrections: Any, infos: Sequence[Mapping], k: float,
    fields: list | None,
):  # fmt: skip
    """:func:`campaign_budget`'s body."""
    from gonio.campaign import budget_terms as bt
    from gonio.campaign.budget import Sensitivity, build_budget

    corr = set(check_corrections(corrections))
    terms = []
    model = result.model
    if cal is not None:
        samples = bt.budget_view(samples)  # directions and capture groups computed once
        spec = cal.specification
        terms += bt.certificate_terms(samples, cal.certificate, "standard" in corr)
        terms += _exposure(samples, cal, spec, corr, infos)
        g = bt.spec_rms(spec.get("veiling_glare"))
        if g > 0:
            # corrected only where every capture had a dark region to measure its veil in;
            # a capture without one carries its whole veil
            glare_done = "glare" in corr and bool(infos) and all("glare" in i for i in infos)
            lens = cal.lens_model()
            res = GLARE_RESIDUAL_DIGITISED if _digitised(lens, infos) else GLARE_RESIDUAL
            u = res * g if glare_done else g
            if lens is not None and cal.mirror is not None:
                from gonio.calibration.reduce import pixel_geometry

                wo, ok = pixel_geometry(lens, cal.mirror.geometry, cal.mirror.method)
                terms += bt.glare_term(samples, model, wo[ok], u, glare_done)
        if "geometry" in corr:
            terms += bt.direction_terms(samples, model, cal, fields)
        sigma = _blur_sigma(cal)
        terms += bt.blur_term(samples, model, sigma)
        terms += bt.digitiser_term(samples, model, cal.lens_model(),
                                   [i.get("image_shape") for i in infos])  # fmt: skip
        terms += bt.tilt_terms(samples, model, bt.spec_rms(spec.get("sample_tilt")))
        terms += _lamp(samples, spec, infos, _capture_u(cal, spec, corr, infos))
        r = bt.spec_rms(spec.get("reillumination"))
        if r > 0:
            terms += bt.reillumination_term(samples, model, r, _rho_std(cal, samples),
                                            _lit_fraction(cal, samples))  # fmt: skip
    sens = Sensitivity(result, samples) if terms else None
    b = build_budget(result, samples, terms, sensitivity=sens, k=k)
    kept = {f.name: getattr(b, f.name) for f in dataclasses.fields(b)}
    return CampaignBudget(**kept, samples=samples, perturbations=tuple(terms),
                          infos=tuple(infos), cal=cal)  # fmt: skip


def _exposure(samples, cal, spec, corr, infos) -> list:
    from gonio.campaign import budget_terms as bt

    flicker = bt.spec_rms(spec.get("lamp_flicker"))
    if "exposure" in corr and cal.fstops is not None:
        terms = bt.exposure_terms(samples, _capture_u(cal, spec, corr, infos))
        u_tab = _table_u(cal.fstops, infos)
        if u_tab > 0:  # the ladder's own uncertainty: the standard's stops vs the sample's
            terms.append(bt.Perturbation("exposure_table", u_tab, "1", samples.value,
                                         note="f-stop ladder table, the stops used"))  # fmt: skip
        return terms
    err = math.hypot(
        bt.spec_rms(spec.get("fstop_error")), bt.spec_rms(spec.get("iris_repeatability"))
    )
    series = 0.02 * bt.spec_rms(spec.get("fstop_series"))  # marked vs √2^k: up to 2 %
    u = math.sqrt(err**2 + series**2 + flicker**2)
    return bt.exposure_terms(samples, u, "exposure(uncorrected)") if u > 0 else []


def _lamp(
    samples: Any, spec: Mapping[str, Any], infos: Sequence[Mapping[str, Any]], u_anchor: float
) -> list:
    """The lamp's warm-up and drift between each sample capture and its standard's, from
    the captures' time stamps (none without them); ``u_anchor``: the exposure scatter of
    one capture, of which a re-measured standard's ratio has two."""
    from gonio.campaign import budget_terms as bt

    if not infos or any("clock_s" not in i or "n_samples" not in i for i in infos):
        return []
    n = [int(i["n_samples"]) for i in infos]
    if sum(n) != len(samples):
        return []
    t_m = np.repeat([float(i["clock_s"]) for i in infos], n)
    t_s = np.repeat([float(i["clock_s_standard"]) for i in infos], n)
    anchors = None
    if all("drift_gain" in i for i in infos):  # corrected by the re-measured standard
        re = [i["restandard"] for i in infos if "clock_s" in i.get("restandard", {})]
        anchors = (np.array([a["clock_s"] for a in re]),
                   np.array([a["clock_s_standard"] for a in re]))  # fmt: skip
    return bt.lamp_terms(samples, t_m, t_s, bt.spec_rms(spec.get("lamp_warmup")),
                         bt.spec_rms(spec.get("lamp_drift")), anchors,
                         math.sqrt(2.0) * u_anchor)  # fmt: skip


def _capture_u(cal: Any, spec: Mapping[str, Any], corr: set, infos: Sequence[Mapping]) -> float:
    """One capture's relative exposure scatter (iris over the bracket's frames, flicker):
    the ``exposure`` terms' ``u``."""
    from gonio.campaign import budget_terms as bt

    flicker = bt.spec_rms(spec.get("lamp_flicker"))
    if "exposure" in corr and cal.fstops is not None:
        m = max((int(i.get("n_frames", 1)) for i in infos), default=1)
        return math.hypot(cal.fstops.sigma_iris / math.sqrt(m), flicker)
    return math.hypot(bt.spec_rms(spec.get("iris_repeatability")), flicker)


def _table_u(fst: Any, infos: Sequence[Mapping[str, Any]]) -> float:
    """RMS over the captures of the ladder table's uncertainty of the ratio between the
    standard's and the sample's stops (their mean log gains, independent stops)."""
    u = fst.u_log_gain
    vals = []
    for i in infos:
        s, m = i.get("stops_standard") or [], i.get("stops") or []
        if not s or not m:
            continue
        us = math.sqrt(sum(u.get(float(x), 0.0) ** 2 for x in s)) / len(s)
        um = math.sqrt(sum(u.get(float(x), 0.0) ** 2 for x in m)) / len(m)
        vals.append(us * us + um * um)
    return math.sqrt(sum(vals) / len(vals)) if vals else 0.0


def _rho_std(cal: Any, samples: Any) -> float:
    if cal.certificate is not None:
        return float(cal.certificate.rho)
    return float(samples.metadata.get("rho_standard", 0.99))


def _lit_fraction(cal: Any, samples: Any) -> np.ndarray:
    """The beam footprint's share of the sample disk, ``min(r_spot² / (r_s² cos θi), 1)``,
    from the design's spot and sample radii."""
    d = cal.info.get("design", {})
    rs, rspot = float(d.get("sample_radius", 0.008)), float(d.get("spot_radius", 0.003))
    return np.minimum(rspot**2 / (rs**2 * np.maximum(np.cos(samples.theta_i), 1e-3)), 1.0)


def _digitised(lens: Any, infos: Sequence[Mapping[str, Any]]) -> bool:
    """Whether the captures' images (their side-car ``image_shape``) are smaller than the
    calibrated lens's: a digitiser averaged boxes of camera pixels."""
    if lens is None:
        return False
    shapes = [i.get("image_shape") for i in infos if i.get("image_shape") is not None]
    return any(int(s[1]) < int(lens.width) or int(s[0]) < int(lens.height) for s in shapes)


def _blur_sigma(cal: Any, f_number: float = 5.6) -> float:
    """Angular RMS blur (rad) the specification implies at a typical working stop: the
    simulator's point-spread model (pixel area, diffraction, defocus;
    :func:`gonio.simulator.lbl_effects.psf_sigma_px`) at the specified magnitudes, over the
    calibrated lens's pixels per radian."""
    lens = cal.lens_model()
    pitch = float(cal.info.get("pixel_pitch_m", 0.0))
    if lens is None or not pitch > 0:
        return 0.0
    from gonio.campaign.budget_terms import spec_rms
    from gonio.simulator.lbl_effects import psf_sigma_px

    mags = {k: spec_rms(cal.specification.get(k))
            for k in ("pixel_fill", "diffraction_wavelength", "focus_error")}  # fmt: skip
    radius = float(cal.mirror.geometry.radius) if cal.mirror is not None else 0.15
    px = psf_sigma_px(f_number, mags, pitch, float(lens.fx), 0.5 * radius)
    return px / float(lens.fx)
