"""``gonio sweep SPEC``: run a grid of campaigns in-process, on local processes or on Dask."""

from __future__ import annotations

import sys

from gonio.cli._common import (
    add_json_option,
    check_output_dir,
    check_outputs,
    format_table,
    output_dir,
    worker_count,
    write_json,
)

COMMAND = "sweep"
HELP = "run a grid of campaigns (materials × settings × seeds) and gather one results table"


def add_arguments(parser) -> None:
    parser.add_argument("spec", help="sweep spec file (.toml or .json)")
    parser.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        type=output_dir,
        help="results folder (default: sweep_<name> in the current folder); re-running into "
        "the same folder skips finished tasks",
    )
    ex = parser.add_mutually_exclusive_group()
    ex.add_argument(
        "--processes",
        metavar="N",
        type=worker_count,
        help="run on N local worker processes (concurrent.futures; at most 4 per CPU)",
    )
    ex.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on an existing Dask distributed scheduler, e.g. tcp://host:8786 "
        "(needs gonio[distributed]; the workers need gonio and must share the --out folder)",
    )
    ex.add_argument(
        "--dask-local",
        metavar="N",
        type=worker_count,
        help="start a Dask LocalCluster of N worker processes (needs gonio[distributed]; at "
        "most 4 per CPU)",
    )
    parser.add_argument(
        "--retries", type=int, default=2, help="retries of a failed task (default 2)"
    )
    parser.add_argument(
        "--no-workers-timeout",
        metavar="S",
        type=float,
        default=60.0,
        help="Dask: fail the waiting tasks when the cluster has had no worker for S seconds "
        "(default 60)",
    )
    parser.add_argument(
        "--raw",
        choices=("keep", "compressed", "none"),
        default=None,
        help="what each task run keeps of its campaign's raw frames: keep them, compress them "
        "(lossless) or none (default: the spec's 'raw', none if it names none)",
    )
    parser.add_argument("--no-plot", action="store_true", help="do not write summary.png")
    parser.add_argument(
        "--dry-run", action="store_true", help="validate the spec and list the tasks only"
    )
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress bar, no per-task lines"
    )
    add_json_option(parser)


def _time_left(elapsed: float, ran: int, left: int) -> str:
    """``"~3.2 min left"``: the tasks left at the mean pace of the tasks run so far (tasks
    finished by an earlier run took no time and do not count); ``"? left"`` before the first."""
    if left == 0:
        return "0 s left"
    if ran == 0:
        return "? left"
    s = elapsed / ran * left
    if s < 90:
        return f"~{s:.0f} s left"
    return f"~{s / 60:.1f} min left" if s < 5400 else f"~{s / 3600:.1f} h left"


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def run(args) -> int:
    from pathlib import Path

    from gonio.campaign import sweep
    from gonio.campaign.progress import Progress
    from gonio.campaign.raw import disk_usage

    check_outputs({"spec": args.spec}, {"--out": args.out, "--json": args.json})
    spec = sweep.load_spec(args.spec)
    if args.processes is not None and args.processes < 1:
        raise ValueError(f"--processes must be >= 1, got {args.processes}")
    if args.dask_local is not None and args.dask_local < 1:
        raise ValueError(f"--dask-local must be >= 1, got {args.dask_local}")
    tasks = sweep.expand(spec)
    if args.dry_run:
        rows = [(sweep.task_id(t), t["material"], t["seed"], t["settings"] or "") for t in tasks]
        print(format_table(("task", "material", "seed", "settings"), rows))
        print(f"{len(tasks)} task(s) of {spec.task!r}")
        return 0
    if args.scheduler or args.dask_local:
        executor = "dask"
    elif args.processes:
        executor = "process"
    else:
        executor = "inprocess"
    out = Path(check_output_dir(args.out or f"sweep_{spec.name}", "--out"))
    bar = Progress(len(tasks), f"sweep {spec.name}", quiet=args.quiet, min_time=0.0,
                   note=_time_left(0.0, 0, len(tasks)))  # fmt: skip
    done, ran = [0], [0]

    def progress(res: dict) -> None:
        done[0] += 1
        if "error" in res:
            state = f"FAILED {res['error']}"
        elif res.get("skipped"):
            state = "done earlier, skipped"
        else:
            state = f"{res['wall_s']:.2f} s"
            ran[0] += 1
        bar.update(note=_time_left(bar.elapsed, ran[0], len(tasks) - done[0]))
        if not args.quiet:
            bar.write(f"[{done[0]}/{len(tasks)}] {res['task_id']}: {state}")

    failed = None
    try:
        result = sweep.run_sweep(
            spec,
            out,
            executor=executor,
            workers=args.processes,
            scheduler=args.scheduler,
            dask_local=args.dask_local,
            retries=args.retries,
            plot=not args.no_plot,
            progress=progress,
            no_workers_timeout=args.no_workers_timeout,
            raw=args.raw,
        )
    except sweep.TaskFailed as exc:
        failed, result = exc, exc.result
    finally:
        bar.close()
    agg = sweep.aggregate(result.rows, spec)
    if agg:
        metric = sweep._headline_metric(spec, result.rows)
        keys = ["material", *spec.settings, "n"]
        cols = keys + ([f"{metric}_mean", f"{metric}_std"] if metric else [])
        print(format_table(cols, [[a.get(c, "") for c in cols] for a in agg]))
    print(
        f"{len(result.rows)}/{len(tasks)} task(s) done ({result.n_run} run, "
        f"{result.n_skipped} skipped) on {executor} in {result.wall_s:.2f} s"
        + (f" (of which {result.startup_s:.2f} s cluster start-up)" if result.startup_s else "")
        + f"; results in {out} ({_megabytes(disk_usage(out)['total'])}; raw frames of the "
        f"tasks run: {args.raw or spec.raw})"
    )
    if args.json:
        doc = result.to_dict()
        doc["failures"] = failed.failures if failed else {}
        write_json(args.json, doc)
    if failed:
        print(f"gonio sweep: {failed}", file=sys.stderr)
        return 1
    return 0
