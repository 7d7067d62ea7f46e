"""Adaptive Cornell campaigns: a short pilot, a fit, the design from its estimate, the plan.

``gonio campaign --instrument cornell --adaptive --target ...`` (:func:`adaptive_cornell`):

1. *pilot*: a short plan (two incidence-plane scans, θi = 30° and 60°, every 15° with a 5°
   step within 5° of the specular direction: 22 geometries) measured and fitted like any
   campaign (``out/pilot``);
2. *design*: :func:`gonio.campaign.design.design_cornell` with the pilot's fit as the prior
   (its values; the shape parameter's range the pilot's expanded uncertainty about its
   estimate, so the design holds over what the pilot leaves open) — the material preset
   gives only the model's structure, as it does to every Cornell fit;
3. *main*: the designed plan measured and fitted (``out``).

The summary (``out/adaptive.json``) gives each stage's real-instrument hours and wall time, the
designed plan's predicted U and the main campaign's achieved U per parameter against the
targets. The final U is the main campaign's alone: the pilot's data are not pooled with it
(their fit would need the two sessions' references tied together).

References
----------
.. [Atkinson2007] A. C. Atkinson, A. N. Donev and R. D. Tobias, "Optimum Experimental
   Designs, with SAS", Oxford University Press, 2007, ch. 17 (designs for non-linear models:
   sequential designs from a first estimate).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["adaptive_cornell", "adaptive_lbl", "pilot_plan"]


def pilot_plan(config: Any = None) -> Any:
    """The pilot's plan (module docstring), on the controller's grid."""
    from gonio.campaign.cornell import build_plan
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_plans import incidence_plane_plan

    cfg = config or CornellConfig().lab_view()
    p = incidence_plane_plan(
        (30.0, 60.0), coarse_step_deg=15.0, fine_step_deg=5.0, fine_half_width_deg=5.0,
        kin=cfg.kinematics,
    )  # fmt: skip
    return build_plan(p, config=cfg)


def _prior_from(summary: dict, material: str) -> tuple[Any, dict[str, tuple[float, float]]]:
    """The pilot's fitted li_torrance model and the shape parameters' range (estimate ± its
    expanded uncertainty, inside the model's bounds)."""
    from gonio import brdf, materials

    base = materials.get(material)
    fit, bud = summary["fit"], summary["budget"]["parameters"]
    params = dict(base.params)
    for k in ("k_dd", "k_udf", "k_uds", "k_fs"):
        if f"{k}[0]" in fit:
            params[k] = np.array([max(fit[f"{k}[{b}]"], 0.0) for b in range(31)])
    prior = {}
    bounds = brdf.spec(base.name).bounds
    for k in ("sigma", "tau"):
        if k in fit:
            params[k] = float(fit[k])
        if k in bud and math.isfinite(bud[k]["U"]) and bud[k]["U"] > 0:
            lo, hi = bounds[k]
            u = float(bud[k]["U"])
            prior[k] = (max(lo, fit[k] - u), min(hi, fit[k] + u))
    return type(base)(**params), prior


def adaptive_cornell(
    material: str,
    targets: dict[str, tuple[float, bool]] | None,
    out: str | Path,
    *,
    seed: int = 0,
    instrument_seed: int | None = None,
    preset: str = "cornell2005",
    time_limit_h: float | None = None,
    n_grid: int = 13,
    theta_i_deg: tuple = (10, 20, 30, 40, 50, 60, 70, 80),
) -> dict[str, Any]:
    """Pilot, design, main campaign (module docstring); the summary (also
    ``out/adaptive.json``). ``n_grid``, ``theta_i_deg``: the design's candidates
    (:func:`gonio.campaign.design.cornell_candidates`)."""
    from gonio.campaign import design
    from gonio.campaign.cornell import run_cornell_campaign

    tg = design.parse_targets(None) if targets is None else targets
    truth, names, *_ = design._fitted(material, None)  # checks before the pilot runs
    design._check_target_names(tg, names, truth.name)
    outp = Path(out)
    kw = dict(seed=seed, instrument_seed=instrument_seed, effects=preset)
    stages: dict[str, dict[str, Any]] = {}
    t0 = time.perf_counter()
    pilot = run_cornell_campaign(material, plan=pilot_plan(), out=outp / "pilot", **kw)
    stages["pilot"] = {"n_geometries": pilot["n_geometries"], "wall_s": time.perf_counter() - t0,
                       "real_instrument_h": pilot["estimated_real_instrument_h"]}  # fmt: skip
    model, prior = _prior_from(pilot, material)
    t1 = time.perf_counter()
    left = None if time_limit_h is None else time_limit_h - stages["pilot"]["real_instrument_h"]
    if left is not None and left <= 0:
        raise design.DesignError(
            f"time limit {time_limit_h} h: the pilot alone takes "
            f"{stages['pilot']['real_instrument_h']:.3g} h"
        )
    res = design.design_cornell(
        material, tg, preset=None if preset == "ideal" else preset, prior=prior,
        time_limit_h=left, model=model, n_grid=n_grid, compare_default=False,
        theta_i_deg=theta_i_deg,
    )  # fmt: skip
    outp.mkdir(parents=True, exist_ok=True)
    plan_file = outp / "designed_plan.csv"
    design.write_cornell_plan(plan_file, res)
    stages["design"] = {"wall_s": time.perf_counter() - t1, "n_geometries": len(res.plan),
                        "predicted_real_instrument_h": res.hours, "prior": prior}  # fmt: skip
    t2 = time.perf_counter()
    main = run_cornell_campaign(material, plan=str(plan_file), out=outp / "main", **kw)
    stages["main"] = {"n_geometries": main["n_geometries"], "wall_s": time.perf_counter() - t2,
                      "real_instrument_h": main["estimated_real_instrument_h"]}  # fmt: skip
    b = main["budget"]["parameters"]
    final = {
        p: {"target": t, "predicted_U": res.predicted[p]["U"], "achieved_U": b[p]["U"],
            "met": bool(b[p]["U"] <= t), "truth_within_U": b[p].get("truth_within_U")}
        for p, t in res.targets.items() if p in b
    }  # fmt: skip
    return _summary(outp, material, "cornell", stages, final, res.unreachable)


def _summary(
    outp: Path, material: str, instrument: str, stages: dict, final: dict, unreachable: dict,
    **extra: Any,
) -> dict[str, Any]:  # fmt: skip
    """The adaptive campaign's summary, written to ``outp/adaptive.json``."""
    from gonio.campaign.cornell import _write_json

    summary = {
        "material": material,
        "instrument": instrument,
        "stages": stages,
        "real_instrument_h": stages["pilot"]["real_instrument_h"]
        + stages["main"]["real_instrument_h"],
        **extra,
        "n_targets": len(final),
        "n_met": sum(f["met"] for f in final.values()),
        "unreachable": unreachable,
        "final": final,
    }
    _write_json(outp / "adaptive.json", summary)
    return summary


def adaptive_text(s: dict[str, Any]) -> str:
    """A short report of an adaptive campaign."""
    st = s["stages"]
    lines = [
        f"{s['material']} (cornell, adaptive): {s['real_instrument_h']:.3f} h on the real "
        f"instrument (estimated)",
        f"  pilot  {st['pilot']['n_geometries']:>4} geometries "
        f"{st['pilot']['real_instrument_h']:.3f} h  ({st['pilot']['wall_s']:.1f} s here)",
        f"  design {st['design']['n_geometries']:>4} geometries predicted "
        f"{st['design']['predicted_real_instrument_h']:.3f} h  ({st['design']['wall_s']:.1f} s)",
        f"  main   {st['main']['n_geometries']:>4} geometries "
        f"{st['main']['real_instrument_h']:.3f} h  ({st['main']['wall_s']:.1f} s here)",
        f"  targets met (achieved U): {s['n_met']}/{s['n_targets']}",
    ]
    worst = sorted(s["final"].items(), key=lambda kv: -kv[1]["achieved_U"] / kv[1]["target"])[:5]
    for p, f in worst:
        lines.append(
            f"    {p}: target {f['target']:.3g}, predicted {f['predicted_U']:.3g}, "
            f"achieved {f['achieved_U']:.3g}"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- LBL
#: the LBL pilot's incidence angles (deg); its rotations: every other one of the material's
#: default rotations (0 and 90 for an anisotropic sample, 0 for an isotropic one)
LBL_PILOT_ANGLES = (15.0, 40.0, 65.0)


def _lbl_prior(res: Any) -> list[Any]:
    """The design's priors from the pilot's fit: its estimate, then its shape parameters
    (every fitted parameter but the reflectances) all at estimate + U and all at estimate - U
    (inside the model's bounds) — one per design instrument, so the design's U at 95 % over
    its instruments holds over what the pilot leaves open too."""
    from gonio import brdf

    model = res.fit.model
    U = res.summary["budget"]["expanded"]
    bounds = brdf.spec(model.name).bounds
    shape = [p for p in res.fit.free if not p.startswith(("rho", "k_"))]
    out = [model]
    for sign in (1.0, -1.0):
        params = dict(model.params)
        for p in shape:
            u = U.get(p)
            if u is None or not math.isfinite(u):
                continue
            lo, hi = bounds.get(p, (-math.inf, math.inf))
            params[p] = float(min(max(float(model.params[p]) + sign * u, lo), hi))
        out.append(type(model)(**params))
    return out


def _hours_taken(res: Any) -> float:
    """A campaign's real-instrument hours with the brackets its instrument took
    (:meth:`gonio.campaign.lbl.LBLCampaignResult.real_instrument_h`)."""
    from gonio.campaign.design import DesignError

    h = res.real_instrument_h()
    if h is None:
        raise DesignError("the campaign's frames do not record their exposure and f-number")
    return float(h)


def adaptive_lbl(
    material: str,
    targets: dict[str, tuple[float, bool]] | None,
    out: str | Path,
    *,
    seed: int = 0,
    instrument_seed: int | None = None,
    preset: str = "modern",
    time_limit_h: float | None = None,
    n_instruments: int = 6,
    candidate_angles_deg: tuple[float, ...] | None = None,
    assurance: float | None = None,
) -> dict[str, Any]:
    """The LBL adaptive campaign: a pilot (:data:`LBL_PILOT_ANGLES`, ``out/pilot``), the
    design from its fit (:func:`gonio.campaign.design_lbl.design_lbl`: its three design
    instruments' candidate campaigns made at the pilot's estimate and at its shape
    parameters ± their U, :func:`_lbl_prior`), then the designed plan (``out/main``, its
    plan file ``out/designed_plan.json``); the summary (also ``out/adaptive.json``) as
    :func:`adaptive_cornell`'s, the pilot's and the main campaign's hours those of the
    brackets their instrument took (:func:`_hours_taken`), the design's its prediction
    (the candidate campaigns' brackets). The final U is the main campaign's alone.
    ``n_instruments`` (1-10) design instruments (the k-th at the k-th prior modulo 3),
    ``candidate_angles_deg`` the design's candidate incidence angles (default the default
    plan's), ``assurance`` the fraction of the preset's instruments on which the design
    meets each target (:func:`gonio.campaign.design_lbl.design_lbl`; default
    :data:`gonio.campaign.design_lbl.ASSURANCE`), recorded in the design stage."""
    from gonio import campaign
    from gonio.campaign import design, design_lbl

    tg = design.parse_targets(None) if targets is None else targets
    if time_limit_h is not None and not (math.isfinite(time_limit_h) and time_limit_h > 0):
        raise design.DesignError(f"time limit {time_limit_h!r} h: expected a positive number")
    if not (isinstance(n_instruments, int) and 1 <= n_instruments <= 10):
        raise design.DesignError(f"n_instruments {n_instruments!r}: expected 1 to 10")
    p = design_lbl.ASSURANCE if assurance is None else design_lbl.check_assurance(assurance)
    design_lbl._precheck(material, tg, preset, time_limit_h)  # before the pilot runs
    outp = Path(out)
    kw = dict(material=material, seed=seed, instrument_seed=instrument_seed, preset=preset,
              plots=False)  # fmt: skip
    rots = campaign.Plan(material=material).resolved().rotations_deg[::2]
    stages: dict[str, dict[str, Any]] = {}
    t0 = time.perf_counter()
    pilot = campaign.run(campaign.Plan(theta_i_deg=LBL_PILOT_ANGLES, rotations_deg=rots, **kw),
                         outp / "pilot", quiet=True)  # fmt: skip
    h_pilot = _hours_taken(pilot)
    stages["pilot"] = {"n_angles": len(LBL_PILOT_ANGLES), "n_rotations": len(rots),
                       "wall_s": time.perf_counter() - t0,
                       "real_instrument_h": h_pilot}  # fmt: skip
    left = None if time_limit_h is None else time_limit_h - h_pilot
    if left is not None and left <= 0:
        raise design.DesignError(
            f"time limit {time_limit_h} h: the pilot alone takes {h_pilot:.3g} h"
        )
    t1 = time.perf_counter()
    three = _lbl_prior(pilot)
    priors = [three[k % 3] for k in range(n_instruments)]
    cands = design_lbl.candidate_sets(material, priors, preset=preset,
                                      angles_deg=candidate_angles_deg)  # fmt: skip
    res = design_lbl.design_lbl(material, tg, preset=preset, time_limit_h=left,
                                candidates=cands, assurance=p)  # fmt: skip
    plan_file = outp / "designed_plan.json"
    design_lbl.write_lbl_plan(plan_file, res)
    stages["design"] = {
        "wall_s": time.perf_counter() - t1, "n_angles": len(res.theta_i_deg),
        "n_rotations": len(res.rotations_deg), "restandard_every": res.restandard_every,
        "predicted_real_instrument_h": res.hours, "assurance": res.assurance,
        "prior": [{k: float(np.asarray(v).ravel()[0]) for k, v in m.params.items()
                   if k in pilot.fit.free} for m in priors],
    }  # fmt: skip
    t2 = time.perf_counter()
    main = campaign.run(
        campaign.Plan(theta_i_deg=res.theta_i_deg, rotations_deg=res.rotations_deg,
                      restandard_every=res.restandard_every, **kw), outp / "main", quiet=True,
    )  # fmt: skip
    stages["main"] = {"n_angles": len(res.theta_i_deg), "n_rotations": len(res.rotations_deg),
                      "wall_s": time.perf_counter() - t2,
                      "real_instrument_h": _hours_taken(main)}  # fmt: skip
    U, fit, truth = (main.summary["budget"]["expanded"], main.summary["fit"],
                     main.summary.get("truth", {}))  # fmt: skip
    final = {
        p: {"target": t, "predicted_U": res.predicted[p], "predicted_U_95": res.predicted_95[p],
            "achieved_U": U[p], "met": bool(U[p] <= t), "unreachable": p in res.unreachable,
            "truth_within_U": bool(abs(fit[p] - truth[p]) <= U[p]) if p in truth else None}
        for p, t in res.targets.items() if p in U
    }  # fmt: skip
    return _summary(outp, material, "lbl", stages, final, res.unreachable,
                    default_plan_h=res.default["hours"])  # fmt: skip


def adaptive_lbl_text(s: dict[str, Any]) -> str:
    """A short report of an LBL adaptive campaign."""
    st = s["stages"]
    level = f"{100 * st['design'].get('assurance', 0.95):g} %"  # the bound's level
    lines = [
        f"{s['material']} (lbl, adaptive): {s['real_instrument_h']:.3f} h on the real "
        f"instrument (estimated; the default plan {s['default_plan_h']:.3f} h)",
        f"  pilot  {st['pilot']['n_angles']:>3} angles x {st['pilot']['n_rotations']} rotations "
        f"{st['pilot']['real_instrument_h']:.3f} h  ({st['pilot']['wall_s']:.1f} s here)",
        f"  design {st['design']['n_angles']:>3} angles x {st['design']['n_rotations']} rotations,"
        f" restandard_every {st['design']['restandard_every']}, predicted "
        f"{st['design']['predicted_real_instrument_h']:.3f} h  ({st['design']['wall_s']:.1f} s)",
        f"  main   {st['main']['real_instrument_h']:.3f} h  ({st['main']['wall_s']:.1f} s here)",
        f"  targets met (achieved U): {s['n_met']}/{s['n_targets']}",
    ]
    for p, f in s["final"].items():
        lines.append(
            f"    {p}: target {f['target']:.3g}, predicted {f['predicted_U']:.3g} "
            f"({level}: {f['predicted_U_95']:.3g}), achieved {f['achieved_U']:.3g}"
            + (" (unreachable)" if f["unreachable"] else "")
        )
    return "\n".join(lines)
