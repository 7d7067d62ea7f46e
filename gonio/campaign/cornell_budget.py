"""The uncertainty budget of a Cornell campaign, in the way of the GUM.

For every fitted parameter: the statistical standard error of the fit from the detector
noise (the covariance from the samples' own standard errors, not rescaled by chi2/dof: the
misfit the instrument's effects cause belongs to their terms, and rescaling counted it
twice — aluminized non-glare glass, chi2/dof 159 on the realistic instrument, a statistical
term 12.6 times its noise), beside the contribution of each effect — its sensitivity
times the standard uncertainty of the effect after the laboratory's correction — combined
in quadrature (uncorrelated inputs) and expanded at k = 2 (JCGM 100:2008, §5.1.2, §6.2).

Sensitivities are linearised (JCGM 100:2008 §5.1.3): the laboratory's own model of how an
effect of unit size changes every reading (``δy``, from the fitted model and the reference —
never from the simulator's truth) is propagated through the fit's linear response
``δp = (Jᵀ W J)⁻¹ Jᵀ W δy`` with ``J`` the Jacobian of the fitted li_torrance model (the
k's are its linear coefficients; σ, τ by central differences) and ``W`` the fit's weights.
The uncertainty after correction: the effect's spread between instruments (what the data
sheet or a characterisation leaves open) where the campaign corrects it; its whole
magnitude where the correction is ablated. Effects drawn afresh at every geometry (the
stages' positioning noise) are propagated geometry by geometry
(:func:`propagate_independent`); the sample's tilt and the stages' backlash change the
irradiance too (``cos θi'`` against the nominal ``cos θi`` the reduction divides by), which
at grazing incidence outweighs their change of the BRDF.

The output has the shape the LBL campaign's budget will have (per parameter ``stat``,
``contributions``, ``combined``, ``U``); the two can share the propagation
(:func:`propagate`) and the combination (:func:`combine`), which know nothing of the
instrument.

References
----------
JCGM 100:2008. Evaluation of measurement data - Guide to the expression of uncertainty in
measurement (GUM). Joint Committee for Guides in Metrology. §5.1 (combined standard
uncertainty), §6.2 (expanded uncertainty).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.samples import BRDFSamples

__all__ = ["combine", "cornell_budget", "propagate", "propagate_independent"]

_K = ("k_dd", "k_udf", "k_uds", "k_fs")


def propagate(jac: NDArray, weights: NDArray, patterns: NDArray) -> NDArray:
    """Linear response of the fitted parameters to data perturbations: ``(P, E)`` for a
    Jacobian ``(n, P)``, weights ``(n,)`` and perturbations ``(n, E)`` (weighted least
    squares, JCGM 100:2008 §5.1.3 sensitivities)."""
    jw = jac * weights[:, None]
    return np.linalg.lstsq(jw, patterns * weights[:, None], rcond=None)[0]


def propagate_independent(
    jac: NDArray, weights: NDArray, patterns: dict[str, list[NDArray]], nb: int
) -> dict[str, NDArray]:
    """Variance ``(P,)`` of the fitted parameters from perturbations drawn independently at
    every geometry (rows ``(G, nb)`` of each pattern; the bands of one geometry move
    together): ``Σ_g (Σ_b S[:, g b] δy[g b])²`` with ``S = (Jᵀ W J)⁻¹ Jᵀ W`` the weighted
    least-squares response (the patterns of one effect add)."""
    if not patterns:
        return {}
    s = np.linalg.pinv(jac * weights[:, None]) * weights[None, :]  # (P, n)
    out = {}
    for name, pats in patterns.items():
        var = np.zeros(s.shape[0])
        for q in pats:
            t = (s * np.nan_to_num(q).reshape(1, -1)).reshape(s.shape[0], -1, nb).sum(axis=2)
            var += np.sum(t * t, axis=1)
        out[name] = var
    return out


def combine(stat: float | None, contributions: dict[str, float], k: float = 2.0) -> dict[str, Any]:
    """``stat`` and the contributions combined in quadrature; expanded at coverage ``k``."""
    s = 0.0 if stat is None or not math.isfinite(stat) else float(stat)
    uc = math.sqrt(s * s + sum(float(v) ** 2 for v in contributions.values()))
    return {
        "stat": s,
        "contributions": {n: float(v) for n, v in contributions.items()},
        "combined": uc,
        "U": k * uc,
        "k": k,
    }


def _unique(samples: BRDFSamples, nb: int) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    g = len(samples) // nb
    wi, wo = samples.wi[::nb], samples.wo[::nb]
    y = samples.value.reshape(g, nb)
    w = (1.0 / samples.sigma).reshape(g, nb) if samples.has_sigma else np.ones((g, nb))
    return wi, wo, y, np.where(np.isfinite(w), w, 0.0)


def _model_values(model: Any, wi: NDArray, wo: NDArray, nb: int, **change: Any) -> NDArray:
    m = type(model)(**{**model.params, **change}) if change else model
    return np.asarray(m(wi, wo), float).reshape(len(wi), -1) * np.ones((1, nb))


def _jacobian(model: Any, free: list[str], wi: NDArray, wo: NDArray, nb: int) -> NDArray:
    """Columns: every free parameter, rows: geometry x band (row-major)."""
    g = len(wi)
    cols = []
    zero = {k: 0.0 for k in _K if k in model.params}
    basis: dict[str, NDArray] = {}
    for name in free:
        if "[" in name:
            k, b = name.split("[")[0], int(name.split("[")[1].rstrip("]"))
            if k not in basis:
                basis[k] = _model_values(model, wi, wo, nb, **{**zero, k: np.ones(nb)})
            col = np.zeros((g, nb))
            col[:, b] = basis[k][:, b]
        else:
            v = float(model.params[name])
            h = 1e-4 * v
            up = _model_values(model, wi, wo, nb, **{name: v + h})
            dn = _model_values(model, wi, wo, nb, **{name: v - h})
            col = (up - dn) / (2 * h)
        cols.append(col.reshape(-1))
    return np.stack(cols, axis=1)


def _u_after(knowledge: dict, name: str, corrected: bool) -> float:
    typ, spread = knowledge.get(name, (0.0, 0.0))
    return float(spread) if corrected else math.hypot(typ, spread)


def _patterns(
    model: Any,
    wi: NDArray,
    wo: NDArray,
    y: NDArray,
    kref: NDArray,
    cfg: Any,
    knowledge: dict,
    corr: dict,
    lamp_u: float,
    mirror_part: bool = False,
    angles: NDArray | None = None,
) -> dict[str, NDArray]:
    """The laboratory's model of each effect's change of the readings, at its uncertainty
    after correction: ``{effect: (G, nb)}`` (or a list of patterns to add in quadrature)."""
    out: dict[str, Any] = {}
    out.update(_spectral_patterns(y, kref, knowledge, corr))
    if lamp_u:
        out["lamp_drift"] = lamp_u * y
    out.update(_cone_patterns(model, wi, wo, y, cfg, knowledge, mirror_part))
    out.update(_geometry_patterns(model, wi, wo, y.shape[1], cfg, knowledge, angles))
    out.update(_footprint_patterns(wi, wo, y, knowledge, corr))
    return out


def _spectral_patterns(y: NDArray, kref: NDArray, knowledge: dict, corr: dict) -> dict:
    """The spectrometer's effects: stray light, slit function, wavelength scale,
    non-linearity (each at its uncertainty after correction)."""
    out: dict[str, Any] = {}
    yr = np.clip(y, 0, None) * kref[None, :]
    u = _u_after(knowledge, "stray_light_fraction", corr["stray"])
    if u:
        rel = yr.mean(1, keepdims=True) / np.where(yr > 0, yr, np.inf) - kref.mean() / kref
        out["stray_light_fraction"] = u * y * np.where(yr > 0, rel, 0.0)
    d1 = np.gradient(y, 10.0, axis=1)
    u = _u_after(knowledge, "slit_fwhm_nm", corr["slit"])
    if u:
        fw = knowledge.get("slit_fwhm_nm", (0.0, 0.0))[0] or u
        d2 = np.zeros_like(y)
        d2[:, 1:-1] = (y[:, 2:] - 2 * y[:, 1:-1] + y[:, :-2]) / 100.0
        dlk = np.gradient(np.log(kref), 10.0)
        out["slit_fwhm_nm"] = (
            u * 2 * fw / (2.0 * math.sqrt(2.0 * math.log(2.0))) ** 2 * (dlk * d1 + 0.5 * d2)
        )
    u = _u_after(knowledge, "wavelength_shift_nm", False)
    if u:
        out["wavelength_shift_nm"] = u * d1
    u = _u_after(knowledge, "nonlinearity", False)
    if u:
        xs = yr / np.maximum(yr.max(1, keepdims=True), 1e-300)
        out["nonlinearity"] = -u * 0.7 * y * (xs - kref / kref.max())
    return out


def _cone_patterns(
    model: Any, wi: NDArray, wo: NDArray, y: NDArray, cfg: Any, knowledge: dict, mirror: bool
) -> dict:
    """The source's solid angle (the mirror part's top hat ρ / (Ω_s cos θi) scales as
    1/Ω_s) and the cones' radiance profiles."""
    from gonio.campaign.cornell_lab import cone_response

    out: dict[str, Any] = {}
    u = _u_after(knowledge, "source_solid_angle_error", False)
    if u and mirror:
        plain = type(model)(**{**model.params, "specular": False, "d_omega_i": None})
        out["source_solid_angle_error"] = -u * (
            cone_response(model, wi, wo, cfg) - cone_response(plain, wi, wo, cfg)
        )
    ts = _u_after(knowledge, "source_cone_taper", False)
    td = _u_after(knowledge, "detector_cone_taper", False)
    if ts or td:
        base = cone_response(model, wi, wo, cfg)
        rel = cone_response(model, wi, wo, cfg, taper=(ts, td)) / np.where(base > 0, base, 1) - 1
        out["cone_taper"] = y * rel
    return out


def _geometry_patterns(
    model: Any, wi: NDArray, wo: NDArray, nb: int, cfg: Any, knowledge: dict,
    angles: NDArray | None = None,
) -> dict:  # fmt: skip
    """The sample's tilt and wobble and the stages' backlash: the true directions differ
    from the commanded ones the reduction uses. The reading is the BRDF at the true
    directions times the true irradiance ``cos θi'`` over the nominal ``cos θi`` the
    reduction divides by. A tilt of magnitude ``t`` at an unknown azimuth is two
    independent tilts about x and y of ``t / √2`` each; the backlash a lag of half the band
    on every axis at once (one magnitude for the three stages), each to the side the plan's
    order of moves (``angles``, :func:`lag_sides`) puts it."""
    from gonio.campaign.cornell_lab import mirror_response
    from gonio.simulator.cornell import forward, inverse

    out: dict[str, Any] = {}
    mirror = bool(getattr(model, "has_delta", False)) and cfg is not None

    def reading(wi2: NDArray, wo2: NDArray) -> NDArray:
        # the smooth part, and a mirror part's top hat where the detector sees it (a tilt
        # moves the mirror image of the source by twice its angle)
        f = _model_values(model, wi2, wo2, nb)
        return f + mirror_response(model, wi2, wo2, cfg) if mirror else f

    f0 = reading(wi, wo)
    cos0 = np.where(wi[:, 2] > 0, wi[:, 2], 1.0)

    def change(wi2: NDArray, wo2: NDArray) -> NDArray:
        irr = np.clip(wi2[:, 2], 0.0, None) / cos0
        return reading(wi2, wo2) * irr[:, None] - f0

    for name in ("sample_tilt_rad", "sample_wobble_rad"):
        u = _u_after(knowledge, name, False)
        if u:
            pats = []
            for axis in (0, 1):
                k = np.zeros(3)
                k[axis] = 1.0
                pats.append(change(_rotate(wi, k, u), _rotate(wo, k, u)) / math.sqrt(2))
            out[name] = pats
    u = _u_after(knowledge, "stage_backlash_deg", False) / 2
    if u:
        if angles is not None and len(angles) == len(wi):
            base, side = np.asarray(angles, float), lag_sides(angles)
        else:  # the order of the moves unknown: a lag to the same side everywhere
            base, side = np.array(inverse(wi, wo, cfg.kinematics).angles, float), None
        # one magnitude for the three stages (the effect's, and the bench's): their lags
        # move together, one pattern
        a = base + math.radians(u) * (1.0 if side is None else side)
        out["stage_backlash_deg"] = change(*forward(a, cfg.kinematics))
    return out


def lag_sides(angles: NDArray, start: NDArray | None = None) -> NDArray:
    """The side each axis's load lags on at every geometry of a campaign measured in the
    order of ``angles`` (N, 3) from ``start`` (default the stages' zero): ``-sign`` of the
    last move of that axis (the backlash of ``gonio.simulator.cornell_physics.stage_offsets``
    and the bench's stages), 0 before its first move."""
    a = np.asarray(angles, float)
    prev = np.zeros(3) if start is None else np.asarray(start, float)
    d = np.diff(np.vstack([prev, a]), axis=0)
    side = np.zeros_like(a)
    last = np.zeros(3)
    for g in range(len(a)):
        last = np.where(d[g] != 0, -np.sign(d[g]), last)
        side[g] = last
    return side


def _independent_patterns(
    model: Any, wi: NDArray, wo: NDArray, nb: int, cfg: Any, knowledge: dict
) -> dict[str, list[NDArray]]:
    """Effects drawn afresh at every geometry: the stages' positioning noise (each axis's
    error at its RMS, independent from geometry to geometry). ``{effect: [(G, nb), ...]}``:
    each pattern's rows are independent draws, not one common shift."""
    from gonio.simulator.cornell import forward, inverse

    u = _u_after(knowledge, "stage_noise_deg", False)
    if not u:
        return {}
    f0 = _model_values(model, wi, wo, nb)
    cos0 = np.where(wi[:, 2] > 0, wi[:, 2], 1.0)
    r = inverse(wi, wo, cfg.kinematics)
    pats = []
    for axis in range(3):
        a = np.array(r.angles, float)
        a[:, axis] += math.radians(u)
        wi2, wo2 = forward(a, cfg.kinematics)
        irr = np.clip(wi2[:, 2], 0.0, None) / cos0
        pats.append(_model_values(model, wi2, wo2, nb) * irr[:, None] - f0)
    return {"stage_noise_deg": pats}


def _footprint_patterns(wi: NDArray, wo: NDArray, y: NDArray, knowledge: dict, corr: dict) -> dict:
    """The lit fraction of the field of view: uncorrected (``footprint="none"``) the whole
    shortfall, divided by the nominal fraction the sizes' uncertainty; refused: nothing."""
    from gonio.campaign.cornell_lab import footprint_fraction

    if corr["footprint"] == "refuse" or knowledge.get("fov_diameter_mm", (0, 0))[0] <= 0:
        return {}
    sizes = [
        knowledge.get(k, (0.0, 0.0))[0]
        for k in ("beam_diameter_mm", "fov_diameter_mm", "sample_size_mm")
    ]
    frac = footprint_fraction(wi, wo, *sizes)
    if corr["footprint"] == "none":
        return {"footprint": y * (frac - 1)[:, None]}
    pats = []
    for j, name in enumerate(("beam_diameter_mm", "fov_diameter_mm")):
        sz = list(sizes)
        sz[j] += knowledge.get(name, (0.0, 0.0))[1]
        f2 = footprint_fraction(wi, wo, *sz)
        pats.append(y * ((f2 - frac) / np.where(frac > 0, frac, 1))[:, None])
    return {"footprint": pats}


def _rotate(w: NDArray, k: NDArray, ang: float) -> NDArray:
    c, s = math.cos(ang), math.sin(ang)
    return w * c + np.cross(k, w) * s + np.outer(w @ k, k) * (1 - c)


def _lamp_u(summary: dict, knowledge: dict, corr: dict, every: int) -> float:
    """Relative uncertainty of the lamp's output left after correction: with re-measured
    references, the leave-one-out residual of their linear interpolation (RMS); without,
    the drift the data sheet allows over the campaign (a rectangular distribution)."""
    drift = summary.get("reference_drift")
    if every and corr["drift"] and drift and len(drift) >= 3:
        t = np.array([d[0] for d in drift])
        r = np.array([d[1] for d in drift])
        res = r[1:-1] - (r[:-2] + (r[2:] - r[:-2]) * (t[1:-1] - t[:-2]) / (t[2:] - t[:-2]))
        return float(np.sqrt(np.mean(res**2)))
    hours = float(summary.get("campaign_clock_h") or summary.get("estimated_real_instrument_h", 0))
    w = math.hypot(*knowledge.get("lamp_warmup", (0.0, 0.0)))
    d = math.hypot(*knowledge.get("lamp_drift", (0.0, 0.0))) * hours
    return (w + d) / math.sqrt(3.0)


def cornell_budget(
    res: Any,
    info: dict,
    samples: BRDFSamples,
    ref: Any,
    cfg: Any,
    knowledge: dict,
    corrections: dict,
    summary: dict,
    *,
    reference_every: int = 0,
    k: float = 2.0,
    angles: NDArray | None = None,
    lamp_u: float | None = None,
) -> dict[str, Any]:
    """The budget of a fitted Cornell campaign (module docstring). ``angles``: the plan's
    commanded motor angles (rad, in the order measured; the side of each stage's backlash).
    ``lamp_u``: the lamp term's relative standard uncertainty, given instead of evaluated
    from the campaign's references (:func:`_lamp_u`; a design's prediction before any
    reference is measured, :func:`gonio.campaign.design.predicted_lamp_u`).

    Returns ``{"parameters": {name: combine(...) + truth_within_U}, "k_summary": {k_dd: ...},
    "coverage": {...}, "effects": [...]}``; the truth is read from ``summary`` (the
    campaign's one comparison with the truth), never used for the uncertainties.
    """
    from gonio.simulator.cornell import BANDS_NM, _hat_projector

    nb = len(BANDS_NM)
    if info.get("mirror_part"):  # the rows the fit used (not the partial mirror peaks)
        from gonio.campaign.cornell import _mirror_partial_mask

        keep = ~_mirror_partial_mask(samples, cfg)
        if not keep.all():
            samples = samples.subset(np.flatnonzero(keep))
            if angles is not None:
                angles = np.asarray(angles)[keep[::nb]]
    wi, wo, y, w = _unique(samples, nb)
    model = res.model
    free = list(res.free)
    use, proj = _hat_projector(tuple(np.round(ref.wavelengths_nm, 9)), tuple(BANDS_NM))
    kref = np.clip(proj @ (0.5 * (ref.rate["s"] + ref.rate["p"]) / ref.scale)[use], 1e-300, None)
    if lamp_u is None:
        lamp_u = _lamp_u(summary, knowledge, corrections, reference_every) if knowledge else 0.0
    elif not (math.isfinite(lamp_u) and lamp_u >= 0):
        raise ValueError(f"lamp_u = {lamp_u!r}: expected a relative uncertainty >= 0")
    pats = {}
    if knowledge:
        pats = _patterns(
            model,
            wi,
            wo,
            y,
            kref,
            cfg,
            knowledge,
            corrections,
            lamp_u,
            bool(info.get("mirror_part")),
            angles,
        )
    cols, names = [], []
    for name, p in pats.items():
        for q in p if isinstance(p, list) else [p]:
            cols.append(np.nan_to_num(q).reshape(-1))
            names.append(name)
    indep = _independent_patterns(model, wi, wo, nb, cfg, knowledge) if knowledge else {}
    contrib: dict[str, dict[str, float]] = {p: {} for p in free}
    if cols or indep:
        jac = _jacobian(model, free, wi, wo, nb)
        acc: list[dict[str, float]] = [{} for _ in free]
        if cols:
            dp = propagate(jac, w.reshape(-1), np.stack(cols, axis=1))
            for i in range(len(free)):
                for e, name in enumerate(names):
                    acc[i][name] = acc[i].get(name, 0.0) + dp[i, e] ** 2
        for name, var in propagate_independent(jac, w.reshape(-1), indep, nb).items():
            names.append(name)
            for i in range(len(free)):
                acc[i][name] = acc[i].get(name, 0.0) + float(var[i])
        for i, p in enumerate(free):
            contrib[p] = {n: math.sqrt(v) for n, v in acc[i].items()}
    params = _combined_parameters(res, free, contrib, summary, nb, k)
    return _with_truth(params, summary, list(dict.fromkeys(names)))


def _combined_parameters(
    res: Any,
    free: list[str],
    contrib: dict[str, dict[str, float]],
    summary: dict,
    nb: int,
    k: float,
) -> dict[str, Any]:
    """Each fitted parameter's budget (:func:`combine`): the detector noise as its
    statistical term, the effects' contributions, and per band the reference's noise and
    the stray-light trap's offset; σ/τ from τ's budget when the fit reports the ratio."""
    ref_rel = summary.get("reference_band_rel_error") or [0.0] * nb
    tot = summary.get("stderr_with_reference", {})
    params: dict[str, Any] = {}
    for p in free:
        c = dict(contrib[p])
        se = res.stderr.get(p)
        # the statistical term: the detector noise alone (the fit's covariance without its
        # chi2/dof scale; the misfit the effects cause is their own terms' business)
        stat = None if se is None else se / math.sqrt(max(float(res.cov_scale), 1.0))
        if "[" in p:
            b = int(p.split("[")[1].rstrip("]"))
            c["reference_noise"] = abs(float(res.params[p])) * float(ref_rel[b])
            st = tot.get(p)
            if st is not None and se is not None and math.isfinite(se):
                rest = st**2 - se**2 - c["reference_noise"] ** 2
                c["stray_trap_offset"] = math.sqrt(max(rest, 0.0))
        params[p] = combine(stat, c, k)
    if "sigma/tau" in summary.get("fit", {}) and "tau" in params and "sigma" not in params:
        r, t = summary["fit"]["sigma/tau"], float(res.params["tau"])
        pt = params["tau"]
        params["sigma/tau"] = combine(
            pt["stat"] * r / t, {n: v * r / t for n, v in pt["contributions"].items()}, k
        )
    return params


def _with_truth(params: dict, summary: dict, effects: list[str]) -> dict[str, Any]:
    truth, fit = summary.get("truth", {}), summary.get("fit", {})
    n_in = n = 0
    ks: dict[str, dict[str, Any]] = {}
    for p, b in params.items():
        if p in truth and p in fit:
            err = abs(fit[p] - truth[p])
            b["error"] = err
            b["truth_within_U"] = bool(err <= b["U"])
            n += 1
            n_in += int(b["truth_within_U"])
            if "[" in p:
                s = ks.setdefault(
                    p.split("[")[0], {"n": 0, "n_within_U": 0, "rel_U": [], "abs_err": []}
                )
                s["n"] += 1
                s["n_within_U"] += int(b["truth_within_U"])
                s["rel_U"].append(b["U"] / max(abs(fit[p]), 1e-12))
                s["abs_err"].append(err)
    for s in ks.values():
        s["median_rel_U"] = float(np.median(s.pop("rel_U")))
        s["rms_error"] = float(np.sqrt(np.mean(np.square(s.pop("abs_err")))))
    return {
        "parameters": params,
        "k_summary": ks,
        "effects": effects,
        "coverage": {"n": n, "n_within_U": n_in},
    }


def budget_text(budget: dict[str, Any]) -> str:
    """Lines of the printed summary: σ/τ (or τ) and each k component."""
    lines = []
    for p in ("sigma", "tau", "sigma/tau"):
        b = budget["parameters"].get(p)
        if b is None:
            continue
        top = sorted(b["contributions"].items(), key=lambda kv: -kv[1])[:3]
        lines.append(
            f"  budget {p}: stat {b['stat']:.3g}, combined {b['combined']:.3g}, "
            f"U(k=2) {b['U']:.3g}; largest: " + ", ".join(f"{n} {v:.2g}" for n, v in top)
        )
    for kname, s in budget["k_summary"].items():
        lines.append(
            f"  budget {kname}: median U/k {100 * s['median_rel_U']:.2f}%, "
            f"truth within U {s['n_within_U']}/{s['n']}"
        )
    c = budget["coverage"]
    lines.append(f"  budget coverage: {c['n_within_U']}/{c['n']} parameters within U (k=2)")
    return "\n".join(lines)


#: terms the laboratory's corrections address (drawn solid in the figure; the rest hatched)
_CORRECTED = {"stray_light_fraction": "stray", "slit_fwhm_nm": "slit", "lamp_drift": "drift",
              "footprint": "footprint"}  # fmt: skip


def figure_view(budget: dict[str, Any], fit: dict[str, float], corrections: dict) -> dict:
    """The budget in the shape :func:`gonio.plots.budget.plot_budget` draws: σ/τ, τ and σ
    (where fitted) as they are, and each k component as the median over its bands of every
    term's relative contribution (times the median ``|k|``, so the panel reads in relative
    terms)."""
    params = budget["parameters"]
    view: dict[str, Any] = {"params": {}, "statistical": {}, "terms": {}, "combined": {},
                            "expanded": {}, "k": 2.0}  # fmt: skip
    names = sorted({n for b in params.values() for n in b["contributions"]})

    def put(label: str, value: float, stat: float, contrib: dict, uc: float, u: float) -> None:
        view["params"][label] = value
        view["statistical"][label] = stat
        view["combined"][label] = uc
        view["expanded"][label] = u
        for n in names:
            c = corrections.get(_CORRECTED.get(n, ""), False) not in (False, "none")
            t = view["terms"].setdefault(n, {"contribution": {}, "corrected": c})
            t["contribution"][label] = float(contrib.get(n, 0.0))

    for p in ("sigma/tau", "tau", "sigma"):
        if p in params and p in fit:
            b = params[p]
            put(p, fit[p], b["stat"], b["contributions"], b["combined"], b["U"])
    families: dict[str, list[str]] = {}
    for p in params:
        if "[" in p and p in fit:
            families.setdefault(p.split("[")[0], []).append(p)
    for fam, ps in families.items():
        ps = [p for p in ps if abs(fit[p]) > 0]
        if not ps:
            continue
        scale = float(np.median([abs(fit[p]) for p in ps]))

        def med(get: Any, ps: list[str] = ps, scale: float = scale) -> float:
            return scale * float(np.median([get(params[p]) / abs(fit[p]) for p in ps]))

        contrib = {n: med(lambda b, n=n: b["contributions"].get(n, 0.0)) for n in names}
        put(f"{fam} (median of {len(ps)} bands)", scale, med(lambda b: b["stat"]), contrib,
            med(lambda b: b["combined"]), med(lambda b: b["U"]))  # fmt: skip
    return view
