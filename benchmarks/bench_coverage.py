"""The coverage matrix: every instrument preset x material family x fitted model.

Generalises ``bench_budget.py`` (the modern LBL instrument on Ward's table) and
``bench_cornell_coverage.py`` (the Cornell default) to the cases a new user tries. Rows:

* the LBL presets ``ideal``, ``modern``, ``ward1992`` x one material of every family among
  the presets (Ward, Li-Torrance, Lafortune, Oren-Nayar, Torrance-Sparrow, Neumann metal
  and plastic; no preset is a tabulated BRDF) x the family's own model and one other
  (``ward``; ``cook_torrance`` for a Ward material);
* the Cornell presets ``ideal``, ``cornell2005`` x the incidence-plane and hemispherical
  plans x a Li-Torrance material (the Cornell campaign fits ``li_torrance`` only).

Each (row, seed) is one campaign in memory (a different physical instrument of the preset
and different noise); the fit is compared with the truth, or for another family than the
truth's with the model's best approximation of it (``summary["reference"]``,
:mod:`gonio.campaign.reference`). Columns per row: ``n`` campaigns, the coverage of the
expanded uncertainty U (k = 2) over the determined parameters, the median over parameters of
U / rms error, the largest |bias| / rms error, crashes (a campaign that raised) and flagged
campaigns (an undetermined parameter, a resolution warning, or a fit whose chi2/dof says the
model cannot describe the data). ``p95`` is the binomial chance of a coverage this low or
lower if the true coverage were 95 % and every parameter an independent trial; the
parameters of one campaign are not independent (a Lafortune lobe's three parameters miss
together), so ``hi`` is the upper 95 % bound of the coverage from a bootstrap over the row's
campaigns (each campaign resampled whole, 4000 resamples, a fixed seed), and ``misfit`` the
campaigns whose summary says their U is a lower bound (chi2/dof above the fit's note
threshold) or that the lobe is narrower than the instrument resolves. The verdict: ``ok``
with ``hi`` >= 95 % and U/rms <= 3; else ``flagged`` when the campaigns without such a
statement cover (their ``hi`` >= 95 %, or there are none) and, with U/rms > 3, there are
none: a user is told, campaign by campaign, where U is not to be trusted; else ``SHORT``
(too few inside U) or ``LOOSE`` (U more than 3x the rms error, unflagged). A parameter
whose U is as large as its value is counted as bounded, not measured.

The campaigns run as tasks of :func:`gonio.campaign.sweep.run_sweep` (``--executor process``
with ``--workers``, or ``dask``), each in its own folder under ``--root``; a rerun skips the
finished ones. The plan is small on purpose (``--angles``, rotation 0; the CPU is shared):
say which n a number covers.

Usage::

    python benchmarks/bench_coverage.py --seeds 2 --workers 2 [--presets modern,ward1992]
        [--families ward,oren_nayar] [--models default,other] [--angles 20,45,70]
        [--root coverage_runs]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

#: one preset material of each family, and the other model fitted to it
FAMILIES: dict[str, tuple[str, str]] = {
    "ward": ("rolled_brass", "cook_torrance"),
    "li_torrance": ("garnet_red_paint", "ward"),
    "lafortune": ("blue_paint_lafortune", "ward"),
    "oren_nayar": ("white_sand", "ward"),
    "torrance_sparrow": ("foam_surface", "ward"),
    "metal_neumann": ("neumann_fig10_silver_sphere", "ward"),
    "plastic_neumann": ("neumann_fig13_plastic_1", "ward"),
}
LBL_PRESETS = ("ideal", "modern", "ward1992")
CORNELL_PRESETS = ("ideal", "cornell2005")
CORNELL_PLANS = ("incidence", "hemispherical")
CORNELL_MATERIAL = "garnet_red_paint"


def rows(
    presets: list[str], families: list[str], cornell: bool, models: str = "default,other"
) -> list[dict[str, Any]]:
    """The matrix's rows as sweep settings (``models``: the family's own model ``default``,
    the ``other`` one, or both)."""
    wanted = set(models.split(","))
    out = []
    for p in presets:
        if p not in LBL_PRESETS:
            continue
        for fam in families:
            mat, other = FAMILIES[fam]
            for model in ("default", other):
                if ("default" if model == "default" else "other") not in wanted:
                    continue
                out.append(
                    {
                        "instrument": "lbl",
                        "preset": p,
                        "family": fam,
                        "material": mat,
                        "model": model,
                    }
                )
    if cornell:
        for p in CORNELL_PRESETS:
            if p not in presets:
                continue
            for plan in CORNELL_PLANS:
                out.append(
                    {
                        "instrument": "cornell",
                        "preset": p,
                        "family": "li_torrance",
                        "material": CORNELL_MATERIAL,
                        "model": "default",
                        "plan": plan,
                    }
                )
    return out


def coverage_task(task: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """One campaign of a row (``task["settings"]["row"]``); flat metrics: per parameter
    ``err:<p>`` (fit - truth or reference), ``U:<p>`` (expanded, absent when undetermined),
    ``ref:<p>``; and ``crash``, ``flagged``, ``n_undetermined``, ``seconds``."""
    row = json.loads(task["settings"]["row"])
    seed = int(task["seed"])
    t = time.perf_counter()
    try:
        s = _cornell(row, seed) if row["instrument"] == "cornell" else _lbl(row, seed, task)
    except Exception as exc:  # a crash is a result of the matrix, not the end of it
        (out_dir / "crash.txt").write_text(f"{type(exc).__name__}: {exc}\n")
        return {"crash": 1, "flagged": 0, "n_undetermined": 0, "seconds": time.perf_counter() - t}
    m: dict[str, Any] = {"crash": 0, "seconds": time.perf_counter() - t}
    m.update(s)
    return m


def _lbl(row: dict[str, Any], seed: int, task: dict[str, Any]) -> dict[str, Any]:
    from gonio.campaign import Plan, run

    angles = tuple(float(a) for a in task["fixed"]["angles"].split(","))
    kw = {} if row["model"] == "default" else {"model": row["model"]}
    r = run(
        Plan(
            material=row["material"],
            preset=row["preset"],
            seed=seed,
            plots=False,
            theta_i_deg=angles,
            rotations_deg=(0.0,),
            **kw,
        ),
        quiet=True,
        workers=1,
    )
    s = r.summary
    json.dumps(s, allow_nan=False, default=str)  # what the campaign writes (inf: a crash)
    ref = (
        s["truth"]
        if s["model"] == s["truth_model"]
        else (s.get("reference") or {}).get("params", {})
    )
    und = s.get("undetermined") or {}
    out: dict[str, Any] = {"n_undetermined": len(und)}
    for k, v in s["fit"].items():
        if k not in ref or k not in s["budget"]["expanded"]:
            continue
        out[f"err:{k}"] = v - ref[k]
        out[f"ref:{k}"] = ref[k]
        u = s["budget"]["expanded"][k]
        if u is not None and k not in und:
            out[f"U:{k}"] = u
    warn = " ".join(s.get("warnings") or [])
    misfit = "narrower than the instrument resolves" in warn or "lower bound" in s.get(
        "fit_status", ""
    )
    out["misfit"] = int(misfit)
    out["flagged"] = int(bool(und) or misfit or s.get("fit_status", "converged") != "converged")
    return out


def _cornell(row: dict[str, Any], seed: int) -> dict[str, Any]:
    from gonio.campaign.cornell import run_cornell_campaign

    effects = None if row["preset"] == "ideal" else row["preset"]
    s = run_cornell_campaign(row["material"], plan=row["plan"], seed=seed, effects=effects)
    s.pop("_samples", None)
    json.dumps(s, allow_nan=False, default=str)  # what the campaign writes (inf: a crash)
    out: dict[str, Any] = {"n_undetermined": 0}
    params = (s.get("budget") or {}).get("parameters", {})
    for k, e in params.items():
        if k not in s["truth"] or k not in s["fit"]:
            continue
        out[f"err:{k}"] = s["fit"][k] - s["truth"][k]
        out[f"ref:{k}"] = s["truth"][k]
        u = e.get("U")
        if u is not None and math.isfinite(u):
            out[f"U:{k}"] = u
        else:
            out["n_undetermined"] += 1
    out["flagged"] = int(out["n_undetermined"] > 0 or not s.get("converged", True))
    return out


def table(results: list[dict[str, Any]]) -> str:
    """Per row: n, coverage of U over the measured parameters, its binomial p (the chance of
    so few inside if the coverage were 95 % and the parameters independent), the bootstrap
    upper bound ``hi`` of the coverage over whole campaigns, median U/rms, max |bias|/rms
    (over the parameters), bounded parameters, crashes, flagged and misfit campaigns, the
    verdict (module docstring).

    A parameter whose U is as large as its value is *bounded*, not measured (the campaign
    says so in its warnings: :func:`gonio.campaign.determined.budget_warnings`); it counts in
    ``bound`` and not in the coverage or U/rms."""
    from scipy.stats import binom

    by: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in results:
        by[r["row"]].append(r)
    head = (
        f"{'instrument':8s} {'preset':11s} {'plan':13s} {'material':28s} {'model':14s} "
        f"{'n':>2s} {'cover':>11s} {'p95':>5s} {'hi':>4s} {'U/rms':>6s} {'|bias|/rms':>10s} "
        f"{'bound':>5s} {'crash':>5s} {'flag':>4s} {'misfit':>6s} verdict"
    )
    lines = [head, "-" * len(head)]

    def order(key: str) -> tuple:
        r = json.loads(key)
        return (
            r["instrument"],
            r["preset"],
            r.get("plan", ""),
            r["family"],
            r["model"] != "default",
        )

    for key, rs in sorted(by.items(), key=lambda kv: order(kv[0])):
        row = json.loads(key)
        ok = [r["metrics"] for r in rs if not r["metrics"].get("crash")]
        st = _stats(ok)
        n_in, n_det = st["inside"], st["determined"]
        cover = f"{n_in}/{n_det} {100 * n_in / n_det:3.0f}%" if n_det else "-"
        p95 = f"{binom.cdf(n_in, n_det, 0.95):5.2f}" if n_det else "    -"
        lines.append(
            f"{row['instrument']:8s} {row['preset']:11s} {row.get('plan', '-'):13s} "
            f"{row['material']:28s} {row['model']:14s} {len(rs):2d} {cover:>11s} {p95} "
            f"{st['hi']:4.2f} {st['u_rms']:6.2f} {st['bias']:10.2f} {st['bound']:5d} "
            f"{sum(r['metrics'].get('crash', 0) for r in rs):5d} "
            f"{sum(r['metrics'].get('flagged', 0) for r in rs):4d} "
            f"{sum(m.get('misfit', 0) for m in ok):6d} {_verdict(ok, st)}"
        )
    return "\n".join(lines)


def _honest(st: dict[str, Any]) -> bool:
    return st["hi"] >= 0.95 and not (st["u_rms"] > 3.0)


def _verdict(campaigns: list[dict[str, Any]], st: dict[str, Any]) -> str:
    """``ok``: the row's coverage is consistent with 95 % (``hi``) and U/rms <= 3;
    ``flagged``: not, but every campaign says its U is a lower bound where U/rms > 3, and
    the campaigns that do not say so cover (``hi`` >= 95 %, U/rms not asked: a few
    campaigns' rms says little), or there are none; ``LOOSE``: U/rms > 3 in campaigns that
    say nothing; ``SHORT``: too few inside U in campaigns that say nothing."""
    if not st["determined"]:
        return "-"
    if _honest(st):
        return "ok"
    plain = [m for m in campaigns if not m.get("misfit", 0)]
    if st["u_rms"] > 3.0 and plain:
        return "LOOSE"
    if not plain:  # (here U/rms <= 3 with plain campaigns, so the coverage fell short)
        return "flagged"
    sp = _stats(plain)
    return "flagged" if not sp["determined"] or sp["hi"] >= 0.95 else "SHORT"


def _stats(campaigns: list[dict[str, Any]]) -> dict[str, Any]:
    """Coverage, its bootstrap upper bound, U/rms and |bias|/rms of a set of campaigns."""
    import numpy as np

    per: dict[str, list[tuple[float, float | None, float]]] = defaultdict(list)
    camp_in, camp_det = [], []
    for m in campaigns:
        c_in = c_det = 0
        for k, v in m.items():
            if k.startswith("err:"):
                p = k[4:]
                u, ref = m.get(f"U:{p}"), m[f"ref:{p}"]
                per[p].append((v, u, ref))
                if u is not None and u < abs(ref):
                    c_det += 1
                    c_in += abs(v) <= u
        camp_in.append(c_in)
        camp_det.append(c_det)
    n_bound = 0
    ratios, biases = [], []
    for vals in per.values():
        n_bound += sum(u is not None and u >= abs(r) for _, u, r in vals)
        det = [(e, u) for e, u, r in vals if u is not None and u < abs(r)]
        if len(det) >= 2:
            errs = [e for e, _ in det]
            rms = math.sqrt(sum(e * e for e in errs) / len(errs))
            if rms > 0:
                ratios.append(statistics.mean(u for _, u in det) / rms)
                biases.append(abs(statistics.mean(errs)) / rms)
    inside, det = np.array(camp_in, float), np.array(camp_det, float)
    hi = math.nan
    if det.sum() > 0:  # percentile bootstrap, each campaign resampled whole
        idx = np.random.default_rng(0).integers(0, len(det), size=(4000, len(det)))
        tot = det[idx].sum(axis=1)
        cov = inside[idx].sum(axis=1)[tot > 0] / tot[tot > 0]
        hi = float(np.quantile(cov, 0.95))
    return {
        "inside": int(inside.sum()),
        "determined": int(det.sum()),
        "hi": hi,
        "u_rms": statistics.median(ratios) if ratios else math.nan,
        "bias": max(biases) if biases else math.nan,
        "bound": n_bound,
    }


def main(argv: list[str] | None = None) -> int:
    from gonio.campaign.sweep import register_task, run_sweep, spec_from_dict

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default=",".join(LBL_PRESETS + CORNELL_PRESETS[1:]))
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--no-cornell", action="store_true")
    ap.add_argument(
        "--models", default="default,other", help="LBL rows: the family's own model, the other"
    )
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--angles", default="20,45,70", help="LBL incidence angles (deg)")
    ap.add_argument("--executor", default="process", choices=("inprocess", "process", "dask"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--root", default="coverage_runs")
    a = ap.parse_args(argv)
    presets = a.presets.split(",")
    fams = [f for f in a.families.split(",") if f]
    unknown = set(fams) - set(FAMILIES)
    if unknown:
        ap.error(f"unknown families {sorted(unknown)}; expected some of {list(FAMILIES)}")
    register_task("coverage_row", coverage_task, metric="crash")
    grid = [json.dumps(r, sort_keys=True) for r in rows(presets, fams, not a.no_cornell, a.models)]
    spec = spec_from_dict(
        {
            "name": "coverage",
            "task": "coverage_row",
            "materials": ["-"],
            "seeds": list(range(a.first_seed, a.first_seed + a.seeds)),
            "settings": {"row": grid},
            "fixed": {"angles": a.angles},
        }
    )
    t = time.perf_counter()
    try:
        run_sweep(spec, a.root, executor=a.executor, workers=a.workers, plot=False)
    except Exception as exc:  # TaskFailed keeps the finished ones: read back below
        print(f"sweep: {type(exc).__name__}: {exc}")
    seeds = set(spec.seeds)
    results = [r for r in _read(Path(a.root)) if r["row"] in grid and r["seed"] in seeds]
    print(
        f"coverage matrix: {len(results)} campaigns, seeds {a.first_seed}.."
        f"{a.first_seed + a.seeds - 1}, LBL angles {a.angles} rotation 0, "
        f"{time.perf_counter() - t:.0f} s on {a.workers} {a.executor} workers"
    )
    print(table(results))
    return 0


def _read(root: Path) -> list[dict[str, Any]]:
    """Every finished task's row and metrics under ``root/tasks``."""
    out = []
    for f in sorted((root / "tasks").glob("*/sweep_task.json")):
        d = json.loads(f.read_text())
        out.append(
            {
                "row": d["task"]["settings"]["row"],
                "seed": d["task"]["seed"],
                "metrics": d["metrics"],
            }
        )
    return out


if __name__ == "__main__":
    raise SystemExit(main())
