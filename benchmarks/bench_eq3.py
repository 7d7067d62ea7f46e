"""Eq. 3 (Ward 1992) against exact ray tracing: angular error table.

Run: ``python benchmarks/bench_eq3.py [--size 512] [--json out.json]``

For each mirror and D/R, the angle between eq. 3's reflected direction and the exactly traced
one, over every pixel of a ``size × size`` equidistant 180° fisheye image.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Eq. 3: the reflection angles recovered from a pixel's camera ray.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from gonio.io.atomic import atomic_write_bytes


def main(argv=None) -> dict:
    from gonio.simulator import eq3_error, eq3_reflection_angles, make_lens

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    lens = make_lens("equidistant", args.size, args.size, fill=1.0)
    rows = []
    for mirror, form in (
        ("hemisphere", "printed"),
        ("ellipsoid", "focal"),
        ("ellipsoid", "printed"),
    ):
        for dr in (0.01, 0.02, 0.05, 0.1, 0.2):
            e = eq3_error(mirror, dr, form=form, lens=lens)
            rows.append({"mirror": mirror, "eq3_form": form, "D/R": dr, **e})
    print(f"eq. 3 angular error vs exact trace ({args.size}x{args.size} equidistant fisheye)")
    print(f"{'mirror':<11}{'eq.3 r_c':<10}{'D/R':>6}{'max (rad)':>12}{'p95 (rad)':>12}"
          f"{'max (deg)':>11}{'max|Q-S|/R':>12}")  # fmt: skip
    for r in rows:
        print(
            f"{r['mirror']:<11}{r['eq3_form']:<10}{r['D/R']:>6g}{r['max']:>12.3e}{r['p95']:>12.3e}"
            f"{math.degrees(r['max']):>11.4f}{r['max_sample_offset_over_r']:>12.3e}"
        )
    n = 1_000_000
    tc = np.random.default_rng(0).uniform(0, math.pi / 2, n)
    pc = np.random.default_rng(1).uniform(-math.pi, math.pi, n)
    t0 = time.perf_counter()
    eq3_reflection_angles(tc, pc, 1.0, 0.05)
    dt = time.perf_counter() - t0
    print(f"eq3_reflection_angles: {dt * 1e3:.1f} ms per 1e6 angles")
    out = {"rows": rows, "pixels": rows[0]["n_pixels"], "eq3_ms_per_1e6": dt * 1e3}
    if args.json:
        atomic_write_bytes(args.json, json.dumps(out, indent=2).encode())
    return out


if __name__ == "__main__":
    main()
