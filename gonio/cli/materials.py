"""``gonio materials``: list the built-in material presets and their sources."""

from __future__ import annotations

from gonio.cli._common import add_json_option, format_table, write_json

COMMAND = "materials"
HELP = "list the built-in material presets (model, parameters, source)"


def add_arguments(parser) -> None:
    parser.add_argument("--model", help="only presets of this model")
    add_json_option(parser)


def run(args) -> int:
    from gonio import materials

    rows, out = [], {}
    for n in materials.names(args.model):
        rec = materials.info(n)
        out[n] = rec
        params = ", ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}=…" for k, v in rec["params"].items()
        )
        rows.append((n, rec["model"], params, rec["source"]))
    print(format_table(("material", "model", "parameters", "source"), rows))
    if args.json:
        write_json(args.json, {"materials": out})
    return 0
