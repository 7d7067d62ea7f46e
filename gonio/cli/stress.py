"""``gonio stress``: numerical stability of every model (and stage) on adversarial input."""

from __future__ import annotations

from gonio.cli._common import add_json_option, check_outputs, format_table, write_json

COMMAND = "stress"
HELP = (
    "sweep every model over adversarial directions and parameters, and the pipeline over "
    "saturated/black/constant images, D -> 0 and D -> R, far-off fit starts; count NaN, inf, "
    "negative, reciprocity and energy violations (exit 1 if any is unexpected)"
)


def add_arguments(parser) -> None:
    size = parser.add_mutually_exclusive_group()
    size.add_argument(
        "--full", action="store_const", const="full", dest="size", help="about 10^7 evaluations"
    )
    size.add_argument(
        "--small", action="store_const", const="small", dest="size", help="a few seconds"
    )
    parser.set_defaults(size="default")
    parser.add_argument("--models", nargs="+", metavar="NAME", help="only these models")
    parser.add_argument("--stages", nargs="+", metavar="STAGE", help="only these stages")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_json_option(parser)


def run(args) -> int:
    from gonio.diagnostics import stress

    check_outputs({}, {"--json": args.json})
    r = stress.run(args.size, models=args.models, rng=args.seed, stages=args.stages)
    known = {(k["model"], k["kind"]) for k in r["known"]}
    rows = []
    for name, counts in r["models"].items():
        info = r["stages"]["models"]["info"].get(name, {})
        cells = []
        for kind in ("nan", "inf", "negative", "horizon", "reciprocity", "energy", "error"):
            n = counts.get(kind, 0)
            cells.append(f"{n}{'*' if n and (name, kind) in known else ''}")
        rows.append((name, *cells, info.get("parameter_sets", ""), info.get("seconds", "")))
    print(
        format_table(
            ("model", "nan", "inf", "neg", "horizon", "recip", "energy", "error", "sets", "s"),
            rows,
        )
    )
    print("(* = documented property of the model, listed under 'known')")
    for k in r["known"]:
        w = k.get("worst", {})
        fig = ""
        if "albedo" in w:
            fig = f" worst albedo {w['albedo']:.4g} at theta_i {w['theta_i_deg']} deg"
        elif "f" in w:
            fig = f" e.g. f = {w['f']} at wi {w.get('wi')}, wo {w.get('wo')}"
        print(f"known: {k['model']} {k['kind']} x{k['count']}:{fig}\n       ({k['issue']})")
    for name, st in r["stages"].items():
        if name != "models":
            subjects = ", ".join(f"{subj} {sum(c.values())}" for subj, c in st["counts"].items())
            print(f"stage {name}: {st['cases']} cases, {st['unexpected']} unexpected ({subjects})")
    for st in r["stages"].values():
        for e in st["examples"][:20]:
            print(f"UNEXPECTED {e['subject']} {e['kind']}: params {e['params']}: {e['detail']}")
    print(
        f"{r['cases']} cases, {r['unexpected']} unexpected violation(s), "
        f"size {r['size']}, {r['seconds']:.1f} s"
    )
    if args.json:
        write_json(args.json, r)
    return 1 if r["unexpected"] > 0 else 0
