"""Mitsuba 3's measured BSDF files from gonio: accuracy of Mitsuba's own ``eval``, measured.

Usage::

    python benchmarks/bench_mitsuba.py                    # fits: 3 materials x grids 32,64,128
        [--pairs 10000] [--grids 32,64,128] [--materials clay_vase,...]
        [--samples DIR/samples.csv --truth PRESET]...     # exported measured samples
        [--render OUT.png] [--json out.json]

Fits: each material preset's model tabulated by :func:`gonio.io.mitsuba.model_table` at each
grid (``--theta-i``, ``--phi-i`` at their defaults), written, loaded by Mitsuba's
``measured`` plugin (``scalar_rgb``; a spectral preset in ``scalar_spectral`` at 400, 500,
600, 700 nm) and its ``eval`` (f_r cos θo) compared with the model's at ``--pairs`` random
direction pairs (uniform over the hemisphere, both directions), at the specular peaks (1000
mirror pairs, θi in [0, 80°], random φi) and near them (1000 pairs whose half vector is
tilted from the normal by atan(α sqrt(-ln u)), Ward's lobe). Printed per material and grid:
the median, 95th percentile and worst relative error, the worst with θi, θo <= 80°, the file
size and the tabulation time. Samples (``--samples``, repeatable with ``--truth``): the
table interpolated from measured samples by :func:`gonio.io.mitsuba.samples_table`, its
coverage, and Mitsuba's eval against the truth preset at the random pairs inside the
measured incidence range (θo <= 80°), beside the samples' own deviation from the truth (the
noise floor). ``--render``: a sphere of the rolled-brass fit under a point light and a
constant environment (``scalar_rgb``, 256 x 256, 64 spp).

Nothing is asserted; the numbers are printed for the notes. Relative errors are per channel,
over the pairs where the truth is above 0, and (printed beside) where it exceeds 1e-3 of its
largest value: the Cornell garnet red paint has no diffuse floor (f_r = 0 far from its
lobe), and at the horizon every f_r cos θo goes to 0, where a relative error has no scale.
The samples' errors count pairs above 1e-3 of the largest value.

Measured (10,000 random pairs, the default --theta-i 16 and --phi-i 9; the machine shared;
median / worst with θi, θo <= 80° at random pairs; worst at the 1000 mirror pairs; median /
worst near the peaks)::

    material (model)            grid  file     random          peak      near peak
    clay_vase (oren_nayar)        32   0.3 MB  0.73 / 15.8 %    2.8 %    0.16 / 10.4 %
                                  64   1.3 MB  0.28 / 13.4 %    2.8 %    0.14 / 6.1 %
                                 128   5.4 MB  0.18 / 13.2 %    2.8 %    0.13 / 5.5 %
    white_ceramic_tile (ward)     32   0.3 MB  0.65 / 5.7 %     0.03 %   0.56 / 38.8 %
                                  64   1.3 MB  0.23 / 1.8 %     0.03 %   0.15 / 23.2 %
                                 128   5.4 MB  0.13 / 1.1 %     0.03 %   0.05 / 22.8 %
    rolled_brass (ward, aniso.)   32   3.0 MB  1.05 / 73.8 %    0.006 %  2.06 / 67.6 %
                                  64  11.8 MB  0.59 / 15.9 %    0.003 %  0.54 / 13.9 %
                                 128  47.3 MB  0.46 / 5.2 %     0.002 %  0.14 / 14.6 %
    garnet_red_paint (31 bands,   32   2.2 MB  1.01 / -         17.9 %   0.29 / 28.9 %
      li_torrance; lit pairs)     64   8.7 MB  0.44 / -         17.9 %   0.18 / 29.7 %
                                 128  34.7 MB  0.28 / -         17.9 %   0.20 / 43.9 %

The worst at all random pairs is at the horizon (cos θo -> 0, where f_r cos θo -> 0 and the
grid's bilinear interpolation keeps a finite value): 1.8e4 to 1.8e5 %. Samples (grid 64):
the default LBL campaign's (rolled brass, 173,406 samples, θi 0-80° by 4°, φi 0/45/90°):
coverage 93.9 %, median 4.71 % (the samples themselves 1.57 %; the truth at the same
geometries 4.44 %: the measurement's geometry, not its noise, sets it); the ideal preset's:
98.6 %, 5.14 % (0.85 %; 4.75 %); the default Cornell campaign's (an incidence-plane plan):
3.9 % coverage and 103 % median over the hemisphere (a plane cannot fill it). Render: 11 s;
a Lambertian file against Mitsuba's diffuse: 0.9989.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gonio import materials
from gonio.geometry import sample_uniform_hemisphere, to_vector
from gonio.io import mitsuba as gm

BANDS = [400.0, 500.0, 600.0, 700.0]


def mi_eval(path: Path, wi: np.ndarray, wo: np.ndarray, spectral: bool) -> np.ndarray:
    """Mitsuba's eval of a measured file, (N, 3) rgb or (N, 4) at BANDS."""
    import mitsuba as mi

    mi.set_variant("scalar_spectral" if spectral else "scalar_rgb")
    b = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    nc = 4 if spectral else 3
    if spectral:
        si.wavelengths = mi.Spectrum(*BANDS)
    out = np.empty((len(wi), nc))
    for k in range(len(wi)):
        si.wi = mi.Vector3f(*wi[k])
        v = b.eval(ctx, si, mi.Vector3f(*wo[k]))
        out[k] = [v[j] for j in range(nc)]
    return out


def truth_cos(model, wi, wo, spectral: bool) -> np.ndarray:
    f = np.asarray(model(wi, wo))
    if spectral:
        idx = [list(model.wavelengths_nm).index(b) for b in BANDS]
        return f[:, idx] * wo[:, 2:3]
    return np.repeat((f * wo[:, 2])[:, None], 3, axis=1)


def rel_error(got, truth, floor: float = 0.0) -> np.ndarray:
    """Per-channel relative error where the truth exceeds ``floor`` times its largest value."""
    lit = truth > floor * truth.max(axis=0)
    return np.where(lit, np.abs(got - truth) / np.where(lit, truth, 1.0), np.nan)


def stats(r: np.ndarray) -> dict:
    r = r[np.isfinite(r)]
    return {
        "median": float(np.median(r)),
        "p95": float(np.percentile(r, 95)),
        "worst": float(r.max()),
        "n": int(r.size),
    }


def direction_sets(n: int, alpha: float, rng) -> dict:
    wi, wo = sample_uniform_hemisphere(n, rng)[0], sample_uniform_hemisphere(n, rng)[0]
    pi = to_vector(np.radians(rng.uniform(0, 80, 1000)), rng.uniform(-np.pi, np.pi, 1000))
    peaks = (pi, pi * [-1.0, -1.0, 1.0])
    # near the peak: half vector tilted by Ward's lobe, wo its reflection
    wi2 = to_vector(np.radians(rng.uniform(0, 75, 1000)), rng.uniform(-np.pi, np.pi, 1000))
    th = np.arctan(alpha * np.sqrt(-np.log(1 - rng.random(1000))))
    m = to_vector(th, rng.uniform(-np.pi, np.pi, 1000))
    wo2 = 2 * np.sum(wi2 * m, -1, keepdims=True) * m - wi2
    up = wo2[:, 2] > 0.02
    return {"random": (wi, wo), "peak": peaks, "near_peak": (wi2[up], wo2[up])}


def bench_fits(args, tmp: Path) -> list[dict]:
    rows = []
    rng = np.random.default_rng(args.seed)
    for name in args.materials.split(","):
        model = materials.get(name)
        spectral = model.wavelengths_nm is not None
        alpha = float(
            np.mean(
                [
                    np.mean(model.params[k])
                    for k in ("alpha_x", "alpha_y", "alpha", "sigma_slope")
                    if k in model.params
                ]
                or [0.1]
            )
        )
        sets = direction_sets(args.pairs, alpha, rng)
        iso = gm.is_isotropic(model)
        for grid in (int(g) for g in args.grids.split(",")):
            t0 = time.perf_counter()
            fields = gm.model_table(model, grid, n_phi_i=None if iso else gm.DEFAULT_PHI_I)
            dt = time.perf_counter() - t0
            path = gm.write_bsdf(tmp / f"{name}_{grid}.bsdf", fields)
            row = {
                "material": name,
                "model": model.name,
                "grid": grid,
                "shape": list(fields["spectra" if spectral else "rgb"].shape),
                "bytes": path.stat().st_size,
                "tabulate_s": round(dt, 3),
            }
            for key, (wi, wo) in sets.items():
                got = mi_eval(path, wi, wo, spectral)
                truth = truth_cos(model, wi, wo, spectral)
                r = rel_error(got, truth)
                row[key] = stats(r)
                if key == "random":
                    inside = (wi[:, 2] >= np.cos(np.radians(80))) & (
                        wo[:, 2] >= np.cos(np.radians(80))
                    )
                    row["random_le80"] = stats(r[inside])
                    row["random_lit"] = stats(rel_error(got, truth, 1e-3))
            rows.append(row)
            print(
                f"{name:24s} grid {grid:3d} {row['shape']} {row['bytes'] / 1e6:6.1f} MB "
                f"{dt:5.1f} s | random median {100 * row['random']['median']:.2f} % p95 "
                f"{100 * row['random']['p95']:.1f} % worst {100 * row['random']['worst']:.3g} % "
                f"(<=80 deg: {100 * row['random_le80']['worst']:.3g} %, truth > 1e-3 max: "
                f"median {100 * row['random_lit']['median']:.2f} % worst "
                f"{100 * row['random_lit']['worst']:.3g} %) | peak median "
                f"{100 * row['peak']['median']:.3f} % worst {100 * row['peak']['worst']:.3f} % | "
                f"near peak median {100 * row['near_peak']['median']:.2f} % worst "
                f"{100 * row['near_peak']['worst']:.1f} %",
                flush=True,
            )
    return rows


def bench_samples(args, tmp: Path) -> list[dict]:
    from gonio.io.samples_table import read_samples

    rows = []
    rng = np.random.default_rng(args.seed + 1)
    for src, truth_name in zip(args.samples, args.truth):
        s = read_samples(src)
        model = materials.get(truth_name)
        t0 = time.perf_counter()
        fields = gm.samples_table(s, args.samples_grid)
        dt = time.perf_counter() - t0
        path = gm.write_bsdf(tmp / "samples.bsdf", fields)
        # the truth at the measured geometries: the same export without the measurement's
        # errors, so what is left is the geometry's (slices, sample spacing) and the grid's
        exact = _truth_at(s, model)
        path0 = gm.write_bsdf(tmp / "exact.bsdf", gm.samples_table(exact, args.samples_grid))
        meta = gm.coverage_summary(fields)
        kind = meta["channels"]
        spectral = kind == "spectral"
        tab = gm.read_bsdf(path)
        wi, wo = (
            sample_uniform_hemisphere(args.pairs, rng)[0],
            sample_uniform_hemisphere(args.pairs, rng)[0],
        )
        ti = np.arccos(np.clip(wi[:, 2], -1, 1))
        keep = (ti >= tab.theta_i.min() - 1e-9) & (ti <= tab.theta_i.max() + 1e-9)
        keep &= wo[:, 2] >= np.cos(np.radians(80))
        wi, wo = wi[keep], wo[keep]
        got = mi_eval(path, wi, wo, spectral)
        truth = truth_cos(model, wi, wo, spectral)
        r = rel_error(got, truth, 1e-3)
        r0 = rel_error(mi_eval(path0, wi, wo, spectral), truth, 1e-3)
        # the samples' own deviation from the truth (the noise floor)
        tv = exact.value
        lit = tv > 1e-3 * tv.max()
        own = np.abs(s.value[lit] - tv[lit]) / tv[lit]
        row = {
            "samples": str(src),
            "truth": truth_name,
            "n_samples": len(s),
            "shape": list(tab.shape),
            "bytes": path.stat().st_size,
            "tabulate_s": round(dt, 2),
            "coverage": meta["coverage"],
            "symmetry_reduction": meta.get("symmetry_reduction"),
            "theta_i_deg": [
                float(np.degrees(tab.theta_i.min())),
                float(np.degrees(tab.theta_i.max())),
            ],
            "mitsuba_vs_truth": stats(r),
            "truth_at_measured_geometry_vs_truth": stats(r0),
            "samples_vs_truth_median": float(np.median(own)),
        }
        rows.append(row)
        print(
            f"samples {src} ({len(s)}, truth {truth_name}): table {row['shape']} "
            f"{row['bytes'] / 1e6:.1f} MB in {dt:.1f} s, coverage {100 * meta['coverage']:.1f} %; "
            f"Mitsuba vs truth at {r.shape[0]} pairs (θi in the measured range, θo <= 80): "
            f"median {100 * row['mitsuba_vs_truth']['median']:.2f} % p95 "
            f"{100 * row['mitsuba_vs_truth']['p95']:.1f} % worst "
            f"{100 * row['mitsuba_vs_truth']['worst']:.3g} %; the samples themselves vs truth: "
            f"median {100 * row['samples_vs_truth_median']:.2f} %; the truth at the measured "
            f"geometries exported the same way: median "
            f"{100 * row['truth_at_measured_geometry_vs_truth']['median']:.2f} % p95 "
            f"{100 * row['truth_at_measured_geometry_vs_truth']['p95']:.1f} %",
            flush=True,
        )
    return rows


def _truth_at(s, model):
    """``s`` with its values replaced by the truth's (the same geometries and bands)."""
    from gonio.samples import BRDFSamples

    tv = np.asarray(model(s.wi, s.wo))
    if s.wavelength_nm is not None:
        wl = list(model.wavelengths_nm)
        tv = tv[np.arange(len(s)), [wl.index(w) for w in s.wavelength_nm]]
    cols = (s.theta_i, s.phi_i, s.theta_o, s.phi_o)
    return BRDFSamples(*cols, tv, s.sigma, s.wavelength_nm, dict(s.metadata))


def render(out: Path, tmp: Path) -> dict:
    """The rolled-brass fit on a sphere; and a Lambertian file against Mitsuba's ``diffuse``.

    The second pair checks the file's sampling (its luminance table and the plugin's pdf)
    end to end: the same scene rendered with gonio's tabulated Lambertian (ρ = 0.5) and with
    Mitsuba's own ``diffuse`` BSDF must agree to the Monte Carlo noise.
    """
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    m = materials.get("rolled_brass")
    path = gm.write_bsdf(tmp / "render.bsdf", gm.model_table(m, n_phi_i=gm.DEFAULT_PHI_I))
    t0 = time.perf_counter()
    img = _render(mi, {"type": "measured", "filename": str(path)})
    dt = time.perf_counter() - t0
    mi.util.write_bitmap(str(out), img)
    print(
        f"render: {out} ({img.shape}, {dt:.1f} s), mean {img.mean():.4f}, max {img.max():.3f}, "
        f"non-finite {int((~np.isfinite(img)).sum())}",
        flush=True,
    )
    from gonio import brdf

    lam = gm.write_bsdf(tmp / "lambert.bsdf", gm.model_table(brdf.create("lambert", rho=0.5)))
    a = _render(mi, {"type": "measured", "filename": str(lam)})
    b = _render(mi, {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}})
    sphere = np.abs(a - b).sum(axis=-1) > 0  # (the background is the same in both)
    ratio = float(a[sphere].mean() / b[sphere].mean())
    print(
        f"render: Lambertian rho 0.5 as a measured file / Mitsuba's diffuse 0.5, mean over "
        f"the sphere's pixels: {ratio:.4f}",
        flush=True,
    )
    return {"png": str(out), "seconds": round(dt, 1), "mean": float(img.mean()), "ratio": ratio}


def _render(mi, bsdf: dict) -> np.ndarray:
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 3},
            "sensor": {
                "type": "perspective",
                "fov": 30,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, -4.5, 1.5], target=[0, 0, 0], up=[0, 0, 1]
                ),
                "film": {"type": "hdrfilm", "width": 256, "height": 256},
                "sampler": {"type": "independent", "sample_count": 64},
            },
            "sphere": {"type": "sphere", "bsdf": bsdf},
            "light": {
                "type": "point",
                "position": [3, -3, 4],
                "intensity": {"type": "rgb", "value": 60},
            },
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.15}},
        }
    )
    return np.array(mi.render(scene))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=10000)
    p.add_argument("--grids", default="32,64,128")
    p.add_argument("--materials", default="clay_vase,white_ceramic_tile,rolled_brass")
    p.add_argument("--samples", action="append", default=[], help="samples table")
    p.add_argument("--truth", action="append", default=[], help="its truth preset")
    p.add_argument("--samples-grid", type=int, default=gm.DEFAULT_RESOLUTION)
    p.add_argument("--render", type=Path)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if len(args.samples) != len(args.truth):
        p.error("give one --truth per --samples")
    report: dict = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.materials:
            report["fits"] = bench_fits(args, tmp)
        if args.samples:
            report["samples"] = bench_samples(args, tmp)
        if args.render:
            report["render"] = render(args.render, tmp)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
