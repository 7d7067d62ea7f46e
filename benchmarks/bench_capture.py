"""Capture timings of the simulated LBL gonioreflectometer and what each skip saves.

Run: ``python benchmarks/bench_capture.py [--repeat 30] [--json out.json]``

One thread (numba, BLAS and OpenMP limited to 1 before import). Reports, for 640 × 480 and
1024 × 1024 with a Ward BRDF (``rolled_brass``): the one-time geometry trace, ms per capture
with the geometry cached (noise off / on), the time to merely copy the output pixels (uint16)
and a float64 image, and for every skip the time with and without it and whether the image
is unchanged.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

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


def bench_size(size, repeat, model):
    from gonio.simulator import LBLInstrument
    from gonio.simulator.lbl import _GEOMETRY_CACHE

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

    # 4. noise skipped when off, vs drawing zero-amplitude noise
    sen = inst.sensor
    rng = np.random.default_rng(0)

    def zero_noise():
        e = inst._render("brdf", model, TH, 0.0, 0.01, 4.0, None, None)
        shot = rng.poisson(np.clip(e, 0, None)) - e
        read = rng.standard_normal(e.shape)
        return sen.digitise(e + 0.0 * shot + 0.0 * read).reshape(ref.shape)

    skips["noise off: no random draws"] = (
        _time(lambda: inst.capture(model, TH, noise=False), repeat),
        _time(zero_noise, max(3, repeat // 5)),
        bool(np.array_equal(zero_noise(), ref)),
    )

    # 5. source-cone average skipped when the lobe is >= 5x the beam divergence
    one = inst.capture(model, TH, noise=False, source_samples=1)[0]
    many = inst.capture(model, TH, noise=False, source_samples=19)[0]
    skips["source cone (1 vs 19 directions)"] = (
        _time(lambda: inst.capture(model, TH, noise=False, source_samples=1), repeat),
        _time(lambda: inst.capture(model, TH, noise=False, source_samples=19), repeat // 3),
        f"max |dDN| = {int(np.abs(one.astype(int) - many).max())}",
    )
    out["skips"] = {
        k: {"with_ms": v[0][2], "without_ms": v[1][2], "unchanged": v[2]} for k, v in skips.items()
    }  # fmt: skip  (CPU ms, medians)
    return out


def bench_bracket(model_fn):
    from gonio.simulator import LBLInstrument

    inst = LBLInstrument(width=640, height=480)
    stops = (32, 22, 16, 11, 8, 5.6, 4, 2.8, 2, 1.4)
    plan = inst.plan_bracket(model_fn, TH, f_stops=stops)
    t0 = time.perf_counter()
    inst.bracket(model_fn, TH, f_stops=stops, noise=False)
    return {"ladder": list(stops), **plan, "bracket_ms": (time.perf_counter() - t0) * 1e3}


def main(argv=None):
    from gonio import materials

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    model = materials.get("rolled_brass")
    results = []
    for size in ((640, 480), (1024, 1024)):
        r = bench_size(size, args.repeat, model)
        results.append(r)
        print(f"\n== {r['size']}  ({r['candidate_pixels']} of {r['pixels']} pixels see the sample)")
        print(f"geometry trace (one-time, CPU) {r['geometry_ms']:9.1f} ms")
        for k in ("capture_noise_off_ms", "capture_noise_on_ms", "copy_uint16_ms",
                  "copy_float64_ms"):  # fmt: skip
            med, mn, cpu = r[k]
            print(f"{k[:-3]:<30} {med:9.3f} ms (median)  {mn:8.3f} ms (min)  {cpu:8.3f} ms (CPU)")
        print(f"{'skip (CPU ms, median)':<46}{'with':>10}{'without':>10}  image unchanged")
        for k, v in r["skips"].items():
            print(f"{k:<46}{v['with_ms']:>8.2f}ms{v['without_ms']:>8.2f}ms  {v['unchanged']}")

    def two_level(wi, wo):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        return np.where(h[..., 2] > math.cos(0.1), 20.0, 0.01)

    br = bench_bracket(two_level)
    print(f"\nbracketing (two-level BRDF, 640x480): ladder {br['ladder']}")
    print(f"  kept {br['f_numbers']}, skipped {br['skipped']},"
          f" covered {br['covered_fraction']:.3f}, {br['bracket_ms']:.1f} ms")  # fmt: skip
    out = {"sizes": results, "bracket": br}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
    return out


if __name__ == "__main__":
    main()
