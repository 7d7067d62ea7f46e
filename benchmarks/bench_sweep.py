"""Wall time of ``gonio sweep`` in-process vs on a Dask LocalCluster, and per-task overhead.

Usage::

    python benchmarks/bench_sweep.py [SPEC] [--workers 2] [--noop 200] [--out DIR] [--json PATH]

1. Runs SPEC (default ``benchmarks/sweeps/campaign_mirrors.toml``: full campaigns) in-process,
   then on a ``LocalCluster`` of ``--workers`` processes, each into a fresh folder, and checks
   that the two ``results.csv`` are byte-identical.
2. Runs ``--noop`` trivial tasks (each writes only its ``summary.json``) both ways: the
   distributed path's cost per task beyond the in-process cost is its overhead.

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

from gonio import sweep


def noop_task(task: dict, out_dir: Path) -> dict:
    """A task that does nothing but return a number (its cost is the framework's)."""
    return {"value": float(task["seed"])}


def _fresh(root: Path, name: str) -> Path:
    p = root / name
    shutil.rmtree(p, ignore_errors=True)
    return p


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parent
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", default=str(here / "sweeps" / "campaign_mirrors.toml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--noop", type=int, default=200, help="number of no-op tasks (0: skip)")
    ap.add_argument("--out", default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--skip-inprocess", action="store_true")
    args = ap.parse_args(argv)

    from distributed import Client, LocalCluster

    root = Path(args.out or tempfile.mkdtemp(prefix="gonio-bench-sweep-"))
    spec = sweep.load_spec(args.spec)
    report: dict = {
        "spec": args.spec,
        "n_tasks": spec.n_tasks,
        "workers": args.workers,
        "cpu_count": os.cpu_count(),
    }
    print(f"spec {args.spec}: {spec.n_tasks} tasks of {spec.task!r}; scratch {root}", flush=True)

    if not args.skip_inprocess:
        t0 = time.perf_counter()
        a = sweep.run_sweep(spec, _fresh(root, "inprocess"), plot=False)
        report["inprocess_wall_s"] = time.perf_counter() - t0
        report["inprocess_task_sum_s"] = sum(t["wall_s"] for t in a.timings)
        print(
            f"in-process: {report['inprocess_wall_s']:.2f} s "
            f"(sum of task times {report['inprocess_task_sum_s']:.2f} s)",
            flush=True,
        )

    t0 = time.perf_counter()
    cluster = LocalCluster(
        n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0"
    )
    client = Client(cluster)
    client.run(lambda: __import__("gonio.sweep"))  # same warm imports as in-process
    report["cluster_startup_s"] = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        b = sweep.run_sweep(spec, _fresh(root, "dask"), executor="dask", client=client, plot=False)
        report["dask_wall_s"] = time.perf_counter() - t0
        report["dask_task_sum_s"] = sum(t["wall_s"] for t in b.timings)
        # worker time not spent inside tasks, per task
        report["dask_overhead_per_task_s"] = (
            report["dask_wall_s"] * args.workers - report["dask_task_sum_s"]
        ) / spec.n_tasks
        print(
            f"LocalCluster({args.workers}): start-up {report['cluster_startup_s']:.2f} s, "
            f"sweep {report['dask_wall_s']:.2f} s (sum of task times "
            f"{report['dask_task_sum_s']:.2f} s)",
            flush=True,
        )
        if not args.skip_inprocess:
            same = (root / "inprocess" / "results.csv").read_bytes() == (
                root / "dask" / "results.csv"
            ).read_bytes()
            report["tables_identical"] = same
            report["speedup"] = report["inprocess_wall_s"] / report["dask_wall_s"]
            print(f"speed-up {report['speedup']:.2f}x; tables identical: {same}", flush=True)

        if args.noop:
            sweep.register_task("bench_noop", noop_task)
            nspec = sweep.spec_from_dict(
                {"task": "bench_noop", "materials": ["none"], "seeds": args.noop}
            )
            t0 = time.perf_counter()
            sweep.run_sweep(nspec, _fresh(root, "noop_in"), plot=False, fn=noop_task)
            t_in = time.perf_counter() - t0
            t0 = time.perf_counter()
            sweep.run_sweep(
                nspec,
                _fresh(root, "noop_dask"),
                executor="dask",
                client=client,
                plot=False,
                fn=noop_task,
            )
            t_dk = time.perf_counter() - t0
            report["noop_tasks"] = args.noop
            report["noop_inprocess_per_task_s"] = t_in / args.noop
            report["noop_dask_per_task_s"] = t_dk / args.noop
            report["noop_dask_overhead_per_task_s"] = (t_dk - t_in) / args.noop
            print(
                f"{args.noop} no-op tasks: in-process {1e3 * t_in / args.noop:.2f} ms/task, "
                f"dask {1e3 * t_dk / args.noop:.2f} ms/task (wall, {args.workers} workers); "
                f"overhead {1e3 * (t_dk - t_in) / args.noop:.2f} ms/task",
                flush=True,
            )
    finally:
        client.close()
        cluster.close()
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
