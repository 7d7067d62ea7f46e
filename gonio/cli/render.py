"""``gonio render``: a raw image of the simulated LBL imaging gonioreflectometer.

Writes the 16-bit image (PNG or TIFF by suffix) and its JSON side-car (``<image>.json``,
the capture metadata), optionally a false-colour picture with the reflection-angle grid that
eq. 3 recovers drawn over it (Ward 1992, §3, Figure 4 and eq. 3).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §3, Figure 4 (a raw image of the gonioreflectometer) and eq. 3 (its angle grid).
"""

from __future__ import annotations

import math

from gonio.cli._common import (
    add_json_option,
    check_outputs,
    format_table,
    int_in,
    name_value_pairs,
    output_file,
    write_json,
)

COMMAND = "render"

#: Largest --width / --height. A capture's peak memory grows by ~120 bytes per pixel
#: (measured: 199 MB at 640 x 480, 489 MB at 1920 x 1440), so 4096 x 4096 peaks near 2 GB;
#: a side of 100000 pixels asked for one 149 GiB array before failing.
MAX_SIDE = 4096
#: ``--binning`` given without WxH: the old flag's meaning (Ward's 108 x 80), with a note.
_BARE_BINNING = "bare"
HELP = "render a raw LBL gonioreflectometer image (16-bit PNG/TIFF + JSON side-car)"


def add_arguments(parser) -> None:
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--material", help="material preset (see `gonio materials`)")
    what.add_argument("--model", help="BRDF model name (see `gonio models`), with --param")
    what.add_argument(
        "--sample",
        choices=("standard", "none"),
        help="image the diffuse standard, or no sample (background)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="model parameter (repeatable; with --model or to override a --material)",
    )
    parser.add_argument(
        "--theta-i", type=float, default=30.0, help="incidence polar angle θi, degrees"
    )
    parser.add_argument("--phi-i", type=float, default=0.0, help="incidence azimuth, deg")
    parser.add_argument(
        "--mirror",
        choices=("ellipsoid", "hemisphere"),
        default="ellipsoid",
        help="dome shape: Ward's hemi-ellipsoid or a hemisphere",
    )
    parser.add_argument("--radius", type=float, default=0.15, help="dome radius R, m")
    parser.add_argument(
        "--half-separation", type=float, default=0.01, help="D, half the lens-sample distance, m"
    )
    parser.add_argument(
        "--lens",
        default="equidistant",
        help="fisheye model: equidistant, equisolid, stereographic, orthographic, kannala_brandt",
    )
    size = int_in(2, MAX_SIDE, "pixels per side; memory grows with width x height")
    parser.add_argument(
        "--width", type=size, default=640, help=f"image width, pixels (2..{MAX_SIDE})"
    )
    parser.add_argument(
        "--height", type=size, default=480, help=f"image height, pixels (2..{MAX_SIDE})"
    )
    parser.add_argument(
        "--exposure",
        type=float,
        default=0.01,
        help="exposure time, seconds; a glossy sample's highlight may saturate, see --bracket",
    )
    parser.add_argument(
        "--f-number", type=float, default=4.0, help="the lens's aperture, f-number N (f/N)"
    )
    parser.add_argument("--seed", type=int, default=None, help="noise seed (recorded)")
    parser.add_argument("--no-noise", action="store_true", help="noise-free image")
    parser.add_argument(
        "--binning",
        nargs="?",
        const=_BARE_BINNING,
        default=None,
        metavar="WxH",
        help="digitise the image to WxH pixels, at most --width x --height, as `gonio campaign "
        "--binning` (e.g. 108x80, Ward's; default none: full resolution)",
    )
    parser.add_argument(
        "--bracket",
        action="store_true",
        help="capture the f-stops that cover the dynamic range (one file per stop: OUT_fN.ext)",
    )
    parser.add_argument(
        "--out", required=True, type=output_file, help="image path (.png, .tif or .tiff)"
    )
    parser.add_argument(
        "--plot", metavar="PATH", type=output_file, help="false-colour PNG with the angle grid"
    )
    add_json_option(parser)


def _binning(text: str | None, width: int, height: int) -> tuple[int, int] | None:
    """``--binning`` as ``gonio campaign`` reads it ('108x80'; '0x0' or absent: none), bounded
    by the image; the bare flag of earlier versions still means 108x80, with a note."""
    import sys

    from gonio.cli.campaign import parse_binning

    if text == _BARE_BINNING:
        print("note: --binning takes WxH now; write --binning 108x80", file=sys.stderr)
        text = "108x80"
    b = parse_binning(text)
    if b is None or b == (0, 0):
        return None
    if not (1 <= b[0] <= width and 1 <= b[1] <= height):
        raise ValueError(
            f"--binning {text!r}: expected WxH between 1x1 and the image's {width}x{height} "
            "(0x0: none)"
        )
    return b


def _sample(args):
    from gonio import brdf, materials

    params = name_value_pairs(args.param, "--param")
    if args.sample == "standard":
        return "standard"
    if args.sample == "none":
        return None
    if args.model:
        return brdf.create(args.model, **params)
    name = args.material or "rolled_brass"
    return materials.get(name, **params) if params else name


def _angle_plot(img, meta, path) -> None:
    """False colour (log DN above black) with eq. 3's θ_r / φ_r grid, written atomically."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from gonio.io.atomic import atomic_write_bytes
    from gonio.simulator import FisheyeLens, eq3_reflection_angles

    lens = FisheyeLens.from_dict(meta["lens"])
    mir = meta["mirror"]
    uv = lens.pixel_grid()
    inside = lens.in_field(uv)
    d = lens.unproject(uv)
    tc = np.clip(np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2]), 0.0, math.pi / 2)
    pc = np.arctan2(d[..., 1], d[..., 0])
    tr, pr = eq3_reflection_angles(tc, pc, mir["radius"], mir["half_separation"], mir["type"])
    pr = np.angle(np.exp(1j * (pr - meta["sample_rotation"])))  # sample frame
    tr = np.where(inside, np.degrees(tr), np.nan)
    pr = np.degrees(pr)
    pr = np.where(inside & (tr > 3.0) & (np.abs(pr) < 165.0), pr, np.nan)  # no seam at ±180°
    black = meta["sensor"]["black_level_dn"]
    val = np.log10(np.maximum(img.astype(float) - black, 1.0))
    fig, ax = plt.subplots(figsize=(8, 8 * img.shape[0] / img.shape[1]), dpi=100)
    im = ax.imshow(np.where(inside, val, np.nan), cmap="inferno")
    cs = ax.contour(tr, levels=np.arange(10, 90, 10), colors="cyan", linewidths=0.6)
    ax.clabel(cs, fmt="%d°", fontsize=7)
    ax.contour(pr, levels=np.arange(-150, 180, 30), colors="white", linewidths=0.4, alpha=0.7)
    fig.colorbar(im, ax=ax, label="log10(DN - black level)", shrink=0.8)
    ax.set_title(
        f"θi={math.degrees(meta['theta_i']):.1f}°  φi={math.degrees(meta['phi_i']):.1f}°  "
        f"f/{meta['f_number']:g}  {meta['exposure_s'] * 1e3:g} ms  "
        f"grid: θr (cyan, 10°), φr (white, 30°)",
        fontsize=9,
    )
    ax.set_axis_off()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def run(args) -> int:
    import re
    from pathlib import Path

    import numpy as np

    from gonio.io.images import IMAGE_SUFFIXES, sidecar_path, write_image
    from gonio.simulator import LBLInstrument

    out = Path(args.out)
    if out.suffix.lower() not in IMAGE_SUFFIXES:
        raise ValueError(f"--out {args.out!r} must end in one of {', '.join(IMAGE_SUFFIXES)}")
    check_outputs({}, {"--out": out, "the side-car of --out": sidecar_path(out),
                       "--plot": args.plot, "--json": args.json})  # fmt: skip
    if args.bracket:  # its frames OUT_fN.ext (and side-cars), named once the stops are known
        stop = re.compile(rf"{re.escape(out.stem)}_f[0-9.]+{re.escape(out.suffix)}(\.json)?")
        for opt, p in (("--plot", args.plot), ("--json", args.json)):
            if (
                p
                and Path(p).resolve().parent == out.resolve().parent
                and stop.fullmatch(Path(p).name)
            ):
                raise ValueError(f"{opt} {p!r} is the name of one of --bracket's frames")
    if not (0.0 <= args.theta_i < 90.0):
        raise ValueError(f"--theta-i must be in [0, 90) degrees, got {args.theta_i}")
    inst = LBLInstrument(
        args.mirror, args.radius, args.half_separation, args.lens, args.width, args.height
    )
    sample = _sample(args)
    th, ph = math.radians(args.theta_i), math.radians(args.phi_i)
    binning = _binning(args.binning, args.width, args.height)
    kw = dict(exposure=args.exposure, noise=not args.no_noise, binning=binning)
    rng = args.seed
    if args.bracket:
        shots = inst.bracket(sample, th, ph, rng=rng, **kw)
        paths = [out.with_name(f"{out.stem}_f{m['f_number']:g}{out.suffix}") for _, m in shots]
    else:
        shots = [inst.capture(sample, th, ph, f_number=args.f_number, rng=rng, **kw)]
        paths = [out]
    rows, results = [], []
    for (img, meta), p in zip(shots, paths):
        write_image(p, img, meta)
        sat = int(np.sum(img >= meta["sensor"]["saturation_dn"]))
        stats = {
            "min": int(img.min()),
            "max": int(img.max()),
            "mean": float(img.mean()),
            "saturated_pixels": sat,
        }
        results.append({"image": str(p), "sidecar": str(sidecar_path(p)), "stats": stats})
        rows.append((str(p), f"f/{meta['f_number']:g}", stats["min"], stats["max"],
                     round(stats["mean"], 1), sat))  # fmt: skip
    print(format_table(("image", "stop", "min", "max", "mean", "saturated"), rows))
    if args.plot:
        img, meta = shots[-1] if not args.bracket else shots[0]
        _angle_plot(img, meta, args.plot)
        print(f"plot: {args.plot}")
    if args.json:
        write_json(
            args.json,
            {
                "images": results,
                "metadata": [m for _, m in shots],
                "plot": args.plot,
            },
        )
    return 0
