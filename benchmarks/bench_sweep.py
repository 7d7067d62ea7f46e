"""Wall time of ``gonio sweep`` in-process vs local processes vs a Dask LocalCluster.

Usage::

    python benchmarks/bench_sweep.py [SPEC] [--workers 2] [--noop 200] [--out DIR] [--json PATH]

1. Runs SPEC (default ``benchmarks/sweeps/campaign_minute.toml``: 120 full campaigns, over a
   minute in-process on the shared 2-core VM) in-process, on ``--workers`` local processes
   (``executor="process"``) and on a ``LocalCluster`` of ``--workers`` processes started by
   :func:`gonio.campaign.sweep.dask_local_cluster` (what ``gonio sweep --dask-local N`` uses),
   each into a fresh folder, and checks that the three ``results.csv`` are byte-identical.
2. Runs ``--noop`` trivial tasks (each writes only its ``sweep_task.json``) all three ways: the
   wall time per task of a sweep that does no work is the executor's per-task overhead.

Cluster start-up is reported separately from the sweep's own time. Not run by the test suite.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from gonio.campaign import sweep


def noop_task(task: dict, out_dir: Path) -> dict:
    """A task that does nothing but return a number (its cost is the framework's)."""
    return {"value": float(task["seed"])}


def _fresh(root: Path, name: str) -> Path:
    p = root / name
    shutil.rmtree(p, ignore_errors=True)
    return p


def _timed(label: str, report: dict, key: str, run) -> sweep.SweepResult:
    t0 = time.perf_counter()
    res = run()
    report[f"{key}_wall_s"] = time.perf_counter() - t0
    report[f"{key}_task_sum_s"] = sum(t["wall_s"] for t in res.timings)
    print(
        f"{label}: {report[f'{key}_wall_s']:.2f} s "
        f"(sum of task times {report[f'{key}_task_sum_s']:.2f} s)",
        flush=True,
    )
    return res


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parent
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", default=str(here / "sweeps" / "campaign_minute.toml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--noop", type=int, default=200, help="number of no-op tasks (0: skip)")
    ap.add_argument("--out", default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    root = Path(args.out or tempfile.mkdtemp(prefix="gonio-bench-sweep-"))
    spec = sweep.load_spec(args.spec)
    n = spec.n_tasks
    report: dict = {"spec": args.spec, "n_tasks": n, "workers": args.workers}
    report["cpu_count"] = os.cpu_count()
    print(f"spec {args.spec}: {n} tasks of {spec.task!r}; scratch {root}", flush=True)

    _timed(
        "in-process",
        report,
        "inprocess",
        lambda: sweep.run_sweep(spec, _fresh(root, "inprocess"), plot=False),
    )
    _timed(
        f"--processes {args.workers}",
        report,
        "process",
        lambda: sweep.run_sweep(
            spec, _fresh(root, "process"), executor="process", workers=args.workers, plot=False
        ),
    )

    t0 = time.perf_counter()
    with sweep.dask_local_cluster(args.workers) as client:
        client.run(lambda: __import__("gonio.campaign.sweep"))  # same warm imports as in-process
        report["cluster_startup_s"] = time.perf_counter() - t0
        _timed(
            f"LocalCluster({args.workers})",
            report,
            "dask",
            lambda: sweep.run_sweep(
                spec, _fresh(root, "dask"), executor="dask", client=client, plot=False
            ),
        )
        tables = {
            k: (root / k / "results.csv").read_bytes() for k in ("inprocess", "process", "dask")
        }
        report["tables_identical"] = len(set(tables.values())) == 1
        for k in ("process", "dask"):
            report[f"{k}_speedup"] = report["inprocess_wall_s"] / report[f"{k}_wall_s"]
        print(
            f"cluster start-up {report['cluster_startup_s']:.2f} s (not in the sweep time); "
            f"speed-up processes {report['process_speedup']:.2f}x, "
            f"dask {report['dask_speedup']:.2f}x; tables identical: {report['tables_identical']}",
            flush=True,
        )

        if args.noop:
            sweep.register_task("bench_noop", noop_task)
            nspec = sweep.spec_from_dict(
                {"task": "bench_noop", "materials": ["none"], "seeds": args.noop}
            )
            runs = {
                "inprocess": {},
                "process": {"executor": "process", "workers": args.workers},
                "dask": {"executor": "dask", "client": client},
            }
            for k, kw in runs.items():
                t0 = time.perf_counter()
                sweep.run_sweep(nspec, _fresh(root, f"noop_{k}"), plot=False, fn=noop_task, **kw)
                report[f"noop_{k}_per_task_s"] = (time.perf_counter() - t0) / args.noop
            report["noop_tasks"] = args.noop
            print(
                f"{args.noop} no-op tasks, wall per task: "
                + ", ".join(f"{k} {1e3 * report[f'noop_{k}_per_task_s']:.2f} ms" for k in runs),
                flush=True,
            )
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
