"""Cornell campaigns: accuracy of the li_torrance fit on the four Li-Torrance samples, and the
time of a full hemispherical campaign in-process and through the fake devices.

    python benchmarks/bench_hw_campaign.py table [--plan incidence] [--seed 0]
        the issue's accuracy table: the four Li-Torrance samples, noise-free and noisy, fitted
        with their constructed models (fit_mode auto), plus fit_mode "both" on the rough three
        (no mirror part: sigma and tau drift together, sigma/tau stays exact)
    python benchmarks/bench_hw_campaign.py stderr [--seeds 5] [--materials a,b]
        are the reported standard errors honest? scatter of the fits over seeds vs stderr
    python benchmarks/bench_hw_campaign.py accuracy [--plan incidence] [--materials a,b]
        [--noise on|off|both] [--general-fit]   (joint least squares instead of variable projection)
    python benchmarks/bench_hw_campaign.py timing [--plan hemispherical]
    python benchmarks/bench_hw_campaign.py served [--plan hemispherical] [--theta-i 40]
        an external driver script against `gonio devices serve --instrument cornell`
    python benchmarks/bench_hw_campaign.py degeneracy
    python benchmarks/bench_hw_campaign.py shifts [--materials a,b]
        footprint, lamp drift and stray light injected alone: shifts of the fit without and
        with the laboratory's correction

The budget's coverage over realised instruments: ``benchmarks/bench_cornell_coverage.py``;
the realistic against the ideal campaign's wall time: ``benchmarks/bench_cornell.py
--realistic``.

accuracy/timing/degeneracy print one JSON line per run (summary without samples); table and
stderr print text tables.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from gonio.campaign.cornell import identifiability_scan, run_cornell_campaign

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


def _z(s: dict, k: str) -> float | None:
    se = s["stderr_with_reference"].get(k)
    if not se or k not in s["fit"]:
        return None
    return (s["fit"][k] - s["truth"][k]) / se


def _row(s: dict) -> str:
    fit, tr, rel = s["fit"], s["truth"], s["relative_error"]
    cells = []
    for k in ("sigma", "tau", "sigma/tau"):
        if k in rel:
            z = _z(s, k) if s["noise"] else None
            zs = f" z{z:+5.1f}" if z is not None else "       "
            cells.append(f"{fit[k]:9.5g} ({100 * rel[k]:7.4f}%){zs}")
        else:
            cells.append(f"{tr[k]:9.5g} (held)  {'':9s}")
    ks = s["k_summary"]
    within = f"{ks['n_within_3_sigma']}/{ks['n']} ({ks['n_within_3_fit_stderr']})"
    return (
        f"{s['material'][:26]:26s} {'noisy' if s['noise'] else 'clean'} {s['fit_mode']:11s} "
        + " ".join(cells)
        + f" {100 * ks['max_relative_error']:7.3f}% {within if s['noise'] else '-':>13s}"
    )


def table(plan: str, seed: int, materials=MATERIALS) -> None:
    """The issue's accuracy table (see the module docstring)."""
    print(
        f"plan {plan}, seed {seed}; value (relative error) and, noisy, z = (fit - truth) / stderr"
        " (stderr incl. the reference's per-band error); k: max relative error, number within"
        " 3 stderr (fit stderr alone in brackets)"
    )
    print(
        f"{'material':26s} {'data':5s} {'fit_mode':11s} {'sigma [um]':26s} {'tau [um]':26s} "
        f"{'sigma/tau':26s} {'max dk/k':>8s} {'k in 3 s.e.':>13s}"
    )
    t0 = time.perf_counter()
    for m in materials:
        for noise in (False, True):
            s = run_cornell_campaign(m, plan=plan, noise=noise, seed=seed)
            print(_row(s), flush=True)
        s = run_cornell_campaign(m, plan=plan, noise=False, seed=seed, fit_mode="both")
        if s["fit_mode"] == "both" and not s["mirror_part"]:
            print(_row(s) + "   <- no mirror part: only sigma/tau identifiable", flush=True)
    print(f"({time.perf_counter() - t0:.1f} s)")


def stderr_check(plan: str, materials, n_seeds: int, seed0: int = 100) -> None:
    """Fits of ``n_seeds`` noisy campaigns per material: are the standard errors honest?

    z = (fit - truth) / stderr over all k's and seeds: its RMS should be about 1 and about
    0.3 % of |z| above 3; the scatter of each k over the seeds divided by its mean stderr
    should be about 1 (median over the k's); sigma/tau (or tau) likewise.
    """
    print(
        f"plan {plan}, seeds {seed0}..{seed0 + n_seeds - 1}: z = (fit - truth) / stderr;"
        " 'fit' = the fit's stderr, 'ref' = fit stderr (+) the reference's per-band error"
    )
    print(
        f"{'material':26s} {'n_k':>4s} {'rms z fit':>9s} {'rms z ref':>9s} {'|z|>3 fit':>9s} "
        f"{'|z|>3 ref':>9s} {'scat/se fit':>11s} {'scat/se ref':>11s} {'shape param z per seed'}"
    )
    for m in materials:
        runs = []
        for j in range(n_seeds):
            s = run_cornell_campaign(m, plan=plan, noise=True, seed=seed0 + j)
            s.pop("_samples")
            runs.append(s)
        keys = [k for k in runs[0]["relative_error"] if "[" in k]
        f = np.array([[r["fit"][k] for k in keys] for r in runs])
        t = np.array([runs[0]["truth"][k] for k in keys])
        se = np.array([[r["stderr"][k] for k in keys] for r in runs])
        ser = np.array([[r["stderr_with_reference"][k] for k in keys] for r in runs])
        z, zr = (f - t) / se, (f - t) / ser
        sd = f.std(axis=0, ddof=1)
        shape = "sigma" if "sigma" in runs[0]["relative_error"] else "tau"
        zs = " ".join(f"{v:+.1f}" for v in (_z(r, shape) for r in runs) if v is not None)
        print(
            f"{m[:26]:26s} {len(keys):4d} {np.sqrt(np.mean(z**2)):9.2f} "
            f"{np.sqrt(np.mean(zr**2)):9.2f} {np.mean(np.abs(z) > 3):9.3f} "
            f"{np.mean(np.abs(zr) > 3):9.3f} {np.median(sd / se.mean(0)):11.2f} "
            f"{np.median(sd / ser.mean(0)):11.2f} {shape}: {zs}",
            flush=True,
        )


def timing(plan: str, material: str) -> None:
    """Wall time of the same campaign in-process and through the fake devices, beside the
    real instrument's estimated time (cornell_plans.Timing, the integration times the
    auto-exposure chose). On the realistic instrument (the default) the two paths draw their
    stage errors and lamp clock each their own way, so ``same_samples`` is False (the ideal
    instrument, ``effects=None``, gives identical samples on both paths)."""
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
                "estimate_breakdown_h": b.get("estimated_real_instrument_breakdown_h"),
                "mean_integration_s": round(b.get("mean_integration_s", float("nan")), 3),
                "same_samples": same,
            }
        ),
        flush=True,
    )


def served(plan: str, material: str, max_geometries: int | None, theta_i: float | None) -> None:
    """A campaign run by this process (an external driver script) against ``gonio devices
    serve --instrument cornell`` in another process (ESP300s on ptys, the USB2000+ over the
    fake USB bus's TCP link), compared with the in-process simulation of the same seed."""
    import os
    import signal
    import subprocess
    import sys
    import tempfile

    from gonio.campaign.cornell import build_plan
    from gonio.campaign.drivers import open_served_rig, run_cornell_measurements

    kw = {"theta_i_deg": (theta_i,)} if theta_i is not None else {}
    p = build_plan(plan, max_geometries=max_geometries, **kw)
    t = time.perf_counter()
    a = run_cornell_campaign(  # the served bench is the ideal instrument
        material,
        plan=plan,
        plan_kw=kw,
        max_geometries=max_geometries,
        seed=0,
        fit=False,
        effects=None,
    )
    t_in = time.perf_counter() - t
    cmd = [sys.executable, "-c", "import sys; from gonio.cli import main; sys.exit(main())",
           "devices", "serve", "--json", "--instrument", "cornell", "--material", material,
           "--seed", "0", "--time-scale", "10000"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())
    try:
        recs = []
        while not recs or recs[-1]["device"] != "bench":
            recs.append(json.loads(proc.stdout.readline()))
        t = time.perf_counter()
        with open_served_rig(recs) as (rig, _):
            res = run_cornell_measurements(rig, np.degrees(p.angles))
        t_srv = time.perf_counter() - t
    finally:
        os.kill(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
    d = np.abs(res["value"].ravel() - a["_samples"].value)
    print(
        json.dumps(
            {
                "plan": plan, "theta_i": theta_i, "material": material, "n_geometries": len(p),
                "in_process_s": round(t_in, 2), "served_external_s": round(t_srv, 2),
                "reads": rig.n_reads, "moves": rig.n_moves, "max_abs_diff": float(d.max()),
            }
        ),
        flush=True,
    )  # fmt: skip


_SHIFTS = {
    "footprint": ({"beam_diameter_mm": 25.0, "fov_diameter_mm": 8.0, "sample_size_mm": 101.6},
                  {"footprint": "none"}, {"footprint": "refuse"}),
    "footprint_divide": ({"beam_diameter_mm": 25.0, "fov_diameter_mm": 8.0,
                          "sample_size_mm": 101.6}, {"footprint": "none"},
                         {"footprint": "divide"}),
    "drift": ({"lamp_drift": 0.0155, "lamp_warmup": 0.005}, {"drift": False}, {"drift": True}),
    "stray": ({"stray_light_fraction": 1e-3}, {"stray": False}, {"stray": True}),
}  # fmt: skip


def _shift_row(s: dict, ideal: dict) -> str:
    out = []
    for p in ("tau",) + tuple(k for k in ("k_dd", "k_uds", "k_fs") if f"{k}[0]" in s["fit"]):
        if p == "tau":
            out.append(f"tau {100 * (s['fit']['tau'] / ideal['fit']['tau'] - 1):+.3f}%")
            continue
        r = [s["fit"][f"{p}[{b}]"] / ideal["fit"][f"{p}[{b}]"] - 1 for b in range(31)
             if abs(ideal["fit"][f"{p}[{b}]"]) > 0.02]  # fmt: skip
        if r:
            out.append(
                f"{p} median {100 * np.median(r):+.2f}% max|.| {100 * np.max(np.abs(r)):.2f}%"
            )
    return ", ".join(out) + f", chi2/dof {s['chi2_dof']:.3g}"


def shifts(plan: str, materials, seed: int) -> None:
    """Each effect alone at a typical magnitude, fitted without and with its correction,
    against the ideal instrument with the same noise seed (the drift: +1 % over the
    campaign's clock with one reference at the start vs a reference every 40 geometries)."""
    for m in materials:
        ideal = run_cornell_campaign(m, plan=plan, seed=seed, effects=None)
        print(f"{m}: ideal chi2/dof {ideal['chi2_dof']:.3g}", flush=True)
        for name, (fx, off, on) in _SHIFTS.items():
            for label, corr in (("uncorrected", off), ("corrected", on)):
                every = 0 if name == "drift" and not corr.get("drift", True) else None
                s = run_cornell_campaign(m, plan=plan, seed=seed, effects=fx, corrections=corr,
                                         reference_every=every, budget=False)  # fmt: skip
                print(f"  {name:16s} {label:11s} refused {s['n_refused_footprint']:3d}: "
                      + _shift_row(s, ideal), flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "what", choices=("table", "stderr", "accuracy", "timing", "served", "degeneracy",
                         "shifts")
    )  # fmt: skip
    ap.add_argument("--max-geometries", type=int, default=None)
    ap.add_argument("--theta-i", type=float, default=None, help="served: one incidence angle")
    ap.add_argument("--seeds", type=int, default=5, help="stderr: noisy campaigns per material")
    ap.add_argument("--plan", default=None)
    ap.add_argument("--materials", default=",".join(MATERIALS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fit-mode", default="auto")
    ap.add_argument("--noise", default="both", choices=("on", "off", "both"))
    ap.add_argument("--general-fit", action="store_true", help="joint fit, no projection")
    a = ap.parse_args()
    mats = [m for m in a.materials.split(",") if m]
    if a.what == "table":
        table(a.plan or "incidence", a.seed, mats)
    elif a.what == "stderr":
        stderr_check(a.plan or "incidence", mats, a.seeds)
    elif a.what == "accuracy":
        noises = {"on": (True,), "off": (False,), "both": (False, True)}[a.noise]
        accuracy(a.plan or "incidence", mats, a.seed, a.fit_mode, noises, not a.general_fit)
    elif a.what == "served":
        served(a.plan or "hemispherical", mats[0] if len(mats) == 1 else "garnet_red_paint",
               a.max_geometries, a.theta_i)  # fmt: skip
    elif a.what == "shifts":
        shifts(a.plan or "incidence", mats, a.seed)
    elif a.what == "timing":
        timing(a.plan or "hemispherical", mats[0] if len(mats) == 1 else "garnet_red_paint")
    else:
        for m in mats:
            print(json.dumps({"material": m, "scan": identifiability_scan(m)}), flush=True)


if __name__ == "__main__":
    main()
