"""Measurement design: the plan that reaches a target uncertainty in the least instrument time.

The inverse of the uncertainty budget (:mod:`gonio.campaign.cornell_budget`): given the
instrument, a prior model of the sample (a material preset, its shape parameters optionally
ranging over an interval) and a target expanded uncertainty U (k = 2) per fitted parameter,
choose, among the geometries the instrument can reach, the set that meets every target in the
least real-instrument time.

The predicted U of a plan is the budget's, evaluated at the prior before anything is measured:

* the statistical term from the fit's information matrix ``F = Jᵀ W J`` (``J`` the Jacobian of
  the fitted model at the prior's parameters over the plan's geometries, ``W = 1/σ²`` with
  σ from the instrument's noise model: the simulated detector's shot, dark and read noise at
  the integration time its auto-exposure picks for the prior's reading — the laboratory's
  model of its detector, not a measurement);
* every systematic effect of the budget (the laboratory's knowledge of the instrument: its
  preset's typical magnitudes and spreads) as the fit's linear response ``F⁻¹ Jᵀ W δy`` to
  that effect's pattern ``δy`` over the plan — a term that more data of the same kind does not
  shrink, but which depends on *which* geometries are measured (the sample's tilt moves the
  forward-scattering coefficients much less in some geometries than in others);
* the terms independent of the plan (the reference's noise, a scale error of every band, and
  the lamp's drift): floors no plan goes below. A target below its floor is reported as
  unreachable, with the floor and its dominant term, and is not chased.

The prediction of the designed plan is made by :func:`gonio.campaign.cornell_budget.cornell_budget`
itself (on the prior's predicted readings), so a designed plan's predicted U is the number its
campaign's summary reports, up to the noise of the measured data.

Search: greedy forward selection on the candidate geometries (an exchange-free Fedorov-type
algorithm for a c-/A-optimal criterion with a hinge at the targets): at each step the
candidates that most reduce ``Φ = Σ_p max(0, log(U_p² / T_p²))`` (summed over the prior's
points, so the worst case counts) per second of instrument time are added (rank-31 Woodbury
updates of ``F⁻¹`` that use the Jacobian's block structure: each band's row sees only that
band's coefficients and the shared shape parameters), until every reachable target is met or
the time limit is spent; then a backward pass drops geometries whose removal keeps every
target met, the slowest first.

The reference cadence (``reference_every``: the white reference measured again after every
N geometries and after the last, the campaign's drift correction interpolating between them)
is chosen too, among :data:`CADENCES`, sparsest first. Its cost is the references' time
(:func:`gonio.simulator.cornell_plans.reference_seconds`, the campaign's lamp clock; in the
search each geometry carries its share ``reference_s / N``, and the hours are
:func:`~gonio.simulator.cornell_plans.estimate_run_time` with the references, which equals
the campaign's clock). Its benefit is the budget's lamp term
(``gonio.campaign.cornell_budget._lamp_u``), predicted by :func:`predicted_lamp_u` from the
data sheet's warm-up and drift alone: the warm-up's curvature that the interpolation leaves
at the references of the plan's schedule plus their read noise, evaluated as the campaign
evaluates its own (the leave-one-out residual of three references or more; the data sheet's
bound over the campaign's hours with fewer). A relative scale of every reading moves each
coefficient k by the same relative amount and no shape parameter, so the search takes the
lamp term as a floor of the k's, first for a guessed schedule, then for the plan it found;
the prediction passes it to the budget (``cornell_budget(..., lamp_u=...)``). A denser
cadence is tried only while the lamp term is at least 30 % of some target's uncertainty (a
cadence whose plan would get fewer than three references is skipped: the same term as
none, more time); the design keeps the cadence with the fewest missed targets, then the
least time, and writes it into the plan file, which the campaign applies. The prediction
against campaigns (``benchmarks/bench_design.py --lamp-table 5``: the default plan, 212
geometries, garnet red paint, instruments 0-4; the campaigns' term is the budget's, from
their own references; RMS over the instruments, min-max):

========  ======  ===========  =======================  ====================  =====================
lamp      every   hours        predicted                campaigns' RMS        min - max
========  ======  ===========  =======================  ====================  =====================
default   160     0.675        1.47e-3                  1.26e-3               1.02e-3 - 1.55e-3
default   40      0.745        3.56e-4                  3.25e-4               2.55e-4 - 3.82e-4
default   10      1.027        6.8e-5                   7.0e-5                5.72e-5 - 8.65e-5
default   none    0.639        3.52e-3                  3.52e-3               3.51e-3 - 3.52e-3
5 x       160     0.675        7.34e-3                  6.36e-3               5.09e-3 - 7.78e-3
5 x       40      0.745        1.77e-3                  1.56e-3               1.24e-3 - 1.96e-3
5 x       10      1.027        2.63e-4                  2.31e-4               1.86e-4 - 2.81e-4
5 x       none    0.639        1.76e-2                  1.76e-2               1.76e-2 - 1.76e-2
========  ======  ===========  =======================  ====================  =====================

(5 x: the warm-up and drift, typical and spread, five times cornell2005's, ``--lamp 5``.) The
prediction is 0.97-1.17 times the campaigns' RMS; the RMS over instruments of the warm-up is
used, so a single instrument's term scatters about it (0.69-1.05 times the prediction at
every 160, three references). The search's guess of the schedule can leave it measuring
more geometries at a sparse cadence where fewer at a denser one are quicker, which is why a
denser cadence is tried while the lamp term matters even with every target met (the
cadences tried are in ``meta["cadences_tried"]``). Measured (garnet red paint,
``--target "k_dd[20]=0.65%" --validate 20``, 13 x 13 candidates): 10 geometries with the
reference every 4 geometries, 0.074 h (the target lies below the floor without
references); achieved / predicted U 0.976-1.021 (median 1.001), the target met on 20/20
instruments, but the truth within U for only 1637/1900 parameters: on instruments 1 and
2 every k_dd band is fitted 1-2 % low with U 0.4-0.6 %, and the same without re-measured
references (``reference_every=0`` on that plan) — a systematic that this 10-geometry
plan's budget misses, not the lamp's; not resolved.

Measured (garnet red paint, cornell2005, every parameter at 5 %, the default 13 x 13 grid:
1186 candidates): a 5-geometry plan of 0.029 h, the first reference only (the default plan:
0.74 h with its references every 40, k_fs at ~25 %;
the hemispherical plan: 11.4 h) run on instruments 0-19: the truth within the achieved U for
1878/1900 parameters, achieved / predicted U 0.86-1.16 (median 1.003), every target met
(1880/1880). A prediction holds for the model it is made with: so few geometries leave
little redundancy to reveal a wrong model. The greedy search can stall short of a target
that a plan could reach when a systematic term dominates (seen with a 3 x 3 grid).

References
----------
.. [JCGM100] JCGM 100:2008, Evaluation of measurement data - Guide to the expression of
   uncertainty in measurement, §5.1 (combined standard uncertainty), §6.2 (expanded
   uncertainty): the budget this module predicts.
.. [Fedorov1972] V. V. Fedorov, "Theory of Optimal Experiments", Academic Press, 1972, ch. 2-3:
   sequential (greedy) construction of A- and c-optimal designs by rank updates of the
   information matrix.
.. [Atkinson2007] A. C. Atkinson, A. N. Donev and R. D. Tobias, "Optimum Experimental
   Designs, with SAS", Oxford University Press, 2007, ch. 10 and 17: A-, c- and D-optimality,
   designs for non-linear models at a prior point and robust over a prior range.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CADENCES",
    "DesignError",
    "DesignResult",
    "design_cornell",
    "parse_prior",
    "parse_targets",
    "predicted_lamp_u",
    "reference_mean_noise",
    "reference_times",
]

_K = ("k_dd", "k_udf", "k_uds", "k_fs")

#: the reference cadences the design tries, sparsest first (0: the first reference only;
#: N: the reference again after every N geometries and after the last)
CADENCES = (0, 160, 40, 10, 4, 2, 1)

#: the campaign's cadence when its plan does not set one (gonio.campaign.cornell: a
#: realistic instrument)
_CAMPAIGN_CADENCE = 40


class DesignError(ValueError):
    """An input a design cannot be made from (names what was wrong)."""


class _NothingReachable(DesignError):
    """Every target lies below its floor at a cadence (``unreachable``: their floors)."""

    def __init__(self, unreachable: dict[str, dict[str, Any]]) -> None:
        super().__init__("every target lies below its floor")
        self.unreachable = unreachable


# ----------------------------------------------------------------------------- inputs
def parse_targets(items: list[str] | None) -> dict[str, tuple[float, bool]]:
    """``["k_fs=5%", "tau=0.01"]`` → ``{"k_fs": (0.05, True), "tau": (0.01, False)}``
    (relative when written with ``%``, else absolute, in the parameter's unit). An empty list
    means every parameter at 5 %. A name is a parameter (``tau``), a per-band family
    (``k_fs``: every band) or one band (``k_fs[12]``); ``all`` sets every parameter."""
    out: dict[str, tuple[float, bool]] = {}
    for item in items or ["all=5%"]:
        m = re.fullmatch(r"\s*([A-Za-z_][\w/]*(?:\[\d+\])?)\s*=\s*([^%\s]+)\s*(%?)\s*", item)
        if not m:
            raise DesignError(f"target {item!r}: expected NAME=VALUE or NAME=VALUE% (e.g. k_fs=5%)")
        name, val, pct = m.groups()
        try:
            v = float(val)
        except ValueError:
            raise DesignError(f"target {item!r}: {val!r} is not a number") from None
        if not (math.isfinite(v) and v > 0):
            raise DesignError(f"target {item!r}: expected a positive, finite uncertainty")
        out[name] = (v / 100.0 if pct else v, bool(pct))
    return out


def parse_prior(items: list[str] | None) -> dict[str, tuple[float, float]]:
    """``["tau=7:9.5"]`` → ``{"tau": (7.0, 9.5)}``: the prior range of a shape parameter."""
    out: dict[str, tuple[float, float]] = {}
    for item in items or []:
        m = re.fullmatch(r"\s*(\w+)\s*=\s*([^:]+):([^:]+)\s*", item)
        if not m:
            raise DesignError(f"prior {item!r}: expected NAME=LOW:HIGH (e.g. tau=7:9.5)")
        try:
            lo, hi = float(m.group(2)), float(m.group(3))
        except ValueError:
            raise DesignError(f"prior {item!r}: LOW and HIGH must be numbers") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise DesignError(f"prior {item!r}: expected finite LOW <= HIGH")
        out[m.group(1)] = (lo, hi)
    return out


# ----------------------------------------------------------------------------- candidates
@dataclasses.dataclass
class _Candidates:
    """Everything the search needs about the reachable candidate geometries."""

    plan: Any  # gonio.simulator.cornell_plans.Plan (measurable, footprint-safe)
    names: list[str]  # fitted parameters: shape parameters first, then k[b] per family
    n_shape: int
    free_k: list[str]
    values: NDArray  # (G, nb) predicted readings at the prior's nominal point
    sigma: NDArray  # (G, nb) the detector's predicted standard error
    t_int: NDArray  # (G,) integration time the auto-exposure picks
    seconds: NDArray  # (G,) instrument time of one geometry (mean move included)
    jt: list[NDArray]  # per prior point: (G, nb, n_shape) shape-parameter columns
    jk: list[NDArray]  # per prior point: (G, nb, nk) k columns (band b's own)
    pats: list[NDArray]  # per prior point: (E, G, nb) systematic patterns
    pat_names: list[str]
    const: NDArray  # (P,) plan-independent standard uncertainty (floor)
    const_terms: dict[str, NDArray]  # its terms
    prior_points: list[dict[str, float]]
    ref: Any = None
    lab: Any = None
    knowledge: dict = dataclasses.field(default_factory=dict)
    corrections: dict = dataclasses.field(default_factory=dict)
    model: Any = None
    info: dict = dataclasses.field(default_factory=dict)
    default: dict | None = None  # the default plan's prediction, made once (_default_prediction)


def _prior_points(truth: Any, fitted_shape: list[str], prior: dict) -> list[dict[str, float]]:
    """The prior's nominal point, then each shape parameter at its range's ends."""
    from gonio import brdf

    bounds = brdf.spec(truth.name).bounds
    for name, (lo, hi) in prior.items():
        if name not in bounds or name not in fitted_shape:
            raise DesignError(
                f"prior {name}: not a fitted shape parameter; expected one of {fitted_shape}"
            )
        blo, bhi = bounds[name]
        if lo < blo or hi > bhi:
            raise DesignError(
                f"prior {name}={lo}:{hi} lies outside the model's bounds [{blo}, {bhi}]"
            )
    nominal = {k: float(truth.params[k]) for k in fitted_shape}
    for name, (lo, hi) in prior.items():
        if not lo <= nominal[name] <= hi:
            nominal[name] = 0.5 * (lo + hi)
    pts = [nominal]
    for name, (lo, hi) in prior.items():
        for v in (lo, hi):
            if v != nominal[name]:
                pts.append({**nominal, name: float(v)})
    return pts


def _candidate_plan(lab: Any, knowledge: dict, n_grid: int, theta_i_deg: tuple) -> Any:
    """The reachable candidates: a hemispherical grid of viewing directions at each incidence
    angle and the default incidence-plane plan (its fine scans near the specular direction),
    on the controller's grid, without the geometries the campaign refuses for the footprint."""
    from gonio.campaign.cornell import _refuse_footprint, build_plan
    from gonio.simulator.cornell_plans import (
        Plan,
        hemispherical_plan,
        incidence_plane_plan,
    )

    kin = lab.kinematics
    h = hemispherical_plan(theta_i_deg, n=n_grid, kin=kin)
    ip = incidence_plane_plan(kin=kin)
    both = Plan(
        np.concatenate([h.wi, ip.wi]), np.concatenate([h.wo, ip.wo]),
        np.concatenate([h.angles, ip.angles]), np.concatenate([h.reachable, ip.reachable]),
        np.concatenate([h.group, ip.group + h.group.max() + 1]), {"kind": "design candidates"},
    )  # fmt: skip
    p = build_plan(both, config=lab)
    if knowledge:
        p, _ = _refuse_footprint(p, lab, knowledge)
    # one candidate per motor position
    _, first = np.unique(np.round(np.degrees(p.angles), 6), axis=0, return_index=True)
    return p.subset(np.sort(first))


#: effects that change the detected counts (so the noise) but not the geometry; the
#: prediction's instrument has them at the laboratory's nominal magnitudes
_COUNT_EFFECTS = ("stray_light_fraction", "slit_fwhm_nm", "sample_polarisation",
                  "source_cone_taper", "detector_cone_taper")  # fmt: skip


def _predicted_readings(
    model: Any, plan: Any, lab: Any, knowledge: dict, reference: str = "standard",
    order: str = "campaign",
):  # fmt: skip
    """The prior's readings on the simulated instrument as the laboratory knows it
    (nominal configuration; the effects that change the counts at their nominal magnitudes,
    :data:`_COUNT_EFFECTS`, and the stray-light correction the campaign applies): values,
    the detector's standard errors at the auto-exposure's integration times, the
    integration times, and the reference.

    The auto-exposure previews through the polariser the campaign puts first at that
    geometry (alternating with its index): ``order="campaign"`` reads the plan as the
    campaign will measure it; ``"worst"`` reads every geometry both ways and keeps the
    larger standard errors (and longer time) — a candidate's place in the plan is not
    known yet."""
    from gonio.simulator.cornell import (
        BANDS_NM,
        CornellInstrument,
        effective_cos,
        first_polarizer,
        forward,
        reduce_measurement,
    )
    from gonio.simulator.cornell_effects import EFFECTS

    fx = {k: float(knowledge[k][0]) for k in _COUNT_EFFECTS if knowledge.get(k, (0, 0))[0]}
    cfg = dataclasses.replace(lab, effects={**dict.fromkeys(EFFECTS, 0.0), **fx}) if fx else lab
    stray = float(knowledge.get("stray_light_fraction", (0.0, 0.0))[0])
    # with the detector's noise on (a fixed seed): the auto-exposure reads the peak of a noisy
    # preview, so its integration times (and the standard errors) are the noisy instrument's
    # (the noise-free preview's give up to 2x longer times at a dark sample)
    inst = CornellInstrument(model, config=cfg, noise=True, rng=0)
    ref = inst.calibrate(reference)
    inst.prime(plan.angles)
    wi, _ = forward(plan.angles, lab.kinematics)
    ce = effective_cos(wi, lab)
    g, nb = len(plan), len(BANDS_NM)
    vals, sig, t = np.empty((g, nb)), np.zeros((g, nb)), np.zeros(g)
    for j, ang in enumerate(plan.angles):
        inst.move_to(ang)
        firsts = (first_polarizer(j),) if order == "campaign" else ("s", "p")
        for q in firsts:
            raws = inst.measure_raw("sample", first=q)
            v, sj, _ = reduce_measurement(raws, ref, float(ce[j]), lab, BANDS_NM, stray)
            vals[j] = v
            if np.sum(sj) > np.sum(sig[j]):
                sig[j] = sj
            t[j] = max(t[j], raws["s"]["t"])
    return vals, sig, t, ref


def _geometry_seconds(t_int: NDArray) -> NDArray:
    """Instrument time of one geometry without its move (the run-time model's schedule,
    ``gonio.simulator.cornell_plans.estimate_run_time``) plus the mean move of an ordered
    plan (1.1 s, that model's figure)."""
    from gonio.simulator.cornell_plans import Timing

    tm = Timing()
    per = tm.settle_s + tm.preview_s + tm.read_overhead_s + tm.polarizer_change_s
    return per + 4.0 * (np.asarray(t_int) + tm.read_overhead_s) + 1.1


def _split_jacobian(jac: NDArray, g: int, nb: int, n_shape: int, nk: int):
    """Dense (G·nb, P) → shape columns (G, nb, n_shape) and each band's own k columns
    (G, nb, nk) (the rest of a row is zero: band b's reading does not see band b′'s k)."""
    j3 = jac.reshape(g, nb, -1)
    jt = j3[:, :, :n_shape].copy()
    jk = np.empty((g, nb, nk))
    for i in range(nk):
        cols = n_shape + i * nb + np.arange(nb)
        jk[:, :, i] = j3[:, np.arange(nb), cols]
    return jt, jk


def _fitted(
    material: str, prior: dict | None, model: Any = None
) -> tuple[Any, list[str], list[str], str, list]:
    """The prior's model and what the campaign's fit frees (cheap: no simulation):
    ``(prior model, names, free_k, fit_mode, prior points)``. The structure (which components
    are on) is the material preset's, as the campaign's fit takes it; the values are the
    preset's, or ``model``'s (an estimate, e.g. a pilot's fit) where given."""
    from gonio import materials
    from gonio.campaign.cornell import _truth_and_template

    materials.info(material)  # unknown preset -> ValueError listing them
    truth, _template, fixed, mode, free_k, mirror = _truth_and_template(material, "auto")
    if mirror:
        raise DesignError(
            f"material {material!r} has a mirror part; the design covers the rough li_torrance "
            "samples (no coherent reflection) for now"
        )
    shape = [k for k in ("sigma", "tau") if k not in fixed]
    names = shape + [f"{k}[{b}]" for k in free_k for b in range(31)]
    if model is not None:
        if getattr(model, "name", None) != truth.name:
            raise DesignError(f"prior model {model!r}: expected a {truth.name} model")
        truth = type(truth)(**{**truth.params, **{k: model.params[k] for k in (*shape, *free_k)}})
    return truth, names, free_k, mode, _prior_points(truth, shape, prior or {})


def _check_target_names(targets: dict, names: list[str], model: str) -> None:
    valid = set(names) | {p.split("[")[0] for p in names} | {"all"}
    for name in targets:
        if name not in valid:
            raise DesignError(
                f"target {name!r} is not a fitted parameter of {model} here; expected one of "
                f"{sorted({p.split('[')[0] for p in names})}, NAME[band] or all"
            )


def cornell_candidates(
    material: str = "garnet_red_paint",
    *,
    preset: str | None = "cornell2005",
    prior: dict[str, tuple[float, float]] | None = None,
    n_grid: int = 13,
    theta_i_deg: tuple = (10, 20, 30, 40, 50, 60, 70, 80),
    corrections: dict | None = None,
    model: Any = None,
) -> _Candidates:
    """The candidate geometries of the Cornell instrument with their predicted readings,
    noise, time, Jacobians and systematic patterns (module docstring)."""
    from gonio.campaign import cornell_budget as cb
    from gonio.campaign.cornell import _check_corrections, reference_band_error
    from gonio.simulator.cornell import BANDS_NM, CornellConfig, effective_cos, forward
    from gonio.simulator.cornell_effects import lab_knowledge

    truth, names, free_k, mode, pts = _fitted(material, prior, model)
    shape = names[: len(names) - 31 * len(free_k)]
    lab = CornellConfig().lab_view()
    knowledge = lab_knowledge(preset) if preset not in (None, "ideal") else {}
    corr = _check_corrections(corrections)
    plan = _candidate_plan(lab, knowledge, n_grid, tuple(theta_i_deg))
    nb = len(BANDS_NM)
    models = [type(truth)(**{**truth.params, **pt}) for pt in pts]
    vals, sig, t_int, ref = _predicted_readings(models[0], plan, lab, knowledge, order="worst")
    ok = np.all(np.isfinite(sig) & (sig > 0), axis=1)
    if not ok.all():
        plan, vals, sig, t_int = plan.subset(np.flatnonzero(ok)), vals[ok], sig[ok], t_int[ok]
    g = len(plan)
    wi, wo = forward(plan.angles, lab.kinematics)
    from gonio.simulator.cornell import _hat_projector

    use, proj = _hat_projector(tuple(np.round(ref.wavelengths_nm, 9)), tuple(BANDS_NM))
    kref = np.clip(proj @ (0.5 * (ref.rate["s"] + ref.rate["p"]) / ref.scale)[use], 1e-300, None)
    jts, jks, pats_all = [], [], []
    pat_names: list[str] = []
    from gonio.campaign.cornell import stray_offset_error

    sd = stray_offset_error(ref, lab)
    ce = effective_cos(wi, lab)
    for m in models:
        jac = cb._jacobian(m, names, wi, wo, nb)
        jt, jk = _split_jacobian(jac, g, nb, len(shape), len(free_k))
        jts.append(jt)
        jks.append(jk)
        pats = []
        names_e = []
        if knowledge:
            y = np.asarray(m(wi, wo), float).reshape(g, -1) * np.ones((1, nb))
            for name, p in cb._patterns(m, wi, wo, y, kref, lab, knowledge, corr, 0.0,
                                        False, None).items():  # fmt: skip
                for q in p if isinstance(p, list) else [p]:
                    pats.append(np.nan_to_num(np.asarray(q, float)))
                    names_e.append(name)
        for b in range(nb):  # the stray-light trap's offset: independent per band
            q = np.zeros((g, nb))
            q[:, b] = sd[b] / ce
            pats.append(q)
            names_e.append("stray_trap_offset")
        pats_all.append(np.stack(pats) if pats else np.zeros((0, g, nb)))
        pat_names = names_e
    # plan-independent floors: the reference's noise (a scale of every band) and the lamp
    ref_rel = reference_band_error(ref, lab)
    kval = np.array([0.0] * len(shape) + [
        float(np.broadcast_to(np.asarray(truth.params[k], float), (nb,))[b])
        for k in free_k for b in range(nb)
    ])  # fmt: skip
    const_terms = {
        "reference_noise": np.abs(kval) * np.r_[np.zeros(len(shape)), np.tile(ref_rel, len(free_k))]
    }
    const = np.sqrt(sum(v**2 for v in const_terms.values()))
    info = {"fit_mode": mode, "free_k": free_k, "mirror_part": False, "truth": truth,
            "kval": np.abs(kval)}  # fmt: skip
    return _Candidates(
        plan, names, len(shape), free_k, vals, sig, t_int, _geometry_seconds(t_int), jts, jks,
        pats_all, pat_names, const, const_terms, pts, ref, lab, knowledge, corr, models[0], info,
    )  # fmt: skip


# ----------------------------------------------------------------------------- the lamp
def reference_times(geometry_s: NDArray, every: int, reference_s: float) -> NDArray:
    """Campaign times (s) of the references: the first at 0, then one after every
    ``every``-th geometry and after the last, each taking ``reference_s`` — the campaign's
    lamp clock (``gonio.simulator.cornell.simulate_campaign``) with the geometries'
    durations ``geometry_s`` (in measuring order)."""
    from gonio.simulator.cornell_plans import n_rereferences

    g = np.asarray(geometry_s, dtype=np.float64).ravel()
    n_re = n_rereferences(len(g), every)
    if n_re == 0:
        return np.zeros(1)
    ends = np.minimum(np.arange(1, n_re + 1) * int(every), len(g))  # geometries before each
    csum = np.concatenate([[0.0], np.cumsum(g)])
    return np.concatenate([[0.0], csum[ends] + np.arange(1, n_re + 1) * float(reference_s)])


def reference_mean_noise(ref: Any, lab: Any) -> float:
    """Relative standard uncertainty of a reference's mean rate (both polarisers, every
    pixel: the quantity ``reference_drift`` follows), from the detector model of
    :func:`gonio.campaign.cornell.reference_band_error` (shot, dark and read noise of
    ``n_reference_reads`` averaged reads at the reference's integration time). A
    re-measured reference keeps the first one's stray light, so that term is left out."""
    n = max(1, int(lab.n_reference_reads))
    t = float(ref.meta.get("t", 1.0))
    tr = lab.filter_transmission if ref.mode == "direct" else 1.0
    g, rd, dk = lab.gain_e_per_count, lab.read_noise_counts, lab.dark_rate
    var, total = 0.0, 0.0
    for q in ("s", "p"):
        rate = np.asarray(ref.rate[q], float)
        stray = np.clip(np.asarray(ref.stray[q], float), 0, None)
        cnt = np.clip(rate + stray, 0, None) * t * tr
        var += float(np.sum(((cnt + 2 * dk * t) / g + 2 * rd**2) / (t * tr) ** 2 / n))
        total += float(np.sum(rate))
    return math.sqrt(var) / abs(total) if total else 0.0


def predicted_lamp_u(
    knowledge: dict,
    geometry_s: NDArray,
    every: int,
    reference_s: float,
    reference_noise: float = 0.0,
    drift_correction: bool = True,
) -> float:
    """The lamp term of the budget (``gonio.campaign.cornell_budget._lamp_u``) predicted
    for a cadence before any reference is measured, from the laboratory's knowledge only.

    The lamp's output ``L(t) = 1 − w e^(−t/τ) + d t`` (the data sheet's warm-up ``w`` with
    time constant ``τ`` and drift ``d`` per hour, their RMS over instruments
    ``√(typical² + spread²)``). With three references or more (and the drift correction),
    the campaign's term is the RMS leave-one-out residual of the references' linear
    interpolation; a straight line removes the drift exactly, so what is left is the
    warm-up's curvature between the neighbours of each interior reference,
    ``w (e^(−t_k/τ) − [(1 − a_k) e^(−t_(k−1)/τ) + a_k e^(−t_(k+1)/τ)])`` with
    ``a_k = (t_k − t_(k−1))/(t_(k+1) − t_(k−1))``, and the references' own read noise
    ``σ`` (:func:`reference_mean_noise`) through the same weights,
    ``σ² (1 + a_k² + (1 − a_k)²)``; the prediction is the RMS of their sum over the
    interior references, at the campaign's schedule (:func:`reference_times`). With
    fewer, the campaign's term is the data sheet's ``(w + d · hours)/√3`` over the
    campaign's hours (references included), and so is the prediction.

    Parameters
    ----------
    knowledge : dict
        The laboratory's ``{effect: (typical, spread)}``
        (``gonio.simulator.cornell_effects.lab_knowledge``); ``{}``: no lamp effect, 0.
    geometry_s : array
        Each geometry's real-instrument time in measuring order (s).
    every : int
        The cadence: 0 (the first reference only) or N >= 1.
    reference_s : float
        One re-measured reference's time (s,
        :func:`gonio.simulator.cornell_plans.reference_seconds`).
    reference_noise : float
        A reference's relative read noise (:func:`reference_mean_noise`).
    drift_correction : bool
        The campaign interpolates the references in time (its ``drift`` correction).

    Returns
    -------
    float
        The relative standard uncertainty of the lamp's output left after correction.

    References
    ----------
    .. [Walker1987] J. H. Walker, R. D. Saunders, J. K. Jackson and D. A. McSparron,
       "Spectral irradiance calibrations", NBS Special Publication 250-20, 1987, §4: a
       quartz-halogen lamp's warm-up of 15-30 min.
    .. [JCGM100] JCGM 100:2008, §4.3.7 (a rectangular distribution: the data sheet's
       bound over √3) and §5.1.2 (sensitivity coefficients: the interpolation's weights).
    """
    from gonio.simulator.cornell_effects import LAMP_WARMUP_TAU_S as tau

    if not knowledge:
        return 0.0
    w = math.hypot(*knowledge.get("lamp_warmup", (0.0, 0.0)))
    d = math.hypot(*knowledge.get("lamp_drift", (0.0, 0.0)))
    t = reference_times(geometry_s, every, reference_s)
    if every and drift_correction and len(t) >= 3:
        a = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
        f = np.exp(-t / tau)
        e = f[1:-1] - ((1 - a) * f[:-2] + a * f[2:])
        var = (w * e) ** 2 + reference_noise**2 * (1 + a**2 + (1 - a) ** 2)
        return float(np.sqrt(np.mean(var)))
    hours = (float(np.sum(geometry_s)) + (len(t) - 1) * float(reference_s)) / 3600.0
    return (w + d * hours) / math.sqrt(3.0)


# ----------------------------------------------------------------------------- search
class _State:
    """Information matrix, its inverse and the patterns' projections of a selection, at one
    prior point (block-structured rows: shape columns + the band's own k columns)."""

    def __init__(self, c: _Candidates, point: int, ridge: NDArray) -> None:
        self.c = c
        self.jt, self.jk, self.pats = c.jt[point], c.jk[point], c.pats[point]
        self.w = 1.0 / c.sigma
        nb = c.sigma.shape[1]
        self.nb, self.ns, self.nk = nb, c.n_shape, len(c.free_k)
        self.P = len(c.names)
        self.F = np.diag(ridge).astype(float)
        self.B = np.zeros((self.P, len(self.pats)))
        self.idx = self.ns + np.arange(self.nk)[:, None] * nb + np.arange(nb)[None, :]  # (nk, nb)

    def rows(self, sel: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Weighted rows L = W^½ J (as shape and k parts) and weighted patterns of ``sel``."""
        w = self.w[sel]
        return self.jt[sel] * w[..., None], self.jk[sel] * w[..., None], self.pats[:, sel] * w

    def add(self, sel: NDArray) -> None:
        lt, lk, u = self.rows(sel)
        # F += Lᵀ L, B += Lᵀ u, done densely (few rows)
        dense = self.dense(lt, lk)
        self.F += dense.T @ dense
        self.B += dense.T @ u.reshape(u.shape[0], -1).T

    def remove(self, sel: NDArray) -> None:
        lt, lk, u = self.rows(sel)
        dense = self.dense(lt, lk)
        self.F -= dense.T @ dense
        self.B -= dense.T @ u.reshape(u.shape[0], -1).T

    def dense(self, lt: NDArray, lk: NDArray) -> NDArray:
        g = lt.shape[0]
        d = np.zeros((g, self.nb, self.P))
        d[:, :, : self.ns] = lt
        for i in range(self.nk):
            d[:, np.arange(self.nb), self.idx[i]] = lk[:, :, i]
        return d.reshape(g * self.nb, self.P)

    def u2(self) -> NDArray:
        """Predicted squared standard uncertainty (P,) of the current selection."""
        cinv = np.linalg.inv(self.F)
        sys = cinv @ self.B
        return np.diag(cinv) + np.sum(sys * sys, axis=1)

    def u2_with(self, cand: NDArray, chunk: int = 256) -> NDArray:
        """Predicted squared standard uncertainty (n_cand, P) after adding each candidate
        alone (Woodbury, rank nb)."""
        cinv = np.linalg.inv(self.F)
        cinv = 0.5 * (cinv + cinv.T)
        cb = cinv @ self.B  # (P, E)
        base = np.diag(cinv)
        out = np.empty((len(cand), self.P))
        ck = cinv[self.idx]  # (nk, nb, P)
        cbk = cb[self.idx]  # (nk, nb, E)
        ns, nk, nb, P = self.ns, self.nk, self.nb, self.P
        for s in range(0, len(cand), chunk):
            sel = cand[s : s + chunk]
            g = len(sel)
            lt, lk, u = self.rows(sel)  # (g, nb, ns), (g, nb, nk), (E, g, nb)
            # M = L C (g, nb, P): the shape columns and each band's own k columns
            m = lt @ cinv[:ns]
            for i in range(nk):
                m += lk[:, :, i, None] * ck[i][None]
            # K = I + M Lᵀ (g, nb, nb)
            k = m[:, :, :ns] @ np.swapaxes(lt, 1, 2)
            mk = m[:, :, ns:].reshape(g, nb, nk, nb)
            for i in range(nk):
                k += mk[:, :, i, :] * lk[:, None, :, i]
            k += np.eye(nb)[None]
            # M B (g, nb, E) and the new patterns' share (K - I) u
            ue = np.moveaxis(u, 0, 2)  # (g, nb, E)
            mb = lt @ cb[:ns]
            for i in range(nk):
                mb += lk[:, :, i, None] * cbk[i][None]
            v = mb + k @ ue - ue
            sol = np.linalg.solve(k, np.concatenate([m, v], axis=2))
            x, z = sol[:, :, :P], sol[:, :, P:]
            diag = base[None, :] - np.sum(m * x, axis=1)
            sysn = cb[None] + np.swapaxes(m, 1, 2) @ (ue - z)
            out[s : s + g] = diag + np.sum(sysn * sysn, axis=2)
        return out


def _objective(u2: NDArray, const: NDArray, t2: NDArray) -> NDArray:
    """Σ_p max(0, log(U_p² / T_p²)) with U = 2 √(u² + floor²); parameters without a
    reachable target have T = ∞. Logarithmic, so that a target far out of reach does not
    outweigh the others (halving any parameter's excess counts the same). Works on
    (..., P)."""
    u_exp2 = 4.0 * (u2 + const**2)
    with np.errstate(divide="ignore"):
        return np.sum(np.maximum(0.0, np.log(np.maximum(u_exp2, 1e-300) / t2)), axis=-1)


@dataclasses.dataclass
class DesignResult:
    """A designed plan and its prediction."""

    instrument: str
    material: str
    plan: Any  # the ordered plan (Cornell: gonio.simulator.cornell_plans.Plan)
    targets: dict[str, float]  # absolute target U per parameter
    predicted: dict[str, dict[str, Any]]  # per parameter: U, stat, floor, dominant, target
    hours: float
    default: dict[str, Any]  # the default plan: hours and predicted U ({}: not predicted)
    unreachable: dict[str, dict[str, Any]]
    design_s: float
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)
    reference_every: int = 0  # the designed reference cadence (0: the first reference only)

    def table(self) -> str:
        """The designed plan's predicted U beside the default plan's, one row per parameter
        family (the worst band) and shape parameter."""
        dflt = (f"; default {self.default['n']} geometries, {self.default['hours']:.2f} h"
                if self.default else "")  # fmt: skip
        lines = [
            f"{self.material} ({self.instrument}): designed {len(self.plan)} geometries, "
            f"{self.hours:.2f} h{dflt} (real instrument, estimated)",
            f"  {'parameter':<14}{'target U':>12}{'designed U':>12}{'default U':>12}"
            f"{'floor':>12}  dominant term",
        ]
        for fam, rows in _families(self.predicted).items():
            worst = max(rows, key=lambda p: self.predicted[p]["U"] / self.targets.get(p, np.inf)
                        if p in self.targets else 0.0)  # fmt: skip
            d = self.predicted[worst]
            rel = "[" in worst
            label = f"{fam} (worst {worst[len(fam) :]})" if rel else fam
            tgt = self.targets.get(worst)
            dv = self.default.get("predicted", {}).get(worst, {}).get("U", float("nan"))

            def f(x: float | None) -> str:
                if x is None or not math.isfinite(x):
                    return "-"
                return f"{x:.3g}"

            lines.append(
                f"  {label:<14}{f(tgt):>12}{f(d['U']):>12}{f(dv):>12}{f(d['floor']):>12}"
                f"  {d['dominant']}"
            )
        if self.instrument == "cornell":
            cad = (f"every {self.reference_every} geometries" if self.reference_every
                   else "the first reference only")  # fmt: skip
            lines.append(f"  reference cadence: {cad} (lamp term u = "
                         f"{self.meta.get('lamp_u', 0.0):.2g}, predicted; references' time "
                         "included in the hours)")  # fmt: skip
        n_met = sum(1 for p, t in self.targets.items() if self.predicted[p]["U"] <= t)
        lines.append(f"  targets met (predicted, worst case over the prior): {n_met}/"
                     f"{len(self.targets)}; design {self.design_s:.1f} s")  # fmt: skip
        if self.unreachable:
            lines.append(f"  unreachable (target below the floor): {len(self.unreachable)}:")
            for p, u in list(self.unreachable.items())[:8]:
                lines.append(
                    f"    {p}: target {u['target']:.3g} < floor {u['floor']:.3g} ({u['dominant']})"
                )
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "instrument": self.instrument,
            "material": self.material,
            "n_geometries": len(self.plan),
            "hours": self.hours,
            "targets": self.targets,
            "predicted": self.predicted,
            "default": self.default,
            "unreachable": self.unreachable,
            "design_s": self.design_s,
            "reference_every": self.reference_every,
            **self.meta,
        }


def _families(pred: dict) -> dict[str, list[str]]:
    fam: dict[str, list[str]] = {}
    for p in pred:
        fam.setdefault(p.split("[")[0], []).append(p)
    return fam


def _absolute_targets(targets: dict[str, tuple[float, bool]], c: _Candidates) -> dict[str, float]:
    """Per fitted parameter, the absolute target U. A relative target of a per-band
    coefficient is taken relative to ``max(|k_b|, 0.1 max_b |k_b|)``: a band where the
    component nearly vanishes (garnet's k_uds below 600 nm is 0; a pilot's fit puts it
    at 1e-4) gets a target on the component's scale, not a vanishing one."""
    truth = c.info["truth"].params
    out: dict[str, float] = {}
    _check_target_names(targets, c.names, c.info["truth"].name)
    for p in c.names:
        fam = p.split("[")[0]
        spec = targets.get(p) or targets.get(fam) or targets.get("all")
        if spec is None:
            continue
        v, rel = spec
        if not rel:
            out[p] = v
            continue
        if "[" in p:
            b = int(p.split("[")[1].rstrip("]"))
            arr = np.broadcast_to(np.asarray(truth[fam], float), (31,))
            top = float(np.max(np.abs(arr)))
            val = max(abs(float(arr[b])), 0.1 * top) if top > 0 else 1.0
        else:
            val = abs(float(truth[p]))
        out[p] = v * val
    return out


def design_cornell(
    material: str = "garnet_red_paint",
    targets: dict[str, tuple[float, bool]] | None = None,
    *,
    preset: str | None = "cornell2005",
    prior: dict[str, tuple[float, float]] | None = None,
    time_limit_h: float | None = None,
    n_grid: int = 13,
    max_steps: int = 400,
    margin: float = 0.1,
    refine: int = 3,
    model: Any = None,
    candidates: _Candidates | None = None,
    compare_default: bool = True,
    theta_i_deg: tuple = (10, 20, 30, 40, 50, 60, 70, 80),
) -> DesignResult:
    """Design a Cornell plan (module docstring). ``targets`` from :func:`parse_targets`
    (default every parameter at 5 %), ``prior`` from :func:`parse_prior`, ``time_limit_h``
    the most real-instrument time the plan may take; the search aims at ``(1 - margin)``
    times each target (the achieved U scatters about the prediction with the data's noise);
    ``model``: the prior's values (default the material preset's)
    and tightens the targets the ordered plan's full budget misses, ``refine`` times.
    ``compare_default``: predict the default plan's budget beside the design's (half of a
    small design's time; the adaptive campaign, which does not report it, skips it).
    ``n_grid``, ``theta_i_deg``: the candidate geometries (:func:`cornell_candidates`).
    Raises :class:`DesignError` for a target that is not a fitted parameter, a prior outside
    the model's bounds or a time limit no plan can meet."""
    import time

    t0 = time.perf_counter()
    if time_limit_h is not None and not (math.isfinite(time_limit_h) and time_limit_h > 0):
        raise DesignError(f"time limit {time_limit_h!r} h: expected a positive number of hours")
    tg = parse_targets(None) if targets is None else targets
    if candidates is None:  # the cheap checks before the instrument's simulation
        truth, names, *_ = _fitted(material, prior, model)
        _check_target_names(tg, names, truth.name)
    c = candidates or cornell_candidates(
        material, preset=preset, prior=prior, n_grid=n_grid, model=model,
        theta_i_deg=tuple(theta_i_deg),
    )  # fmt: skip
    tabs = _absolute_targets(tg, c)
    # the cheapest identifiable plan must fit in the time limit
    n_min = c.n_shape + len(c.free_k)
    if time_limit_h is not None:
        cheapest = np.sort(c.seconds)[:n_min].sum() / 3600.0
        if cheapest > time_limit_h:
            raise DesignError(
                f"time limit {time_limit_h} h: no plan can meet it (the {n_min} quickest "
                f"geometries alone take {cheapest:.3g} h)"
            )
    best: DesignResult | None = None
    tried: list[dict[str, Any]] = []
    n_guess = max(2 * n_min, 10)
    n_last: int | None = None  # the last designed plan's geometries
    below: dict[str, dict[str, Any]] = {}
    for every in CADENCES if c.knowledge else (0,):
        if every and n_last is not None and n_last < 2 * every:
            continue  # fewer than three references: the data sheet's term, as with none
        try:
            r = _design_at(c, tabs, every, n_guess, time_limit_h, max_steps, margin, refine,
                           material, compare_default)  # fmt: skip
        except _NothingReachable as exc:
            below = exc.unreachable
            tried.append({"reference_every": every, "targets_missed": len(tabs),
                          "every_target_below_its_floor": True})  # fmt: skip
            if any(u["dominant"] == "lamp_drift" for u in below.values()):
                continue  # denser references lower the floor
            break
        except DesignError:
            if best is None:  # the sparsest cadence's failure: a denser one takes longer
                raise
            break
        n_last = len(r.plan)
        missed = [p for p, t in tabs.items() if r.predicted[p]["U"] > t]
        r.meta["missed"] = missed
        tried.append({"reference_every": every, "n_geometries": len(r.plan), "hours": r.hours,
                      "lamp_u": r.meta["lamp_u"], "targets_missed": len(missed)})  # fmt: skip
        if best is None or (len(missed), r.hours) < (len(best.meta["missed"]), best.hours):
            best = r
        n_guess = max(n_guess, len(r.plan))
        # a denser cadence only while the lamp's term is a material part of a target's
        # uncertainty (a missed target above what no cadence removes: a denser cadence may
        # meet it; a met one: may need fewer geometries); the best kept
        if not any(_lamp_matters(r, p) for p in tabs):
            break
    if best is None:
        p, u = next(iter(below.items()))
        raise DesignError(
            f"every target lies below its floor at every reference cadence tried (e.g. {p}: "
            f"target {u['target']:.3g} < floor {u['floor']:.3g}, {u['dominant']})"
        )
    best.meta.pop("missed", None)
    best.meta["cadences_tried"] = tried
    best.design_s = time.perf_counter() - t0
    return best


def _lamp_matters(r: DesignResult, p: str) -> bool:
    """Whether denser references could help parameter ``p`` of ``r`` (reach its target, or
    reach it with fewer geometries): the lamp's term is at least 30 % of its combined
    uncertainty and, if unreachable, the lamp is its floor's dominant term."""
    if p in r.unreachable and r.unreachable[p]["dominant"] != "lamp_drift":
        return False
    e = r.predicted[p]
    return e.get("contributions", {}).get("lamp_drift", 0.0) >= 0.3 * e["combined"]


def _design_at(
    c: _Candidates, tabs: dict, every: int, n_guess: int, time_limit_h: float | None,
    max_steps: int, margin: float, refine: int, material: str, compare_default: bool,
) -> DesignResult:  # fmt: skip
    """The geometries designed for the reference cadence ``every``: each geometry's time with
    its share of the references' (``reference_s / every``), the lamp's predicted term a
    floor of every coefficient (a relative scale of every reading moves each k by that
    relative amount and no shape parameter), first for a guessed schedule (``n_guess``
    geometries of the candidates' median time), then for the plan found."""
    from gonio.simulator.cornell_plans import Timing, reference_seconds

    ref_s = reference_seconds(Timing(), float(c.ref.meta.get("t", 1.0)), c.lab.n_reference_reads)
    seconds = c.seconds + (ref_s / every if every else 0.0)
    lamp = predicted_lamp_u(
        c.knowledge, np.full(n_guess, float(np.median(c.seconds))), every, ref_s,
        reference_mean_noise(c.ref, c.lab), bool(c.corrections.get("drift", True)),
    )  # fmt: skip
    kval = c.info["kval"]
    scale = np.array([abs(float(c.info["truth"].params[p])) if "[" not in p else 1.0
                      for p in c.names])  # fmt: skip
    ridge = 1.0 / (100.0 * np.maximum(scale, 1e-3)) ** 2
    states = [_State(c, j, ridge) for j in range(len(c.prior_points))]
    chosen = np.zeros(len(c.plan), bool)
    limit_s = math.inf if time_limit_h is None else time_limit_h * 3600.0
    t2_search = None
    for _round in range(refine + 1):
        lamp_terms = {**c.const_terms, "lamp_drift": lamp * kval}
        const = np.sqrt(sum(v**2 for v in lamp_terms.values()))
        t2, unreachable = _reachable(c, tabs, const, lamp_terms)
        if not np.isfinite(t2).any():
            raise _NothingReachable(unreachable)
        t2 *= (1.0 - margin) ** 2  # aim below the target: the achieved U scatters about it
        if t2_search is not None:  # the earlier rounds' tightened targets kept
            t2 = np.where(np.isfinite(t2), np.minimum(t2, t2_search), np.inf)
        cs = dataclasses.replace(c, seconds=seconds, const=const, const_terms=lamp_terms)
        for st in states:
            st.c = cs
        phi = _greedy(states, chosen, cs, t2, limit_s, max_steps)
        if phi > 0 and not chosen.any():
            raise DesignError("no candidate geometry reduces the uncertainty of the targets")
        _prune(states, chosen, cs, t2)
        result = _finish(cs, np.flatnonzero(chosen), tabs, unreachable, material,
                         compare_default, every)  # fmt: skip
        lamp = result.meta["lamp_u"]
        # the budget of the ordered plan has terms the search approximates (the backlash's
        # sides, the stages' noise, the exposure of the polariser put first, the lamp's
        # schedule): tighten the search's targets of the parameters it missed and continue
        missed = [i for i, p in enumerate(c.names) if p in tabs and p not in unreachable
                  and result.predicted[p]["U"] > tabs[p]]  # fmt: skip
        if not missed or _round == refine:
            break
        t2_search = t2.copy()
        for i in missed:
            p = c.names[i]
            t2_search[i] *= (tabs[p] / result.predicted[p]["U"]) ** 2 * (1.0 - margin) ** 2
    c.default = cs.default  # the default plan's prediction, made once
    result.meta["objective_left"] = float(phi)
    result.meta["rounds"] = _round + 1
    result.meta["not_met"] = [c.names[i] for i in missed]
    if time_limit_h is not None and result.hours > time_limit_h:
        raise DesignError(
            f"time limit {time_limit_h} h: the designed plan takes {result.hours:.3g} h once "
            "ordered; no plan within the limit was found"
        )
    return result


def _reachable(
    c: _Candidates, tabs: dict, const: NDArray, terms: dict[str, NDArray]
) -> tuple[NDArray, dict[str, dict[str, Any]]]:
    """Squared targets (∞ where none) and the targets below their floor ``2 const``; the
    dominant term named is the one no cadence removes (:attr:`_Candidates.const_terms`) when
    the target lies below those alone, else the lamp's (denser references would lower it)."""
    t2 = np.full(len(c.names), np.inf)
    unreachable: dict[str, dict[str, Any]] = {}
    for i, p in enumerate(c.names):
        if p not in tabs:
            continue
        floor = float(2.0 * const[i])
        if tabs[p] <= floor:
            fixed = 2.0 * math.sqrt(sum(float(v[i]) ** 2 for v in c.const_terms.values()))
            pool = c.const_terms if tabs[p] <= fixed else terms
            dom = max(pool, key=lambda n: pool[n][i])
            unreachable[p] = {"target": tabs[p], "floor": floor, "dominant": dom}
        else:
            t2[i] = tabs[p] ** 2
    return t2, unreachable


def _greedy(
    states: list[_State], chosen: NDArray, c: _Candidates, t2: NDArray, limit_s: float,
    max_steps: int,
) -> float:  # fmt: skip
    """Forward selection (module docstring) from ``chosen`` (updated in place); returns the
    objective left (0: every reachable target met at every prior point)."""
    spent = float(c.seconds[chosen].sum())
    phi = sum(_objective(s.u2(), c.const, t2) for s in states)
    for _ in range(max_steps):
        if phi <= 0:
            break
        cand = np.flatnonzero(~chosen & (c.seconds + spent <= limit_s))
        if cand.size == 0:
            break
        new = sum(_objective(s.u2_with(cand), c.const, t2) for s in states)
        gain = (phi - new) / c.seconds[cand]
        order = np.argsort(-gain)[: max(1, int(chosen.sum()) // 8)]
        order = order[gain[order] > 0]
        if order.size == 0:
            break
        add = []
        for j in cand[order]:
            if spent + c.seconds[j] <= limit_s:
                add.append(j)
                spent += c.seconds[j]
        add = np.array(add, int)
        chosen[add] = True
        for s in states:
            s.add(add)
        phi = sum(_objective(s.u2(), c.const, t2) for s in states)
    return float(phi)


def _prune(states: list[_State], chosen: NDArray, c: _Candidates, t2: NDArray) -> None:
    """Backward pass: drop geometries (slowest first) whose removal keeps every reachable
    target met at every prior point."""
    met = all(_objective(s.u2(), c.const, t2) <= 0 for s in states)
    if not met:
        return
    for j in np.flatnonzero(chosen)[np.argsort(-c.seconds[chosen])]:
        for s in states:
            s.remove(np.array([j]))
        ok = all(
            np.linalg.matrix_rank(s.F) == s.P and _objective(s.u2(), c.const, t2) <= 0
            for s in states
        )
        if ok:
            chosen[j] = False
        else:
            for s in states:
                s.add(np.array([j]))


# ----------------------------------------------------------------------------- prediction
def plan_schedule(
    lab: Any, plan: Any, t_int: NDArray, ref: Any, every: int, knowledge: dict,
    corrections: dict | None = None,
) -> tuple[float, float]:  # fmt: skip
    """A plan's predicted lamp term (:func:`predicted_lamp_u`) and its real-instrument hours
    (``gonio.simulator.cornell_plans.estimate_run_time`` with the ``every`` references) at
    the integration times ``t_int`` and the reference ``ref`` the laboratory predicts."""
    from gonio.simulator.cornell_plans import (
        Timing,
        estimate_run_time,
        measurement_seconds,
        reference_seconds,
    )

    tm = Timing()
    ref_s = reference_seconds(tm, float(ref.meta.get("t", 1.0)), lab.n_reference_reads)
    hours = float(estimate_run_time(plan, tm, t_int, reference_every=every,
                                    reference_s=ref_s)["total_h"])  # fmt: skip
    drift = bool((corrections or {}).get("drift", True))
    lamp = predicted_lamp_u(knowledge, measurement_seconds(plan, tm, t_int), every, ref_s,
                            reference_mean_noise(ref, lab), drift)  # fmt: skip
    return lamp, hours


def predict_cornell(
    c: _Candidates, plan: Any, point: int = 0, reference_every: int = 0,
    info: dict | None = None,
) -> tuple[dict, float]:  # fmt: skip
    """The budget (:func:`gonio.campaign.cornell_budget.cornell_budget`) of ``plan`` (a
    Plan in measuring order) at prior point ``point``, on the prior's readings predicted in
    that order, with the lamp term predicted for the cadence ``reference_every``
    (:func:`predicted_lamp_u`): per parameter ``U``, ``stat``, the contributions; and the
    plan's estimated real-instrument hours (its references included); ``info`` receives
    the predicted lamp term (``lamp_u``)."""
    import types

    from gonio.campaign import cornell_budget as cb
    from gonio.campaign.cornell import offset_sensitivity, reference_band_error, stray_offset_error
    from gonio.samples import BRDFSamples
    from gonio.simulator.cornell import BANDS_NM, forward

    nb = len(BANDS_NM)
    model = type(c.model)(**{**c.model.params, **c.prior_points[point]})
    vals, sig, t_int, ref = _predicted_readings(model, plan, c.lab, c.knowledge)
    lamp_u, hours = plan_schedule(c.lab, plan, t_int, ref, reference_every, c.knowledge,
                                  c.corrections)  # fmt: skip
    if info is not None:
        info["lamp_u"] = lamp_u
    wi, wo = forward(plan.angles, c.lab.kinematics)
    g = len(plan)
    samples = BRDFSamples.from_directions(
        np.repeat(wi, nb, axis=0), np.repeat(wo, nb, axis=0), vals.reshape(-1),
        sig.reshape(-1), wavelength_nm=np.tile(BANDS_NM, g),
    )  # fmt: skip
    jac = cb._jacobian(model, c.names, wi, wo, nb) / sig.reshape(-1, 1)
    f = jac.T @ jac
    if np.linalg.matrix_rank(f) < len(c.names):
        inf = {"U": math.inf, "stat": math.inf, "combined": math.inf, "contributions": {}}
        return {p: dict(inf) for p in c.names}, hours
    se = np.sqrt(np.diag(np.linalg.inv(f)))
    params = {p: float(model.params[p]) for p in c.names if "[" not in p}
    for k in c.free_k:
        arr = np.broadcast_to(np.asarray(model.params[k], float), (nb,))
        params.update({f"{k}[{b}]": float(arr[b]) for b in range(nb)})
    stderr = dict(zip(c.names, map(float, se)))
    res = types.SimpleNamespace(model=model, free=list(c.names), stderr=stderr, params=params,
                                cov_scale=1.0)  # fmt: skip
    ref_rel = reference_band_error(ref, c.lab)
    sd = stray_offset_error(ref, c.lab)
    sens = offset_sensitivity(model, samples, c.free_k, c.lab)
    tot = {}
    for p in c.names:
        if "[" in p:
            k, b = p.split("[")[0], int(p.split("[")[1].rstrip("]"))
            tot[p] = math.hypot(stderr[p], abs(params[p]) * ref_rel[b], abs(sens[k][b]) * sd[b])
        else:
            tot[p] = stderr[p]
    summary = {"reference_band_rel_error": list(map(float, ref_rel)),
               "stderr_with_reference": tot, "estimated_real_instrument_h": hours}  # fmt: skip
    b = cb.cornell_budget(res, {"mirror_part": False}, samples, ref, c.lab, c.knowledge,
                          c.corrections, summary, angles=plan.angles,
                          lamp_u=lamp_u if c.knowledge else None)  # fmt: skip
    return b["parameters"], hours


def _dominant(entry: dict[str, Any]) -> str:
    terms = {"statistical": entry.get("stat", 0.0), **entry.get("contributions", {})}
    return max(terms, key=lambda n: terms[n])


def _finish(
    c: _Candidates, sel: NDArray, tabs: dict, unreachable: dict, material: str,
    compare_default: bool = True, every: int = 0,
) -> DesignResult:  # fmt: skip
    """Order the selection as the campaign will, predict its budget at every prior point
    (the worst case kept) with the references every ``every`` geometries, and the default
    plan's beside it (``compare_default``)."""
    from gonio.simulator.cornell_plans import order_plan

    sub = c.plan.subset(sel)
    sub.meta = {"kind": "designed"}
    ordered = order_plan(sub)
    lamp: dict[str, float] = {}
    pred, hours = _worst_prediction(c, ordered, every, lamp)
    for p, t in tabs.items():
        pred[p]["target"] = t
    default = _default_prediction(c) if compare_default else {}
    return DesignResult("cornell", material, ordered, dict(tabs), pred, float(hours), default,
                        unreachable, 0.0, {"n_candidates": len(c.plan),
                                           "prior_points": c.prior_points,
                                           "lamp_u": lamp.get("lamp_u", 0.0)},
                        reference_every=int(every))  # fmt: skip


def _worst_prediction(
    c: _Candidates, plan: Any, every: int = 0, lamp: dict | None = None
) -> tuple[dict[str, dict[str, Any]], float]:
    """The plan's budget at every prior point with the references every ``every``
    geometries, each parameter's worst case; the hours (the longest); ``lamp`` receives the
    largest predicted lamp term (``lamp_u``)."""
    out: dict[str, dict[str, Any]] = {}
    hours = 0.0
    for j in range(len(c.prior_points)):
        info: dict[str, float] = {}
        pj, hj = predict_cornell(c, plan, j, every, info)
        hours = max(hours, hj)
        if lamp is not None:
            lamp["lamp_u"] = max(lamp.get("lamp_u", 0.0), info["lamp_u"])
        for p, e in pj.items():
            if p not in out or e["U"] > out[p]["U"]:
                out[p] = e
    for i, p in enumerate(c.names):
        e = out[p]
        sys2 = e["combined"] ** 2 - e["stat"] ** 2 if math.isfinite(e["combined"]) else math.inf
        e["floor"] = 2.0 * float(c.const[i])
        e["systematic_U"] = 2.0 * math.sqrt(max(sys2, 0.0))
        e["dominant"] = _dominant(e)
    keep = ("U", "stat", "combined", "floor", "systematic_U", "dominant", "contributions")
    return {p: {k: v for k, v in e.items() if k in keep} for p, e in out.items()}, hours


def default_cornell_plan(lab: Any, knowledge: dict) -> Any:
    """The default campaign's plan (incidence plane, ordered, footprint refusals removed)."""
    from gonio.campaign.cornell import _refuse_footprint, build_plan

    p = build_plan("incidence", config=lab)
    if knowledge:
        p, _ = _refuse_footprint(p, lab, knowledge)
    return p


def _default_prediction(c: _Candidates) -> dict[str, Any]:
    """The default incidence-plane plan's predicted U and hours (its budget made once per
    candidate set: it does not depend on the targets or the search's rounds)."""
    if c.default is None:
        p = default_cornell_plan(c.lab, c.knowledge)
        every = _CAMPAIGN_CADENCE if c.knowledge else 0
        pred, hours = _worst_prediction(c, p, every)
        c.default = {"n": len(p), "hours": float(hours), "reference_every": every,
                     "predicted": {q: {"U": e["U"]} for q, e in pred.items()}}  # fmt: skip
    d = c.default
    return {**d, "predicted": {q: dict(e) for q, e in d["predicted"].items()}}


def write_cornell_plan(path: Any, result: DesignResult) -> None:
    """The designed plan as a Cornell plan CSV (``theta_i, phi_i, theta_o, phi_o`` in degrees,
    the campaign's ``--plan FILE``), with the design's figures in a ``# gonio design: {...}``
    comment line — among them the designed ``reference_every``, which the campaign applies
    (``gonio.campaign.cornell.plan_file_reference_every``); written atomically."""
    import json

    from gonio.geometry import to_spherical
    from gonio.io.atomic import atomic_write_bytes

    ti, pi = to_spherical(result.plan.wi)
    to, po = to_spherical(result.plan.wo)
    deg = np.degrees(np.c_[ti, pi, to, po])
    head = {"material": result.material, "instrument": result.instrument,
            "hours": round(result.hours, 4), "n_geometries": len(result.plan),
            "reference_every": int(result.reference_every)}  # fmt: skip
    lines = [f"# gonio design: {json.dumps(head)}", "theta_i,phi_i,theta_o,phi_o"]
    lines += [",".join(f"{v:.9f}" for v in row) for row in deg]
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
