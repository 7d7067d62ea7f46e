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
rotations, default noise, cells 16 and resolution 5 — a few minutes on one core.

Nothing here is asserted; the numbers are printed (and optionally saved) for the notes. The
builds are long: run one at a time, niced.
"""

from __future__ import annotations

import argparse
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
    times = ", ".join(f"{k} {v:.1f} s" for k, v in seconds.items())
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
    from gonio.io.samples_table import read_samples

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", help="a campaign's results folder (samples.csv, fit.json)")
    ap.add_argument("--cells", default=None, help="averaging cells per side, e.g. 16,32")
    ap.add_argument("--resolution", default=None, help="bsdf2ttree -g, e.g. 5,6")
    ap.add_argument("--model-route", action="store_true", help="also the fit's .cal route")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    reduced = args.campaign is None
    cells = _ints(args.cells or ("16" if reduced else "16,32"))
    res = _ints(args.resolution or ("5" if reduced else "6"))
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_bsdf_") as tmp:
        folder = _reduced_campaign(Path(tmp, "campaign")) if reduced else Path(args.campaign)
        refs, plan = _references(folder)
        samples = read_samples(folder / "samples.csv")
        rot = plan.get("rotations_deg") or [0.0]
        print(f"{folder}: {samples.value.size} samples, fit {refs['fit']!r}")
        for c in cells:
            for g in res:
                out = Path(tmp, f"m{c}_{g}")
                b = pabopto.build_bsdf(
                    samples, out, "sample", kind="ttree", resolution=g, negative="clip", cells=c
                )
                rows = pabopto.bsdf_error_table(b.xml, refs, phi_i_deg=rot)
                _table(f"measured, cells {c}, -g {g}", b.seconds, rows)
                results.append(
                    {
                        "route": "measured",
                        "cells": c,
                        "resolution": g,
                        "seconds": b.seconds,
                        "rows": rows,
                    }
                )
        if args.model_route:
            for g in res:
                out = Path(tmp, f"f{g}")
                out.mkdir()
                b = pabopto.build_model_bsdf(refs["fit"], out, "fit", kind="ttree", resolution=g)
                rows = pabopto.bsdf_error_table(b.xml, refs, phi_i_deg=rot)
                _table(f"model route (fit's .cal), -g {g}", b.seconds, rows)
                results.append(
                    {"route": "model", "resolution": g, "seconds": b.seconds, "rows": rows}
                )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
