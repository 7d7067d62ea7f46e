"""Reduction accuracy benchmark (issue 4): Ward's table materials at θi = 10, 30, 50, 70°.

Usage: ``python benchmarks/bench_reduce.py MIRROR NOISE METHOD`` with MIRROR ellipsoid |
hemisphere (D/R = 0.05), NOISE on | off, METHOD eq3 | exact. Prints the per-capture median and
95th-percentile |relative error| of the reduced (thinned) samples against the true BRDF at the
sample directions, and the std of (sample − truth)/σ. One seeded run; 320 × 240 equidistant lens;
brackets with ``min_signal_dn=400`` (the default 16 DN floor leaves ADC quantisation of ~1-3 % in
the dim diffuse pixels with noise off).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from gonio.calibration import Capture, reduce_capture
from gonio.simulator import LBLInstrument

from gonio import materials


def main(mirror: str = "ellipsoid", noise: str = "off", method: str = "eq3") -> None:
    on = noise == "on"
    d = 0.0075 if mirror == "hemisphere" else 0.01
    inst = LBLInstrument(
        mirror=mirror, radius=0.15, half_separation=d, lens="equidistant", width=320, height=240
    )
    names = [n for n in materials.names("ward") if materials.info(n).get("table") == "ward"]
    med, p95, zs, t_red, counts = [], [], [], 0.0, []
    for i, name in enumerate(names):
        for th in (10, 30, 50, 70):
            ti = np.radians(th)
            kw = {"noise": on, "rng": np.random.default_rng(i * 100 + th)}
            meas = Capture(inst.bracket(name, ti, 0.0, min_signal_dn=400, **kw))
            std = Capture(inst.bracket("standard", ti, 0.0, **kw))
            bg = Capture(
                [
                    inst.capture(
                        None, ti, 0.0, exposure=m["exposure_s"], f_number=m["f_number"], **kw
                    )
                    for _, m in std.frames
                ]
            )
            t = time.perf_counter()
            r = reduce_capture(meas, std, bg, method=method)
            t_red += time.perf_counter() - t
            s = r.samples
            tr = materials.get(name)(s.wi, s.wo)
            rel = np.abs(s.value / tr - 1)
            med.append(np.median(rel))
            p95.append(np.percentile(rel, 95))
            zs.append((s.value - tr) / s.sigma)
            counts.append((r.stats["n_before"], r.stats["n_after"]))
    z = np.concatenate(zs)
    n_over = sum(m > 0.005 or p > 0.02 for m, p in zip(med, p95))
    c = np.array(counts)
    print(
        f"{mirror} {method} noise={noise}: captures {len(med)}; median|rel| worst {max(med):.4%} "
        f"(median {np.median(med):.4%}); p95|rel| worst {max(p95):.4%} (median "
        f"{np.median(p95):.4%}); captures over 0.5%/2%: {n_over}; "
        f"z std {z.std():.3f}; pixels {int(c[:, 0].mean())} -> samples {int(c[:, 1].mean())} "
        f"per capture; reduce {1000 * t_red / len(med):.1f} ms/capture"
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
