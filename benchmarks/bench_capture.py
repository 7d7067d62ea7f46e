"""Capture timings of the simulated LBL gonioreflectometer and what each skip saves.

Run: ``python benchmarks/bench_capture.py [--repeat 30] [--json out.json] [--quick]``

One thread (numba, BLAS and OpenMP limited to 1 before import). Reports, for 640 × 480 and
1024 × 1024 with a Ward BRDF (``rolled_brass``): the one-time geometry trace, ms per capture
with the geometry cached (noise off / on), the time to merely copy the output pixels (uint16)
and a float64 image IN THE SAME RUN and the ratios capture / copy (issue 8: "one 1024 × 1024
capture with cached geometry <= 3x the copy time of its pixel data"), and for every skip the
time with and without it and whether the image is unchanged. Then:

* the capture stage of the default ``gonio campaign`` (21 θi × {standard, background, 2
  rotations} = 84 brackets, 120 frames at 640 × 480), noise on and off, wall and CPU time;
* one bracket rendered once and composed per stop vs plan + a separate capture per stop
  (the pre-fast-bracket way), and that the frames are identical;
* the sensor effects: ms per capture with each effect of ``Sensor`` alone at its realistic
  magnitude and all of them, as ratios to the ideal sensor;
* the noise: time of the compiled draw vs numpy's exact Poisson + normal on a 640 × 480
  image (and the noise + ADC kernel alone, and the compiled normal generator against numba's
  ``Generator.standard_normal``), and the mean, variance and skewness of both draws against
  Poisson(λ) + N(0, σ²).

``--quick`` leaves out the per-skip timings.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402

from gonio.io.atomic import atomic_write_bytes  # noqa: E402

TH = math.radians(30)


def _time(fn, repeat):
    """(median wall ms, min wall ms, median CPU ms). One thread, so CPU time is this
    process's own cost even when the machine is shared; wall time includes waiting."""
    fn()  # warm (JIT, caches)
    ts, cs = [], []
    for _ in range(max(1, repeat)):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return float(np.median(ts)) * 1e3, float(np.min(ts)) * 1e3, float(np.median(cs)) * 1e3


def _fresh(size, **kw):
    from gonio.simulator import LBLInstrument
    from gonio.simulator.lbl import _GEOMETRY_CACHE

    _GEOMETRY_CACHE.clear()
    return LBLInstrument(width=size[0], height=size[1], **kw)


def bench_size(size, repeat, model, skips=True):
    out = {"size": f"{size[0]}x{size[1]}"}
    # one-time geometry
    geo = []
    for _ in range(3):
        inst = _fresh(size)
        t0 = time.process_time()
        g = inst.geometry
        geo.append(time.process_time() - t0)
    out["geometry_ms"] = min(geo) * 1e3  # CPU time
    out["candidate_pixels"] = int(g.idx.size)
    out["pixels"] = size[0] * size[1]
    inst.capture(model, TH, noise=False)
    phis = iter(np.linspace(0, 2 * math.pi, 100000))
    out["capture_noise_off_ms"] = _time(
        lambda: inst.capture(model, TH, next(phis), noise=False), repeat
    )
    out["capture_noise_on_ms"] = _time(
        lambda: inst.capture(model, TH, next(phis), rng=1), max(3, repeat // 5)
    )
    img, _ = inst.capture(model, TH, noise=False)
    f64 = np.zeros(img.shape)
    out["copy_uint16_ms"] = _time(lambda: img.copy(), repeat)
    out["copy_float64_ms"] = _time(lambda: f64.copy(), repeat)
    # lower bounds of any capture, in the same run: numpy's SIMD exp over the pixels that see
    # the sample (Ward's one transcendental per pixel) and one standard normal per pixel
    # from the capture's own generator (noise on)
    from gonio.simulator import _kernels

    lit = np.random.default_rng(0).uniform(-30.0, 0.0, g.idx.size)
    buf = np.empty_like(lit)
    out["exp_lit_pixels_ms"] = _time(lambda: np.exp(lit, out=buf), repeat)
    z = np.empty(out["pixels"])
    state = _kernels.seed_state(np.random.default_rng(0))
    out["normals_all_pixels_ms"] = _time(lambda: _kernels.standard_normals(state, z), repeat)
    for k in ("exp_lit_pixels", "normals_all_pixels"):
        out[f"ratio_{k}_vs_copy_float64"] = out[f"{k}_ms"][2] / out["copy_float64_ms"][2]
    for k in ("off", "on"):  # CPU medians
        cap = out[f"capture_noise_{k}_ms"][2]
        out[f"ratio_noise_{k}_vs_copy_uint16"] = cap / out["copy_uint16_ms"][2]
        out[f"ratio_noise_{k}_vs_copy_float64"] = cap / out["copy_float64_ms"][2]
    # the render alone (no metadata dict): scene + fused compose
    out["render_noise_off_ms"] = _time(
        lambda: inst._render("brdf", model, TH, 0.2, 0.01, 4.0, None, None, digitise=True),
        repeat,
    )

    out["skips"] = {}
    if not skips:
        return out
    skips = _skip_timings(inst, size, model, repeat)
    out["skips"] = {
        k: {"with_ms": v[0][2], "without_ms": v[1][2], "unchanged": v[2]} for k, v in skips.items()
    }  # fmt: skip  (CPU ms, medians)
    return out


def _skip_timings(inst, size, model, repeat):
    """Each skip rule's capture time with and without it (timings of :func:`_time`) and
    whether the image is unchanged."""
    from gonio.simulator import LBLInstrument
    from gonio.simulator.lbl import _GEOMETRY_CACHE

    skips = {}
    ref, _ = inst.capture(model, TH, noise=False)

    # 1. geometry cache
    def recompute():
        _GEOMETRY_CACHE.clear()
        i2 = LBLInstrument(width=size[0], height=size[1])
        return i2.capture(model, TH, noise=False)[0]

    no = _time(recompute, max(2, repeat // 10))
    same = np.array_equal(recompute(), ref)
    inst = LBLInstrument(width=size[0], height=size[1])  # re-cache
    inst.capture(model, TH, noise=False)
    yes = _time(lambda: inst.capture(model, TH, noise=False), repeat)
    skips["geometry cache"] = (yes, no, same)

    # 2. BRDF only on pixels that see the illuminated sample (generic numpy path both sides;
    #    "without" evaluates every pixel of the image and masks afterwards). Ellipsoid: the
    #    saving is the corners outside the image circle; hemisphere with a 2 mm spot on a
    #    12 mm sample: also the pixels seeing unlit sample.
    def render(ins=inst, **kw):
        return ins._render("brdf", model, TH, 0.3, 0.01, 4.0, None, None, digitise=True, **kw)

    from gonio.simulator import Source

    hemi = LBLInstrument(
        "hemisphere", 0.15, 0.02, width=size[0], height=size[1], sample_radius=0.012,
        source=Source(spot_radius=0.002),
    )  # fmt: skip
    for label, ins in (("ellipsoid", inst), ("hemisphere, 2 mm spot", hemi)):
        a = render(ins, kernel=False, visible_only=True)
        b = render(ins, kernel=False, visible_only=False)
        skips[f"BRDF on lit pixels only ({label})"] = (
            _time(lambda ins=ins: render(ins, kernel=False, visible_only=True), repeat // 2),
            _time(lambda ins=ins: render(ins, kernel=False, visible_only=False), repeat // 2),
            bool(np.array_equal(a, b)),
        )
    a = render(kernel=False)
    # 2b. specialised Ward kernel vs the generic evaluate_unchecked path
    c = render()
    skips["Ward kernel vs generic model path"] = (
        _time(render, repeat),
        _time(lambda: render(kernel=False), repeat),
        bool(np.array_equal(a, c)),
    )

    # 3. grey BRDF evaluated once for 3 colour filters
    x = inst.capture_bands(model, TH, noise=False)
    y = inst.capture_bands(model, TH, noise=False, evaluate_once=False)
    skips["grey BRDF once for 3 filters"] = (
        _time(lambda: inst.capture_bands(model, TH, noise=False), repeat // 2),
        _time(lambda: inst.capture_bands(model, TH, noise=False, evaluate_once=False), repeat // 2),
        all(np.array_equal(p[0], q[0]) for p, q in zip(x, y)),
    )

    # 4. noise skipped when off, vs drawing zero-amplitude noise (capture's own switch)
    skips["noise off: no random draws"] = (
        _time(lambda: inst.capture(model, TH, noise=False), repeat),
        _time(lambda: inst.capture(model, TH, noise=False, skip_noise_draws=False), repeat // 3),
        bool(np.array_equal(inst.capture(model, TH, noise=False, skip_noise_draws=False)[0], ref)),
    )

    # 5. source-cone average skipped when the lobe is >= 5x the beam divergence
    one = inst.capture(model, TH, noise=False, source_samples=1)[0]
    many = inst.capture(model, TH, noise=False, source_samples=19)[0]
    skips["source cone (1 vs 19 directions)"] = (
        _time(lambda: inst.capture(model, TH, noise=False, source_samples=1), repeat),
        _time(lambda: inst.capture(model, TH, noise=False, source_samples=19), repeat // 3),
        f"max |dDN| = {int(np.abs(one.astype(int) - many).max())}",
    )
    return skips


def bench_bracket(model_fn):
    from gonio.simulator import LBLInstrument

    inst = LBLInstrument(width=640, height=480)
    stops = (32, 22, 16, 11, 8, 5.6, 4, 2.8, 2, 1.4)
    plan = inst.plan_bracket(model_fn, TH, f_stops=stops)
    t0 = time.perf_counter()
    inst.bracket(model_fn, TH, f_stops=stops, noise=False)
    return {"ladder": list(stops), **plan, "bracket_ms": (time.perf_counter() - t0) * 1e3}


def bench_bracket_reuse(repeat):
    """One bracket from one render vs plan + one capture per stop; frames identical?"""
    from gonio.simulator import LBLInstrument

    from gonio import materials

    inst = LBLInstrument(width=640, height=480)
    brass = materials.get("rolled_brass")
    out = {}
    for label, smp in (("rolled_brass", brass), ("standard", "standard")):
        plan = inst.plan_bracket(smp, TH)

        def separate(smp=smp):
            p = inst.plan_bracket(smp, TH)
            return [inst.capture(smp, TH, f_number=n, noise=False)[0] for n in p["f_numbers"]]

        def once(smp=smp):
            return [img for img, _ in inst.bracket(smp, TH, noise=False)]

        same = all(np.array_equal(a, b) for a, b in zip(once(), separate()))
        out[label] = {
            "stops": plan["f_numbers"],
            "once_ms": _time(once, repeat)[2],
            "plan_plus_captures_ms": _time(separate, repeat)[2],
            "identical": same,
        }
    return out


def bench_campaign_stage(noise, repeat=3):
    """The default campaign's capture stage (the brackets ``gonio campaign`` takes)."""
    from gonio import campaign, materials

    plan = campaign.Plan(plots=False).resolved()
    inst = campaign.lbl._SimulatedLBL(plan).inst
    truth = materials.get(plan.material)

    def stage():
        n = 0
        for th in plan.theta_i_deg:
            ti = math.radians(th)
            s = campaign.capture_seed(plan.seed, campaign.folder.group_key(th))
            n += len(inst.bracket("standard", ti, 0.0, rng=s, noise=noise))
            n += len(inst.bracket(None, ti, 0.0, rng=s + 1, noise=noise))
            for rot in plan.rotations_deg:
                n += len(inst.bracket(truth, ti, math.radians(rot), rng=s, noise=noise))
        return n

    frames = stage()  # warm
    ts, cs = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        stage()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return {
        "noise": noise,
        "frames": frames,
        "brackets": len(plan.theta_i_deg) * (2 + len(plan.rotations_deg)),
        "wall_s_min": min(ts),
        "cpu_s_min": min(cs),
        "ms_per_frame_cpu": min(cs) / frames * 1e3,
    }


def bench_noise(repeat):
    """Compiled draw vs numpy's exact draw: time on 640x480 and moments vs the model."""
    from gonio.simulator import LBLInstrument, Sensor

    inst = LBLInstrument(width=640, height=480)
    e = inst.electrons("rolled_brass", TH, f_number=4.0)
    sen = inst.sensor
    rng = np.random.default_rng(0)
    from gonio.simulator import _kernels
    from numba import njit

    @njit(nogil=True)
    def numba_normals(gen, out):  # numba's Generator.standard_normal, the previous source
        for i in range(out.size):
            out[i] = gen.standard_normal()

    flat = e.ravel()
    z = np.empty(flat.size)
    img = np.empty(flat.size, dtype=np.uint16)
    st = _kernels.seed_state(rng)
    adc = sen.linear_adc
    out = {
        "threshold_e": sen.normal_threshold,
        "fast_ms": _time(lambda: sen.add_noise(e, rng), repeat)[2],
        "exact_ms": _time(lambda: sen.add_noise(e, rng, exact=True), max(3, repeat // 3))[2],
        "noise_u16_kernel_ms": _time(
            lambda: _kernels.noise_u16(flat, st, sen.normal_threshold, sen.read_noise, *adc, img),
            repeat,
        )[2],
        "normals_xoshiro_ms": _time(lambda: _kernels.standard_normals(st, z), repeat)[2],
        "normals_numba_generator_ms": _time(lambda: numba_normals(rng, z), repeat)[2],
        "moments": [],
    }
    n = 1_000_000
    for sigma in (8.0, 3.0):
        s = Sensor(read_noise=sigma)
        for lam in (0.2, 5.0, 20.0, 30.0, 100.0, 1000.0, 30000.0):
            v = lam + sigma**2
            row = {"read_noise": sigma, "lam": lam, "model_var": v, "model_skew": lam / v**1.5}
            for kind, exact in (("fast", False), ("exact", True)):
                x = s.add_noise(np.full(n, lam), np.random.default_rng(int(lam) + 1), exact=exact)
                d = x - x.mean()
                var = float((d * d).mean())
                row[f"{kind}_mean"] = float(x.mean())
                row[f"{kind}_var"] = var
                row[f"{kind}_skew"] = float((d**3).mean() / var**1.5)
            row["se_mean"] = math.sqrt(v / n)
            row["se_var"] = v * math.sqrt(2.0 / n)
            row["se_skew"] = math.sqrt(6.0 / n)
            out["moments"].append(row)
    return out


def bench_sensor_effects(repeat):
    """CPU ms per 640 x 480 rolled-brass capture (f/2: the specular peak saturates, so
    blooming has work), noise on and off, for the ideal sensor, each sensor effect alone at
    its realistic magnitude, and all of them (``Sensor.realistic()``); ratios to the ideal
    sensor in the same run, and whether the ideal sensor with a physical array of the image's
    shape gives the same image (an effect "on" at no magnitude costs nothing)."""
    from gonio.simulator import Sensor
    from gonio.simulator.sensor import REALISTIC

    from gonio import materials

    model = materials.get("rolled_brass")
    arr = {"array_shape": (480, 640)}
    cases = {"ideal": Sensor(), "ideal, array_shape set": Sensor(**arr)}
    groups = {
        "charge_clip": ("charge_clip",),
        "blooming": ("blooming",),
        "smear": ("smear",),
        "offsets (pixel, row, column)": ("offset_dsnu", "row_dsnu", "column_dsnu"),
        "hot pixels": ("hot_pixels", "hot_pixel_dark"),
    }
    for label, names in groups.items():
        cases[label] = Sensor(**arr, **{n: REALISTIC[n] for n in names})
    cases["realistic (all)"] = Sensor.realistic()
    # the cases interleaved (one call of each per round), so a change of the machine's load
    # affects them alike; CPU time of this process, median over the rounds
    fns, images = {}, {}
    for label, sen in cases.items():
        inst = _fresh((640, 480), sensor=sen)
        for noise in (False, True):
            fn = partial(inst.capture, model, TH, f_number=2.0, rng=1, noise=noise)
            fn()  # warm (JIT, caches)
            fns[label, "noise_on" if noise else "noise_off"] = fn
        images[label] = inst.capture(model, TH, f_number=2.0, rng=1)[0]
    cpu: dict = {key: [] for key in fns}
    for _ in range(max(1, repeat)):
        for key, fn in fns.items():
            c0 = time.process_time()
            fn()
            cpu[key].append(time.process_time() - c0)
    out = {label: {} for label in cases}
    for (label, k), ts in cpu.items():
        out[label][k] = float(np.median(ts)) * 1e3
    base = out["ideal"]
    for label, row in out.items():
        for k in ("noise_off", "noise_on"):
            row[f"{k}_ratio"] = row[k] / base[k]
        row["same_image_as_ideal"] = bool(np.array_equal(images[label], images["ideal"]))
    return out


def _tv_distance(lam, sigma, gain):
    """Exact total-variation distance between the DN histograms (DN = rint(e / gain)) of
    Poisson(lam) + N(0, sigma²) and of the skew-corrected normal the sensor draws."""
    from scipy import stats

    v = lam + sigma**2
    half = 12.0 * math.sqrt(v) + 20.0
    j = np.arange(math.floor((lam - half) / gain) - 1, math.ceil((lam + half) / gain) + 2)
    edges = (j - 0.5) * gain
    k = np.arange(0, int(lam + 12.0 * math.sqrt(lam) + 20.0))
    pk = stats.poisson.pmf(k, lam)
    if sigma > 0:
        exact = pk @ np.diff(stats.norm.cdf((edges[None, :] - k[:, None]) / sigma), axis=1)
    else:
        idx = np.clip(np.searchsorted(edges, k, side="right") - 1, 0, len(edges) - 2)
        exact = np.bincount(idx, weights=pk, minlength=len(edges) - 1)
    c = lam / (6.0 * v)
    s = math.sqrt(v - 2.0 * c * c)
    if c > 0:  # e = lam + s z + c (z² - 1) is increasing for z > -s / 2c: invert it
        disc = s * s + 4.0 * c * (edges - lam + c)
        z = np.where(disc >= 0, (-s + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * c), -np.inf)
    else:
        z = (edges - lam) / s
    approx = np.diff(stats.norm.cdf(z))
    return 0.5 * float(np.abs(exact - approx).sum())


def noise_tv_table():
    """Worst TV distance of the approximation, where the sensor uses it and at λ >= 30."""
    from gonio.simulator import Sensor

    lams = (0.05, 0.2, 0.5, 1, 2, 3, 5, 10, 20, 30, 100, 300, 1000, 3000, 10000)
    rows = []
    for sigma in (2.0, 3.0, 4.0, 6.0, 8.0, 10.0):
        thr = Sensor(read_noise=sigma).normal_threshold
        used, hi = 0.0, 0.0
        for gain in (40000.0 / 65535.0, 1.0, 2.5, 10.0):  # 0.61: a 16-bit ADC at 40 000 e-
            for lam in lams:
                tv = _tv_distance(lam, sigma, gain)
                if lam >= thr:
                    used = max(used, tv)
                if lam >= 30:
                    hi = max(hi, tv)
        rows.append({"read_noise": sigma, "threshold_e": thr, "worst_tv_used": used,
                     "worst_tv_lam_ge_30": hi})  # fmt: skip
    return rows


def _print_size(r):
    """The printed rows of one image size's :func:`bench_size` result."""
    print(f"\n== {r['size']}  ({r['candidate_pixels']} of {r['pixels']} pixels see the sample)")
    print(f"geometry trace (one-time, CPU) {r['geometry_ms']:9.1f} ms")
    for k in ("capture_noise_off_ms", "capture_noise_on_ms", "render_noise_off_ms",
              "copy_uint16_ms", "copy_float64_ms", "exp_lit_pixels_ms",
              "normals_all_pixels_ms"):  # fmt: skip
        med, mn, cpu = r[k]
        print(f"{k[:-3]:<30} {med:9.3f} ms (median)  {mn:8.3f} ms (min)  {cpu:8.3f} ms (CPU)")
    print(
        "capture / copy (CPU medians):  noise off "
        f"{r['ratio_noise_off_vs_copy_uint16']:.0f}x uint16, "
        f"{r['ratio_noise_off_vs_copy_float64']:.1f}x float64;  noise on "
        f"{r['ratio_noise_on_vs_copy_uint16']:.0f}x uint16, "
        f"{r['ratio_noise_on_vs_copy_float64']:.1f}x float64  (issue 8 target: <= 3x)"
    )
    print(
        "lower bounds / float64 copy: numpy exp over the lit pixels "
        f"{r['ratio_exp_lit_pixels_vs_copy_float64']:.1f}x, one normal per pixel "
        f"{r['ratio_normals_all_pixels_vs_copy_float64']:.1f}x"
    )
    if r["skips"]:
        print(f"{'skip (CPU ms, median)':<46}{'with':>10}{'without':>10}  image unchanged")
    for k, v in r["skips"].items():
        print(f"{k:<46}{v['with_ms']:>8.2f}ms{v['without_ms']:>8.2f}ms  {v['unchanged']}")


def _print_noise(nz):
    """The printed rows of :func:`bench_noise`'s result."""
    print(
        f"\nnoise on a 640x480 rolled-brass frame (f/4), CPU ms: compiled {nz['fast_ms']:.2f}"
        f" (normal from {nz['threshold_e']:g} e-), numpy exact Poisson {nz['exact_ms']:.2f}"
    )
    print(
        f"  kernel alone (noise + ADC, no allocation) {nz['noise_u16_kernel_ms']:.2f};"
        f" 307200 standard normals: xoshiro256++ ziggurat {nz['normals_xoshiro_ms']:.2f},"
        f" numba Generator.standard_normal {nz['normals_numba_generator_ms']:.2f}"
    )
    print("moments of 1e6 draws, (value - model) / standard error; fast | exact")
    for m in nz["moments"]:
        dm = [(m[f"{k}_mean"] - m["lam"]) / m["se_mean"] for k in ("fast", "exact")]
        dv = [(m[f"{k}_var"] - m["model_var"]) / m["se_var"] for k in ("fast", "exact")]
        dg = [(m[f"{k}_skew"] - m["model_skew"]) / m["se_skew"] for k in ("fast", "exact")]
        print(f"  sigma {m['read_noise']:3g} lam {m['lam']:7g}: mean {dm[0]:+5.1f} | {dm[1]:+5.1f}"
              f"   var {dv[0]:+5.1f} | {dv[1]:+5.1f}   skew {dg[0]:+5.1f} | {dg[1]:+5.1f}"
              f"   (skew model {m['model_skew']:.4f}, fast {m['fast_skew']:.4f},"
              f" exact {m['exact_skew']:.4f})")  # fmt: skip


def main(argv=None):
    from gonio import materials

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--quick", action="store_true", help="skip the per-skip timings")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    model = materials.get("rolled_brass")
    results = []
    for size in ((640, 480), (1024, 1024)):
        r = bench_size(size, args.repeat, model, skips=not args.quick)
        results.append(r)
        _print_size(r)

    def two_level(wi, wo):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        return np.where(h[..., 2] > math.cos(0.1), 20.0, 0.01)

    br = bench_bracket(two_level)
    print(f"\nbracketing (two-level BRDF, 640x480): ladder {br['ladder']}")
    print(f"  kept {br['f_numbers']}, skipped {br['skipped']},"
          f" covered {br['covered_fraction']:.3f}, {br['bracket_ms']:.1f} ms")  # fmt: skip
    reuse = bench_bracket_reuse(max(3, args.repeat // 5))
    print("\none bracket, 640x480, noise off (CPU ms, median): scene rendered once vs "
          "plan + one capture per stop")  # fmt: skip
    for k, v in reuse.items():
        sep = v["plan_plus_captures_ms"]
        print(f"  {k:<14} stops {v['stops']}: {v['once_ms']:.2f} ms vs "
              f"{sep:.2f} ms, frames identical: {v['identical']}")  # fmt: skip
    camp = [bench_campaign_stage(nz) for nz in (False, True)]
    print("\ndefault campaign capture stage (84 brackets, 640x480):")
    for c in camp:
        print(f"  noise {'on ' if c['noise'] else 'off'}: {c['frames']} frames  "
              f"wall {c['wall_s_min']:.3f} s  CPU {c['cpu_s_min']:.3f} s  "
              f"({c['ms_per_frame_cpu']:.2f} ms/frame CPU, plan included)")  # fmt: skip
    nz = bench_noise(max(5, args.repeat // 3))
    _print_noise(nz)
    fx = bench_sensor_effects(args.repeat)
    print("\nsensor effects, 640x480 rolled brass at f/2 (CPU ms, median; ratio to the ideal"
          " sensor in this run):")  # fmt: skip
    for label, r in fx.items():
        print(f"  {label:<30} noise off {r['noise_off']:6.2f} ms ({r['noise_off_ratio']:4.2f}x)"
              f"  noise on {r['noise_on']:6.2f} ms ({r['noise_on_ratio']:4.2f}x)"
              f"  image = ideal's: {r['same_image_as_ideal']}")  # fmt: skip
    tv = noise_tv_table()
    print("\nTV distance of DN histograms, approximated vs exact draw (gains 0.61, 1, 2.5,"
          " 10 e-/DN; lambda 0.05..1e4 e-):")  # fmt: skip
    for r in tv:
        used, hi = r["worst_tv_used"], r["worst_tv_lam_ge_30"]
        print(f"  read noise {r['read_noise']:4g} e-: normal from {r['threshold_e']:g} e-, worst "
              f"TV where used {used:.1e}, at lambda >= 30 {hi:.1e}")  # fmt: skip
    out = {"sizes": results, "bracket": br, "bracket_reuse": reuse, "campaign_stage": camp,
           "noise": nz, "noise_tv": tv, "sensor_effects": fx}  # fmt: skip
    if args.json:
        atomic_write_bytes(args.json, json.dumps(out, indent=2).encode())
    return out


if __name__ == "__main__":
    main()
