"""Cornell campaigns: plan → measurements → BRDFSamples → ``li_torrance`` fit → results.

:func:`run_cornell_campaign` measures a material on the simulated Cornell three-axis
gonioreflectometer (Li and Torrance 2005, §5.1), either in-process
(:func:`gonio.simulator.cornell.simulate_campaign`) or through the device drivers against
the fake devices (:mod:`gonio.campaign.drivers`: ESP300s on pseudo-terminals, the USB2000+ on the
fake pyusb backend), and fits ``li_torrance`` (eq. 3-14) with shared σ, τ and per-band
coefficients k. Both paths measure the same ordered plan with the motor angles rounded to
the controller's resolution (``resolution_deg``), so that for the same seed they give the
same samples.

Identifiability (verified here, :func:`identifiability_scan`): in eq. 3-14 every term but
the mirror part depends on σ and τ only through τ/σ — the shadowing S (eq. 6, exponent τ/σ)
and its shortcut (eq. 7), the effective roughness (eq. 8: σ_e/σ is a function of τ/σ alone,
so the effective slope m_e = σ_e/τ = (σ/τ)·h(τ/σ)), the slope distribution D (eq. 10, a
function of m_e only: the paper says so, and its (v̄·v̄/v̄·N)² is read with v̄ = L + V, the
2π/λ of the printed v̄ making it dimensional), the directional-diffuse term (eq. 9 = F S D),
and the forward-scattering term (eq. 13, through m_e); F, T (eq. 5, 12) see neither. Only
the coherent mirror part (eq. 3) has exp(−g), g = (2πσ_e/λ)²(cos θi + cos θr)² (eq. 4), in
which σ appears alone (relative to λ). Scaling σ and τ together therefore changes the model
by exactly 0 for the samples whose constructed models have no mirror part (aluminized
ground glass, eq. 17; garnet red paint, eq. 18; laser paper — the paper: "the specular
reflection is negligible", "no coherent reflection is observed"), and σ and τ cannot be
recovered separately from any BRDF data of them: ``fit_mode="auto"`` then holds σ at the
table value and fits τ (equivalently, the ratio). For aluminized non-glare glass (eq. 16,
mirror part) both are fitted, provided the plan puts the detector inside the mirror image of
the source at least once (the incidence plan does; the hemispherical grid never does, and
the paper used incidence-plane sampling for this sample) — otherwise σ is held there too.

Results directory (``out``)::

    plan.json        the resolved campaign settings
    checkpoint.npz   completed measurements (through drivers; resume with resume=True)
    reference.npz    the reference measurement (through drivers)
    reference_<session>_<count>.npz
                     the standard re-measured after <count> geometries (through drivers)
    spectra/<j>.npz  raw spectra of geometry j, reduced again against the interpolated
                     references at the end (through drivers, with the drift correction)
    samples.csv      BRDF samples (31 rows per geometry, wavelength_nm column)
    samples.astm     the same as an ASTM E1392 table, one row per geometry (gonio.io.astm)
    fit.json         the fit (FitResult.to_dict())
    summary.json     material, model, truth, fit, stderr, relative_error, rms, n_samples,
                     converged, timings_s, seed (+ fit_mode, k_summary, within_3_sigma,
                     budget, estimated_real_instrument_h and _u_h, ...)
    plots/budget.png the uncertainty budget (gonio.plots.budget)
    plots/incidence_plane.png, plots/residuals.png  the data against the fit (three bands)

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Here: the model fitted (eq. 3-14, the identifiability of σ and τ through eq. 6-9), the
   source solid angle of eq. 16, and the instrument of §5.1 the campaign runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign import folder as results
from gonio.campaign.executor import CampaignExecutor
from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = [
    "build_plan",
    "fit_li_torrance",
    "identifiability_scan",
    "main",
    "offset_sensitivity",
    "plan_file_reference_every",
    "reference_band_error",
    "run_cornell_campaign",
    "stray_offset_error",
]

PLANS = ("incidence", "incidence_plane", "hemispherical")


def _write_json(path: Path, obj: Any) -> None:
    from gonio.io.jsonfile import to_json

    atomic_write_bytes(path, (to_json(obj) + "\n").encode())


#: the header line ``gonio design`` writes at the top of a Cornell plan file (a JSON object)
PLAN_HEADER = "# gonio design:"
#: what plan files written before the design chose the cadence hold (the campaign's default)
_LEGACY_CADENCE = "the campaign's (not designed)"


def plan_file_reference_every(path: str | os.PathLike) -> int | None:
    """The reference cadence a Cornell plan file carries (``reference_every`` of its
    ``# gonio design: {...}`` line, :func:`gonio.campaign.design.write_cornell_plan`): an
    integer >= 0, or None when the file has no such line or field (or the text earlier
    versions wrote there, :data:`_LEGACY_CADENCE`): the campaign's default applies.
    ``ValueError`` naming the file and the field for anything else (a negative number, a
    fraction, a string, a line that is not JSON)."""
    import json

    with open(path, encoding="utf-8-sig") as f:
        head = next((ln for ln in f if ln.startswith(PLAN_HEADER)), None)
    if head is None:
        return None
    try:
        fields = json.loads(head[len(PLAN_HEADER) :])
    except ValueError as exc:
        raise ValueError(f"{path}: its '{PLAN_HEADER}' line is not a JSON object ({exc})") from None
    if not isinstance(fields, dict):
        raise ValueError(f"{path}: its '{PLAN_HEADER}' line is not a JSON object")
    v = fields.get("reference_every")
    if v is None or v == _LEGACY_CADENCE:
        return None
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ValueError(
            f"{path}: reference_every = {v!r} in its '{PLAN_HEADER}' line: expected an "
            "integer >= 0 (re-measure the reference after every N geometries; 0: once)"
        )
    return v


def build_plan(
    plan: Any = "incidence",
    *,
    config: Any = None,
    resolution_deg: float = 1e-3,
    max_geometries: int | None = None,
    **plan_kw: Any,
) -> Any:
    """The ordered plan with motor angles on the controller's grid.

    ``plan``: ``"incidence"`` (= ``"incidence_plane"``), ``"hemispherical"``, a CSV path
    (``theta_i,phi_i,theta_o,phi_o`` in degrees) or a ``gonio.simulator.cornell_plans.Plan``.
    ``plan_kw`` go to the plan maker (e.g. ``theta_i_deg=(30, 60)``, ``n=9``).
    ``max_geometries`` keeps the first geometries of the ordered plan (quick runs).
    """
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_plans import (
        Plan,
        hemispherical_plan,
        incidence_plane_plan,
        order_plan,
        read_plan_csv,
    )

    cfg = config or CornellConfig()
    kin = cfg.kinematics
    if isinstance(plan, Plan):
        p = plan
    elif plan in ("incidence", "incidence_plane"):
        p = incidence_plane_plan(kin=kin, **plan_kw)
    elif plan == "hemispherical":
        p = hemispherical_plan(kin=kin, **plan_kw)
    elif isinstance(plan, str | os.PathLike) and Path(plan).is_file():
        p = read_plan_csv(plan, kin)
    else:
        raise ValueError(f"plan = {plan!r}: expected one of {list(PLANS)}, a CSV file or a Plan")
    if not (resolution_deg > 0 and math.isfinite(resolution_deg)):
        raise ValueError(f"resolution_deg = {resolution_deg!r}: expected > 0")
    p = order_plan(p)
    if max_geometries is not None:
        if int(max_geometries) < 1:
            raise ValueError(f"max_geometries = {max_geometries!r}: expected >= 1")
        p = p.subset(np.arange(min(int(max_geometries), len(p))))
    deg = np.round(np.degrees(p.angles) / resolution_deg) * resolution_deg
    deg = np.round(deg, 6)  # exactly what the controller is sent (6 decimals)
    q = p.subset(np.arange(len(p)))
    q.angles = np.radians(deg)
    q.reachable = p.reachable & np.array([kin.within_limits(a) for a in q.angles], dtype=bool)
    q = q.measurable()
    q.meta = {**p.meta, "resolution_deg": resolution_deg, "n_geometries": len(q)}
    return q


def _samples_from(angles_rad, values, sigmas, kin, metadata) -> BRDFSamples:
    from gonio.simulator.cornell import BANDS_NM, forward

    wi, wo = forward(np.asarray(angles_rad, float), kin)
    nb = len(BANDS_NM)
    n = len(wi)
    return BRDFSamples.from_directions(
        np.repeat(wi, nb, axis=0),
        np.repeat(wo, nb, axis=0),
        np.asarray(values, float).reshape(-1),
        np.asarray(sigmas, float).reshape(-1),
        wavelength_nm=np.tile(BANDS_NM, n),
        metadata=metadata,
    )


# ----------------------------------------------------------------------------- fit
def _truth_and_template(material: str, fit_mode: str, start: dict | None = None):
    from gonio import brdf, materials
    from gonio.simulator.cornell import BANDS_NM

    truth = materials.get(material)
    if truth.name != "li_torrance":
        raise ValueError(f"material = {material!r}: expected a li_torrance preset")
    tp = truth.params
    nb = len(BANDS_NM)
    params: dict[str, Any] = {}
    fixed: dict[str, Any] = {}
    free_k = []
    for k in ("k_dd", "k_udf", "k_uds", "k_fs"):
        v = np.asarray(tp[k], float)
        if np.all(v == 0):
            params[k] = 0.0
            fixed[k] = 0.0
        else:
            params[k] = np.full(nb, 0.5)
            free_k.append(k)
    for k in ("f0", "n_ior", "specular", "shadowing", "effective_roughness", "shortcut"):
        if k in tp:
            params[k] = tp[k]
    params["wavelength_nm"] = BANDS_NM.copy()
    mirror = bool(tp.get("specular", True)) and "k_dd" in free_k
    if mirror:
        from gonio.simulator.cornell import CornellConfig

        params["d_omega_i"] = CornellConfig().source_solid_angle  # eq. 16's top hat
    mode = fit_mode
    if mode == "auto":
        mode = "both" if mirror else "sigma_fixed"
    if mode not in ("both", "sigma_fixed", "tau_fixed"):
        raise ValueError(
            f"fit_mode = {fit_mode!r}: expected 'auto', 'both', 'sigma_fixed', 'tau_fixed'"
        )
    s0 = dict(start or {})
    params["sigma"] = float(s0.get("sigma", tp["sigma"] * (1.0 if mode == "sigma_fixed" else 1.2)))
    params["tau"] = float(s0.get("tau", tp["tau"] * (1.0 if mode == "tau_fixed" else 0.8)))
    if mode == "sigma_fixed":
        fixed["sigma"] = float(tp["sigma"])
        params["sigma"] = float(tp["sigma"])
    elif mode == "tau_fixed":
        fixed["tau"] = float(tp["tau"])
        params["tau"] = float(tp["tau"])
    template = brdf.create("li_torrance", **params)
    return truth, template, fixed, mode, free_k, mirror


def _mirror_partial_mask(samples: BRDFSamples, config: Any) -> np.ndarray:
    """Rows whose detector cone only partly overlaps the mirror image of the source cone.

    There the instrument reads a fraction of the mirror peak that the model's top hat
    (``d_omega_i``) cannot represent; the fit leaves them out (a laboratory knows its cone
    sizes).
    """
    from gonio.simulator.cornell import _alpha

    wi, wo = samples.wi, samples.wo
    d = wi * np.array([-1.0, -1.0, 1.0])
    beta = np.arccos(np.clip(np.sum(d * wo, -1), -1, 1))
    a_s, a_d = _alpha(config.source_solid_angle), _alpha(config.detector_solid_angle)
    return (beta > abs(a_s - a_d)) & (beta < a_s + a_d)


def _mirror_full_mask(samples: BRDFSamples, config: Any) -> np.ndarray:
    """Rows whose detector cone lies wholly inside the mirror image of the source cone (the
    rows that measure the mirror part's full height ρ / (Ω_s cos θi))."""
    from gonio.simulator.cornell import _alpha

    d = samples.wi * np.array([-1.0, -1.0, 1.0])
    beta = np.arccos(np.clip(np.sum(d * samples.wo, -1), -1, 1))
    a_s, a_d = _alpha(config.source_solid_angle), _alpha(config.detector_solid_angle)
    return beta <= abs(a_s - a_d)


def cone_response(model: Any, wi: np.ndarray, wo: np.ndarray, config: Any) -> np.ndarray:
    """What the laboratory expects the instrument to read for ``model`` at ``wi``, ``wo``
    (G, 3): :func:`gonio.campaign.cornell_lab.cone_response` (nominal top-hat cones, the
    laboratory's own quadrature; the simulator's rule and true cones are not used).
    Returns (G, n_bands).
    """
    from gonio.campaign.cornell_lab import cone_response as lab_cone_response

    return lab_cone_response(model, wi, wo, config)


def _stray_variance(stray: np.ndarray, c: Any, n: int) -> np.ndarray:
    """Variance (counts/s)² of the stray-light rate from ``n`` beam-trap reads of ``t_max``
    (signal and dark shot noise, two read noises)."""
    g, rd, dk, t = c.gain_e_per_count, c.read_noise_counts, c.dark_rate, c.t_max
    return ((stray * t + 2 * dk * t) / g + 2 * rd**2) / t**2 / n


def reference_band_error(ref: Any, config: Any) -> np.ndarray:
    """Relative standard error (31 bands) that the reference measurement puts on every sample.

    The reference (standard or direct beam, ``config.n_reference_reads`` averaged reads, and
    the beam-trap stray light) divides every spectrum, so its shot and read noise is common to
    all samples of a band: a per-band scale error that no number of geometries averages
    away, and that the fit's standard errors (from the scatter of the samples) do not
    contain. Computed from the reference rates with the detector model of
    ``gonio.simulator.cornell._net_rate`` and projected onto the bands like the data.
    """
    from gonio.simulator.cornell import BANDS_NM, _hat_projector

    c = config
    n = max(1, int(c.n_reference_reads))
    t = float(ref.meta.get("t", 1.0))
    tr = c.filter_transmission if ref.mode == "direct" else 1.0
    g, rd, dk = c.gain_e_per_count, c.read_noise_counts, c.dark_rate
    use, proj = _hat_projector(tuple(np.round(ref.wavelengths_nm, 9)), tuple(BANDS_NM))
    rel2 = np.zeros(len(BANDS_NM))
    for q in ("s", "p"):
        rate = np.maximum(np.asarray(ref.rate[q], float), 1e-30)
        stray = np.clip(np.asarray(ref.stray[q], float), 0, None)
        cnt = (rate + stray) * t * tr
        var = ((cnt + 2 * dk * t) / g + 2 * rd**2) / (t * tr) ** 2 / n
        var_stray = _stray_variance(stray, c, n)
        rel = (var + var_stray) / rate**2
        rel2 += 0.25 * ((proj * proj) @ rel[use])
    return np.sqrt(rel2)


def stray_offset_error(ref: Any, config: Any) -> np.ndarray:
    """Standard error (31 bands, BRDF units) of the additive offset the stray-light
    subtraction leaves in every sample of a band, ``δ_b / cos θi_eff``.

    The stray light is estimated once, from the beam trap (``config.n_reference_reads``
    reads at ``t_max`` per polarisation), and subtracted from every spectrum; the error of
    that estimate is common to all samples of a band — an additive offset ∝ 1/cos θi (the
    reduction divides by the effective cosine) that no number of geometries averages away.
    It barely moves a large k, but a k near 0 (e.g. garnet's k_uds below 600 nm) absorbs
    it: garnet, hemispherical plan, seed 0: k_uds up to 14 fit standard errors above its
    true 0. Same detector model as :func:`reference_band_error`.
    """
    from gonio.simulator.cornell import BANDS_NM, _hat_projector

    c = config
    n = max(1, int(c.n_reference_reads))
    use, proj = _hat_projector(tuple(np.round(ref.wavelengths_nm, 9)), tuple(BANDS_NM))
    var = np.zeros(len(BANDS_NM))
    for q in ("s", "p"):
        rate = np.maximum(np.asarray(ref.rate[q], float), 1e-30)
        stray = np.clip(np.asarray(ref.stray[q], float), 0, None)
        var_stray = _stray_variance(stray, c, n)
        to_brdf = np.asarray(ref.scale, float) / rate  # counts/s -> BRDF x cos θi
        var += 0.25 * ((proj * proj) @ (var_stray * to_brdf**2)[use])
    return np.sqrt(var)


def offset_sensitivity(
    model: Any, samples: BRDFSamples, free_k: list[str], config: Any
) -> dict[str, np.ndarray]:
    """∂k/∂δ: the change of each free per-band k when every sample of its band gets an
    additive offset ``δ / cos θi_eff`` (the stray-light pattern, :func:`stray_offset_error`),
    for the weighted linear least squares that determines the k's at the fitted σ, τ.
    Returns ``{name: (31,)}``.
    """
    from gonio.simulator.cornell import BANDS_NM, effective_cos

    nb = len(BANDS_NM)
    key = np.round(np.c_[samples.wi, samples.wo], 12)
    _u, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    wi, wo = samples.wi[first], samples.wo[first]
    zero = {k: 0.0 for k in ("k_dd", "k_udf", "k_uds", "k_fs")}
    base = {**model.params, **zero, "d_omega_i": None}
    basis = [
        np.asarray(type(model)(**{**base, k: 1.0})(wi, wo), float).reshape(len(wi), -1)
        for k in free_k
    ]
    band = np.clip(np.rint((samples.wavelength_nm - BANDS_NM[0]) / 10.0).astype(int), 0, nb - 1)
    w = 1.0 / samples.sigma if samples.has_sigma else np.ones(len(samples))
    u = 1.0 / effective_cos(samples.wi, config)
    out = {k: np.zeros(nb) for k in free_k}
    for b in range(nb):
        rows = np.flatnonzero(band == b)
        if rows.size == 0:
            continue
        a = np.stack([bs[inv[rows], min(b, bs.shape[1] - 1)] for bs in basis], axis=1)
        g = np.linalg.lstsq(a * w[rows, None], u[rows] * w[rows], rcond=None)[0]
        for k, v in zip(free_k, g):
            out[k][b] = v
    return out


def _cone_ratio(model: Any, samples: BRDFSamples, config: Any) -> np.ndarray:
    """Per row: instrument response / plain model (1 where the model is negligible)."""
    from gonio.simulator.cornell import BANDS_NM

    key = np.round(np.c_[samples.wi, samples.wo], 12)
    _uniq, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    wi, wo = samples.wi[first], samples.wo[first]
    resp = cone_response(model, wi, wo, config)
    plain = np.asarray(model(wi, wo), float).reshape(resp.shape)
    band = np.clip(np.rint((samples.wavelength_nm - BANDS_NM[0]) / 10.0).astype(int), 0, 30)
    r_rows = resp[inv, band]
    p_rows = plain[inv, band]
    big = p_rows > 1e-6 * np.max(plain, axis=0)[band]
    ratio = np.ones(len(samples))
    ok = big & (r_rows > 0)
    ratio[ok] = np.clip(r_rows[ok] / p_rows[ok], 0.5, 2.0)
    return ratio


def fit_li_torrance(
    samples: BRDFSamples,
    material: str,
    *,
    fit_mode: str = "auto",
    residual: str = "absolute",
    config: Any = None,
    start: dict | None = None,
    cone_corrections: int = 2,
    linear: bool = True,
) -> tuple[Any, dict[str, Any]]:
    """Fit ``li_torrance`` (shared σ, τ; per-band k's) to Cornell ``samples`` of ``material``.

    The model's structure comes from the preset (components that are zero stay off, f0 / n,
    switches); the k's start flat at 0.5 and σ, τ at +20 % / −20 % of the table values
    (``start`` overrides). ``fit_mode``: ``"auto"`` (both σ and τ with a mirror part that
    the data see — at least one row with the detector cone inside the source's mirror
    image —, else σ held at the table value), ``"both"``, ``"sigma_fixed"``,
    ``"tau_fixed"``. Rows where the detector sees part of the mirror peak are excluded
    (:func:`_mirror_partial_mask`).

    The instrument reads the BRDF averaged over the source (≈0.0005 sr) and detector cones;
    near a narrow lobe this differs from the model's point value by up to a few per cent,
    enough to bias σ/τ and to trade k_dd against k_fs. With ``cone_corrections = n`` the fit
    is repeated ``n`` times on the data divided by (instrument response / point model) of the
    previous fit (:func:`cone_response`; the cone sizes are known properties of the
    instrument). Returns ``(FitResult, info)``.

    Every coefficient k enters eq. 2-14 as a pure scale factor (eq. 3 and the top hat of
    eq. 16 included), and the cone correction only rescales the data, so with ``linear``
    (default) the k's are solved exactly by bounded linear least squares for each trial σ/τ
    (``gonio.fit.fit(..., linear=free_k)``, variable projection): the same minimum and
    standard errors as the joint fit (``linear=False``) at 4 model evaluations per trial
    instead of finite differences over ~95 parameters.
    """
    from gonio import fit as _fit
    from gonio.simulator.cornell import CornellConfig

    cfg = config or CornellConfig()
    truth, template, fixed, mode, free_k, mirror = _truth_and_template(material, fit_mode, start)
    use = samples
    n_excl = n_full = 0
    if mirror:
        bad = _mirror_partial_mask(samples, cfg)
        n_full = int(_mirror_full_mask(samples, cfg).sum())
        n_excl = int(bad.sum())
        if n_excl:
            use = samples.subset(np.flatnonzero(~bad))
        if fit_mode == "auto" and n_full == 0:
            # the mirror part is the only term that sees σ alone (module docstring); a plan
            # that never puts the detector inside the source's mirror image (e.g. the
            # hemispherical grid) leaves σ and τ degenerate: hold σ as for the rough samples
            truth, template, fixed, mode, free_k, mirror = _truth_and_template(
                material, "sigma_fixed", start
            )
    kw: dict[str, Any] = {"fixed": fixed} if fixed else {}
    if linear:
        # the k's enter eq. 2-14 (and the cone-corrected data) as pure scale factors:
        # variable projection, the same minimum with 4 model evaluations per trial σ/τ
        kw["linear"] = list(free_k)
    res = _fit.fit(use, template, residual=residual, guess=False, **kw)
    history = [{k: float(res.params[k]) for k in ("sigma", "tau")}]
    for _ in range(int(cone_corrections)):
        ratio = _cone_ratio(res.model, use, cfg)
        corr = dataclasses.replace(use, value=use.value / ratio, sigma=use.sigma / ratio)
        res = _fit.fit(corr, res.model, residual=residual, guess=False, **kw)
        history.append({k: float(res.params[k]) for k in ("sigma", "tau")})
    info = {
        "cone_corrections": int(cone_corrections),
        "history": history,
        "fit_mode": mode,
        "free_k": free_k,
        "mirror_part": mirror,
        "n_excluded_partial_mirror": n_excl,
        "n_full_mirror_rows": n_full,
        "fixed": {k: (v if np.ndim(v) == 0 else list(v)) for k, v in fixed.items()},
        "truth_model": truth,
    }
    return res, info


def _truth_flat(info: dict[str, Any]) -> dict[str, float]:
    """The true σ, τ and every free k per band, flat (``k_dd[0]`` ...)."""
    tp = info["truth_model"].params
    out = {k: float(tp[k]) for k in ("sigma", "tau")}
    for k in info["free_k"]:
        v = np.broadcast_to(np.asarray(tp[k], float), (31,))
        out.update({f"{k}[{b}]": float(v[b]) for b in range(31)})
    return out


def _stderr_with_reference(
    stderr: dict[str, float | None], fitp: dict[str, float], ref_err: np.ndarray,
    offset_err: dict[str, float] | None,
) -> dict[str, float | None]:  # fmt: skip
    """A k of band b also carries the reference's per-band scale error and the stray-light
    estimate's offset (both common to all samples of the band)."""
    out: dict[str, float | None] = {}
    for k, v in stderr.items():
        if v is not None and "[" in k:
            b = int(k.split("[")[1].rstrip("]"))
            off = (offset_err or {}).get(k, 0.0)
            out[k] = float(math.hypot(v, abs(fitp[k]) * ref_err[b], off))
        else:
            out[k] = v
    return out


def _comparison(truth: dict, fitp: dict, res: Any, stderr_total: dict) -> tuple[dict, dict, dict]:
    """Relative errors and whether the truth lies within 3 fit standard errors (``within_fit``)
    and within 3 standard errors with the reference's (``within``)."""
    rel, within, within_fit = {}, {}, {}
    for k, tv in truth.items():
        if k in fitp and k in res.free:
            rel[k] = abs(fitp[k] - tv) / abs(tv) if tv else abs(fitp[k])
            s = res.stderr.get(k, float("nan"))
            within_fit[k] = bool(abs(fitp[k] - tv) <= 3 * s) if math.isfinite(s) else None
            st = stderr_total.get(k)
            within[k] = bool(abs(fitp[k] - tv) <= 3 * st) if st is not None else None
    return rel, within, within_fit


def _add_ratio(
    truth: dict, fitp: dict, res: Any, stderr: dict, stderr_total: dict, rel: dict, within: dict
) -> None:
    """σ/τ (the identifiable combination of the rough samples) into the tables, with its
    standard error where one of σ, τ is held fixed."""
    if "sigma" not in fitp or "tau" not in fitp:
        return
    r_true = truth["sigma"] / truth["tau"]
    r_fit = fitp["sigma"] / fitp["tau"]
    rel["sigma/tau"] = abs(r_fit - r_true) / r_true
    fitp["sigma/tau"] = r_fit
    truth["sigma/tau"] = r_true
    free = set(res.free)
    st_t, st_s = stderr.get("tau"), stderr.get("sigma")
    sr = None
    if "tau" in free and "sigma" not in free and st_t is not None:
        sr = r_fit * st_t / fitp["tau"]
    elif "sigma" in free and "tau" not in free and st_s is not None:
        sr = st_s / fitp["tau"]
    stderr["sigma/tau"] = sr
    stderr_total["sigma/tau"] = sr
    if sr is not None and sr > 0:
        within["sigma/tau"] = bool(abs(r_fit - r_true) <= 3 * sr)


def _k_summary(rel: dict, within: dict, within_fit: dict) -> dict[str, Any]:
    krel = [rel[k] for k in rel if "[" in k]
    kwithin = [within[k] for k in within if "[" in k and within[k] is not None]
    kwithin_fit = [within_fit[k] for k in within_fit if "[" in k and within_fit[k] is not None]
    return {
        "n": len(krel),
        "max_relative_error": max(krel) if krel else None,
        "n_within_3_sigma": int(sum(kwithin)),
        "n_within_3_fit_stderr": int(sum(kwithin_fit)),
        "n_with_stderr": len(kwithin),
    }


def _summarise(
    material, res, info, samples, seed, noise, timings, extra, ref_err=None, offset_err=None
) -> dict[str, Any]:
    """The summary of a fit: the truth beside the fit (:func:`_truth_flat`,
    :func:`_comparison`, :func:`_add_ratio`, :func:`_k_summary`) and the fit's figures."""
    truth_flat = _truth_flat(info)
    fitp = {k: float(v) for k, v in res.params.items()}
    stderr = {k: (float(v) if math.isfinite(v) else None) for k, v in res.stderr.items()}
    ref_err = np.zeros(31) if ref_err is None else np.asarray(ref_err, float)
    stderr_total = _stderr_with_reference(stderr, fitp, ref_err, offset_err)
    rel, within, within_fit = _comparison(truth_flat, fitp, res, stderr_total)
    _add_ratio(truth_flat, fitp, res, stderr, stderr_total, rel, within)
    return {
        "material": material,
        "model": "li_torrance",
        "instrument": "cornell",
        "truth": truth_flat,
        "fit": fitp,
        "stderr": stderr,
        "stderr_with_reference": stderr_total,
        "reference_band_rel_error": [float(x) for x in ref_err],
        "relative_error": rel,
        "within_3_sigma": within,
        "k_summary": _k_summary(rel, within, within_fit),
        "fit_mode": info["fit_mode"],
        "cone_corrections": info["cone_corrections"],
        "sigma_tau_history": info["history"],
        "mirror_part": info["mirror_part"],
        "n_excluded_partial_mirror": info["n_excluded_partial_mirror"],
        "n_full_mirror_rows": info["n_full_mirror_rows"],
        "rms": float(res.rms),
        "rms_relative": float(res.rms_relative),
        "chi2_dof": float(res.chi2_dof) if math.isfinite(res.chi2_dof) else None,
        "n_samples": len(samples),
        "converged": bool(res.converged),
        "timings_s": {k: round(float(v), 4) for k, v in timings.items()},
        "seed": int(seed),
        "noise": bool(noise),
        **extra,
    }


# ----------------------------------------------------------------------------- campaign
def run_cornell_campaign(
    material: str = "garnet_red_paint",
    *,
    plan: Any = "incidence",
    noise: bool | float = True,
    seed: int = 0,
    out: str | os.PathLike | None = None,
    through_drivers: bool = False,
    quiet: bool = True,
    reference: str = "standard",
    resume: bool = False,
    fit: bool = True,
    fit_mode: str = "auto",
    residual: str = "absolute",
    config: Any = None,
    resolution_deg: float = 1e-3,
    max_geometries: int | None = None,
    time_scale: float = 1e4,
    faults: dict[str, Any] | None = None,
    checkpoint_every: int = 50,
    prime: bool = True,
    on_measurement: Any = None,
    plan_kw: dict[str, Any] | None = None,
    cone_corrections: int = 2,
    device_timeout: float = 2.0,
    fit_linear: bool = True,
    effects: Any = "cornell2005",
    instrument_seed: int | None = None,
    reference_every: int | None = None,
    corrections: dict[str, Any] | None = None,
    budget: bool = True,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Run a Cornell campaign end to end; the summary dict (also ``out/summary.json``).

    Parameters
    ----------
    material : str
        A ``li_torrance`` preset (gonio/materials/data/li_torrance.json).
    plan : {"incidence", "hemispherical"} or path or Plan
        Sampling plan (:func:`build_plan`; ``plan_kw`` to its maker).
    noise : bool
        Detector noise on/off (any non-zero number is on).
    seed : int
        Noise seed (the simulator's keyed noise: same seed, same samples on both paths).
    out : path, optional
        Results directory (module docstring).
    through_drivers : bool
        Drive the fake devices through the real drivers (:mod:`gonio.campaign.drivers`) instead of
        simulating in-process.
    quiet : bool
        No stage messages on stderr.
    resume : bool
        Through drivers: continue from ``out/checkpoint.npz`` (measured geometries are not
        measured again).
    fit : bool
        Fit ``li_torrance`` (:func:`fit_li_torrance`, ``fit_mode``, ``residual``,
        ``cone_corrections``).
    resolution_deg : float
        Motor-angle grid of the controller (both paths use the same rounded angles).
    max_geometries : int, optional
        Only the first geometries of the ordered plan.
    time_scale : float
        Simulated seconds per real second on the fake bench.
    faults : dict, optional
        ``{"esp300": Faults, "usb2000plus": Faults}`` for the fake devices.
    device_timeout : float
        The drivers' reply timeout (s) on the fake devices.
    fit_linear : bool
        Solve the k's by linear least squares per trial σ/τ (variable projection, the
        default; :func:`fit_li_torrance`); ``False``: the general joint least squares over
        all parameters (the same fit, ~100 times slower; for comparisons).
    checkpoint_every : int
        Checkpoint write interval (records; also every 2 s).
    prime : bool
        Let the fake bench's simulator precompute the plan's poses (speed only).
    effects : str, mapping or None
        The true instrument: a preset of :mod:`gonio.simulator.cornell_effects`
        (``"cornell2005"``, the default realistic instrument, or ``"ideal"``), realised with
        ``instrument_seed`` (default ``seed``), or a mapping of magnitudes, or None (ideal).
    reference_every : int, optional
        Re-measure the standard after every N geometries (default: the plan file's
        ``reference_every`` (:func:`plan_file_reference_every`), else 40 for a non-ideal
        instrument, 0 = once at the start), in-process and through the drivers.
    corrections : dict, optional
        The laboratory's corrections, each ablatable (:data:`DEFAULT_CORRECTIONS`):
        ``footprint`` ``"refuse"`` (the plan drops geometries whose field of view leaves
        the lit spot or the sample; the count is reported), ``"divide"`` (divide by the
        nominal lit fraction) or ``"none"``; ``drift`` (reduce against the references
        interpolated in time), ``stray`` (remove the data sheet's uniform stray light),
        ``slit`` (second-order slit deconvolution) True/False.
    budget : bool
        The uncertainty budget (:mod:`gonio.campaign.cornell_budget`) in the summary.
    on_measurement : callable(j, n), optional
        Called after each geometry through drivers (progress, fault injection in tests).
    overwrite : bool
        Replace the results of another campaign found in ``out`` (its ``plan.json`` holds
        other settings; else refused, as for the LBL campaign).
    """
    with results.locked(Path(out) if out is not None else None):
        # 1. prepare (under the folder's lock)
        t0 = time.perf_counter()
        setup = _prepare(
            material, plan, noise=noise, seed=seed, out=out, reference=reference,
            config=config, resolution_deg=resolution_deg, max_geometries=max_geometries,
            plan_kw=plan_kw, through_drivers=through_drivers, effects=effects,
            instrument_seed=instrument_seed, reference_every=reference_every,
            corrections=corrections, fit=fit, resume=resume, overwrite=overwrite,
        )  # fmt: skip
        t_plan = time.perf_counter() - t0
        try:
            return _stages(
                setup, t_plan, through_drivers=through_drivers, resume=resume,
                time_scale=time_scale, faults=faults, checkpoint_every=checkpoint_every,
                prime=prime, on_measurement=on_measurement, device_timeout=device_timeout, fit=fit,
                fit_mode=fit_mode, residual=residual, cone_corrections=cone_corrections,
                fit_linear=fit_linear, quiet=quiet, budget=budget,
            )  # fmt: skip
        except BaseException:
            if setup.out is not None:  # no derived output of a failed run
                results.discard_outputs(setup.out)
            raise


def _stages(
    setup: _Setup, t_plan: float, *, through_drivers: bool, resume: bool, time_scale: float,
    faults: Any, checkpoint_every: int, prime: Any, on_measurement: Any, device_timeout: Any,
    fit: bool, fit_mode: str, residual: str, cone_corrections: Any, fit_linear: Any, quiet: bool,
    budget: bool,
) -> dict[str, Any]:  # fmt: skip
    """Stages 2-4 of :func:`run_cornell_campaign` (measure, correct, fit, report)."""
    material = setup.material
    drawn = setup.out is not None and fit
    # BLAS on one thread, stage timings, and the figures drawn in a process of their own
    # (it loads matplotlib while this one measures)
    with CampaignExecutor(1, plots=drawn, plot_process=True) as ex, ex.blas():
        ex.timings["plan"] = t_plan
        if not quiet:
            how = "through the drivers on the fake devices" if through_drivers else "in-process"
            print(f"cornell: measuring {len(setup.plan)} geometries {how} ...", file=sys.stderr,
                  flush=True)  # fmt: skip
        # 2. measure
        with ex.stage("measure"):
            if through_drivers:
                samples, ref_obj, t_int, extra = _measure_through_drivers(
                    setup, resume=resume, time_scale=time_scale, faults=faults,
                    checkpoint_every=checkpoint_every, prime=prime,
                    on_measurement=on_measurement, device_timeout=device_timeout,
                )  # fmt: skip
            else:
                samples, ref_obj, t_int, extra = _measure_in_process(setup)
        extra.update(_run_time_estimate(setup, samples, t_int, ref_obj))
        if setup.fx is not None:
            with ex.stage("correct"):
                samples = _apply_corrections(setup, samples, ref_obj, extra)
        if setup.out is not None:
            with ex.stage("save_samples"):
                samples.write(setup.out / "samples.csv")
                from gonio.io.astm import write_cornell_astm

                write_cornell_astm(samples, setup.out / "samples.astm", setup.lab)
        # 3. fit
        if fit:
            if not quiet:
                print(f"cornell: fitting li_torrance to {len(samples)} samples "
                      f"({cone_corrections} cone corrections) ...", file=sys.stderr,
                      flush=True)  # fmt: skip
            with ex.stage("fit"):
                res_fit, info = fit_li_torrance(
                    samples, material, fit_mode=fit_mode, residual=residual, config=setup.lab,
                    cone_corrections=cone_corrections, linear=fit_linear,
                )  # fmt: skip
            if drawn:  # drawn while the report is made
                _draw_fit(ex, setup, samples, res_fit.model)
        ex.timings["total"] = ex.elapsed()
        # 4. report
        if fit:
            with ex.stage("report"):
                summary = _report(setup, res_fit, info, samples, ref_obj, ex.timings, extra,
                                  budget=budget)  # fmt: skip
        else:
            summary = {
                "material": material, "model": None, "n_samples": len(samples),
                "timings_s": {k: round(v, 4) for k, v in ex.timings.items()},
                "seed": setup.seed, "noise": setup.noise, **extra,
            }  # fmt: skip
        summary["files"] = {"samples": "samples.csv", "fit": "fit.json"} if setup.out else {}
        plots = []
        if drawn and summary.get("budget") and _draw_budget(ex, setup, summary):
            plots.append("plots/budget.png")
        if drawn:
            plots += [f"plots/{n}.png" for n in _FIT_PLOTS]
            summary["files"]["plots"] = plots
        ex.wait_plots()
    if setup.out is not None:
        _write_json(setup.out / "summary.json", summary)
    summary["_samples"] = samples  # in-memory only (dropped from JSON by callers)
    return summary


def _draw_budget(ex: CampaignExecutor, setup: _Setup, summary: dict[str, Any]) -> bool:
    """``plots/budget.png`` (:func:`gonio.campaign.report.draw_budget`, the LBL campaign's
    figure) from the budget's figure view, sent to the executor's plots; False when the
    view has no parameter (nothing drawn)."""
    from gonio.campaign.cornell_budget import figure_view
    from gonio.campaign.report import draw_budget

    view = figure_view(summary["budget"], summary["fit"], setup.corrections)
    view["model"] = "li_torrance"  # the parameters' units
    if not view["params"]:
        return False
    folder = setup.out / "plots"
    folder.mkdir(exist_ok=True)
    ex.plot(draw_budget, view, folder, f"{setup.material} (cornell)", each=["budget"])
    return True


#: the figures of the data against the fit (:func:`_draw_fit`)
_FIT_PLOTS = ("incidence_plane", "residuals")


def _draw_fit(ex: CampaignExecutor, setup: _Setup, samples: BRDFSamples, model: Any) -> None:
    """``plots/incidence_plane.png`` and ``plots/residuals.png``: the data against the fit
    (:func:`gonio.campaign.report.draw`, the LBL campaign's figures; three bands), sent to
    the executor's plots (both at once: in parallel forks of the plot process)."""
    from gonio.campaign.report import draw

    (setup.out / "plots").mkdir(exist_ok=True)
    ex.plot(draw, samples, model, setup.out / "plots", f"{setup.material} (cornell)",
            each=_FIT_PLOTS)  # fmt: skip


@dataclasses.dataclass
class _Setup:
    """The checked campaign settings the stages share."""

    material: str
    plan: Any
    cfg: Any
    noise: bool
    seed: int
    reference: str
    out: Path | None
    settings: dict[str, Any]
    lab: Any = None  # what the laboratory knows (cfg without the true effects)
    fx: dict[str, float] | None = None  # the realised true effects (simulator side only)
    knowledge: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    corrections: dict[str, Any] = dataclasses.field(default_factory=dict)
    reference_every: int = 0

    @property
    def meta(self) -> dict[str, Any]:
        """The samples' metadata."""
        return {"instrument": "cornell", "material": self.material, "seed": self.seed,
                "noise": self.noise}  # fmt: skip


def _effects_setting(effects: Any) -> Any:
    """The ``effects`` argument as plan.json records it (a custom preset as its
    distributions)."""
    if isinstance(effects, str | None):
        return effects
    return {k: (dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v)
            for k, v in effects.items()}  # fmt: skip


def _prepare(
    material: str, plan: Any, *, noise: Any, seed: Any, out: Any, reference: str, config: Any,
    resolution_deg: float, max_geometries: int | None, plan_kw: dict | None,
    through_drivers: bool, effects: Any = None, instrument_seed: int | None = None,
    reference_every: int | None = None, corrections: dict | None = None, fit: bool = True,
    resume: bool = False, overwrite: bool = False,
) -> _Setup:  # fmt: skip
    """Check the inputs, realise the true instrument, build the ordered plan (refusing the
    geometries whose field of view leaves the lit spot, when asked) and write
    ``plan.json``."""
    from gonio import materials
    from gonio.campaign.drivers import eeprom_coeffs
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_effects import is_preset, lab_knowledge, resolve_effects

    cfg = config or CornellConfig()
    # the spectrometer's calibration as its EEPROM stores it, on both paths
    cfg = dataclasses.replace(cfg, wavelength_coeffs=eeprom_coeffs(cfg.wavelength_coeffs))
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed = {seed!r}: expected a non-negative integer")
    if reference not in ("standard", "direct"):
        raise ValueError(f"reference = {reference!r}: expected 'standard' or 'direct'")
    materials.info(material)  # unknown preset -> ValueError listing them
    iseed = int(seed) if instrument_seed is None else instrument_seed
    if not isinstance(iseed, int | np.integer) or iseed < 0:
        raise ValueError(f"instrument_seed = {instrument_seed!r}: expected an integer >= 0")
    fx = resolve_effects(effects, int(iseed))
    cfg = dataclasses.replace(cfg, effects=fx, instrument_seed=int(iseed))
    lab = cfg.lab_view()
    knowledge = {}
    if fx is not None:
        knowledge = (lab_knowledge(effects) if is_preset(effects)
                     else {k: (float(v), 0.0) for k, v in fx.items() if v})  # fmt: skip
    corr = _check_corrections(corrections)
    if isinstance(plan, str | os.PathLike) and str(plan) not in PLANS and Path(plan).is_file():
        in_file = plan_file_reference_every(plan)  # the design's cadence
        if in_file is not None:
            if reference_every is not None and reference_every != in_file:
                raise ValueError(
                    f"reference_every = {reference_every!r} and the plan file's "
                    f"reference_every = {in_file}: give one (the plan file's is the design's)"
                )
            reference_every = in_file
    every = (40 if fx is not None else 0) if reference_every is None else reference_every
    if int(every) != every or every < 0:
        raise ValueError(f"reference_every = {reference_every!r}: expected an integer >= 0")
    p = build_plan(
        plan, config=lab, resolution_deg=resolution_deg, max_geometries=max_geometries,
        **(plan_kw or {}),
    )  # fmt: skip
    n_refused = 0
    if fx is not None and corr["footprint"] == "refuse":
        p, n_refused = _refuse_footprint(p, lab, knowledge)
    from gonio.campaign.determined import cornell_preflight

    if fit:  # a plan that cannot determine the model it will fit: refused
        cornell_preflight(p, material, lab)
    outp = Path(out) if out is not None else None
    settings = {
        "material": material,
        "plan": str(plan) if not hasattr(plan, "angles") else "custom",
        "plan_kw": plan_kw or {},
        "n_geometries": len(p),
        "noise": bool(noise),
        "seed": int(seed),
        "reference": reference,
        "resolution_deg": resolution_deg,
        "max_geometries": max_geometries,
        "through_drivers": bool(through_drivers),
        "effects": _effects_setting(effects),
        "instrument_seed": int(iseed),
        "reference_every": int(every),
        "corrections": corr,
        "n_refused_footprint": int(n_refused),
    }
    if outp is not None:
        if outp.is_dir():  # another campaign's results: replaced only with overwrite
            results.check_settings(outp, settings, resume, overwrite)
        outp.mkdir(parents=True, exist_ok=True)
        results.discard_outputs(outp)  # an earlier run's outputs and unfinished writes
        _write_json(outp / "plan.json", settings)
    return _Setup(material, p, cfg, bool(noise), int(seed), reference, outp, settings, lab, fx,
                  knowledge, corr, int(every))  # fmt: skip


#: the laboratory's corrections a campaign applies by default (each ablatable)
DEFAULT_CORRECTIONS: dict[str, Any] = {"footprint": "refuse", "drift": True, "stray": True,
                                       "slit": True}  # fmt: skip


def _check_corrections(corrections: dict | None) -> dict[str, Any]:
    corr = {**DEFAULT_CORRECTIONS, **(corrections or {})}
    unknown = set(corr) - set(DEFAULT_CORRECTIONS)
    if unknown:
        raise ValueError(
            f"corrections {sorted(unknown)} unknown; expected {list(DEFAULT_CORRECTIONS)}"
        )
    if corr["footprint"] not in ("refuse", "divide", "none"):
        raise ValueError(
            f"corrections footprint = {corr['footprint']!r}: expected 'refuse', 'divide' or 'none'"
        )
    for k in ("drift", "stray", "slit"):
        corr[k] = bool(corr[k])
    return corr


def _nominal(knowledge: dict[str, tuple[float, float]], name: str) -> float:
    return float(knowledge.get(name, (0.0, 0.0))[0])


def _refuse_footprint(p: Any, lab: Any, knowledge: dict) -> tuple[Any, int]:
    """The plan without the geometries whose (nominal) field of view leaves the lit spot or
    the sample, with a margin of twice the sizes' relative uncertainty (at least 5 %)."""
    from gonio.campaign.cornell_lab import footprint_refused
    from gonio.simulator.cornell import forward

    beam, fov = _nominal(knowledge, "beam_diameter_mm"), _nominal(knowledge, "fov_diameter_mm")
    size = _nominal(knowledge, "sample_size_mm")
    if fov <= 0:
        return p, 0
    rel = [knowledge.get(k, (1.0, 0.0))[1] / max(knowledge.get(k, (1.0, 0.0))[0], 1e-12)
           for k in ("beam_diameter_mm", "fov_diameter_mm")]  # fmt: skip
    margin = max(0.05, 2.0 * math.hypot(*rel))
    wi, wo = forward(p.angles, lab.kinematics)
    bad = footprint_refused(wi, wo, beam, fov, size, margin)
    if not bad.any():
        return p, 0
    q = p.subset(np.flatnonzero(~bad))
    q.meta = {**p.meta, "n_geometries": len(q), "n_refused_footprint": int(bad.sum())}
    return q, int(bad.sum())


def _apply_corrections(
    setup: _Setup, samples: BRDFSamples, ref_obj: Any, extra: dict
) -> BRDFSamples:
    """The laboratory's corrections of the reduced samples: the nominal footprint fraction
    (``footprint="divide"``) and the slit function's second-order bias (``slit``)."""
    from gonio.campaign.cornell_lab import footprint_fraction, slit_correction
    from gonio.simulator.cornell import BANDS_NM, _hat_projector

    kn, corr = setup.knowledge, setup.corrections
    vals = samples.value.reshape(-1, len(BANDS_NM)).copy()
    sig = samples.sigma.reshape(vals.shape).copy() if samples.has_sigma else None
    if corr["footprint"] == "divide" and _nominal(kn, "fov_diameter_mm") > 0:
        sizes = [_nominal(kn, k) for k in ("beam_diameter_mm", "fov_diameter_mm", "sample_size_mm")]
        nb = len(BANDS_NM)
        frac = footprint_fraction(samples.wi[::nb], samples.wo[::nb], *sizes)
        keep = frac > 0.05
        extra["n_footprint_divided"] = int(np.sum(frac < 1.0))
        vals[keep] /= frac[keep, None]
        if sig is not None:
            sig[keep] /= frac[keep, None]
    if corr["slit"] and _nominal(kn, "slit_fwhm_nm") > 0:
        use, proj = _hat_projector(tuple(np.round(ref_obj.wavelengths_nm, 9)), tuple(BANDS_NM))
        k_band = proj @ (0.5 * (ref_obj.rate["s"] + ref_obj.rate["p"]) / ref_obj.scale)[use]
        vals = slit_correction(vals, k_band, _nominal(kn, "slit_fwhm_nm"))
    return dataclasses.replace(samples, value=vals.reshape(-1),
                               sigma=samples.sigma if sig is None else sig.reshape(-1))  # fmt: skip


def _stray_correction(setup: _Setup) -> float:
    """The stray-light fraction the laboratory removes (its data sheet's; 0 = off)."""
    if not setup.corrections.get("stray"):
        return 0.0
    return _nominal(setup.knowledge, "stray_light_fraction")


def _reference_s(ref: Any, cfg: Any) -> float:
    """Real-instrument time of one re-measured reference like ``ref`` (its integration
    time) on the configuration ``cfg``."""
    from gonio.simulator.cornell_plans import Timing, reference_seconds

    return reference_seconds(Timing(), float(ref.meta.get("t", 1.0)), cfg.n_reference_reads)


def _drift_summary(p: Any, res: dict, cfg: Any) -> dict[str, Any]:
    """``n_references`` and ``reference_drift`` (hours, mean rate / the first's) of a
    campaign through the drivers, its references placed in time by the run-time estimate
    (the laboratory's clock: geometries measured x the estimated time per geometry, plus
    the earlier re-measured references' time,
    :func:`gonio.simulator.cornell_plans.reference_seconds`)."""
    from gonio.simulator.cornell import _reference_drift
    from gonio.simulator.cornell_plans import Timing, estimate_run_time

    per_s = estimate_run_time(p, Timing(), res["t"])["per_measurement_s"]
    ref_s = _reference_s(res["reference"], cfg)
    refs = [(count * per_s + k * ref_s, ref) for k, (count, ref) in enumerate(res["references"])]
    return {"n_references": len(refs), "reference_drift": _reference_drift(refs)}


def _measure_in_process(setup: _Setup) -> tuple[BRDFSamples, Any, None, dict[str, Any]]:
    """The plan measured by the simulator in this process; samples, reference, no integration
    times (they are estimated), extra summary fields."""
    from gonio.simulator.cornell import simulate_campaign

    stray = _stray_correction(setup)
    refs: list = []
    samples = simulate_campaign(
        setup.plan, setup.material, rng=setup.seed, noise=setup.noise,
        reference=setup.reference, config=setup.cfg, order=False,
        reference_every=setup.reference_every,
        drift_correction=bool(setup.corrections.get("drift", True)), stray_correction=stray,
        references=refs,
    )  # fmt: skip
    samples.metadata.update(setup.meta)
    ref_obj = refs[0][1]  # the campaign's first reference (with the beam trap's stray light)
    extra = {"through_drivers": False, "n_geometries": len(setup.plan),
             "n_saturated": int(samples.metadata.get("n_saturated", 0))}  # fmt: skip
    for k in ("n_references", "reference_drift", "campaign_clock_h"):
        if k in samples.metadata:
            extra[k] = samples.metadata[k]
    return samples, ref_obj, None, extra


def _measure_through_drivers(
    setup: _Setup, *, resume: bool, time_scale: float, faults: Any, checkpoint_every: int,
    prime: bool, on_measurement: Any, device_timeout: float,
) -> tuple[BRDFSamples, Any, np.ndarray, dict[str, Any]]:  # fmt: skip
    """The plan measured through the real drivers on the fake devices (checkpointed, so a
    resumed run measures only what is missing)."""
    from gonio.campaign.drivers import (
        Checkpoint,
        fake_cornell_rig,
        fingerprint,
        run_cornell_measurements,
    )

    p, outp = setup.plan, setup.out
    extra: dict[str, Any] = {"through_drivers": True, "n_geometries": len(p)}
    key = fingerprint({**setup.settings,
                       "angles": fingerprint(np.round(np.degrees(p.angles), 6))})  # fmt: skip
    ck = None
    if outp is not None:
        ck = Checkpoint(outp / "checkpoint.npz", key, every=checkpoint_every)
        if resume:
            ck.load()
        elif (outp / "checkpoint.npz").exists():
            (outp / "checkpoint.npz").unlink()
            (outp / "reference.npz").unlink(missing_ok=True)
            for f in outp.glob("reference_*_*.npz"):  # re-measured references
                f.unlink()
            if (outp / "spectra").is_dir():  # raw spectra kept for the drift correction
                shutil.rmtree(outp / "spectra")
    with fake_cornell_rig(
        setup.material, seed=setup.seed, noise=setup.noise, config=setup.cfg,
        time_scale=time_scale, faults=faults, prime=p.angles if prime else None,
        device_timeout=device_timeout,
    ) as (rig, _parts):  # fmt: skip
        res = run_cornell_measurements(
            rig, np.degrees(p.angles), config=setup.lab, reference=setup.reference,
            checkpoint=ck, reference_path=(outp / "reference.npz") if outp is not None else None,
            on_measurement=on_measurement, reference_every=setup.reference_every,
            drift_correction=bool(setup.corrections.get("drift", True)),
            stray_correction=_stray_correction(setup),
        )  # fmt: skip
        extra["device_reads"] = rig.n_reads
        extra["device_moves"] = rig.n_moves
    if setup.reference_every:
        extra.update(_drift_summary(p, res, setup.lab))
    sig = res["sigma"] if setup.noise else np.full_like(res["sigma"], np.nan)
    samples = _samples_from(
        np.radians(res["positions_deg"]), res["value"], sig, setup.lab.kinematics, setup.meta
    )
    extra["resumed_geometries"] = int(res["resumed"])
    extra["n_saturated"] = int(res["saturated"].sum())
    if ck is not None:
        extra["checkpoint_writes"] = ck.writes
    return samples, res["reference"], res["t"], extra


def _run_time_estimate(setup: _Setup, samples: BRDFSamples, t_int: Any, ref: Any) -> dict[str, Any]:
    """What the real instrument would take for the plan, its re-measured references
    included (summary fields)."""
    from gonio.simulator.cornell_plans import Timing, estimate_run_time

    p = setup.plan
    extra: dict[str, Any] = {}
    kw = {"reference_every": setup.reference_every, "reference_s": _reference_s(ref, setup.lab)}
    if t_int is None:
        est = estimate_run_time(p, Timing(), None, **kw)
        est_h = float(samples.metadata.get("estimated_run_time_h", est["total_h"]))
        est["total_u_h"] = float(samples.metadata.get("estimated_run_time_u_h", est["total_u_h"]))
    else:
        est = estimate_run_time(p, Timing(), t_int, **kw)
        est_h = float(est["total_h"])
        extra["estimated_real_instrument_breakdown_h"] = {
            k: round(est[k] / 3600.0, 3) for k in ("move_s", "integration_s", "overhead_s")
        }
        extra["mean_integration_s"] = float(np.mean(t_int))
    extra["estimated_real_instrument_h"] = est_h
    extra["estimated_real_instrument_u_h"] = float(est["total_u_h"])
    return extra


def _report(
    setup: _Setup, res_fit: Any, info: dict[str, Any], samples: BRDFSamples, ref_obj: Any,
    timings: dict[str, float], extra: dict[str, Any], budget: bool = True,
) -> dict[str, Any]:  # fmt: skip
    """The summary of a fitted campaign (with the reference's and the stray-light offset's
    error contributions when noise is on, and the uncertainty budget); writes ``fit.json``."""
    cfg = setup.lab
    ref_err = reference_band_error(ref_obj, cfg) if setup.noise else np.zeros(31)
    offset_err = None
    if setup.noise:  # the stray-light estimate's additive offset, through each k
        sd = stray_offset_error(ref_obj, cfg)
        sens = offset_sensitivity(res_fit.model, samples, info["free_k"], cfg)
        offset_err = {
            f"{k}[{b}]": float(abs(g[b]) * sd[b]) for k, g in sens.items() for b in range(31)
        }
    summary = _summarise(
        setup.material, res_fit, info, samples, setup.seed, setup.noise, timings, extra,
        ref_err, offset_err,
    )  # fmt: skip
    summary["effects"] = setup.settings["effects"]
    summary["instrument_seed"] = setup.settings["instrument_seed"]
    summary["corrections"] = setup.corrections
    summary["n_refused_footprint"] = setup.settings["n_refused_footprint"]
    summary["warnings"] = list(res_fit.warnings)  # the fit's notes, one list (issue 35)
    if setup.fx is not None:
        summary["true_effects"] = dict(setup.fx)  # the truth side of the comparison
    if budget:
        from gonio.campaign.cornell_budget import cornell_budget

        summary["budget"] = cornell_budget(
            res_fit, info, samples, ref_obj, cfg, setup.knowledge, setup.corrections,
            summary, reference_every=setup.reference_every, angles=setup.plan.angles,
        )  # fmt: skip
    if setup.out is not None:
        _write_json(setup.out / "fit.json", res_fit.to_dict())
    return summary


def summary_text(summary: dict[str, Any]) -> str:
    """A short text report of a summary."""
    how = "drivers" if summary.get("through_drivers") else "in-process"
    lines = [
        f"{summary['material']} (cornell, {how}): "
        f"{summary.get('n_geometries')} geometries, {summary['n_samples']} samples, "
        f"est. real instrument {summary.get('estimated_real_instrument_h', float('nan')):.2f}"
        f" +- {summary.get('estimated_real_instrument_u_h', float('nan')):.2f} h"
    ]
    if summary.get("model"):
        fitp, rel, se = summary["fit"], summary["relative_error"], summary["stderr"]
        for k in ("sigma", "tau", "sigma/tau"):
            if k in rel:
                lines.append(
                    f"  {k}: truth {summary['truth'][k]:.5g} fit {fitp[k]:.5g}"
                    f" (stderr {se.get(k) or float('nan'):.2g}) rel.err {100 * rel[k]:.3f}%"
                )
        ks = summary["k_summary"]
        if ks["max_relative_error"] is not None:
            lines.append(
                f"  k's: {ks['n']} free, max rel.err {100 * ks['max_relative_error']:.3f}%,"
                f" {ks['n_within_3_sigma']}/{ks['n_with_stderr']} within 3 stderr"
            )
        lines.append(
            f"  fit_mode {summary['fit_mode']}, converged {summary['converged']},"
            f" rms {summary['rms']:.4g}"
        )
    lines += [f"  warning: {w}" for w in summary.get("warnings", [])]
    if summary.get("budget"):
        from gonio.campaign.cornell_budget import budget_text

        lines.append(budget_text(summary["budget"]))
    if summary.get("effects") is not None:
        n_ref = summary.get("n_refused_footprint", 0)
        lines.append(
            f"  instrument {summary['effects']!s} (seed {summary.get('instrument_seed')}),"
            f" {n_ref} geometries refused (footprint)"
        )
    lines.append(
        "  time (s): " + ", ".join(f"{k} {v:.2f}" for k, v in summary["timings_s"].items())
    )
    return "\n".join(lines)


def identifiability_scan(
    material: str, ratios: tuple[float, ...] = (0.5, 1.0, 2.0), *, plan: Any = "incidence"
) -> list[dict[str, float]]:
    """Noise-free check of the σ/τ degeneracy: the largest relative change of the model over
    the plan's geometries when σ and τ are both scaled by each factor (σ/τ fixed)."""
    from gonio import materials
    from gonio.simulator.cornell import CornellConfig

    cfg = CornellConfig()
    p = build_plan(plan, config=cfg)
    from gonio.simulator.cornell import forward

    wi, wo = forward(p.angles, cfg.kinematics)
    base = materials.get(material)
    f0 = base(wi, wo)
    out = []
    rho0 = base.delta(wi)[1] if base.has_delta else None
    if rho0 is not None and not np.max(rho0) > 0:
        rho0 = None
    for r in ratios:
        m = type(base)(**{**base.params, "sigma": base.params["sigma"] * r,
                          "tau": base.params["tau"] * r})  # fmt: skip
        f = m(wi, wo)
        big = f0 > 1e-3 * f0.max()
        ch = float(np.max(np.abs(f - f0)[big] / f0[big])) if big.any() else 0.0
        if rho0 is not None:  # the mirror part's reflectance rho = k_dd F S exp(-g)
            rho = m.delta(wi)[1]
            ok = rho0 > 1e-3 * rho0.max()
            ch = max(ch, float(np.max(np.abs(rho - rho0)[ok] / rho0[ok])))
        out.append({"scale": r, "max_rel_change": ch})
    return out


# ----------------------------------------------------------------------------- entry point
def main(argv: list[str] | None = None) -> int:
    """``python -m gonio.campaign.cornell [--material M] [--plan P] ...``"""
    ap = argparse.ArgumentParser(
        prog="python -m gonio.campaign.cornell", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--material", default="garnet_red_paint")
    ap.add_argument("--plan", default="incidence", help="incidence | hemispherical | CSV path")
    ap.add_argument("--noise", default="on", choices=("on", "off"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--through-drivers", action="store_true")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument(
        "--fit-mode", default="auto", choices=("auto", "both", "sigma_fixed", "tau_fixed")
    )
    ap.add_argument("--max-geometries", type=int, default=None)
    ap.add_argument("--time-scale", type=float, default=1e4)
    ap.add_argument("--no-fit", action="store_true")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--json", default=None, help="write the summary here")
    a = ap.parse_args(argv)
    try:
        s = run_cornell_campaign(
            a.material, plan=a.plan, noise=a.noise == "on", seed=a.seed, out=a.out,
            through_drivers=a.through_drivers, quiet=True, resume=a.resume, fit=not a.no_fit,
            fit_mode=a.fit_mode, max_geometries=a.max_geometries, time_scale=a.time_scale,
        )  # fmt: skip
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    s.pop("_samples", None)
    if not a.quiet:
        print(summary_text(s))
    if a.json:
        _write_json(Path(a.json), s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
