"""``gonio fit``: fit a reflectance model to a samples file (CSV or NPZ)."""

from __future__ import annotations

from gonio.cli._common import (
    add_json_option,
    check_model_terms,
    check_outputs,
    cli_text,
    format_table,
    name_value_pairs,
    write_json,
)

COMMAND = "fit"
HELP = "fit a BRDF model (or a sum 'lambert + ward') to a samples file"


def add_arguments(parser) -> None:
    parser.add_argument("samples", help="samples table (.csv, .npz or an ASTM E1392 .astm)")
    parser.add_argument(
        "--model", default="ward", help="model name or sum, e.g. 'lambert + ward' (default ward)"
    )
    parser.add_argument(
        "--residual",
        default="absolute",
        choices=["absolute", "relative", "log", "li_torrance"],
        help="misfit of one sample (default absolute; weighted by sigma when known)",
    )
    parser.add_argument(
        "--fixed",
        action="append",
        default=[],
        metavar="NAME[=VALUE]",
        help="hold a parameter (at VALUE, or at its start); repeatable",
    )
    parser.add_argument(
        "--init", action="append", default=[], metavar="NAME=VALUE", help="start value; repeatable"
    )
    parser.add_argument(
        "--per-band",
        default=None,
        metavar="A,B",
        help="grey model on spectral data: parameters fitted per band (default the rho's)",
    )
    parser.add_argument("--starts", type=int, default=None, help="extra random starts")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    add_json_option(parser)


def run(args) -> int:
    from gonio import fit
    from gonio.io.samples_table import read_samples

    check_outputs({"samples": args.samples}, {"--json": args.json})
    check_model_terms(args.model, "--model")
    fixed = name_value_pairs(args.fixed, "--fixed", need_value=False)
    init = name_value_pairs(args.init, "--init", need_value=True)
    both = sorted(k for k in set(fixed) & set(init) if fixed[k] is not None)
    if both:
        raise ValueError(f"{', '.join(both)}: held by --fixed at a value and started by --init")
    samples = read_samples(args.samples)
    per_band = None
    if args.per_band is not None:
        per_band = [p.strip() for p in args.per_band.split(",") if p.strip()]
    r = fit.fit(
        samples,
        args.model,
        residual=args.residual,
        fixed=fixed or None,
        init=init or None,
        per_band=per_band,
        n_starts=args.starts,
        rng=args.seed,
    )
    rows = [
        (k, v, r.stderr[k], "fixed" if k in r.fixed else ("bound" if k in r.at_bounds else ""))
        for k, v in r.params.items()
    ]
    print(format_table(("parameter", "value", "stderr", ""), rows))
    state = "converged" if r.converged else "NOT converged"
    if not r.identifiable:
        state += ", NOT identifiable"
    print(
        f"{r.model_name}: {state}; "
        f"n = {r.n_samples}, rms = {r.rms:.4g} sr^-1, chi2/dof = {r.chi2_dof:.4g}"
    )
    for note in r.message.split("; note: ")[1:]:
        print("note: " + cli_text(note, args))
    if args.json:
        d = r.to_dict()
        d["samples"] = str(args.samples)
        write_json(args.json, d)
    return 0 if r.converged and r.identifiable else 1
