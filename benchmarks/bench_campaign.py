"""Campaign accuracy and speed: the targets of issue 5, measured.

Usage::

    python benchmarks/bench_campaign.py                 # default campaign timing, ideal and
                                                        # realistic (modern) instrument A B A B
    python benchmarks/bench_campaign.py --first-run     # the first campaign after an install
                                                        # (numba's and the calibration cache
                                                        # empty) against a warm one, A B A B
    python benchmarks/bench_campaign.py --ward-table    # every Ward-table material, noise off/on
    python benchmarks/bench_campaign.py --others        # blue paint, plaster, Li-Torrance
    python benchmarks/bench_campaign.py --blue-paint    # only Lafortune's blue paint
    python benchmarks/bench_campaign.py --json out.json

Every run goes through the whole chain (simulated LBL captures → eq. 2 reduction → fit).
Nothing here is asserted; the numbers are printed (and optionally saved) for the notes.

References
----------
.. [Lafortune1997] E. P. F. Lafortune, S.-C. Foo, K. E. Torrance and D. P. Greenberg, "Non-linear
   approximation of reflectance functions", Proc. SIGGRAPH '97, 117-126, 1997.
   https://doi.org/10.1145/258734.258801
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


#: Lafortune et al. table 1: blue paint, three lobes (C_x = C_y, C_z, n) and "Diffuse" 0.13
#: (Lafortune et al. 1997, §6.2); there is no preset of it, so it is measured as a user BRDF.
BLUE_PAINT = dict(
    lobes=[(0.86, 0.86, 0.77, 18.6), (-0.41, -0.41, 0.018, 2.58), (-1.03, -1.03, 0.70, 63.8)],
    rho_d=0.13,
)


def run_one(
    material: str, model: str | None, noise: float, compare=(), plots=False, truth=None
) -> dict:
    plan = campaign.Plan(
        material=material, model=model, noise=noise, compare=tuple(compare), plots=plots
    )
    with tempfile.TemporaryDirectory() as d:
        res = campaign.run(plan, d if plots else None, truth=truth)
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
        "lobes": s.get("lobes"),
        "fit": s["fit"],
        "truth": s["truth"],
        "identifiable": res.fit.identifiable,
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
    f, t = r.get("fit", {}), r.get("truth", {})
    if "sigma" in f and "tau" in f and "tau" in t:  # Li-Torrance: the slope sigma/tau
        print(f"    sigma/tau fit {f['sigma'] / f['tau']:.5g} truth {t['sigma'] / t['tau']:.5g}"
              f" (identifiable: {r['identifiable']})")  # fmt: skip
    if r.get("lobes"):
        for name in ("truth", "fit"):
            print(f"    lobes ({name}, sorted by n): "
                  + "; ".join("(" + ", ".join(f"{x:.4g}" for x in lb) + ")"
                              for lb in r["lobes"][name]))  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ward-table", action="store_true")
    ap.add_argument("--others", action="store_true")
    ap.add_argument("--blue-paint", action="store_true")
    ap.add_argument("--latex", action="store_true", help="with --ward-table: latex tables too")
    ap.add_argument("--materials", default=None, help="comma-separated subset")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--presets", default="ideal,modern", help="instrument presets timed side by side"
    )
    ap.add_argument(
        "--first-run", action="store_true",
        help="the last preset's campaign on empty caches (as after an install) against warm",
    )  # fmt: skip
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    out: dict = {}
    if not (args.ward_table or args.others or args.blue_paint):
        presets = tuple(args.presets.split(","))
        out["default"] = cold_runs(args.repeat, presets, first_run=args.first_run)
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
        from gonio import brdf

        if not materials.names("lafortune"):
            truth = brdf.create("lafortune", **BLUE_PAINT)
            r = run_one("blue_paint", "lafortune", 1.0, ("ward",), truth=truth)
            _print(r)
            rows.append(r)
        for material, model, comp in _others():
            r = run_one(material, model, 1.0, comp)
            _print(r)
            rows.append(r)
        out["others"] = rows
    if args.blue_paint:
        from gonio import brdf

        truth = brdf.create("lafortune", **BLUE_PAINT)
        r = run_one("blue_paint", "lafortune", 1.0, ("ward",), truth=truth)
        _print(r)
        out["blue_paint"] = r
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                out,
                f,
                indent=1,
                default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else str(o),
            )
    return 0


def cold_runs(
    repeat: int, presets: tuple[str, ...] = ("ideal", "modern"), first_run: bool = False
) -> list[dict]:
    """``gonio campaign --preset P`` in a fresh interpreter, ``repeat`` times for each preset,
    alternating (A B A B): wall clock from the shell's view (start-up, imports and JIT-cache
    loading included) beside the campaign's own total, so start-up = wall − total; then
    each preset's wall time over the first's, pair by pair (the realistic instrument's cost
    against the ideal one's, measured side by side), and the same for the CPU seconds of
    the campaign's processes (workers and plot process included). On a shared machine whose
    scheduler groups a session's processes (Linux autogroup), a loaded machine gives the
    session about the same CPU share however many processes it runs, so there the wall
    ratio follows the CPU ratio and parallel stages gain nothing; on an idle machine they
    do.

    ``first_run``: the last preset's campaign with the user's caches ("warm", filled by one
    run not counted) against the same with numba's cache and the calibration cache empty
    ("first", as after ``pip install .``: ``NUMBA_CACHE_DIR`` and ``GONIO_CACHE_DIR`` set to
    empty folders), A B A B; the ratios are then the first run's over the warm one's.
    """
    import os
    import resource
    import subprocess

    def children_cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    # the console script's own entry point (it ends with a quick exit, see console_main)
    code = "from gonio.cli import console_main; console_main()"
    rows = []
    runs = [(p, p) for p in presets]  # (label, preset)
    if first_run:
        runs = [("warm", presets[-1]), ("first", presets[-1])]
        with tempfile.TemporaryDirectory() as d:  # one run, not counted, fills the caches
            subprocess.run([sys.executable, "-c", code, "campaign", "--out", f"{d}/out",
                            "--quiet", "--preset", presets[-1]], check=True, cwd=d)  # fmt: skip
    for k in range(repeat):
        for label, preset in runs:
            with tempfile.TemporaryDirectory() as d:
                env = dict(os.environ)
                if label == "first":  # empty caches: every kernel compiled, calibration made
                    env.update(NUMBA_CACHE_DIR=f"{d}/numba", GONIO_CACHE_DIR=f"{d}/gonio")
                t, c = time.perf_counter(), children_cpu()
                subprocess.run(
                    [sys.executable, "-c", code, "campaign", "--out", f"{d}/out", "--quiet",
                     "--json", f"{d}/s.json", "--preset", preset],
                    check=True, cwd=d, env=env,
                )  # fmt: skip
                wall, cpu = time.perf_counter() - t, children_cpu() - c
                with open(f"{d}/s.json") as f:
                    summ = json.load(f)
            tim = summ["timings_s"]
            rows.append({"preset": label, "run": k, "wall_s": wall, "cpu_s": cpu,
                         "startup_s": wall - tim["total"], "timings_s": tim,
                         "relative_error": summ["relative_error"]})  # fmt: skip
            stages = ", ".join(f"{s} {v:.2f}" for s, v in tim.items())
            print(f"run {k} {label}: wall {wall:.2f} s = start-up {wall - tim['total']:.2f} s "
                  f"+ campaign {tim['total']:.2f} s ({stages}); CPU {cpu:.2f} s",
                  flush=True)  # fmt: skip
    labels = [label for label, _ in runs]
    for preset in labels:
        walls = sorted(r["wall_s"] for r in rows if r["preset"] == preset)
        print(f"default campaign, {preset}, wall clock (s): median "
              f"{walls[len(walls) // 2]:.2f}, min {walls[0]:.2f}, max {walls[-1]:.2f}")  # fmt: skip
    for what in ("wall_s", "cpu_s"):  # CPU: the processes' user + system seconds
        base = [r[what] for r in rows if r["preset"] == labels[0]]
        for preset in labels[1:]:
            ratios = sorted(r[what] / b for r, b in
                            zip((r for r in rows if r["preset"] == preset), base))  # fmt: skip
            print(
                f"{what[:-2]} {preset} / {labels[0]}, pair by pair: "
                + ", ".join(f"{x:.2f}" for x in ratios)
                + f"; median {ratios[len(ratios) // 2]:.2f}"
            )
    return rows


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
