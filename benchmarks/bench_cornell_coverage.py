"""Coverage of the Cornell campaign's uncertainty budget over many realised instruments.

Run: ``python benchmarks/bench_cornell_coverage.py [--seeds 20] [--material NAME ...]
[--off EFFECT ...] [--workers 2] [--records PATH]``

For every material and seed: the default Cornell campaign (incidence plan, noise on) on the
instrument ``cornell2005`` realised with that seed (``--off``: the preset with those effects
at zero, truth and laboratory knowledge alike: an ablation), and per fitted parameter the
signed error against the truth and the budget's expanded uncertainty U (k = 2). Printed per
material and parameter family (σ/τ, τ, σ, each k over its 31 bands): the mean bias, the rms
error over the seeds, the median U, the coverage (truth within U) and the median over the
parameters of U / rms (the done-when asks coverage >= 95 % and U <= 3 x rms). The largest
budget terms are listed beside, to compare with an ablation's change of the rms.

The JSON lines of ``--records`` keep every campaign's result (appended; a rerun skips the
(material, seed, off) already there).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

MATERIALS = (
    "garnet_red_paint",
    "laser_paper",
    "aluminized_ground_glass",
    "aluminized_non_glare_glass",
)


def one(material: str, seed: int, off: tuple[str, ...]) -> dict:
    """One campaign's per-parameter error, U and budget terms."""
    from gonio.simulator.cornell_effects import PRESETS
    from gonio.simulator.effects import Distribution

    from gonio.campaign.cornell import run_cornell_campaign

    preset = {
        k: (Distribution(0.0, 0.0, d.valid) if k in off else d)
        for k, d in PRESETS["cornell2005"].items()
    }
    s = run_cornell_campaign(material, seed=seed, effects=preset if off else "cornell2005")
    b = s["budget"]["parameters"]
    out = {}
    for p, e in b.items():
        if p not in s["truth"] or p not in s["fit"]:
            continue
        out[p] = {
            "err": float(s["fit"][p] - s["truth"][p]),
            "U": float(e["U"]),
            "stat": float(e["stat"]),
            "terms": {n: float(v) for n, v in e["contributions"].items()},
        }
    return {
        "material": material,
        "seed": seed,
        "off": list(off),
        "params": out,
        "wall_s": s["timings_s"]["total"],
    }


def family(p: str) -> str:
    return p.split("[")[0]


def table(records: list[dict]) -> list[dict]:
    """Rows (material, family): bias, rms, median U, coverage, U/rms."""
    by: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in records:
        by[(r["material"], ",".join(r["off"]))].append(r)
    rows = []
    for (mat, off), rs in sorted(by.items()):
        params = sorted({p for r in rs for p in r["params"]})
        fam: dict[str, dict] = defaultdict(
            lambda: {
                "n": 0,
                "in": 0,
                "ratio": [],
                "bias": [],
                "rms": [],
                "U": [],
                "terms": defaultdict(list),
            }
        )
        for p in params:
            err = np.array([r["params"][p]["err"] for r in rs if p in r["params"]])
            u = np.array([r["params"][p]["U"] for r in rs if p in r["params"]])
            f = fam[family(p)]
            f["n"] += len(err)
            f["in"] += int(np.sum(np.abs(err) <= u))
            rms = float(np.sqrt(np.mean(err**2)))
            f["bias"].append(float(np.mean(err)))
            f["rms"].append(rms)
            f["U"].append(float(np.median(u)))
            if rms > 0:
                f["ratio"].append(float(np.median(u)) / rms)
            for r in rs:
                for n, v in r["params"].get(p, {}).get("terms", {}).items():
                    f["terms"][n].append(v / rms if rms > 0 else 0.0)
                f["terms"]["stat"].append(
                    r["params"].get(p, {}).get("stat", 0.0) / rms if rms > 0 else 0.0
                )
        for name, f in fam.items():
            terms = {n: float(np.median(v)) for n, v in f["terms"].items()}
            top = sorted(terms.items(), key=lambda kv: -kv[1])[:3]
            rows.append(
                {
                    "material": mat,
                    "off": off or "-",
                    "parameter": name,
                    "n_seeds": len(rs),
                    "n": f["n"],
                    "coverage": f["in"] / max(f["n"], 1),
                    "bias": float(np.median(np.abs(f["bias"]))),
                    "rms": float(np.median(f["rms"])),
                    "U": float(np.median(f["U"])),
                    "U_over_rms_median": float(np.median(f["ratio"])) if f["ratio"] else None,
                    "U_over_rms_max": float(np.max(f["ratio"])) if f["ratio"] else None,
                    "top_terms_over_rms": top,
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--material", nargs="+", default=list(MATERIALS))
    ap.add_argument("--off", nargs="*", default=[], help="effects at zero (an ablation)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--records", default=None, help="JSON lines of every campaign (appended)")
    ap.add_argument("--report-only", action="store_true", help="only tabulate --records")
    a = ap.parse_args(argv)
    off = tuple(sorted(a.off))
    done: list[dict] = []
    path = Path(a.records) if a.records else None
    if path is not None and path.is_file():
        done = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    have = {(r["material"], r["seed"], tuple(r["off"])) for r in done}
    todo = [
        (m, s, off)
        for m in a.material
        for s in range(a.first_seed, a.first_seed + a.seeds)
        if (m, s, off) not in have
    ]
    if not a.report_only and todo:
        with ProcessPoolExecutor(max(1, a.workers)) as ex:
            for rec in ex.map(one, *zip(*todo)):
                done.append(rec)
                if path is not None:
                    with path.open("a") as fh:
                        fh.write(json.dumps(rec) + "\n")
    seeds = set(range(a.first_seed, a.first_seed + a.seeds))
    use = [
        r
        for r in done
        if r["material"] in a.material and r["seed"] in seeds and tuple(r["off"]) == off
    ]
    rows = table(use)
    print(
        f"{'material':27s} {'param':9s} {'seeds':>5s} {'bias':>9s} {'rms':>9s} {'U':>9s} "
        f"{'cover':>6s} {'U/rms':>6s} {'max':>6s}  largest terms / rms"
    )
    n_all = n_in = 0
    for r in rows:
        n_all += r["n"]
        n_in += round(r["coverage"] * r["n"])
        top = ", ".join(f"{n} {v:.2f}" for n, v in r["top_terms_over_rms"])
        ur = r["U_over_rms_median"]
        um = r["U_over_rms_max"]
        print(
            f"{r['material']:27s} {r['parameter']:9s} {r['n_seeds']:5d} {r['bias']:9.3g} "
            f"{r['rms']:9.3g} {r['U']:9.3g} {100 * r['coverage']:5.1f}% "
            f"{ur if ur is not None else float('nan'):6.2f} "
            f"{um if um is not None else float('nan'):6.2f}  {top}"
        )
    print(f"all: {n_in}/{n_all} parameters within U ({100 * n_in / max(n_all, 1):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
