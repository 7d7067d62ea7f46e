"""``gonio campaign``: run a simulated measurement campaign end to end (the main job)."""

from __future__ import annotations

import math
import os

from gonio.cli._common import (
    add_json_option,
    add_preset_option,
    check_output_dir,
    check_outputs,
    int_in,
    output_dir,
    worker_count,
    write_json,
)

COMMAND = "campaign"
HELP = "capture, reduce, fit and report a material on a simulated instrument (LBL or Cornell)"


def add_arguments(parser) -> None:
    """The campaign's options, in four groups: what is measured, the plan, the instrument
    and its laboratory, the output."""
    _measurement_options(parser.add_argument_group("what is measured"))
    _plan_options(parser.add_argument_group("the plan"))
    _instrument_options(parser.add_argument_group("the instrument and its laboratory"))
    _output_options(parser.add_argument_group("output and execution"))
    add_json_option(parser)


def _measurement_options(group) -> None:
    group.add_argument(
        "--instrument",
        choices=("lbl", "cornell"),
        default="lbl",
        help="LBL imaging (default) or Cornell three-axis gonioreflectometer",
    )
    group.add_argument(
        "--material",
        default=None,
        help="material preset (default rolled_brass on lbl, garnet_red_paint on cornell)",
    )
    group.add_argument("--model", default=None, help="model to fit (default: the preset's)")
    group.add_argument(
        "--compare",
        default=None,
        metavar="M1,M2",
        help="other models fitted to the same samples ('' for none)",
    )
    group.add_argument(
        "--residual",
        default=None,
        choices=["absolute", "relative", "log", "li_torrance"],
        help="fit residual (LBL; default absolute)",
    )


def _plan_options(group) -> None:
    group.add_argument(
        "--plan",
        default=None,
        help="cornell: incidence (default) | hemispherical | CSV of theta_i,phi_i,theta_o,phi_o "
        "(deg; gonio design's also carries the reference cadence, reference_every); lbl: a JSON "
        "plan file (theta_i_deg, rotations_deg, restandard_every; as gonio design writes it)",
    )
    group.add_argument(
        "--adaptive",
        action="store_true",
        help="a short pilot, a fit, the plan designed from it (gonio design) to the --target "
        "uncertainties, then that plan; summary in OUT/adaptive.json (cornell or lbl)",
    )
    group.add_argument(
        "--target",
        action="append",
        default=[],
        metavar="NAME=U[%]",
        help="--adaptive: target expanded uncertainty, as gonio design takes it",
    )
    group.add_argument(
        "--assurance",
        type=float,
        default=None,
        metavar="P",
        help="--adaptive, lbl: the fraction of the preset's instruments on which the design "
        "meets each target (0.5 < P < 1; default 0.95), as gonio design takes it",
    )
    group.add_argument(
        "--design-instruments",
        type=int,
        default=None,
        metavar="K",
        help="--adaptive, lbl: the design's instruments (1-10, default 6), as gonio design "
        "takes them (on 60 instruments ten met 179/180 reachable targets where six met "
        "174/180, with a quicker plan, in 1.7 times the design time)",
    )
    group.add_argument(
        "--through-drivers",
        action="store_true",
        help="cornell: drive fake ESP300 and USB2000+ devices through the drivers",
    )
    group.add_argument(
        "--angles",
        default=None,
        metavar="DEG",
        help="incidence angles: 'START:STOP:N' (inclusive) or 'a,b,c' (default 0:80:21)",
    )
    group.add_argument(
        "--rotations",
        default=None,
        metavar="DEG",
        help="sample rotations 'a,b,...' (default 0,45,90 for anisotropic materials, else 0)",
    )
    group.add_argument(
        "--restandard-every",
        type=int_in(0, 10**6),
        default=0,
        metavar="N",
        help="LBL: re-measure the standard after every N-th incidence angle of each rotation, "
        "for the drift correction (default 0: never)",
    )
    group.add_argument("--noise", default="on", help="off, on, or a factor (default on)")
    group.add_argument(
        "--seed", type=int_in(0, 2**63 - 1), default=0, help="campaign seed (default 0)"
    )


def _instrument_options(group) -> None:
    add_preset_option(
        group,
        "the instrument's build and its imperfections (default modern on lbl, "
        "cornell2005 on cornell; ideal = none; --instrument-preset is the same option)",
    )
    group.add_argument(
        "--instrument-seed",
        type=int,
        default=None,
        help="which instrument of the preset (default the campaign seed)",
    )
    group.add_argument(
        "--mirror",
        default=None,
        choices=["ellipsoid", "hemisphere"],
        help="LBL dome (default ellipsoid)",
    )
    group.add_argument(
        "--d-over-r", type=float, default=None, help="LBL dome D/R (default the instrument's)"
    )
    group.add_argument(
        "--binning",
        default=None,
        metavar="WxH",
        help="digitise the LBL images to WxH, at most the camera's 640x480 (default the "
        "preset's: 108x80 for ward1992; 0x0 full resolution)",
    )
    group.add_argument(
        "--corrections",
        default=None,
        metavar="LIST",
        help="the laboratory's corrections (LBL), comma list of geometry, standard, exposure, "
        "glare, saturation, drift; 'none' for none (default all)",
    )
    group.add_argument(
        "--calibration",
        default=None,
        metavar="DIR",
        help="a calibration folder (calibration.json) to reduce with (LBL)",
    )
    group.add_argument(
        "--no-calibration-cache",
        action="store_true",
        help="calibrate anew, keep nothing (LBL; default: a calibration made before for this "
        "instrument is read from $GONIO_CACHE_DIR, default ~/.cache/gonio)",
    )
    group.add_argument(
        "--no-debias",
        action="store_true",
        help="keep eq. 2's second-order ratio bias (LBL; see Plan.debias)",
    )


def _output_options(group) -> None:
    group.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        type=output_dir,
        help="results directory (default ./campaign_MATERIAL_seedN)",
    )
    group.add_argument("--resume", action="store_true", help="reuse completed captures in DIR")
    group.add_argument(
        "--raw",
        choices=("keep", "compressed", "none"),
        default="keep",
        help="LBL: the raw frames once the campaign is done: kept as written, compressed "
        "(lossless LZW, read back bit for bit; ~3x smaller) or removed (no --resume then)",
    )
    group.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of another plan (LBL) or other settings (Cornell) found in DIR "
        "(else refused)",
    )
    group.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    group.add_argument(
        "--plot-dpi",
        type=int_in(50, 1200, "dots per inch"),
        default=None,
        metavar="DPI",
        help="resolution of the PNG plots (default 150; 300-600 for print)",
    )
    group.add_argument(
        "--workers",
        type=worker_count,
        default=None,
        help="processes for capture/reduce/plots (default: CPU count for >= 8 angles; 1 = none; "
        "at most 4 per CPU)",
    )
    group.add_argument("--quiet", action="store_true", help="no progress bars, no table")


def parse_angles(text: str, option: str = "--angles") -> tuple[float, ...]:
    """'0:80:21' (inclusive, N values) or '0,10,20' -> angles in degrees."""
    text = text.strip()
    try:
        if ":" in text:
            a, b, n = text.split(":")
            n = int(n)
            if n < 1:
                raise ValueError
            if n == 1:
                return (float(a),)
            step = (float(b) - float(a)) / (n - 1)
            return tuple(float(a) + k * step for k in range(n))
        vals = tuple(float(x) for x in text.split(",") if x.strip())
        if not vals:
            raise ValueError
        return vals
    except ValueError:
        raise ValueError(
            f"{option} {text!r}: expected 'START:STOP:N' or a comma-separated list of degrees"
        ) from None


def parse_binning(text: str | None) -> tuple[int, int] | None:
    """'108x80' -> (108, 80); None -> None (the preset's)."""
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--binning {text!r}: expected WxH, e.g. 108x80 (0x0: none)") from None
    return (w, h)


def parse_noise(text: str) -> float:
    """'off' -> 0, 'on' -> 1, a number -> that factor."""
    t = str(text).strip().lower()
    if t == "off":
        return 0.0
    if t == "on":
        return 1.0
    try:
        v = float(t)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"--noise {text!r}: expected off, on or a factor >= 0")
    return v


#: Options of one instrument only -> the value that means "not given".
_LBL_ONLY = {
    "--assurance": ("assurance", None),
    "--design-instruments": ("design_instruments", None),
    "--model": ("model", None),
    "--mirror": ("mirror", None),
    "--angles": ("angles", None),
    "--rotations": ("rotations", None),
    "--compare": ("compare", None),
    "--residual": ("residual", None),
    "--d-over-r": ("d_over_r", None),
    "--no-debias": ("no_debias", False),
    "--workers": ("workers", None),
    "--binning": ("binning", None),
    "--restandard-every": ("restandard_every", 0),
    "--raw": ("raw", "keep"),
}
_CORNELL_ONLY = {
    "--through-drivers": ("through_drivers", False),
}


def _refuse_other_instrument(args) -> None:
    """An option of the other instrument is an error, not silently ignored."""
    other = _LBL_ONLY if args.instrument == "cornell" else _CORNELL_ONLY
    given = [opt for opt, (attr, unset) in other.items() if getattr(args, attr) != unset]
    if given:
        owner = "lbl" if args.instrument == "cornell" else "cornell"
        raise ValueError(
            f"{', '.join(given)}: option(s) of --instrument {owner} only, not of "
            f"--instrument {args.instrument}"
        )


_PRESETS = {"lbl": ("modern", "ward1992", "ideal"), "cornell": ("cornell2005", "ideal")}


def _preset(args, instrument: str, default: str) -> str:
    """The instrument preset of the command line, checked against the instrument."""
    p = args.preset or default
    if p not in _PRESETS[instrument]:
        raise SystemExit(
            f"error: --preset {p} is not a {instrument} preset; expected one of "
            f"{', '.join(_PRESETS[instrument])}"
        )
    return p


#: The fit's hints (:func:`gonio.hints.keyword`) in a campaign's own terms, per instrument:
#: a campaign fits its model from the fit's own starts, with nothing held fixed by the user,
#: so it cannot pass ``fixed=``, ``n_starts=`` or ``init=``; what it can do is fit a model with
#: fewer free parameters or measure more geometries, and its ``samples.csv`` can be fitted
#: again with ``gonio fit``, whose options these keywords are.
_FIT_HINTS = {
    "lbl": (
        "fit a --model with fewer free parameters, measure more geometries (--angles, "
        "--rotations), or refit samples.csv with gonio fit --fixed NAME=VALUE",
        "fit another --model, or refit samples.csv with gonio fit --starts N or --init NAME=VALUE",
    ),
    "cornell": (
        "measure more geometries (--plan hemispherical), or refit samples.csv with gonio fit "
        "--fixed NAME=VALUE",
        "refit samples.csv with gonio fit --starts N or --init NAME=VALUE",
    ),
}

#: Any other phrasing of those hints: ``gonio fit``'s option.
_FIT_OPTIONS = {
    "fixed": "gonio fit --fixed",
    "n_starts": "gonio fit --starts",
    "init": "gonio fit --init",
}


def campaign_text(text: str, instrument: str = "lbl") -> str:
    """A campaign's printed report with the fit's hints in the campaign's own options
    (``fix some (fixed=) or measure more geometries`` -> ``fit a --model with fewer free
    parameters, measure more geometries (--angles, --rotations), ...``)."""
    from gonio.hints import as_options, keyword

    fewer, starts = _FIT_HINTS[instrument]
    text = text.replace(f"fix some ({keyword('fixed')}) or measure more geometries", fewer)
    text = text.replace(f"try {keyword('n_starts')} or {keyword('init')}", starts)
    return as_options(text, _FIT_OPTIONS)


def _run_adaptive(args) -> int:
    from gonio.campaign import design
    from gonio.campaign import design_adaptive as da

    given = [o for o, a in (("--plan", "plan"), ("--through-drivers", "through_drivers"),
             ("--resume", "resume"), ("--angles", "angles"), ("--rotations", "rotations"),
             ("--restandard-every", "restandard_every"), ("--overwrite", "overwrite"))
             if getattr(args, a)]  # fmt: skip
    if given:
        raise ValueError(f"--adaptive: designs its own plan (no {', '.join(given)})")
    lbl = args.instrument == "lbl"
    material = args.material or ("rolled_brass" if lbl else "garnet_red_paint")
    targets = design.parse_targets(args.target or None)
    out = check_output_dir(args.out or f"adaptive_{material}_seed{args.seed}", "--out")
    check_outputs({}, {"--out": out, "--json": args.json})
    kw = dict(seed=args.seed, instrument_seed=args.instrument_seed)
    if lbl:
        n = 6 if args.design_instruments is None else args.design_instruments
        s = da.adaptive_lbl(material, targets, out, preset=_preset(args, "lbl", "modern"),
                            assurance=args.assurance, n_instruments=n, **kw)  # fmt: skip
    else:
        s = da.adaptive_cornell(material, targets, out,
                                preset=_preset(args, "cornell", "cornell2005"), **kw)  # fmt: skip
    if not args.quiet:
        print(da.adaptive_lbl_text(s) if lbl else da.adaptive_text(s))
    if args.json:
        write_json(args.json, s)
    return 0


def _run_cornell(args) -> int:
    from gonio.campaign.cornell import run_cornell_campaign, summary_text

    if args.adaptive:
        return _run_adaptive(args)
    if args.target:
        raise ValueError("--target: an option of --adaptive (gonio design takes targets too)")

    s = run_cornell_campaign(
        args.material or "garnet_red_paint",
        effects=_preset(args, "cornell", "cornell2005"),
        instrument_seed=args.instrument_seed,
        plan=args.plan or "incidence",
        noise=parse_noise(args.noise) > 0,
        seed=args.seed,
        out=args.out,
        through_drivers=args.through_drivers,
        resume=args.resume,
        quiet=args.quiet,
        overwrite=args.overwrite,
    )
    s.pop("_samples", None)
    if not args.quiet:
        print(campaign_text(summary_text(s), "cornell"))
    if args.json:
        write_json(args.json, s)
    return 0 if s.get("converged", True) else 1


def run(args) -> int:
    if args.plot_dpi is not None:  # read by gonio.plots.figures.plot_dpi, in the plot process too
        os.environ["GONIO_PLOT_DPI"] = str(args.plot_dpi)
    _refuse_other_instrument(args)
    if args.instrument == "cornell":
        return _run_cornell(args)
    if args.adaptive:
        return _run_adaptive(args)
    if args.target:
        raise ValueError("--target: an option of --adaptive (gonio design takes targets too)")
    for opt, given in (
        ("--assurance", args.assurance),
        ("--design-instruments", args.design_instruments),
    ):
        if given is not None:
            raise ValueError(f"{opt}: an option of --adaptive (gonio design takes it too)")
    from gonio import campaign

    args.material = args.material or "rolled_brass"
    kw = dict(
        material=args.material,
        model=args.model,
        mirror=args.mirror or "ellipsoid",
        noise=parse_noise(args.noise),
        seed=args.seed,
        residual=args.residual or "absolute",
        plots=not args.no_plots,
        d_over_r=args.d_over_r,
        debias=not args.no_debias,
        preset=_preset(args, "lbl", "modern"),
        instrument_seed=args.instrument_seed,
        binning=parse_binning(args.binning),
        calibration=args.calibration,
        restandard_every=args.restandard_every,
    )
    if args.corrections is not None:
        text = args.corrections.strip()
        kw["corrections"] = (
            () if text == "none" else tuple(c.strip() for c in text.split(",") if c.strip())
        )
    if args.angles is not None:
        kw["theta_i_deg"] = parse_angles(args.angles)
    if args.rotations is not None:
        kw["rotations_deg"] = parse_angles(args.rotations, "--rotations")
    if args.plan is not None:  # an LBL plan file: its fields, not also the options'
        from gonio.campaign.plan import read_plan_file

        both = [
            o for o, a in (("--angles", "angles"), ("--rotations", "rotations")) if getattr(args, a)
        ]
        if both or args.restandard_every:
            raise ValueError(
                f"--plan: the plan file sets what {both or ['--restandard-every']} would"
            )
        kw.update(read_plan_file(args.plan))
    if args.compare is not None:
        kw["compare"] = tuple(c.strip() for c in args.compare.split(",") if c.strip())
    plan = campaign.Plan(**kw)
    out = check_output_dir(args.out or f"campaign_{args.material}_seed{args.seed}", "--out")
    check_outputs({"--calibration": args.calibration}, {"--out": out, "--json": args.json})
    res = campaign.run(plan, out, resume=args.resume, quiet=args.quiet, workers=args.workers,
                       overwrite=args.overwrite,
                       calibration_cache=not args.no_calibration_cache)  # fmt: skip
    from gonio.campaign.raw import disk_usage, keep_raw

    keep_raw(res.out, args.raw)
    disk = disk_usage(res.out)
    if not args.quiet:
        print(campaign_text(campaign.summary_table(res.summary)))
        print(f"results in {res.out}: {disk['total'] / 1e6:.1f} MB on the disk, raw frames "
              f"{disk['raw'] / 1e6:.1f} MB ({args.raw})")  # fmt: skip
    if args.json:
        write_json(args.json, {**res.summary, "disk_bytes": disk, "raw": args.raw})
    return 0 if res.summary["converged"] else 1
