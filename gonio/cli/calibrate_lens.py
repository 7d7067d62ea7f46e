"""``gonio calibrate-lens``: fisheye intrinsics from ChArUco board images (cv2.fisheye)."""

from __future__ import annotations

from gonio.cli._common import add_json_option, check_outputs, output_file, write_json

COMMAND = "calibrate-lens"
HELP = "calibrate a fisheye lens (Kannala-Brandt) from ChArUco board images"


def add_arguments(parser) -> None:
    parser.add_argument("images", nargs="+", help="8-bit board images")
    parser.add_argument(
        "--squares",
        type=int,
        nargs=2,
        default=(9, 7),
        metavar=("X", "Y"),
        help="ChArUco board squares across and down",
    )
    parser.add_argument(
        "--square-length", type=float, default=0.04, help="side of a board square, metres"
    )
    parser.add_argument(
        "--marker-length", type=float, default=0.02, help="side of an ArUco marker, metres"
    )
    parser.add_argument(
        "--out", required=True, type=output_file, help="lens-calibration JSON to write"
    )
    add_json_option(parser)


def run(args) -> int:
    import cv2

    from gonio.calibration.lens import calibrate_fisheye, make_board, write_lens_calibration

    check_outputs({"images": args.images}, {"--out": args.out, "--json": args.json})
    try:
        board = make_board(*args.squares, args.square_length, args.marker_length)
    except ValueError as exc:
        raise ValueError(f"--squares / --square-length / --marker-length: {exc}") from None
    imgs = []
    for p in args.images:
        a = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if a is None:
            raise ValueError(f"cannot read image {p!r}")
        imgs.append(a)
    cal = calibrate_fisheye(imgs, board)
    write_lens_calibration(cal, args.out)
    lens = cal.lens
    print(
        f"{cal.n_views} views, {cal.n_points} corners: fx={lens.fx:.3f} fy={lens.fy:.3f} "
        f"cx={lens.cx:.3f} cy={lens.cy:.3f} k={[round(k, 6) for k in lens.k]} "
        f"rms={cal.rms:.4f} px -> {args.out}"
    )
    if args.json:
        write_json(args.json, cal.to_dict())
    return 0
