"""``gonio materials``: list the built-in material presets and their sources."""

from __future__ import annotations

import textwrap

from gonio.cli._common import add_json_option, write_json

COMMAND = "materials"
HELP = "list the built-in material presets (model, parameters, source)"

#: the printed table's width (columns): parameters and source wrap within it
WIDTH = 100


def add_arguments(parser) -> None:
    parser.add_argument("--model", help="only presets of this model (see `gonio models`)")
    add_json_option(parser)


def table(rows: list[tuple[str, str, str, str]], width: int = WIDTH) -> str:
    """``(material, model, parameters, source)`` rows as a table at most ``width`` columns
    wide: parameters and then the source wrap in the last column."""
    w0 = max(len("material"), *(len(r[0]) for r in rows))
    w1 = max(len("model"), *(len(r[1]) for r in rows))
    w2 = max(20, width - w0 - w1 - 4)
    pad = " " * (w0 + w1 + 4)
    lines = [f"{'material':<{w0}}  {'model':<{w1}}  parameters; source", "-" * (w0 + w1 + 4 + w2)]
    for name, model, params, source in rows:
        body = textwrap.wrap(params, w2, break_on_hyphens=False) or [""]
        body += textwrap.wrap(source, w2, initial_indent="source: ", break_on_hyphens=False)
        lines.append(f"{name:<{w0}}  {model:<{w1}}  {body[0]}".rstrip())
        lines += [pad + b for b in body[1:]]
    return "\n".join(lines)


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
    if rows:
        print(table(rows))
    else:
        known = sorted({materials.info(n)["model"] for n in materials.names()})
        text = f"no material preset of model {args.model!r}; presets exist for {', '.join(known)}"
        print(textwrap.fill(text, WIDTH, break_on_hyphens=False))
    if args.json:
        write_json(args.json, {"materials": out})
    return 0
