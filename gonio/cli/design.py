"""``gonio design``: the plan that reaches a target uncertainty in the least instrument time."""

from __future__ import annotations

from gonio.cli._common import add_json_option, output_file, write_json

COMMAND = "design"
HELP = "design a measurement plan that reaches target uncertainties in the least instrument time"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--instrument",
        choices=("cornell",),
        default="cornell",
        help="the instrument (cornell: geometries of the three-axis gonioreflectometer)",
    )
    parser.add_argument(
        "--material", default="garnet_red_paint", help="the prior: a li_torrance material preset"
    )
    parser.add_argument(
        "--instrument-preset",
        "--preset",
        dest="preset",
        default="cornell2005",
        choices=["cornell2005", "ideal"],
        help="the instrument's build as the laboratory knows it (default cornell2005)",
    )
    parser.add_argument(
        "--target",
        action="append",
        default=[],
        metavar="NAME=U[%]",
        help="target expanded uncertainty (k=2) of a fitted parameter (tau), a per-band family "
        "(k_fs: every band), one band (k_fs[12]) or all; relative with %% (repeatable; default "
        "all=5%%)",
    )
    parser.add_argument(
        "--prior",
        action="append",
        default=[],
        metavar="NAME=LOW:HIGH",
        help="prior range of a shape parameter (tau=7:9.5); the design holds over its ends",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="HOURS",
        help="the most real-instrument time the plan may take",
    )
    parser.add_argument(
        "--grid",
        type=int,
        default=13,
        metavar="N",
        help="candidates: N x N viewing directions per incidence angle (default 13)",
    )
    parser.add_argument(
        "--out",
        type=output_file,
        default="designed_plan.csv",
        help="plan file to write (for gonio campaign --plan; default designed_plan.csv)",
    )
    add_json_option(parser)


def run(args) -> int:
    from gonio.campaign import design

    if args.grid < 3:
        raise ValueError(f"--grid {args.grid}: expected at least 3")
    targets = design.parse_targets(args.target or None)
    prior = design.parse_prior(args.prior)
    res = design.design_cornell(
        args.material,
        targets,
        preset=None if args.preset == "ideal" else args.preset,
        prior=prior,
        time_limit_h=args.time_limit,
        n_grid=args.grid,
    )
    design.write_cornell_plan(args.out, res)
    print(res.table())
    print(f"plan written to {args.out} (run it: gonio campaign --instrument cornell --plan "
          f"{args.out} --material {args.material})")  # fmt: skip
    if args.json:
        write_json(args.json, res.to_dict())
    return 0
