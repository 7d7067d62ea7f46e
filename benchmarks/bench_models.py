"""Time 10⁶ evaluations of every registered BRDF model against a memory copy of the same bytes.

Usage::

    python benchmarks/bench_models.py [--n 1000000] [--repeat 3] [--models a b] [--json PATH]

One thread (thread-pool variables are set to 1 before numpy is imported), float64, inputs of
shape (N, 3) through the public API ``model(wi, wo)``. Every model listed by
``brdf.names()`` is created with its defaults (``tabulated`` with a random table on the MERL
grid, as it has no default data); a model that cannot be created is reported, not fatal.
Slow models get fewer evaluations (enough for about ``--budget`` seconds, at least 10⁴); the
time is reported per evaluation.

The reference is ``numpy.copyto`` of a buffer the size of the data one evaluation touches —
wi, wo (3 float64 each) and the result (1 float64; ``n_bands`` for spectral models), 56 bytes
per evaluation for a grey model — timed right before each model in the same run, so the
ratio model/copy survives a noisy machine. Each time is the best of ``--repeat`` runs after a
warm-up call (numba compilation excluded).

The ordering is compared with Li & Torrance's Table 4 (Li and Torrance 2005, §5.3: 10⁶
evaluations in Java on a Pentium III 550 MHz, seconds): Blinn-Phong 1.1, Ward 2.0-2.1,
Lafortune 2.3-3.9, Cook-Torrance 3.3-3.5, Neumann-Neumann 3.5-4.0, constructed (Li-Torrance)
models 4.3-6.8 (He-Torrance 59-122 s has no counterpart here). For a row matched by several
gonio models (Neumann-Neumann) the median of their times is used.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

#: Li & Torrance Table 4 (seconds per 10⁶ evaluations, range) -> gonio models
TABLE4 = {
    "Blinn-Phong": ((1.1, 1.1), ["blinn_phong"]),
    "Ward": ((2.0, 2.1), ["ward"]),
    "Lafortune": ((2.3, 3.9), ["lafortune"]),
    "Cook-Torrance": ((3.3, 3.5), ["cook_torrance"]),
    "Neumann-Neumann": (
        (3.5, 4.0),
        ["phong_neumann", "blinn_neumann", "ward_neumann", "metal_neumann", "plastic_neumann"],
    ),
    "Constructed (Li-Torrance)": ((4.3, 6.8), ["li_torrance"]),
}


def _directions(n: int, rng: np.random.Generator) -> np.ndarray:
    w = rng.normal(size=(n, 3))
    w[:, 2] = np.abs(w[:, 2])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    return w


def _best(f, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def _make(name: str):
    from gonio import brdf

    if name == "tabulated":
        from gonio.io.merl import SHAPE

        table = np.random.default_rng(1).random(SHAPE) * 0.3
        return brdf.create("tabulated", data=table)
    return brdf.create(name)


def bench(n: int, repeat: int, budget: float, names: list[str] | None) -> dict:
    from gonio import brdf

    rng = np.random.default_rng(0)
    wi_all = _directions(n, rng)
    wo_all = _directions(n, rng)
    rows = []
    for name in names or brdf.names():
        try:
            m = _make(name)
        except Exception as exc:  # report and go on: other helpers add models concurrently
            rows.append({"model": name, "error": f"cannot create with defaults: {exc!r}"})
            continue
        try:
            m(wi_all[:1000], wo_all[:1000])  # warm-up (numba compilation, caches)
            t0 = time.perf_counter()
            m(wi_all[:10000], wo_all[:10000])
            per = (time.perf_counter() - t0) / 10000
        except Exception as exc:
            rows.append({"model": name, "error": f"evaluation failed: {exc!r}"})
            continue
        k = n if per * n <= budget else max(10_000, int(budget / per))
        k = min(k, n)
        wi, wo = wi_all[:k], wo_all[:k]
        out_per_eval = m.n_bands or 1
        nbytes = n * (6 + out_per_eval) * 8
        src = np.ones(nbytes // 8)
        dst = np.empty_like(src)
        np.copyto(dst, src)
        t_copy = _best(lambda src=src, dst=dst: np.copyto(dst, src), repeat) / n
        t_model = _best(lambda m=m, wi=wi, wo=wo: m(wi, wo), repeat if k == n else 1) / k
        rows.append(
            {
                "model": name,
                "n_evals": k,
                "ns_per_eval": t_model * 1e9,
                "copy_ns_per_eval": t_copy * 1e9,
                "ratio_to_copy": t_model / t_copy,
                "bytes_per_eval": (6 + out_per_eval) * 8,
            }
        )
    copies = [r["copy_ns_per_eval"] for r in rows if "copy_ns_per_eval" in r]
    best = min(copies) if copies else None
    for r in rows:
        if best and "ns_per_eval" in r:
            r["ratio_to_best_copy"] = r["ns_per_eval"] / best
    return {
        "n": n,
        "repeat": repeat,
        "threads": 1,
        "copy_ns_per_eval_best": best,
        "rows": rows,
        "table4": _table4(rows),
    }


def _table4(rows: list[dict]) -> dict:
    ours = {r["model"]: r["ns_per_eval"] for r in rows if "ns_per_eval" in r}
    matched = []
    for label, ((lo, hi), models) in TABLE4.items():
        have = [ours[m] for m in models if m in ours]
        if have:
            matched.append(
                {
                    "paper": label,
                    "paper_s": (lo + hi) / 2,
                    "paper_range_s": [lo, hi],
                    "gonio_models": [m for m in models if m in ours],
                    "gonio_ns": statistics.median(have),
                }
            )
    paper_order = [r["paper"] for r in sorted(matched, key=lambda r: r["paper_s"])]
    our_order = [r["paper"] for r in sorted(matched, key=lambda r: r["gonio_ns"])]
    tau = _kendall([r["paper_s"] for r in matched], [r["gonio_ns"] for r in matched])
    return {
        "rows": matched,
        "paper_order": paper_order,
        "gonio_order": our_order,
        "kendall_tau": tau,
    }


def _kendall(a: list[float], b: list[float]) -> float | None:
    n = len(a)
    if n < 2:
        return None
    s = 0
    for i in range(n):
        for j in range(i + 1, n):
            s += np.sign(a[i] - a[j]) * np.sign(b[i] - b[j])
    return float(s / (n * (n - 1) / 2))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=1_000_000, help="evaluations per model")
    p.add_argument("--repeat", type=int, default=3, help="best of this many runs")
    p.add_argument("--budget", type=float, default=3.0, help="seconds per slow model")
    p.add_argument("--models", nargs="+", help="only these models")
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    a = p.parse_args(argv)
    if a.n < 1000 or a.repeat < 1 or a.budget <= 0:
        p.error("--n must be >= 1000, --repeat >= 1, --budget > 0")
    from gonio.console import format_table
    from gonio.io.jsonfile import write_json

    r = bench(a.n, a.repeat, a.budget, a.models)
    table = []
    for row in r["rows"]:
        if "error" in row:
            table.append((row["model"], "-", "-", "-", "-", row["error"][:60]))
        else:
            table.append(
                (
                    row["model"],
                    row["n_evals"],
                    f"{row['ns_per_eval']:.1f}",
                    f"{row['copy_ns_per_eval']:.2f}",
                    f"{row['ratio_to_copy']:.1f}",
                    "",
                )
            )
    print(f"one thread, float64, (N, 3) inputs, N = {a.n}; copy = numpy.copyto of the same bytes")
    print(format_table(("model", "evals", "ns/eval", "copy ns/eval", "ratio", "note"), table))
    if r["copy_ns_per_eval_best"]:
        print(
            f"(copy timed right before each model; fastest copy in this run "
            f"{r['copy_ns_per_eval_best']:.2f} ns/eval — ratios against it are in the JSON)"
        )
    t4 = r["table4"]
    print("\nLi & Torrance Table 4 (s per 10^6 evals, Java, P-III 550 MHz) vs gonio (ns/eval):")
    print(
        format_table(
            ("paper model", "paper s", "gonio ns/eval", "gonio models"),
            [
                (
                    x["paper"],
                    f"{x['paper_range_s'][0]}-{x['paper_range_s'][1]}",
                    f"{x['gonio_ns']:.1f}",
                    ", ".join(x["gonio_models"]),
                )
                for x in t4["rows"]
            ],
        )
    )
    print("paper order: " + " < ".join(t4["paper_order"]))
    print("gonio order: " + " < ".join(t4["gonio_order"]))
    if t4["kendall_tau"] is not None:
        print(f"Kendall tau between the two orderings: {t4['kendall_tau']:.2f}")
    if a.json:
        write_json(a.json, r)
    json.dumps(r, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
