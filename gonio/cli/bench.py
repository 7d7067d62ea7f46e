"""``gonio bench``: run time against error for each knob, and the skip-rule ablations."""

from __future__ import annotations

import sys

from gonio.cli._common import (
    add_json_option,
    check_outputs,
    format_table,
    output_file,
    write_json,
)

COMMAND = "bench"
HELP = "benchmark run time against error for every accuracy knob, and ablate the skip rules"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--quick", action="store_true", help="few settings per knob (runs in seconds)"
    )
    parser.add_argument(
        "--knob", action="append", metavar="NAME", help="only this knob (repeatable)"
    )
    parser.add_argument(
        "--seeds", type=int, default=1, metavar="N", help="fixed seeds 0..N-1 (default 1)"
    )
    parser.add_argument(
        "--repeat", type=int, default=1, metavar="N", help="time each run N times, keep the best"
    )
    parser.add_argument("--no-ablations", action="store_true", help="skip the ablation section")
    parser.add_argument("--csv", metavar="PATH", type=output_file, help="write the table as CSV")
    parser.add_argument(
        "--plot", metavar="PATH", type=output_file, help="write the Pareto plot (PNG)"
    )
    parser.add_argument("--list", action="store_true", help="list the knobs and ablations")
    add_json_option(parser)


def run(args) -> int:
    from gonio.diagnostics import bench

    check_outputs({}, {"--csv": args.csv, "--plot": args.plot, "--json": args.json})

    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    if args.repeat < 1:
        raise ValueError(f"--repeat must be >= 1, got {args.repeat}")
    if args.list:
        rows = [(k.name, "knob", k.description) for k in bench.KNOBS.values()]
        rows += [(a.name, "ablation", a.description) for a in bench.ABLATIONS.values()]
        print(format_table(("name", "kind", "description"), rows))
        return 0
    report = bench.run_bench(
        args.knob,
        quick=args.quick,
        seeds=range(args.seeds),
        repeat=args.repeat,
        ablations=not args.no_ablations,
    )
    rows = [
        (
            r["knob"],
            r["setting"],
            r["seed"],
            r["time_s"],
            r["primary"],
            r["error"],
            r.get("max_rel_err", ""),
        )
        for r in report["rows"]
    ]
    print(
        format_table(
            ("knob", "setting", "seed", "time_s", "error kind", "error", "max_rel_err"), rows
        )
    )
    waiting = [(n, i["waiting_on"]) for n, i in report["knobs"].items() if not i["available"]]
    if waiting:
        print("\nknobs not yet available:")
        print(format_table(("knob", "waiting on"), waiting))
    if report["ablations"]:
        print("\nablations (skip rule off vs on):")
        arows = []
        for a in report["ablations"]:
            if a["available"]:
                arows.append(
                    (
                        a["name"],
                        a["time_off_s"],
                        a["time_on_s"],
                        a["speedup"],
                        "yes (bit-identical)"
                        if a["identical"]
                        else (
                            f"{'yes' if a['unchanged'] else 'NO'} (max rel diff "
                            f"{a['max_rel_diff']:.3g}, allowed {a['rtol']:.3g})"
                        ),
                    )
                )
            else:
                arows.append((a["name"], "-", "-", "-", f"not yet available: {a['waiting_on']}"))
        print(format_table(("rule", "off_s", "on_s", "speed-up", "result unchanged"), arows))
    if args.csv:
        from gonio.io.atomic import atomic_write_bytes

        atomic_write_bytes(args.csv, bench.rows_csv(report["rows"]))
    if args.plot:
        bench.plot_pareto(report, args.plot)
    if args.json:
        write_json(args.json, report)
    bad = [a["name"] for a in report["ablations"] if a.get("available") and not a["unchanged"]]
    if bad:
        print(f"gonio bench: skip rule(s) changed the result: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0
