"""Radiance tensor trees of a campaign's samples: build time against error, measured.

Usage::

    python benchmarks/bench_bsdf.py                         # reduced: a small campaign
    python benchmarks/bench_bsdf.py --campaign DIR          # a campaign's samples.csv and fit.json
        [--cells 16,32] [--resolution 5,6] [--model-route] [--json out.json]

The measured route (:func:`gonio.io.pabopto.build_bsdf`: samples averaged in ``cells`` ×
``cells`` cells per incident direction → PAB-Opto files → ``pabopto2bsdf`` → ``bsdf2ttree
-g resolution`` → ``checkBSDF``) for every pair of ``--cells`` and ``--resolution``, and with
``--model-route`` the fitted model's exact ``.cal`` through ``bsdf2ttree -t4 -f``
(:func:`gonio.io.pabopto.build_model_bsdf`) at each resolution. For each tree: every
program's seconds and the tree's error against the fitted model and against the truth (the
material preset) at the mirror peak, off-peak and near grazing, at θi 0, 30, 60, 75° and
the campaign's rotations (:func:`gonio.io.pabopto.bsdf_error_table`). The reduced setting
(no ``--campaign``) runs a small campaign first: θi 0, 15, 30, 45, 60, 75°, the default
rotations, default noise, cells 16 and resolution 5 (measured: the campaign 23 s, then
pabopto2bsdf 15 and bsdf2ttree 160 processor seconds, the model route 5; peak error against
the fit +2 / −23..−35 / −35..−48 / −54..−70 % measured, −5 / −2..−10 / −20..−23 / −34..−48 %
model route).

Nothing here is asserted; the numbers are printed (and optionally saved) for the notes. The
builds are long: run one at a time, niced.

Measured (the default campaign: ``gonio campaign --out DIR``, rolled brass, 61 incident
directions, 173,406 samples; ``--resolution 5``; processor seconds of pabopto2bsdf +
bsdf2ttree, the machine shared with other jobs; peak error against the fit at θi 0 / 30 /
60 / 75°, and the largest off-peak error):

    setting (points per direction)  cpu s            peak                               off-peak
    cells 16, no split (254)        (wall 28 + 265)  −54 / −55..−64 / −70..−79 / −74..−76  +1929 %
    cells 16, spread 2 (583)        47 + 147         −12 / −33.5..−46 / −32..−49 / −64..−81  +524 %
    the same, bsdf2ttree -l 2000    45 + 99          −13 / −36.5..−46 / −32..−50 / −65..−81  +402 %
    cells 32, spread 2 (1196)       48 + 148         −12.5 / −33.5..−46 / −32..−49 / −64..−81 +520 %
    model route (the fit's .cal)    4                −5 / −2..−10 / −18..−23 / −32..−48      +119 %

The fit and the truth agree to 0.2 % in these tables (the fit is that close), so the error
against the truth is the same. At ``-g 5`` a tree cell spans about 3.6° of exiting and of
incident direction; both routes lose the sharp brass peak (α_x = 0.05) to it, and the
measured route adds pabopto2bsdf's lobes. ``-g 6`` (bsdf2ttree's default) costs about 16
times the bsdf2ttree time (the model route: 623 s, measured in an earlier session on the
0°/30°/60°/90° campaign's fit: peak +0 / +1.1 / −2..−8.5 / −23..−26 %).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from pathlib import Path


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _references(folder: Path):
    from gonio import brdf, materials

    fit = json.loads((folder / "fit.json").read_text())
    plan = json.loads((folder / "plan.json").read_text())
    info = materials.info(plan["material"])
    return (
        {
            "fit": brdf.create(fit["model"], **fit["params"]),
            "truth": brdf.create(info["model"], **info["params"]),
        },
        plan,
    )


def _table(label: str, seconds: dict, rows: list[dict]) -> None:
    times = ", ".join(
        f"{k} {v:.1f} s (cpu {seconds.get(k + '_cpu', float('nan')):.1f} s)"
        for k, v in seconds.items()
        if not k.endswith("_cpu")
    )
    print(f"\n{label}: {times}")
    print(
        f"{'theta_i':>7} {'phi_i':>5} {'peak':>8} | {'fit: peak':>9} {'off-peak':>8} "
        f"{'grazing':>8} | {'truth: peak':>11} {'off-peak':>8} {'grazing':>8}"
    )
    for r in rows:
        print(
            f"{r['theta_i']:7.0f} {r['phi_i']:5.0f} {r['peak']:8.3f} | "
            f"{100 * r['fit_peak']:+8.1f}% {100 * r['fit_off_peak']:+7.1f}% "
            f"{100 * r['fit_grazing']:+7.1f}% | {100 * r['truth_peak']:+10.1f}% "
            f"{100 * r['truth_off_peak']:+7.1f}% {100 * r['truth_grazing']:+7.1f}%"
        )


def _reduced_campaign(out: Path) -> Path:
    from gonio import campaign

    t0 = time.perf_counter()
    plan = campaign.Plan(theta_i_deg=(0.0, 15.0, 30.0, 45.0, 60.0, 75.0), plots=False)
    campaign.run(plan, out, quiet=True)
    print(f"reduced campaign (6 theta_i x 3 rotations): {time.perf_counter() - t0:.1f} s")
    return out


def main(argv: list[str] | None = None) -> int:
    from gonio.io import pabopto
    from gonio.io.atomic import atomic_write_bytes
    from gonio.io.samples_table import read_samples

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", help="a campaign's results folder (samples.csv, fit.json)")
    ap.add_argument(
        "--cells", default=None, help="averaging cells per side, e.g. 16,32 (default 16)"
    )
    ap.add_argument("--resolution", default=None, help="bsdf2ttree -g, e.g. 5,6")
    ap.add_argument("--spread", type=float, default=2.0, help="split factor (0: none)")
    ap.add_argument("--max-lobes", default="15000", help="bsdf2ttree -l, e.g. 2000,15000")
    ap.add_argument("--model-route", action="store_true", help="also the fit's .cal route")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--keep", help="build the trees in this folder and keep them")
    args = ap.parse_args(argv)
    reduced = args.campaign is None
    cells = _ints("16" if args.cells is None else args.cells)  # "": the model route only
    res = _ints(args.resolution or ("5" if reduced else "6"))
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_bsdf_") as tmp_dir:
        tmp = args.keep or tmp_dir
        folder = _reduced_campaign(Path(tmp, "campaign")) if reduced else Path(args.campaign)
        refs, plan = _references(folder)
        samples = read_samples(folder / "samples.csv")
        rot = plan.get("rotations_deg") or [0.0]
        print(f"{folder}: {samples.value.size} samples, fit {refs['fit']!r}")
        spread = args.spread or None
        for c, g, lobes in itertools.product(cells, res, _ints(args.max_lobes)):
            out = Path(tmp, f"m{c}_{g}_{lobes}")
            b = pabopto.build_bsdf(
                samples,
                out,
                "sample",
                kind="ttree",
                resolution=g,
                negative="clip",
                cells=c,
                spread=spread,
                max_lobes=lobes,
            )
            rows = pabopto.bsdf_error_table(b.xml, refs, phi_i_deg=rot)
            label = f"measured, cells {c}, spread {spread}, -g {g}, -l {lobes}"
            _table(label, b.seconds, rows)
            results.append(
                {
                    "checkBSDF": b.components,
                    "route": "measured",
                    "cells": c,
                    "spread": spread,
                    "resolution": g,
                    "max_lobes": lobes,
                    "seconds": b.seconds,
                    "rows": rows,
                }
            )
            if args.json:
                atomic_write_bytes(args.json, json.dumps(results, indent=1).encode())
        if args.model_route:
            for g in res:
                out = Path(tmp, f"f{g}")
                out.mkdir(parents=True, exist_ok=True)
                b = pabopto.build_model_bsdf(refs["fit"], out, "fit", kind="ttree", resolution=g)
                rows = pabopto.bsdf_error_table(b.xml, refs, phi_i_deg=rot)
                _table(f"model route (fit's .cal), -g {g}", b.seconds, rows)
                results.append(
                    {"route": "model", "resolution": g, "seconds": b.seconds, "rows": rows}
                )
    if args.json:
        atomic_write_bytes(args.json, json.dumps(results, indent=1).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
