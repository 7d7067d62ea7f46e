"""The dome figure's budget term: how many Monte Carlo realisations it needs.

The LBL budget's ``dome_figure`` row is the root sum of squares of the parameter shifts of
:data:`gonio.campaign.budget_terms.FIGURE_REALISATIONS` random dome figures of the specified
RMS slope error (the same realisations for every instrument). This runs one campaign (in
memory, its calibration made anew: no calibration cache, so the realisations are traced
here) with ``--realisations N`` of them and prints, for the first 4, 8, ..., N, the RMS of
their shifts per parameter at the specified slope, beside the campaign's expanded U, and
the time :func:`gonio.campaign.budget_terms.direction_fields` took.

Measured (rolled brass, modern, instrument 54, plan 36, 52, 56 deg x rotations 0, 90, the
plan the LBL design chose with ten design instruments before the term had 64 realisations;
the defaults here): the alpha_x RMS of the first 4, 8, 16, 32, 64, 128, 256 realisations
5.21, 4.60, 5.76, 5.74, 6.99, 8.13, 8.18 x 1e-5 (rho_s 5.87, 5.23, 6.53, 6.45, 7.70, 9.00,
9.15 x 1e-4; the campaign's U of alpha_x 2.04e-4): 4 are 36 % below 256, 64 15 % below,
128 within 1 %; the fields of 256 took 2.24 s.

Usage::

    python benchmarks/bench_dome_figure.py [--material rolled_brass] [--instrument-seed 54] \\
        [--angles 36,52,56] [--rotations 0,90] [--realisations 256]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--material", default="rolled_brass")
    ap.add_argument("--instrument-seed", type=int, default=54)
    ap.add_argument("--angles", default="36,52,56")
    ap.add_argument("--rotations", default="0,90")
    ap.add_argument("--realisations", type=int, default=256)
    a = ap.parse_args(argv)
    if a.realisations < 4:
        ap.error("--realisations: at least 4")

    from gonio import campaign
    from gonio.campaign import budget_terms
    from gonio.campaign.budget import Sensitivity

    budget_terms.FIGURE_REALISATIONS = a.realisations  # (this process only)
    made = budget_terms.direction_fields
    took: list[float] = []

    def timed(cal):
        t = time.perf_counter()
        out = made(cal)
        took.append(time.perf_counter() - t)
        return out

    budget_terms.direction_fields = timed
    plan = campaign.Plan(
        material=a.material, plots=False, seed=a.instrument_seed,
        instrument_seed=a.instrument_seed,
        theta_i_deg=tuple(float(x) for x in a.angles.split(",")),
        rotations_deg=tuple(float(x) for x in a.rotations.split(",")),
    )  # fmt: skip
    res = campaign.run(plan, None, quiet=True, workers=1, calibration_cache=False)
    pert = {p.name: p for p in res.budget.perturbations}
    sens = Sensitivity(res.fit, res.budget.samples)
    k_n = a.realisations
    shifts = np.array([
        sens.shift(pert[f"dome_figure[{k}]"].dy) * pert[f"dome_figure[{k}]"].u * math.sqrt(k_n)
        for k in range(k_n)
    ])  # fmt: skip
    names, U = sens.names, res.summary["budget"]["expanded"]
    print(f"{a.material}, instrument {a.instrument_seed}, plan {a.angles} deg x {a.rotations} "
          f"deg: RMS of the first K realisations' shifts at the specified slope")  # fmt: skip
    print(f"{'K':>5}  " + "  ".join(f"{n:>11}" for n in names))
    k = 4
    while k <= k_n:
        rms = np.sqrt((shifts[:k] ** 2).mean(axis=0))
        print(f"{k:>5}  " + "  ".join(f"{v:11.3g}" for v in rms))
        k *= 2
    print(f"{'U':>5}  " + "  ".join(f"{U[n]:11.3g}" for n in names) + "  (the campaign's, k=2)")
    if took:
        print(f"direction fields with {k_n} realisations: {took[0]:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
