"""``gonio reduce``: raw LBL images + side-cars → a BRDF samples table (Ward 1992 §3.2).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §3.2: calibration and data reduction.
"""

from __future__ import annotations

from gonio.cli._common import add_json_option, check_outputs, output_file, write_json

COMMAND = "reduce"
HELP = "reduce raw LBL images (eq. 2, eq. 3, thinning) to a BRDF samples table"


def add_arguments(parser) -> None:
    parser.add_argument(
        "images",
        nargs="+",
        help="the sample's frames (a bracket), with .json side-cars; at most 4096 x 4096 pixels",
    )
    parser.add_argument("--standard", nargs="+", required=True, help="the standard's frames")
    parser.add_argument("--background", nargs="+", required=True, help="background frames")
    parser.add_argument("--lens-calibration", help="lens-calibration JSON (gonio calibrate-lens)")
    parser.add_argument("--method", choices=("eq3", "exact"), default="eq3",
                        help="reflection angles by eq. 3 or the exact traced map")  # fmt: skip
    parser.add_argument("--no-thinning", action="store_true", help="one row per pixel")
    parser.add_argument(
        "--out", required=True, type=output_file, help="output samples file (.csv or .npz)"
    )
    add_json_option(parser)


def run(args) -> int:
    from gonio.calibration import load_capture, reduce_capture
    from gonio.io.images import sidecar_path

    frames = {"images": args.images, "--standard": args.standard, "--background": args.background}
    inputs = {**frames, "--lens-calibration": args.lens_calibration}
    for opt, paths in frames.items():
        inputs[f"a side-car of {opt}"] = [sidecar_path(p) for p in paths]
    check_outputs(inputs, {"--out": args.out, "--json": args.json})
    res = reduce_capture(
        load_capture(args.images),
        load_capture(args.standard),
        load_capture(args.background),
        lens=args.lens_calibration,
        method=args.method,
        thinning=not args.no_thinning,
    )
    res.samples.write(args.out)
    st = res.stats
    print(
        f"{st['n_before']} pixels -> {st['n_after']} samples "
        f"({st['n_masked_eq2']} masked by eq. 2) in {st['timings_s']['total']:.3f} s -> {args.out}"
    )
    if args.json:
        write_json(args.json, {"out": args.out, "stats": st})
    return 0
