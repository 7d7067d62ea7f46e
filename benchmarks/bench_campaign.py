"""Campaign accuracy and speed: the targets of issue 5, measured.

Usage::

    python benchmarks/bench_campaign.py                 # default campaign timing (3 runs)
    python benchmarks/bench_campaign.py --ward-table    # every Ward-table material, noise off/on
    python benchmarks/bench_campaign.py --others        # blue paint, plaster, Li-Torrance
    python benchmarks/bench_campaign.py --json out.json

Every run goes through the whole chain (simulated LBL captures → eq. 2 reduction → fit).
Nothing here is asserted; the numbers are printed (and optionally saved) for the notes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time

from gonio import campaign, materials


def ward_table_materials(latex: bool = False) -> list[str]:
    """The presets of Ward's §6 table of fits (with ``latex``: also the latex paint tables)."""
    tables = ("ward", "ward_latex") if latex else ("ward",)
    return [n for n in materials.names("ward") if materials.info(n).get("table") in tables]


def run_one(material: str, model: str | None, noise: float, compare=(), plots=False) -> dict:
    plan = campaign.Plan(
        material=material, model=model, noise=noise, compare=tuple(compare), plots=plots
    )
    with tempfile.TemporaryDirectory() as d:
        res = campaign.run(plan, d if plots else None)
    s = res.summary
    pulls = {}
    for k, t in s["truth"].items():
        se = s["stderr"].get(k)
        if k in s["fit"] and se:
            pulls[k] = (s["fit"][k] - t) / se
    return {
        "material": material,
        "model": s["model"],
        "noise": noise,
        "converged": s["converged"],
        "relative_error": s["relative_error"],
        "pulls": pulls,
        "within_3_sigma": s["within_3_sigma"],
        "rms": s["rms"],
        "chi2_dof": s["chi2_dof"],
        "n_samples": s["n_samples"],
        "compare": {k: v.get("rms") for k, v in s["compare"].items()},
        "time_s": s["timings_s"]["total"],
        "timings_s": s["timings_s"],
    }


def _print(r: dict) -> None:
    rel = " ".join(f"{k} {100 * v:.3f}%" for k, v in r["relative_error"].items())
    pul = " ".join(f"{k} {v:+.1f}" for k, v in r["pulls"].items() if k in r["relative_error"])
    comp = " ".join(f"{k} {v:.4g}" for k, v in r["compare"].items() if v is not None)
    print(
        f"{r['material']:34s} {r['model']:12s} noise {r['noise']:g} "
        f"{'ok ' if r['converged'] else 'NOT'} | {rel} | pulls {pul} | rms {r['rms']:.4g}"
        + (f" | {comp}" if comp else "")
        + f" | n {r['n_samples']} | {r['time_s']:.1f} s"
        + " ("
        + ", ".join(f"{k} {v:.1f}" for k, v in r["timings_s"].items() if v >= 0.5)
        + ")",
        flush=True,
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ward-table", action="store_true")
    ap.add_argument("--others", action="store_true")
    ap.add_argument("--latex", action="store_true", help="with --ward-table: latex tables too")
    ap.add_argument("--materials", default=None, help="comma-separated subset")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    out: dict = {}
    if not (args.ward_table or args.others):
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            with tempfile.TemporaryDirectory() as d:
                res = campaign.run(campaign.Plan(), d)
            times.append(time.perf_counter() - t)
            print(campaign.summary_table(res.summary), flush=True)
        print("default campaign wall clock (s):", " ".join(f"{x:.2f}" for x in times))
        out["default_wall_s"] = times
        out["default_timings_s"] = res.summary["timings_s"]
    if args.ward_table:
        names = args.materials.split(",") if args.materials else ward_table_materials(args.latex)
        rows = []
        for n in names:
            for noise in (0.0, 1.0):
                comp = ("cook_torrance", "lafortune") if noise else ()
                r = run_one(n, None, noise, comp)
                _print(r)
                rows.append(r)
        out["ward_table"] = rows
        off = [r for r in rows if r["noise"] == 0]
        on = [r for r in rows if r["noise"] > 0]
        worst = max(v for r in off for v in r["relative_error"].values())
        n3 = sum(all(v for v in r["within_3_sigma"].values() if v is not None) for r in on)
        print(f"noise off: worst relative error {100 * worst:.3f}% over {len(off)} materials")
        print(f"default noise: {n3}/{len(on)} materials with every parameter within 3 sigma")
    if args.others:
        rows = []
        for material, model, comp in _others():
            r = run_one(material, model, 1.0, comp)
            _print(r)
            rows.append(r)
        out["others"] = rows
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                out,
                f,
                indent=1,
                default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else str(o),
            )
    return 0


def _others() -> list[tuple[str, str, tuple[str, ...]]]:
    """(material, model, compared models): Lafortune presets with lafortune, Oren-Nayar's
    plaster with oren_nayar (and lambert), Li-Torrance presets with li_torrance and ward."""
    out = []
    for n in materials.names("lafortune"):
        out.append((n, "lafortune", ("ward",)))
    if "wall_plaster" in materials.names("oren_nayar"):
        out.append(("wall_plaster", "oren_nayar", ("lambert",)))
    for n in ("garnet_red_paint", "aluminized_ground_glass"):
        if n in materials.names("li_torrance"):
            out.append((n, "li_torrance", ("ward",)))
    return out


if __name__ == "__main__":
    sys.exit(main())
