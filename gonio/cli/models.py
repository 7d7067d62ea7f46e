"""``gonio models``: list the registered BRDF models with their parameters."""

from __future__ import annotations

import math

from gonio.cli._common import add_json_option, format_table, write_json

COMMAND = "models"
HELP = "list the registered BRDF models, their parameters (bounds, defaults) and sources"


def add_arguments(parser) -> None:
    parser.add_argument("name", nargs="?", help="show one model in detail")
    add_json_option(parser)


def _finite(x: float) -> float | None:
    """JSON has no infinity: an unbounded side is written as null."""
    return x if math.isfinite(x) else None


def run(args) -> int:
    from gonio import brdf

    selected = [args.name] if args.name else brdf.names()
    out = {}
    rows = []
    for n in selected:
        s = brdf.spec(n)
        params = {
            k: {
                "default": p.default,
                "lower": _finite(p.lower),
                "upper": _finite(p.upper),
                "unit": p.unit,
                "doc": p.doc,
                "kind": p.kind,
            }
            for k, p in s.params.items()
        }
        out[n] = {
            "reference": s.reference,
            "summary": s.summary,
            "params": params,
            "reciprocal": s.reciprocal,
            "energy_conserving": s.energy_conserving,
            "known_issues": list(s.known_issues),
            "sampler": s.has_sampler,
            "delta": s.has_delta,
            "analytic_albedo": s.analytic_albedo,
        }
        rows.append((n, ", ".join(s.params), s.reference))
    print(format_table(("model", "parameters", "reference"), rows))
    if args.name:
        for k, p in out[args.name]["params"].items():
            print(
                f"  {k}: default {p['default']}, bounds [{p['lower']}, {p['upper']}]"
                f" {p['unit']}  {p['doc']}"
            )
    if args.json:
        write_json(args.json, {"models": out})
    return 0
