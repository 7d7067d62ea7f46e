"""Measurement design (``gonio.campaign.design``): its run time, its plans against the usual
ones, and the honesty of its predictions.

Run: ``python benchmarks/bench_design.py [--material garnet_red_paint] [--target k_fs=5% ...]``
prints the design's time by stage (candidates: the instrument simulated at the prior over the
candidate geometries; search; the ordered plan's budget and the default plan's), beside the
default Cornell campaign (incidence plan, realistic instrument, fit and budget) timed in the
same run as the baseline (the issue asks for a design in at most 60 s on 2 cores).

``--table``: one campaign (seed 0) of each plan — the default incidence plan, the
hemispherical plan, ``--uniform`` random plans of the designed plan's size (drawn uniformly
from the reachable candidates) and the designed plan — with real-instrument hours and the
achieved U per parameter family (the worst band's U/|k| and the median).

``--lbl``: the LBL design instead (rolled brass, the default plan's U as the targets: its
candidate campaigns on the design instruments, then the search), beside the default LBL
campaign timed in the same run (the issue asks for at most 20 s).

``--lbl --validate N [--factor F] [--with-default] [--assurance P ...]``: the designed LBL
plan (targets F times the default plan's predicted U) on N instruments, with the default
plan on the same instruments if asked; with several assurance levels, one design each from
the same candidate campaigns, each validated (a plan validated once).

``--lamp F``: the cornell2005 instrument with a lamp F times less stable (its warm-up and
drift, typical and spread, times F) for the design and its campaigns.

``--lamp-table N``: the lamp term the design predicts for the default plan
(:func:`gonio.campaign.design.predicted_lamp_u`, from the laboratory's knowledge) at the
cadences 160, 40, 10 and 0 (first reference only), beside the term the campaign's budget
evaluates from its own references on instruments 0..N-1 (their RMS, min and max).

``--validate N``: the designed plan run on N instruments (seeds 0..N-1 of the preset, noise
seeds the same): the fraction of parameters whose truth lies within the achieved U, the ratio
achieved / predicted U, and the targets met.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign import design as d
from gonio.campaign.cornell import run_cornell_campaign


def _time_design(
    material: str, targets: dict, prior: dict, preset: Any = "cornell2005"
) -> tuple[d.DesignResult, dict]:
    t0 = time.perf_counter()
    c = d.cornell_candidates(material, prior=prior, preset=preset)
    t1 = time.perf_counter()
    r = d.design_cornell(material, targets, candidates=c, prior=prior, preset=preset)
    t2 = time.perf_counter()
    return r, {"candidates_s": t1 - t0, "search_and_prediction_s": t2 - t1, "total_s": t2 - t0}


def _families(summary: dict) -> dict[str, str]:
    b = summary["budget"]["parameters"]
    fit = summary["fit"]
    out = {}
    for fam in ("tau", "k_dd", "k_uds", "k_fs"):
        ps = [p for p in b if p.split("[")[0] == fam]
        if not ps:
            continue
        if fam == "tau":
            out[fam] = f"{100 * b['tau']['U'] / fit['tau']:.2f}%"
            continue
        truth = summary["truth"]  # relative to the true k (the fit may sit at its bound 0)
        rel = [b[p]["U"] / abs(truth[p]) for p in ps if abs(truth.get(p, 0)) > 0]
        out[fam] = f"max {100 * max(rel):.1f}% med {100 * float(np.median(rel)):.1f}%"
    return out


def table(
    material: str, r: d.DesignResult, n_uniform: int, folder: Path, hemispherical: bool = True
) -> None:
    plans = {"default (incidence)": "incidence"}
    if hemispherical:
        plans["hemispherical"] = "hemispherical"
    c = d.cornell_candidates(material, n_grid=13)
    rng = np.random.default_rng(0)
    for u in range(n_uniform):
        idx = np.sort(rng.choice(len(c.plan), size=len(r.plan), replace=False))
        res = d.DesignResult("cornell", material, c.plan.subset(idx), {}, {}, 0.0, {}, {}, 0.0)
        path = folder / f"uniform{u}.csv"
        d.write_cornell_plan(path, res)
        plans[f"uniform {len(r.plan)} #{u}"] = str(path)
    path = folder / "designed.csv"
    d.write_cornell_plan(path, r)
    plans["designed"] = str(path)
    print(f"\n{'plan':<22}{'geoms':>7}{'hours':>8}  achieved U/k (k=2), seed 0")
    for name, plan in plans.items():
        try:
            s = run_cornell_campaign(material, plan=plan, seed=0)
        except Exception as exc:  # a plan the fit cannot use: say so and go on
            print(f"{name:<22}  failed: {exc}")
            continue
        fam = _families(s)
        cov = s["budget"]["coverage"]
        print(
            f"{name:<22}{s['n_geometries']:>7}{s['estimated_real_instrument_h']:>8.3f}  "
            + "; ".join(f"{k} {v}" for k, v in fam.items())
            + f"; truth within U {cov['n_within_U']}/{cov['n']}",
            flush=True,
        )


def lamp_preset(factor: float) -> Any:
    """cornell2005 with the lamp's warm-up and drift (typical and spread) times ``factor``
    (the preset's name itself for 1)."""
    from gonio.simulator.cornell_effects import PRESETS

    if factor == 1.0:
        return "cornell2005"
    out = dict(PRESETS["cornell2005"])
    for k in ("lamp_warmup", "lamp_drift"):
        out[k] = dataclasses.replace(out[k], typical=out[k].typical * factor,
                                     spread=out[k].spread * factor)  # fmt: skip
    return out


def lamp_table(material: str, preset: Any, n: int) -> None:
    """Predicted lamp term of the default plan against the campaigns' (module docstring)."""
    from gonio.simulator.cornell import CornellConfig
    from gonio.simulator.cornell_effects import lab_knowledge

    from gonio.campaign.cornell import _check_corrections
    from gonio.campaign.cornell_budget import _lamp_u

    kn = lab_knowledge(preset)
    lab = CornellConfig().lab_view()
    plan = d.default_cornell_plan(lab, kn)
    truth, *_ = d._fitted(material, None)
    _v, _s, t_int, ref = d._predicted_readings(truth, plan, lab, kn)
    corr = _check_corrections(None)
    print(f"\nlamp term (relative u), default plan ({len(plan)} geometries), {material}, "
          f"instruments 0-{n - 1}:")  # fmt: skip
    print(f"  {'cadence':<10}{'hours':>8}{'predicted':>12}{'campaign RMS':>14}{'min':>10}"
          f"{'max':>10}")  # fmt: skip
    for every in (160, 40, 10, 0):
        pred, hours = d.plan_schedule(lab, plan, t_int, ref, every, kn, corr)
        got = []
        for seed in range(n):
            s = run_cornell_campaign(material, seed=seed, effects=preset, reference_every=every,
                                     budget=False)  # fmt: skip
            got.append(_lamp_u(s, kn, corr, every))
        g = np.array(got)
        print(
            f"  {every or 'none':<10}{hours:>8.3f}{pred:>12.3g}"
            f"{math.sqrt(np.mean(g**2)):>14.3g}{g.min():>10.3g}{g.max():>10.3g}",
            flush=True,
        )


def validate(r: d.DesignResult, n: int, folder: Path, preset: Any = "cornell2005") -> None:
    path = folder / "designed.csv"
    d.write_cornell_plan(path, r)
    within = total = met = n_t = 0
    ratios = []
    for seed in range(n):
        s = run_cornell_campaign(r.material, plan=str(path), seed=seed, effects=preset)
        b = s["budget"]["parameters"]
        within += s["budget"]["coverage"]["n_within_U"]
        total += s["budget"]["coverage"]["n"]
        ratios += [b[p]["U"] / r.predicted[p]["U"] for p in r.predicted if p in b]
        ok = [b[p]["U"] <= t for p, t in r.targets.items() if p in b and p not in r.unreachable]
        met += sum(ok)
        n_t += len(ok)
    q = np.array(ratios)
    print(f"\nvalidation over {n} instrument seeds, designed plan ({len(r.plan)} geometries, "
          f"reference every {r.reference_every or 'none'}, {r.hours:.3f} h):")  # fmt: skip
    print(f"  truth within achieved U: {within}/{total} = {within / total:.4f}")
    print(
        f"  achieved / predicted U: median {np.median(q):.3f}, range {q.min():.3f}-{q.max():.3f},"
        f" within 25 %: {np.mean(np.abs(q - 1) <= 0.25):.4f}"
    )
    print(f"  achieved U at or below target: {met}/{n_t}")


def _cpu() -> float:
    """Processor seconds of this process and its finished children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def bench_lbl(
    validate: int = 0, factor: float = 1.0, n_instruments: int = 6, with_default: bool = False,
    workers: int | None = None, brackets: bool = False, assurance: tuple = (),
) -> None:  # fmt: skip
    from gonio import campaign
    from gonio.campaign import design_lbl

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        campaign.run(
            campaign.Plan(material="rolled_brass", plots=False), tmp, quiet=True, workers=1
        )
        t_base = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), _cpu()
    if brackets:  # the thresholds' candidate campaigns inside the design (its whole time)
        r = design_lbl.design_lbl("rolled_brass", default_factor=factor, brackets=True,
                                  n_instruments=n_instruments, workers=workers,
                                  assurance=(assurance or (design_lbl.ASSURANCE,))[0])  # fmt: skip
        t1, c1 = t0, c0
    else:
        cands = design_lbl.candidate_sets("rolled_brass", [None] * n_instruments,
                                          workers=workers)  # fmt: skip
        t1, c1 = time.perf_counter(), _cpu()
        ps = assurance or (design_lbl.ASSURANCE,)
        rs = [design_lbl.design_lbl("rolled_brass", default_factor=factor, candidates=cands,
                                    assurance=p) for p in ps]  # fmt: skip
        r = rs[0]
    t2, c2 = time.perf_counter(), _cpu()
    print(r.table())
    if brackets:
        print(
            f"\ndesign time with the bracket search (s): {t2 - t0:.1f} (processor "
            f"{c2 - c0:.1f}), {2 * n_instruments} candidate campaigns; the default LBL "
            f"campaign in this run {t_base:.1f} s; load average {os.getloadavg()[0]:.1f}"
        )
    else:
        print(
            f"\ndesign time (s): {n_instruments} candidate campaigns {t1 - t0:.1f} (processor "
            f"{c1 - c0:.1f}), search {t2 - t1:.2f} (processor {c2 - c1:.2f}), total "
            f"{t2 - t0:.1f}; the default LBL campaign in this run {t_base:.1f} s (ratio "
            f"{(t2 - t0) / t_base:.2f}); load average {os.getloadavg()[0]:.1f} (shared machine)"
        )
    if validate:
        validate_lbl(r, validate, with_default)
    done = {(r.theta_i_deg, r.rotations_deg, r.restandard_every): r.assurance}
    for r in [] if brackets else rs[1:]:  # the other assurance levels (one search each)
        print(f"\nassurance {r.assurance:g}:\n{r.table()}")
        key = (r.theta_i_deg, r.rotations_deg, r.restandard_every)
        if validate and key not in done:
            validate_lbl(r, validate, with_default)
        elif validate:
            print(f"  the plan of assurance {done[key]:g}: validated above (its targets the same)")
        done.setdefault(key, r.assurance)


def validate_lbl(r, n: int, with_default: bool = False) -> None:
    """The designed LBL plan on instruments 0..n-1 (campaign seed = instrument seed): truth
    within the achieved U, achieved / predicted (central) U, achieved U at or below each
    target (reachable targets; the unreachable ones' counts apart), and optionally the
    default plan's achieved U on the same instruments."""
    from gonio import campaign

    within = total = met = n_t = met_u = n_u = le_def = 0
    ratios: dict[str, list[float]] = {p: [] for p in r.predicted}
    misses: dict[str, list[str]] = {p: [] for p in r.predicted}  # truth outside U: which
    hours: dict[str, list[float]] = {"designed": [], "default": []}  # each campaign's own
    for seed in range(n):
        kw = dict(material=r.material, plots=False, seed=seed)
        res = campaign.run(
            campaign.Plan(**kw, theta_i_deg=r.theta_i_deg, rotations_deg=r.rotations_deg,
                          restandard_every=r.restandard_every,
                          bracket_min_signal_dn=r.bracket_min_signal_dn),
            None, quiet=True, workers=1,
        )  # fmt: skip
        s = res.summary
        hours["designed"].append(res.real_instrument_h())
        U, fit, truth = s["budget"]["expanded"], s["fit"], s["truth"]
        dU = None
        if with_default:
            dres = campaign.run(campaign.Plan(**kw), None, quiet=True, workers=1)
            dU = dres.summary["budget"]["expanded"]
            hours["default"].append(dres.real_instrument_h())
        for p, up in r.predicted.items():
            total += 1
            within += abs(fit[p] - truth[p]) <= U[p]
            if abs(fit[p] - truth[p]) > U[p]:  # |error| / U, and U / the predicted U
                misses[p].append(f"{seed}: {abs(fit[p] - truth[p]) / U[p]:.2f}, "
                                 f"{U[p] / up:.2f}")  # fmt: skip
            ratios[p].append(U[p] / up)
            if p in r.unreachable:
                n_u += 1
                met_u += U[p] <= r.targets[p]
            elif p in r.targets:
                n_t += 1
                met += U[p] <= r.targets[p]
            if dU is not None:
                le_def += U[p] <= dU[p]
        print(f"  instrument {seed}: " + ", ".join(f"{p} {U[p] / r.targets[p]:.3f}"
              for p in r.predicted) + " (achieved U / target)", flush=True)  # fmt: skip
    q = np.concatenate([np.array(v) for v in ratios.values()])
    print(f"\nvalidation over {n} instruments, designed plan {len(r.theta_i_deg)} angles x "
          f"{len(r.rotations_deg)} rotations, restandard_every {r.restandard_every}, "
          f"{r.hours:.3f} h (default {r.default['hours']:.3f} h: "
          f"{r.hours / r.default['hours']:.2f}):")  # fmt: skip
    print(f"  truth within achieved U: {within}/{total}")
    for p, m in misses.items():
        if m:  # instrument: |fit - truth| / achieved U, achieved / predicted U
            print(f"    {p} outside on {len(m)}/{n} (instrument: |error| / U, U / predicted): "
                  + "; ".join(m))  # fmt: skip
    from gonio.campaign.design_lbl import plan_hours

    for name, h in hours.items():  # the estimate against each campaign's own brackets
        if not h:
            continue
        h = np.array(h)
        est = r.hours if name == "designed" else r.default["hours"]
        angles = r.theta_i_deg if name == "designed" else campaign.Plan().theta_i_deg
        rots = r.rotations_deg if name == "designed" else (
            campaign.Plan(material=r.material).resolved().rotations_deg)  # fmt: skip
        three = plan_hours(angles, rots, "modern",
                           r.restandard_every if name == "designed" else 0, brackets=3)  # fmt: skip
        print(f"  {name} plan's hours from each campaign's own brackets: median {np.median(h):.4f}"
              f" h, range {h.min():.4f}-{h.max():.4f}; the design's estimate {est:.4f} h "
              f"({est / np.median(h):.3f} x the median), at 3 frames a capture {three:.4f} h "
              f"({three / np.median(h):.3f} x)")  # fmt: skip
    print(
        f"  achieved / predicted U: median {np.median(q):.3f}, range {q.min():.3f}-"
        f"{q.max():.3f}, within 25 %: {np.sum(np.abs(q - 1) <= 0.25)}/{q.size}"
    )
    for p, v in ratios.items():
        v = np.array(v)
        print(f"    {p}: median {np.median(v):.3f}, range {v.min():.3f}-{v.max():.3f}")
    print(f"  achieved U at or below target (reachable targets): {met}/{n_t}")
    if n_u:
        print(
            f"  unreachable targets ({', '.join(r.unreachable)}): achieved U at or below "
            f"them {met_u}/{n_u}"
        )
    if with_default:
        print(
            f"  designed U at or below the default plan's on the same instrument: {le_def}/{total}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--material", default="garnet_red_paint")
    ap.add_argument("--target", action="append", default=[])
    ap.add_argument("--prior", action="append", default=[])
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--no-hemispherical", action="store_true", help="leave it out of --table")
    ap.add_argument("--uniform", type=int, default=2)
    ap.add_argument("--validate", type=int, default=0)
    ap.add_argument("--lbl", action="store_true")
    ap.add_argument("--factor", type=float, default=1.0, help="lbl: targets x default U")
    ap.add_argument("--instruments", type=int, default=6, help="lbl: design instruments")
    ap.add_argument(
        "--workers", type=int, default=None, help="lbl: processes of the candidate campaigns"
    )
    ap.add_argument(
        "--brackets", action="store_true", help="lbl: the design searches the bracket threshold"
    )
    ap.add_argument(
        "--assurance", type=float, nargs="+", default=(), help="lbl: the design's level(s)"
    )
    ap.add_argument(
        "--with-default",
        action="store_true",
        help="lbl --validate: the default plan too, on the same instruments",
    )
    ap.add_argument("--lamp", type=float, default=1.0,
                    help="cornell: the lamp's warm-up and drift times this factor")  # fmt: skip
    ap.add_argument("--lamp-table", type=int, default=0, metavar="N",
                    help="cornell: predicted vs campaigns' lamp term on N instruments")  # fmt: skip
    a = ap.parse_args()
    if a.lbl:
        return bench_lbl(a.validate, a.factor, a.instruments, a.with_default, a.workers,
                         a.brackets, tuple(a.assurance))  # fmt: skip
    preset = lamp_preset(a.lamp)
    if a.lamp_table:
        return lamp_table(a.material, preset, a.lamp_table)
    targets = d.parse_targets(a.target or None)
    prior = d.parse_prior(a.prior)
    t0 = time.perf_counter()
    base = run_cornell_campaign(a.material, seed=0, effects=preset)
    t_base = time.perf_counter() - t0
    r, times = _time_design(a.material, targets, prior, preset)
    print(r.table())
    print(
        f"\ndesign time (s): candidates {times['candidates_s']:.1f}, search + prediction "
        f"{times['search_and_prediction_s']:.1f}, total {times['total_s']:.1f}; the default "
        f"campaign in this run {t_base:.1f} s (ratio {times['total_s'] / t_base:.2f}); "
        f"shared machine"
    )
    if not math.isfinite(base["estimated_real_instrument_h"]):
        raise SystemExit("baseline campaign failed")
    with tempfile.TemporaryDirectory() as tmp:
        if a.table:
            table(a.material, r, a.uniform, Path(tmp), not a.no_hemispherical)
        if a.validate:
            validate(r, a.validate, Path(tmp), preset)


if __name__ == "__main__":
    main()
