"""Timing of the simulated Cornell gonioreflectometer, beside the real instrument's estimate.

Run: ``python benchmarks/bench_cornell.py [--material NAME ...] [--quick] [--json PATH]``
or ``python benchmarks/bench_cornell.py --realistic [--pairs 5] [--material NAME ...]``

``--realistic``: the default Cornell campaign (``gonio.campaign.cornell.run_cornell_campaign``:
incidence plan, noise, fit and budget) on the realistic instrument (``cornell2005``, the
default) beside the ideal one, in A B A B pairs in this process after one warm-up of each;
prints each pair's wall times and the median ratio realistic / ideal (issue 18 asks <= 1.5).

For each material: the in-process time of a full hemispherical campaign (θi = 10°…80°, 441
positions per θi, ordered, noise on), the time per measurement, the cost of the cone
integration with and without an adaptive skip at tolerance 1e-3 (off by default; the largest
change it makes), and
the estimated real-instrument run time from stage speeds and the simulated integration times,
to compare with the ≈11 hours of Li and Torrance 2005, §5.1.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from gonio.simulator.cornell import CornellConfig, CornellInstrument, simulate_campaign
from gonio.simulator.cornell_plans import estimate_run_time, hemispherical_plan, order_plan

from gonio.io.atomic import atomic_write_bytes


def bench(material: str, n: int) -> dict:
    plan = hemispherical_plan(n=n)
    t0 = time.perf_counter()
    ordered = order_plan(plan)
    t_order = time.perf_counter() - t0
    t0 = time.perf_counter()
    s = simulate_campaign(ordered, material, rng=0, order=False)
    t_campaign = time.perf_counter() - t0
    n_geo = s.metadata["n_geometries"]
    # the adaptive skip is off by default (it biases fits, gonio.simulator.cornell docstring);
    # here with the old tolerance 1e-3, to show what it saves and changes
    inst = CornellInstrument(material, noise=False, config=CornellConfig(skip_tol=1e-3))
    t0 = time.perf_counter()
    adaptive = inst.expected_brdf(ordered.angles)
    t_adaptive = time.perf_counter() - t0
    skipped = inst.stats["conv_skipped"]
    t0 = time.perf_counter()
    full = inst.expected_brdf(ordered.angles, convolve=True)
    t_full = time.perf_counter() - t0
    big = full > 1e-6 * full.max()
    skip_change = float(np.max(np.abs(adaptive - full)[big] / full[big]))
    unordered = estimate_run_time(plan)["total_h"]
    return {
        "material": material,
        "n_geometries": n_geo,
        "campaign_s": t_campaign,
        "ordering_s": t_order,
        "per_measurement_ms": 1e3 * t_campaign / n_geo,
        "conv_adaptive_s": t_adaptive,
        "conv_full_s": t_full,
        "conv_skipped": skipped,
        "skip_max_rel_change": skip_change,
        "integration_s_median": s.metadata["integration_s_median"],
        "real_instrument_h": s.metadata["estimated_run_time_h"],
        "real_instrument_h_unordered_1s": unordered,
        "paper_h": 11.0,
    }


def side_by_side(material: str, pairs: int) -> dict:
    """Wall time of the default campaign, realistic (A) and ideal (B), in A B pairs."""
    from gonio.campaign.cornell import run_cornell_campaign

    def wall(effects: str) -> float:
        t0 = time.perf_counter()
        run_cornell_campaign(material, effects=effects)
        return time.perf_counter() - t0

    wall("cornell2005"), wall("ideal")  # warm-up: imports, numba, caches
    rows = [(wall("cornell2005"), wall("ideal")) for _ in range(pairs)]
    ratios = [a / b for a, b in rows]
    return {"material": material, "pairs_s": rows, "ratios": ratios,
            "median_ratio": float(np.median(ratios))}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--material",
        nargs="+",
        default=["garnet_red_paint", "laser_paper", "aluminized_ground_glass"],
    )
    ap.add_argument("--quick", action="store_true", help="9 x 9 grid instead of 21 x 21")
    ap.add_argument("--json", default=None, help="write the results as JSON")
    ap.add_argument("--realistic", action="store_true",
                    help="default campaign, realistic vs ideal instrument, A B pairs")  # fmt: skip
    ap.add_argument("--pairs", type=int, default=5)
    args = ap.parse_args(argv)
    if args.realistic:
        given = args.material != ap.get_default("material")
        mats = args.material if given else ["garnet_red_paint"]
        out = [side_by_side(m, args.pairs) for m in mats]
        for r in out:
            pairs = ", ".join(f"{a:.2f}/{b:.2f}" for a, b in r["pairs_s"])
            print(f"{r['material']}: realistic/ideal s per pair {pairs}; "
                  f"ratios {', '.join(f'{x:.3f}' for x in r['ratios'])}; "
                  f"median {r['median_ratio']:.3f}")  # fmt: skip
        if args.json:
            atomic_write_bytes(args.json, json.dumps(out, indent=1).encode())
        return 0
    rows = [bench(m, 9 if args.quick else 21) for m in args.material]
    hdr = (
        f"{'material':28s} {'geoms':>6s} {'campaign s':>10s} {'ms/meas':>8s} "
        f"{'conv adapt/full s':>17s} {'skipped':>8s} {'skip Δmax':>9s} {'t_int med':>9s} "
        f"{'real h':>7s} {'paper h':>7s}"
    )
    print(hdr)
    for r in rows:
        print(
            f"{r['material']:28s} {r['n_geometries']:6d} {r['campaign_s']:10.2f} "
            f"{r['per_measurement_ms']:8.2f} {r['conv_adaptive_s']:8.2f}/{r['conv_full_s']:<8.2f} "
            f"{r['conv_skipped']:8d} {r['skip_max_rel_change']:9.1e} "
            f"{r['integration_s_median']:9.3f} {r['real_instrument_h']:7.2f} {r['paper_h']:7.1f}"
        )
    if args.json:
        atomic_write_bytes(args.json, json.dumps(rows, indent=1).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
