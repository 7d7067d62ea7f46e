"""Pipeline stages of ``gonio stress`` (issue 8): images, mirror geometry, far-off fits.

Registered with :func:`gonio.diagnostics.stress.register_stage` when
:mod:`gonio.diagnostics.stress` is imported:

``images``
    Ward's eq. 2 reduction (:func:`~gonio.calibration.reduce.reduce_selected` and
    :func:`~gonio.calibration.reduce.reduce_capture`) of every combination of real,
    saturated, black, constant and one-hot brackets for the sample, the standard and the
    background (5³ combinations × 2 reductions). A clear ``ValueError`` (e.g. "no pixel
    survived eq. 2 masking") is an accepted outcome, counted under ``info``; a table with a
    non-finite value or σ, a negative σ, another exception or a ``RuntimeWarning`` is a
    violation.
``geometry``
    The traced pixel geometry and Ward's eq. 3 (Ward 1992, §3.3) for both
    mirrors as D → 0 and D → R (D/R from 1e-9 to 1 − 1e-9): non-finite or non-unit
    reflected directions, directions below the sample plane, eq. 3 angles outside
    [0, π/2]. D = 0 itself must be refused with a ``ValueError`` (the sample would cover
    the lens).
``fits``
    :func:`gonio.fit.fit` on noisy samples of a model, started at the lower and at the upper
    corner of its parameter bounds without the data-driven guess: non-finite parameters, a
    NaN standard error (inf marks an unidentifiable parameter and is allowed), exceptions
    and warnings are violations. How many far starts still reach the fit of the guessed
    start (χ²/dof within 10 %) is reported under ``info``: a local minimum is a property of
    the misfit, not an instability.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Eq. 2 (the reduction) and eq. 3 with its limits (§3.3).
"""

from __future__ import annotations

import itertools
import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from gonio.diagnostics.stress import StageResult, StressConfig, register_stage

__all__ = ["fit_stage", "geometry_stage", "image_stage"]

#: D/R ratios of the geometry stage (D → 0 and D → R)
D_OVER_R = (1e-9, 1e-6, 1e-3, 0.1, 0.5, 0.9, 0.999, 1 - 1e-6, 1 - 1e-9)

#: frame kinds of the image stage
FRAME_KINDS = ("real", "saturated", "black", "constant", "one_hot")

#: truths of the fit stage (model name -> parameters; ``None`` = the model's defaults)
FIT_TRUTHS: dict[str, dict[str, Any] | None] = {
    "lambert": None,
    "ward": {"rho_d": 0.1, "rho_s": 0.33, "alpha_x": 0.05, "alpha_y": 0.16},
    "oren_nayar": {"rho": 0.6, "sigma": 0.4},
    "cook_torrance": None,
    "torrance_sparrow": None,
    "blinn_phong": None,
}


def _violate(res: StageResult, subject: str, kind: str, n: int = 1, detail: str = "") -> None:
    if n <= 0:
        return
    c = res.counts.setdefault(subject, {})
    c[kind] = c.get(kind, 0) + int(n)
    res.unexpected += int(n)
    if len(res.examples) < 20:
        res.examples.append({"subject": subject, "kind": kind, "params": {}, "detail": detail})


def _guarded(fn: Callable[[], Any]) -> tuple[Any, BaseException | None, int]:
    """``fn()`` with warnings recorded: (result or None, exception or None, RuntimeWarnings)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            out, exc = fn(), None
        except Exception as e:  # reported by the caller
            out, exc = None, e
    n_warn = sum(issubclass(w.category, RuntimeWarning) for w in caught)
    return out, exc, n_warn


# ----------------------------------------------------------------------------- images
def _frames(frames: list, kind: str, max_dn: int) -> list:
    out = []
    for img, meta in frames:
        if kind == "real":
            im = img
        elif kind == "saturated":
            im = np.full_like(img, max_dn)
        elif kind == "black":
            im = np.zeros_like(img)
        elif kind == "constant":
            im = np.full_like(img, max_dn // 3)
        else:  # one lit pixel near the centre
            im = np.zeros_like(img)
            im.flat[img.size // 2 + img.shape[1] // 2] = max_dn
        out.append((im, meta))
    return out


@register_stage("images")
def image_stage(cfg: StressConfig) -> StageResult:
    """eq. 2 reduction of saturated, black, constant and one-hot brackets (module doc)."""
    from gonio import materials
    from gonio.calibration.reduce import Capture, reduce_capture, reduce_selected
    from gonio.simulator import LBLInstrument

    res = StageResult("images")
    size = (80, 60) if cfg.size == "small" else (160, 120)
    inst = LBLInstrument(width=size[0], height=size[1])
    ti = math.radians(30.0)
    real = {
        "m": inst.bracket(materials.get("rolled_brass"), ti, 0.0, rng=cfg.rng + 1),
        "s": inst.bracket("standard", ti, 0.0, rng=cfg.rng + 2),
        "b": inst.bracket(None, ti, 0.0, rng=cfg.rng + 3),
    }
    kinds = FRAME_KINDS[:3] if cfg.size == "small" else FRAME_KINDS
    reductions = {
        "reduce_selected": lambda c: reduce_selected(*c, rng=cfg.rng, debias=True),
        "reduce_capture": lambda c: reduce_capture(*c),
    }
    outcomes = {name: {"tables": 0, "rejected": 0, "samples": 0} for name in reductions}
    for km, ks, kb in itertools.product(kinds, repeat=3):
        caps = [
            Capture(_frames(real[x], k, inst.sensor.max_dn))
            for x, k in (("m", km), ("s", ks), ("b", kb))
        ]
        for name, reduce in reductions.items():
            res.cases += 1
            label = f"{name} sample={km} standard={ks} background={kb}"
            red, exc, n_warn = _guarded(lambda r=reduce, c=caps: r(c))
            _violate(res, name, "warning", n_warn, label)
            if isinstance(exc, ValueError):
                outcomes[name]["rejected"] += 1
                continue
            if exc is not None:
                _violate(res, name, "error", 1, f"{label}: {type(exc).__name__}: {exc}")
                continue
            s = red.samples
            outcomes[name]["tables"] += 1
            outcomes[name]["samples"] += len(s)
            for col in (s.value, s.sigma):
                _violate(res, name, "nan", int(np.isnan(col).sum()), label)
                _violate(res, name, "inf", int(np.isinf(col).sum()), label)
            _violate(res, name, "negative", int((s.sigma < 0).sum()), f"{label}: sigma < 0")
    res.info = {"frame_kinds": list(kinds), "image_size": list(size), **outcomes}
    for name in reductions:
        res.counts.setdefault(name, {})
    return res


# ----------------------------------------------------------------------------- geometry
@register_stage("geometry")
def geometry_stage(cfg: StressConfig) -> StageResult:
    """Traced geometry and eq. 3 for both mirrors as D → 0 and D → R (module doc)."""
    from gonio.simulator import LBLInstrument
    from gonio.simulator.optics import eq3_reflection_angles

    res = StageResult("geometry")
    radius = 0.15
    size = (48, 36) if cfg.size == "small" else (96, 72)
    ratios = D_OVER_R[::2] if cfg.size == "small" else D_OVER_R
    theta_c = np.concatenate(
        [np.linspace(0.0, math.pi / 2, 181), [math.pi / 2 - 1e-9, math.pi / 2 - 1e-12]]
    )
    info: dict[str, Any] = {}
    for kind in ("ellipsoid", "hemisphere"):
        # D = 0 puts the sample on the lens: a clear error, not a geometry
        res.cases += 1
        _, exc, n_warn = _guarded(
            lambda k=kind: LBLInstrument(k, radius=radius, half_separation=0.0).geometry
        )
        if not isinstance(exc, ValueError):
            _violate(res, kind, "error", 1, f"D = 0 not refused ({exc!r})")
        _violate(res, kind, "warning", n_warn, "D = 0")
        for ratio in ratios:
            d = ratio * radius
            label = f"{kind} D/R = {ratio:.12g}"

            def trace(k=kind, d=d):
                inst = LBLInstrument(
                    k, radius=radius, half_separation=d, width=size[0], height=size[1],
                    sample_radius=min(0.008, d),
                )  # fmt: skip
                g = inst.geometry
                tr, pr = eq3_reflection_angles(theta_c, np.zeros_like(theta_c), radius, d, mirror=k)
                return g, tr, pr

            res.cases += 1
            out, exc, n_warn = _guarded(trace)
            _violate(res, kind, "warning", n_warn, label)
            if exc is not None:
                _violate(res, kind, "error", 1, f"{label}: {type(exc).__name__}: {exc}")
                continue
            g, tr, pr = out
            w = np.stack([g.wx, g.wy, g.wz], axis=1)
            finite = np.isfinite(w).all(axis=1)
            _violate(res, kind, "nan", int(np.isnan(w).any(axis=1).sum()), label)
            _violate(res, kind, "inf", int((np.isinf(w).any(axis=1)).sum()), label)
            norm = np.abs(np.linalg.norm(w[finite], axis=1) - 1.0)
            _violate(res, kind, "norm", int((norm > 1e-9).sum()), f"{label}: |w| != 1")
            _violate(res, kind, "horizon", int((w[finite, 2] < 0).sum()), f"{label}: z < 0")
            _violate(res, kind, "nan", int((~np.isfinite(tr) | ~np.isfinite(pr)).sum()), label)
            ok = np.isfinite(tr)
            outside = (tr[ok] < 0) | (tr[ok] > math.pi / 2 + 1e-12)
            _violate(res, kind, "horizon", int(outside.sum()), f"{label}: eq. 3 theta")
            info[label] = {"candidates": int(g.idx.size), "eq3_theta_max": float(tr[ok].max())}
        res.counts.setdefault(kind, {})
    res.info = info
    return res


# ----------------------------------------------------------------------------- fits
def _corner(spec: Any, which: str) -> dict[str, float]:
    """Start values at the lower or upper corner of the float parameters' bounds (just
    inside; ±1e3 × the default's scale where a side is unbounded)."""
    out = {}
    for p in spec.params.values():
        if p.kind != "float":
            continue
        scale = max(abs(float(p.default or 0.0)), 1.0) * 1e3
        lo = p.lower if math.isfinite(p.lower) else -scale
        hi = p.upper if math.isfinite(p.upper) else scale
        out[p.name] = lo + 1e-6 * (hi - lo) if which == "lower" else hi - 1e-6 * (hi - lo)
    return out


@register_stage("fits")
def fit_stage(cfg: StressConfig) -> StageResult:
    """Fits started at the corners of the parameter bounds (module doc)."""
    from gonio import brdf
    from gonio.fit import fit
    from gonio.geometry import to_vector
    from gonio.samples import BRDFSamples

    res = StageResult("fits")
    rng = np.random.default_rng(cfg.rng)
    n = 400 if cfg.size == "small" else 2000
    wi = to_vector(rng.uniform(0.0, 1.4, n), rng.uniform(-math.pi, math.pi, n))
    wo = to_vector(np.arccos(rng.uniform(0.05, 1.0, n)), rng.uniform(-math.pi, math.pi, n))
    names = [m for m in FIT_TRUTHS if m in brdf.names()]
    if cfg.size == "small":
        names = names[:3]
    info: dict[str, Any] = {}
    for name in names:
        truth = brdf.create(name, **(FIT_TRUTHS[name] or {}))
        f = np.asarray(truth(wi, wo), dtype=np.float64)
        y = f * (1.0 + 0.01 * rng.standard_normal(n))
        samples = BRDFSamples.from_directions(wi, wo, y, 0.01 * np.abs(f) + 1e-6)
        spec = brdf.spec(name)
        starts = {
            "guess": {"guess": True},
            "lower": {"guess": False, "init": _corner(spec, "lower")},
            "upper": {"guess": False, "init": _corner(spec, "upper")},
        }
        chi2 = {}
        for label, kw in starts.items():
            res.cases += 1
            t0 = time.perf_counter()
            r, exc, n_warn = _guarded(lambda kw=kw, s=samples, m=name: fit(s, m, **kw))
            _violate(res, name, "warning", n_warn, f"start {label}")
            if exc is not None:
                msg = f"{type(exc).__name__}: {exc}"
                if not isinstance(exc, ValueError):  # (a ValueError is a clear refusal)
                    _violate(res, name, "error", 1, f"start {label}: {msg}")
                chi2[label] = {"error": msg}
                continue
            vals = np.array([v for v in r.params.values() if isinstance(v, float)])
            ses = np.array([v for v in r.stderr.values() if isinstance(v, float)])
            _violate(res, name, "nan", int(np.isnan(vals).sum() + np.isnan(ses).sum()), label)
            _violate(res, name, "inf", int(np.isinf(vals).sum()), f"start {label}: parameter")
            if not math.isfinite(r.chi2_dof):
                _violate(res, name, "nan", 1, f"start {label}: chi2/dof {r.chi2_dof}")
            chi2[label] = {
                "chi2_dof": r.chi2_dof,
                "converged": r.converged,
                "seconds": round(time.perf_counter() - t0, 3),
            }
        ref = chi2.get("guess", {}).get("chi2_dof")
        far = [chi2[k].get("chi2_dof") for k in ("lower", "upper") if k in chi2]
        recovered = sum(
            1 for c in far if c is not None and ref is not None and c <= 1.1 * ref + 1e-12
        )
        info[name] = {"starts": chi2, "far_starts_recovered": f"{recovered}/{len(far)}"}
        res.counts.setdefault(name, {})
    res.info = info
    return res
