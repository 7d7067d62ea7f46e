"""Cornell campaigns: accuracy of the li_torrance fit on the four Li-Torrance samples, and the
time of a full hemispherical campaign in-process and through the fake devices.

    python benchmarks/bench_hw_campaign.py accuracy [--plan incidence] [--materials a,b]
        [--noise on|off|both] [--general-fit]   (joint least squares instead of variable projection)
    python benchmarks/bench_hw_campaign.py timing [--plan hemispherical]
    python benchmarks/bench_hw_campaign.py degeneracy

Prints one JSON line per run (summary without samples).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from gonio.cornell_campaign import identifiability_scan, run_cornell_campaign

MATERIALS = (
    "aluminized_non_glare_glass",
    "aluminized_ground_glass",
    "garnet_red_paint",
    "laser_paper",
)


def _short(s: dict) -> dict:
    s = {k: v for k, v in s.items() if k != "_samples"}
    keep = ("sigma", "tau", "sigma/tau")
    return {
        "material": s["material"],
        "noise": s["noise"],
        "fit_mode": s.get("fit_mode"),
        "n_geometries": s.get("n_geometries"),
        "n_samples": s["n_samples"],
        "converged": s.get("converged"),
        "truth": {k: s["truth"][k] for k in keep if k in s.get("truth", {})},
        "fit": {k: s["fit"][k] for k in keep if k in s.get("fit", {})},
        "stderr": {k: s["stderr"].get(k) for k in keep if k in s.get("stderr", {})},
        "relative_error": {
            k: s["relative_error"][k] for k in keep if k in s.get("relative_error", {})
        },
        "within_3_sigma": {
            k: s["within_3_sigma"].get(k) for k in keep if k in s.get("within_3_sigma", {})
        },
        "k_summary": s.get("k_summary"),
        "timings_s": s["timings_s"],
    }


def accuracy(
    plan: str, materials, seed: int, fit_mode: str, noises=(False, True), linear: bool = True
) -> None:
    for m in materials:
        for noise in noises:
            s = run_cornell_campaign(
                m, plan=plan, noise=noise, seed=seed, fit_mode=fit_mode, fit_linear=linear
            )
            print(json.dumps(_short(s)), flush=True)


def timing(plan: str, material: str) -> None:
    t = time.perf_counter()
    a = run_cornell_campaign(material, plan=plan, seed=0, fit=False)
    t_in = time.perf_counter() - t
    t = time.perf_counter()
    b = run_cornell_campaign(material, plan=plan, seed=0, fit=False, through_drivers=True)
    t_dr = time.perf_counter() - t
    va, vb = a["_samples"].value, b["_samples"].value
    d = np.abs(va - vb)
    big = np.abs(va) > 1e-6
    same = bool(
        np.allclose(va, vb, rtol=1e-12, atol=1e-15)
        and np.array_equal(a["_samples"].wo, b["_samples"].wo)
    )
    print(
        json.dumps(
            {
                "plan": plan,
                "material": material,
                "n_geometries": a["n_geometries"],
                "in_process_s": round(t_in, 2),
                "through_fake_devices_s": round(t_dr, 2),
                "device_reads": b.get("device_reads"),
                "device_moves": b.get("device_moves"),
                "max_abs_diff": float(d.max()),
                "max_rel_diff_above_1e-6": float(np.max(d[big] / np.abs(va[big]))),
                "estimated_real_instrument_h": round(b["estimated_real_instrument_h"], 3),
                "same_samples": same,
            }
        ),
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=("accuracy", "timing", "degeneracy"))
    ap.add_argument("--plan", default=None)
    ap.add_argument("--materials", default=",".join(MATERIALS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fit-mode", default="auto")
    ap.add_argument("--noise", default="both", choices=("on", "off", "both"))
    ap.add_argument("--general-fit", action="store_true", help="joint fit, no projection")
    a = ap.parse_args()
    mats = [m for m in a.materials.split(",") if m]
    if a.what == "accuracy":
        noises = {"on": (True,), "off": (False,), "both": (False, True)}[a.noise]
        accuracy(a.plan or "incidence", mats, a.seed, a.fit_mode, noises, not a.general_fit)
    elif a.what == "timing":
        timing(a.plan or "hemispherical", mats[0] if len(mats) == 1 else "garnet_red_paint")
    else:
        for m in mats:
            print(json.dumps({"material": m, "scan": identifiability_scan(m)}), flush=True)


if __name__ == "__main__":
    main()
