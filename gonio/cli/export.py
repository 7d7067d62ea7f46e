"""``gonio export``: samples and fits to Radiance (PAB-Opto files, BSDF XML, materials).

* ``gonio export pabopto SAMPLES OUT`` — one PAB-Opto file per incident direction
  (:func:`gonio.io.pabopto.write_pabopto`);
* ``gonio export bsdf SAMPLES OUT`` — those files through pabopto2bsdf and bsdf2klems or
  bsdf2ttree, checked by checkBSDF (:func:`gonio.io.pabopto.build_bsdf`);
* ``gonio export material OUT --fit fit.json`` (or ``--model NAME --param k=v``) — the
  ``material.rad`` (+ ``.cal``) that renders the fitted model exactly
  (:func:`gonio.io.radiance.model_material`), optionally ``--bsdf klems|ttree`` built from
  its ``.cal`` (:func:`gonio.io.pabopto.build_model_bsdf`).

* ``gonio export mitsuba SAMPLES OUT.bsdf`` — the samples interpolated onto Mitsuba 3's
  measured BSDF grid, their coverage printed; ``gonio export mitsuba --fit fit.json OUT.bsdf``
  (or ``--model``) — the model tabulated on it (:mod:`gonio.io.mitsuba`).

The BSDF builds need Radiance's programs: ``pip install 'gonio[radiance]'``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gonio.cli._common import (
    add_json_option,
    check_outputs,
    name_value_pairs,
    worker_count,
    write_json,
)

COMMAND = "export"
HELP = (
    "export samples or a fit to Radiance (PAB-Opto files, BSDF XML, material.rad) "
    "or to Mitsuba 3 (measured .bsdf)"
)


def _vector(text: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--up {text!r}: expected three numbers x,y,z") from None
    if len(v) != 3:
        raise ValueError(f"--up {text!r}: expected three numbers x,y,z")
    return v  # type: ignore[return-value]


def add_arguments(parser) -> None:
    parser.usage = (
        "gonio export pabopto|bsdf|mitsuba SAMPLES OUT [options]\n"
        "       gonio export material OUT (--fit fit.json | --model M [--param P=V]) [options]\n"
        "       gonio export mitsuba OUT.bsdf (--fit fit.json | --model M [--param P=V]) [options]"
    )
    parser.add_argument(
        "what", choices=["pabopto", "bsdf", "material", "mitsuba"], help="what to write"
    )
    parser.add_argument(
        "source",
        metavar="SAMPLES|OUT",
        help="pabopto, bsdf, mitsuba: the samples table to export (.csv/.npz/.astm); material: "
        "the output folder to write material.rad into; mitsuba --fit/--model: OUT.bsdf",
    )
    parser.add_argument(
        "out", metavar="OUT", nargs="?", help="pabopto, bsdf: the output folder; mitsuba: OUT.bsdf"
    )
    parser.add_argument("--name", default="gonio", help="sample / material name (default gonio)")
    parser.add_argument(
        "--negative",
        default="error",
        choices=["error", "clip", "drop"],
        help="values below 0: refuse (default), clip to 0 or drop",
    )
    parser.add_argument(
        "--cells",
        type=int,
        default=None,
        help="average each incident direction's samples in NxN equal-solid-angle cells "
        "(power of two 8..256; 0 = every sample), bounding pabopto2bsdf's and bsdf2ttree's "
        "time (default 16)",
    )
    parser.add_argument(
        "--spread",
        type=float,
        default=None,
        help="split a cell whose values differ by more than this factor (keeps the peak's "
        "points; 0 = never split; default 2)",
    )
    parser.add_argument("--max-lobes", type=int, default=None, help="bsdf2ttree -l (default 15000)")
    parser.add_argument(
        "--kind",
        default="klems",
        choices=["klems", "ttree"],
        help="BSDF form: Klems basis (bsdf2klems) or tensor tree (bsdf2ttree)",
    )
    parser.add_argument(
        "--samples-per-patch",
        type=int,
        default=None,
        help="bsdf2klems -n (default 128 for samples, whose interpolation error dominates "
        "from there; 1024 for a fit's .cal)",
    )
    parser.add_argument(
        "--resolution", type=int, default=6, help="tensor-tree resolution, bsdf2ttree -g (4..7)"
    )
    parser.add_argument("--reciprocity", action="store_true", help="bsdf2ttree +a")
    parser.add_argument(
        "--symmetry",
        choices=["isotropic", "quadrilateral", "bilateral", "up", "anisotropic"],
        help="pabopto2bsdf -s (default: inferred from the incident azimuths)",
    )
    parser.add_argument("--up", default="0,1,0", help="the sample's y axis in the scene (x,y,z)")
    parser.add_argument(
        "--nproc", type=worker_count, default=None,
        help="processes of pabopto2bsdf (-n; default: every processor; at most 4 per CPU)",
    )  # fmt: skip
    parser.add_argument("--fit", help="fit.json (material): its model and parameters")
    parser.add_argument("--model", help="model name (material, instead of --fit)")
    parser.add_argument(
        "--param", action="append", default=[], metavar="NAME=VALUE", help="model parameter"
    )
    parser.add_argument(
        "--class",
        dest="material_class",
        default="dielectric",
        help="sample class: metal (metal2) or dielectric (plastic2); default dielectric",
    )
    parser.add_argument(
        "--bsdf", choices=["klems", "ttree"], help="material: also build the model's BSDF XML"
    )
    from gonio.io import mitsuba

    parser.add_argument(
        "--grid",
        type=int,
        default=mitsuba.DEFAULT_RESOLUTION,
        help=f"mitsuba: half-vector grid NxN (default {mitsuba.DEFAULT_RESOLUTION})",
    )
    parser.add_argument(
        "--theta-i",
        type=int,
        default=mitsuba.DEFAULT_THETA_I,
        help=f"mitsuba --fit: incident elevations (default {mitsuba.DEFAULT_THETA_I})",
    )
    parser.add_argument(
        "--phi-i",
        type=int,
        default=mitsuba.DEFAULT_PHI_I,
        help=f"mitsuba --fit, anisotropic model: incident azimuths (default "
        f"{mitsuba.DEFAULT_PHI_I})",
    )
    parser.add_argument(
        "--channels",
        choices=["grey", "rgb", "spectral"],
        help="mitsuba: file channels (default grey or spectral, as the source)",
    )
    add_json_option(parser)


def _mitsuba(args, report: dict) -> None:
    from gonio.io import mitsuba

    if args.fit is not None or args.model is not None:
        out = args.out or args.source
        if args.out is not None and args.source != args.out:
            raise ValueError("mitsuba --fit: give only OUT.bsdf")
        model = _model(args)
        iso = mitsuba.is_isotropic(model)
        fields = mitsuba.model_table(
            model, args.grid, args.theta_i, None if iso else args.phi_i, args.channels
        )
    else:
        from gonio.io.samples_table import read_samples

        if args.out is None:
            raise ValueError("mitsuba: give OUT.bsdf after the samples table")
        out = args.out
        fields = mitsuba.samples_table(read_samples(args.source), args.grid, args.channels)
    path = mitsuba.write_bsdf(out, fields)
    meta = mitsuba.coverage_summary(fields)
    shape = fields["rgb" if "rgb" in fields else "spectra"].shape
    line = f"{meta['channels']} measured BSDF {path} ({path.stat().st_size} bytes, table {shape})"
    if "coverage" in meta:
        line += f"; samples cover {100 * meta['coverage']:.1f} % of the grid above the horizon"
        if meta.get("isotropic_assumed"):
            line += " (isotropic assumed: the incident directions are not on a θi × φi grid)"
    print(line)
    report.update(file=str(path), bytes=path.stat().st_size, shape=list(shape), **meta)


def _unflatten(params: dict) -> dict:
    """A fit's per-band entries ``name[k]`` (fit.json of a spectral fit) as arrays."""
    out: dict = {}
    bands: dict[str, dict[int, float]] = {}
    for k, v in params.items():
        base, sep, idx = k.partition("[")
        if sep and idx.endswith("]") and idx[:-1].isdigit():
            bands.setdefault(base, {})[int(idx[:-1])] = v
        else:
            out[k] = v
    for base, d in bands.items():
        out[base] = [d[i] for i in sorted(d)]
    return out


def _model(args):
    from gonio import brdf

    if (args.fit is None) == (args.model is None):
        raise ValueError("material: give either --fit fit.json or --model NAME")
    if args.fit is not None:
        from gonio.io.jsonfile import get, get_mapping, read_document

        src = f"--fit {args.fit!r}"
        d = read_document(args.fit, what="a fit.json")
        name = get(d, "model", src, str)
        params = _unflatten(dict(get_mapping(d, "params", src, default={})))
        if not isinstance(name, str) or "+" in name:
            raise ValueError(
                f"--fit {args.fit}: model {name!r}; sums and lobe models are exported "
                "through the Python API (gonio.io.radiance.model_material)"
            )
    else:
        name, params = args.model, {}
    params.update(name_value_pairs(args.param, "--param"))  # (over those of --fit)
    return brdf.create(name, **params)


def run(args) -> int:
    try:
        return _run(args)
    except (FileNotFoundError, RuntimeError) as exc:  # Radiance missing, or a tool failed
        raise ValueError(str(exc)) from None


def _run(args) -> int:
    from gonio.io import pabopto

    up = _vector(args.up)
    if args.what == "material":
        inputs, outputs = {"--fit": args.fit}, {"the output folder": args.source}
    elif args.what == "mitsuba" and (args.fit is not None or args.model is not None):
        inputs, outputs = {"--fit": args.fit}, {"the output file": args.source}
    elif args.what == "mitsuba":
        inputs, outputs = {"the samples table": args.source}, {"the output file": args.out}
    else:
        inputs, outputs = {"the samples table": args.source}, {"the output folder": args.out}
    check_outputs(inputs, {**outputs, "--json": args.json})
    report: dict = {"what": args.what}
    if args.what == "mitsuba":
        _mitsuba(args, report)
    elif args.what == "material":
        from gonio.io import radiance

        out = Path(args.source)
        out.mkdir(parents=True, exist_ok=True)
        model = _model(args)
        mat = radiance.model_material(model, args.material_class, name=args.name)
        paths = radiance.write_material_files(out, mat)
        print(f"{mat.kind} {mat.name}: " + ", ".join(str(p) for p in paths))
        report.update(kind=mat.kind, files=[str(p) for p in paths])
        if args.bsdf:
            spp = 1024 if args.samples_per_patch is None else args.samples_per_patch
            b = pabopto.build_model_bsdf(model, out, args.name, args.bsdf, spp, args.resolution, up)
            _print_build(b)
            report["bsdf"] = b.to_dict()
    else:
        from gonio.io.samples_table import read_samples

        if args.out is None:
            raise ValueError(f"{args.what}: give the output folder after the samples table")
        samples = read_samples(args.source)
        cells = pabopto.DEFAULT_CELLS if args.cells is None else (args.cells or None)
        spread = pabopto.DEFAULT_SPREAD if args.spread is None else (args.spread or None)
        if args.what == "pabopto":
            paths = pabopto.write_pabopto(
                samples, args.out, args.name, args.negative, cells, spread
            )
            sym = pabopto.pabopto_symmetry([(t, p) for t, p, _ in pabopto.incidences(samples)])
            print(f"{len(paths)} PAB-Opto files in {args.out} ({pabopto.SYMMETRIES[sym]})")
            report.update(files=[str(p) for p in paths], symmetry=pabopto.SYMMETRIES[sym])
        else:
            b = pabopto.build_bsdf(
                samples,
                args.out,
                args.name,
                kind=args.kind,
                samples_per_patch=(
                    pabopto.DEFAULT_SAMPLES_PER_PATCH
                    if args.samples_per_patch is None
                    else args.samples_per_patch
                ),
                resolution=args.resolution,
                reciprocity=args.reciprocity,
                symmetry=args.symmetry,
                up=up,
                negative=args.negative,
                nproc=args.nproc,
                cells=cells,
                spread=spread,
                max_lobes=(pabopto.DEFAULT_MAX_LOBES if args.max_lobes is None else args.max_lobes),
                progress=_progress,
            )
            _print_build(b)
            report["bsdf"] = b.to_dict()
    if args.json:
        write_json(args.json, report)
    return 0


def _progress(line: str) -> None:
    """A BSDF build's progress, on stderr (stdout keeps the result)."""
    print(line, file=sys.stderr, flush=True)


def _print_build(b) -> None:
    refl = b.components.get("Interior Refl", {})
    times = ", ".join(
        f"{k} {v:.1f} s (cpu {b.seconds.get(k + '_cpu', float('nan')):.1f} s)"
        for k, v in b.seconds.items()
        if not k.endswith("_cpu")
    )
    print(
        f"{b.kind} BSDF ({b.symmetry}) {b.xml}; primitive {b.rad}; checkBSDF: Lambertian "
        f"{refl.get('lambertian', [float('nan')])[0]:.3f}, max directional reflectance "
        f"{refl.get('max_total', float('nan')):.3f}; {times}"
    )
