"""``gonio bench``: run time against error for every knob that trades one for the other.

A *knob* (:class:`Knob`, registered in :data:`KNOBS`) is a name, a list of settings and a
function ``run(setting, seed) -> {error name: value, ...}``; :func:`run_bench` times each
call (wall clock, best of ``repeat``) on fixed seeds and records the errors it buys. Errors
are the relative error of each recovered parameter (``rel_err_<param>``, their maximum
``max_rel_err``) and the RMS log-BRDF error of the fitted model against the truth over the
fixed direction set of :func:`error_directions` (``rms_log_brdf``); knobs that do not fit a
model report the error of what they compute (``rel_err`` of an albedo, say). Each knob names a
``primary`` error for the table and the Pareto plot.

An *ablation* (:class:`Ablation`, in :data:`ABLATIONS`) is a skip rule of the pipeline (a
geometry cache, a visible-pixel mask, ...): ``run(enabled) -> ndarray`` is timed with the rule
off and on, and the two results are compared (``identical`` and ``max_abs_diff``), the proof
that skipping changes nothing.

Knobs and ablations whose code lives in modules that are not there yet are listed with
``available = False`` and the reason, never faked.

The pure fitting task :func:`fit_preset` (material preset → noisy samples on a direction
design → fit → errors) is also the default task of ``gonio sweep``.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
"""

from __future__ import annotations

import csv
import importlib
import io
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.geometry import to_vector

__all__ = [
    "ABLATIONS",
    "KNOBS",
    "Ablation",
    "Knob",
    "brdf_errors",
    "error_directions",
    "fit_preset",
    "fit_preset_options",
    "register_ablation",
    "register_knob",
    "run_bench",
    "sample_design",
]


# --------------------------------------------------------------------------- errors
def error_directions() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The fixed direction set over which fitted models are compared with the truth.

    Incidence θi ∈ {0, 15, 30, 45, 60, 75}° at φi = 0 and 90°; for each, a 10° grid of
    outgoing directions (θo 5…85°, φo every 15°) plus rings at 1, 2, 4, 8 and 16° around the
    mirror direction (8 azimuths each), so narrow specular lobes are sampled too. Returns
    ``(wi, wo)``, each ``(N, 3)``; deterministic, independent of any model.
    """
    wis, wos = [], []
    t_o = np.radians(np.arange(5.0, 86.0, 10.0))
    p_o = np.radians(np.arange(0.0, 360.0, 15.0))
    grid = to_vector(*np.meshgrid(t_o, p_o, indexing="ij")).reshape(-1, 3)
    ring_d = np.radians([1.0, 2.0, 4.0, 8.0, 16.0])
    ring_a = np.radians(np.arange(0.0, 360.0, 45.0))
    for ti in np.radians([0.0, 15.0, 30.0, 45.0, 60.0, 75.0]):
        for pi_ in (0.0, np.pi / 2):
            wi = to_vector(ti, pi_)
            mirror = wi * np.array([-1.0, -1.0, 1.0])
            # orthonormal frame around the mirror direction
            a = np.array([0.0, 0.0, 1.0]) if abs(mirror[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            u = np.cross(mirror, a)
            u /= np.linalg.norm(u)
            v = np.cross(mirror, u)
            d, az = np.meshgrid(ring_d, ring_a, indexing="ij")
            ring = (
                np.cos(d)[..., None] * mirror
                + np.sin(d)[..., None] * (np.cos(az)[..., None] * u + np.sin(az)[..., None] * v)
            ).reshape(-1, 3)
            ring = ring[ring[:, 2] > 0.02]
            wo = np.concatenate([grid, ring])
            wos.append(wo)
            wis.append(np.broadcast_to(wi, wo.shape))
    return np.concatenate(wis), np.concatenate(wos)


def brdf_errors(
    truth: Any,
    fitted: Any,
    true_params: Mapping[str, float] | None = None,
    fitted_params: Mapping[str, float] | None = None,
) -> dict[str, float]:
    """Errors of a fitted model against the truth.

    ``rel_err_<p>`` = ``|fitted − true| / |true|`` for each float parameter present in both
    (``abs_err_<p>`` when the true value is 0), ``max_rel_err`` their maximum, and
    ``rms_log_brdf`` = RMS of ``ln f_fit − ln f_true`` over :func:`error_directions` where the
    truth is positive (the fitted value is floored at 1e-12 × the truth's maximum, so a
    model that predicts 0 where the truth does not gives a large but finite error). Spectral
    values are compared band by band.
    """
    wi, wo = error_directions()
    ft = np.asarray(truth(wi, wo), dtype=np.float64)
    ff = np.asarray(fitted(wi, wo), dtype=np.float64)
    if ft.shape != ff.shape:
        raise ValueError(f"truth values have shape {ft.shape}, fitted {ff.shape}; expected equal")
    pos = ft > 0
    if not pos.any():
        raise ValueError("truth is zero over the whole error direction set")
    tiny = 1e-12 * float(ft.max())
    d = np.log(np.maximum(ff[pos], tiny)) - np.log(ft[pos])
    out: dict[str, float] = {}
    tp = dict(true_params if true_params is not None else getattr(truth, "params", {}))
    fp = dict(fitted_params if fitted_params is not None else getattr(fitted, "params", {}))
    rels = []
    for k, t in tp.items():
        if k not in fp or not isinstance(t, int | float) or not isinstance(fp[k], int | float):
            continue
        if t == 0:
            out[f"abs_err_{k}"] = abs(float(fp[k]))
        else:
            r = abs(float(fp[k]) - float(t)) / abs(float(t))
            out[f"rel_err_{k}"] = r
            rels.append(r)
    if rels:
        out["max_rel_err"] = max(rels)
    out["rms_log_brdf"] = float(np.sqrt(np.mean(d * d)))
    return out


# --------------------------------------------------------------------------- fit_preset task
def sample_design(
    n_samples: int, rng: int | np.random.Generator | None = None, lobe_deg: float = 15.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A measurement design of ``n_samples`` direction pairs: half spread, half near the lobe.

    θi uniform in cos over 0…70°, φi uniform; ``wo`` cosine-distributed over the hemisphere
    for half the samples and within ``lobe_deg`` of the mirror direction for the others
    (directions below 2° elevation are redrawn). Reproducible for a given ``rng``.
    """
    if not isinstance(n_samples, int) or n_samples < 2:
        raise ValueError(f"n_samples must be an integer >= 2, got {n_samples!r}")
    g = np.random.default_rng(rng)
    wis, wos, have = [], [], 0
    while have < n_samples:
        n = 2 * (n_samples - have) + 8
        ti = np.arccos(1.0 - g.random(n) * (1.0 - math.cos(math.radians(70.0))))
        wi = to_vector(ti, 2 * np.pi * g.random(n))
        half = n // 2
        to = np.arcsin(np.sqrt(g.random(half)))
        wo_spread = to_vector(to, 2 * np.pi * g.random(half))
        mirror = wi[half:] * np.array([-1.0, -1.0, 1.0])
        d = np.radians(lobe_deg) * np.sqrt(g.random(n - half))
        az = 2 * np.pi * g.random(n - half)
        a = np.where(np.abs(mirror[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
        u = np.cross(mirror, a)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        v = np.cross(mirror, u)
        wo_lobe = np.cos(d)[:, None] * mirror + np.sin(d)[:, None] * (
            np.cos(az)[:, None] * u + np.sin(az)[:, None] * v
        )
        wo = np.concatenate([wo_spread, wo_lobe])
        ok = wo[:, 2] > math.sin(math.radians(2.0))
        wis.append(wi[ok])
        wos.append(wo[ok])
        have += int(ok.sum())
    return np.concatenate(wis)[:n_samples], np.concatenate(wos)[:n_samples]


_FIT_PRESET_DEFAULTS: dict[str, Any] = {
    "noise": 0.02,
    "n_samples": 400,
    "weighted": True,
    "residual": "relative",
    "fit_model": "",
    "lobe_deg": 15.0,
    "design_seed": 12345,
}


def fit_preset_options(task: Mapping[str, Any]) -> dict[str, Any]:
    """Validated options of a ``fit_preset`` task (its ``fixed`` and ``settings`` merged).

    ``noise`` (relative Gaussian noise σ/f, 0 ≤ noise < 1, default 0.02), ``n_samples``
    (≥ 8, default 400), ``residual`` (a :mod:`gonio.fit` residual, default ``"relative"``),
    ``fit_model`` (default: the preset's own model), ``lobe_deg`` (cone of the lobe samples),
    ``design_seed`` (the direction design is the same for every noise seed), ``weighted``
    (give the fit the samples' σ = noise·f, default true; without σ the residual choice
    matters).
    """
    from gonio import materials

    mat = task.get("material")
    if mat not in materials.names():
        raise ValueError(
            f"material {mat!r} is not a preset; known presets are: {', '.join(materials.names())}"
        )
    opts = dict(_FIT_PRESET_DEFAULTS)
    given = {**dict(task.get("fixed", {})), **dict(task.get("settings", {}))}
    unknown = sorted(set(given) - set(opts))
    if unknown:
        raise ValueError(f"fit_preset: unknown option(s) {unknown}; expected some of {list(opts)}")
    opts.update(given)
    noise = opts["noise"]
    if not isinstance(noise, int | float) or isinstance(noise, bool) or not 0 <= noise < 1:
        raise ValueError(f"fit_preset: noise must be a number in [0, 1), got {noise!r}")
    n = opts["n_samples"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 8:
        raise ValueError(f"fit_preset: n_samples must be an integer >= 8, got {n!r}")
    from gonio.fit import RESIDUALS

    if opts["residual"] not in RESIDUALS:
        raise ValueError(
            f"fit_preset: residual must be one of {list(RESIDUALS)}, got {opts['residual']!r}"
        )
    if not isinstance(opts["weighted"], bool):
        raise ValueError(f"fit_preset: weighted must be true or false, got {opts['weighted']!r}")
    lobe = opts["lobe_deg"]
    if not isinstance(lobe, int | float) or not 0 < lobe <= 90:
        raise ValueError(f"fit_preset: lobe_deg must be in (0, 90], got {lobe!r}")
    if not isinstance(opts["design_seed"], int):
        raise ValueError(f"fit_preset: design_seed must be an integer, got {opts['design_seed']!r}")
    fm = opts["fit_model"] or materials.info(mat)["model"]
    if not isinstance(fm, str):
        raise ValueError(f"fit_preset: fit_model must be a model name, got {fm!r}")
    from gonio.fit import parse_model

    parse_model(fm)  # raises ValueError listing the registered models
    opts["fit_model"] = fm
    return opts


def fit_preset(task: Mapping[str, Any], out_dir: str | os.PathLike | None = None) -> dict:
    """Simulate noisy samples of a material preset, fit a model, return the errors.

    The pure task behind ``gonio sweep``'s default ``task = "fit_preset"``: the preset's BRDF
    is evaluated on :func:`sample_design` (seeded by ``design_seed``), multiplied by
    ``1 + noise·N(0, 1)`` drawn from ``task["seed"]`` (σ = noise·f recorded), fitted with
    :func:`gonio.fit.fit` (``residual``), and compared with :func:`brdf_errors`. Writes
    ``samples.csv`` and ``fit.json`` to ``out_dir`` if given. Returns the errors plus
    ``converged``, ``nfev``-free counters (``n_samples``, ``chi2_dof``).
    """
    from gonio import fit, materials
    from gonio.io.samples_table import write_samples
    from gonio.samples import BRDFSamples

    opts = fit_preset_options(task)
    truth = materials.get(task["material"])
    if truth.n_bands:
        raise ValueError(f"fit_preset: material {task['material']!r} is spectral; expected grey")
    wi, wo = sample_design(opts["n_samples"], opts["design_seed"], opts["lobe_deg"])
    f = np.asarray(truth(wi, wo), dtype=np.float64)
    rng = np.random.default_rng(int(task.get("seed", 0)))
    noise = float(opts["noise"])
    y = f * (1.0 + noise * rng.standard_normal(f.shape)) if noise > 0 else f.copy()
    sigma = noise * f if noise > 0 and opts["weighted"] else None
    samples = BRDFSamples.from_directions(
        wi, wo, y, sigma, metadata={"material": task["material"], "noise": noise}
    )
    r = fit.fit(samples, opts["fit_model"], residual=opts["residual"], rng=0)
    errs = brdf_errors(truth, r.model)
    out = {**errs, "converged": bool(r.converged), "chi2_dof": float(r.chi2_dof)}
    if not math.isfinite(out["chi2_dof"]):
        out["chi2_dof"] = None
    if out_dir is not None:
        out_dir = Path(out_dir)
        write_samples(samples, out_dir / "samples.csv")
        from gonio.io.jsonfile import write_json

        write_json(
            out_dir / "fit.json",
            {"truth": truth.params, "truth_model": truth.name, "fit": r.to_dict()},
        )
    return out


# --------------------------------------------------------------------------- registries
@dataclass(frozen=True)
class Knob:
    """A setting that trades run time for accuracy.

    ``run(setting, seed)`` performs the computation at that setting and returns its errors
    (a dict of floats); the bench times the call. ``requires`` lists modules that must be
    importable (with ``needs`` the attributes that must exist in them, ``"module:attr"``);
    otherwise the knob is reported as not yet available with ``waiting_on``.
    """

    name: str
    description: str
    settings: tuple[Any, ...]
    quick_settings: tuple[Any, ...]
    run: Callable[[Any, int], Mapping[str, float]] | None
    primary: str = "rms_log_brdf"
    unit: str = ""
    needs: tuple[str, ...] = ()
    waiting_on: str = ""
    prepare: Callable[[], Any] | None = None  # untimed set-up (references, caches, JIT)
    quick_run: Callable[[Any, int], Mapping[str, float]] | None = None  # cheaper form


@dataclass(frozen=True)
class Ablation:
    """A skip rule: ``run(enabled) -> result`` with the rule on (True) and off (False)."""

    name: str
    description: str
    run: Callable[[bool], Any] | None
    quick_run: Callable[[bool], Any] | None = None
    needs: tuple[str, ...] = ()
    waiting_on: str = ""
    #: 0: the results must be bit-identical; > 0: the rule is an approximation by design and
    #: the largest relative difference must stay below this
    rtol: float = 0.0
    prepare: Callable[[], Any] | None = None  # untimed set-up


KNOBS: dict[str, Knob] = {}
ABLATIONS: dict[str, Ablation] = {}


def register_knob(knob: Knob) -> Knob:
    """Add ``knob`` to :data:`KNOBS` (replacing one of the same name)."""
    KNOBS[knob.name] = knob
    return knob


def register_ablation(ab: Ablation) -> Ablation:
    """Add ``ab`` to :data:`ABLATIONS` (replacing one of the same name)."""
    ABLATIONS[ab.name] = ab
    return ab


def _missing(needs: Sequence[str]) -> str | None:
    """The first unmet requirement ``"module"`` or ``"module:attr"``, or ``None``."""
    for need in needs:
        mod_name, _, attr = need.partition(":")
        try:
            mod = importlib.import_module(mod_name)
        except Exception:  # not written yet, or broken while being written
            return need
        obj: Any = mod
        for part in filter(None, attr.split(".")):
            if not hasattr(obj, part):
                return need
            obj = getattr(obj, part)
    return None


def _time_call(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    best, out = math.inf, None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def run_bench(
    knobs: Sequence[str] | None = None,
    *,
    quick: bool = False,
    seeds: Sequence[int] = (0,),
    repeat: int = 1,
    ablations: bool = True,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the knob sweeps (and the ablations) and return the JSON-ready report.

    Returns ``{"rows": [...], "knobs": {name: {"available", "waiting_on", "description",
    "primary"}}, "ablations": [...], "quick": bool, "seeds": [...]}``; each row is
    ``{"knob", "setting", "seed", "time_s", "primary", "error", <all errors>}``; each ablation
    ``{"name", "available", "waiting_on", "time_off_s", "time_on_s", "speedup", "identical",
    "max_abs_diff"}``.
    """
    names = list(KNOBS) if knobs is None else list(knobs)
    for n in names:
        if n not in KNOBS:
            raise ValueError(f"unknown knob {n!r}; known knobs are: {', '.join(KNOBS)}")
    say = progress or (lambda _m: None)
    rows: list[dict[str, Any]] = []
    info: dict[str, dict[str, Any]] = {}
    for n in names:
        k = KNOBS[n]
        miss = _missing(k.needs)
        if k.run is None:
            waiting = k.waiting_on or "not wired yet"
        elif miss is not None:
            waiting = f"{k.waiting_on} (missing {miss})"
        else:
            waiting = ""
        info[n] = {
            "description": k.description,
            "primary": k.primary,
            "unit": k.unit,
            "available": not waiting,
            "waiting_on": waiting,
        }
        if waiting:
            say(f"knob {n}: not yet available: {waiting}")
            continue
        try:
            rows.extend(_run_knob(k, quick, seeds, repeat, say))
        except Exception as exc:  # a module being rewritten, or a real failure: reported
            info[n]["available"] = False
            info[n]["error"] = f"{type(exc).__name__}: {exc}"
            info[n]["waiting_on"] = f"failed: {info[n]['error']}"
            say(f"knob {n}: FAILED {info[n]['error']}")
    abl = run_ablations(quick=quick, repeat=repeat, progress=say) if ablations else []
    return {"quick": quick, "seeds": list(seeds), "rows": rows, "knobs": info, "ablations": abl}


def _run_knob(k: Knob, quick: bool, seeds: Sequence[int], repeat: int, say) -> list[dict]:
    rows = []
    run = (k.quick_run or k.run) if quick else k.run
    if k.prepare is not None:
        k.prepare()
    for setting in k.quick_settings if quick else k.settings:
        for seed in seeds:
            say(f"knob {k.name} = {setting!r} seed {seed}")
            t, errs = _time_call(lambda s=setting, sd=seed: run(s, sd), repeat)
            errs = {e: float(v) for e, v in dict(errs).items()}
            if k.primary not in errs:
                raise RuntimeError(f"knob {k.name} returned no primary error {k.primary!r}")
            rows.append(
                {
                    "knob": k.name,
                    "setting": setting,
                    "seed": int(seed),
                    "time_s": t,
                    "primary": k.primary,
                    "error": errs[k.primary],
                    **errs,
                }
            )
    return rows


def run_ablations(
    names: Sequence[str] | None = None,
    *,
    quick: bool = False,
    repeat: int = 1,
    progress: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Time each skip rule off and on and compare the results (see :class:`Ablation`)."""
    say = progress or (lambda _m: None)
    out = []
    for n in list(ABLATIONS) if names is None else names:
        if n not in ABLATIONS:
            raise ValueError(f"unknown ablation {n!r}; known: {', '.join(ABLATIONS)}")
        ab = ABLATIONS[n]
        miss = _missing(ab.needs)
        rec: dict[str, Any] = {"name": n, "description": ab.description}
        if ab.run is None or miss is not None:
            why = ab.waiting_on or "no switch exposed"
            rec.update(
                available=False, waiting_on=why if miss is None else f"{why} (missing {miss})"
            )
            say(f"ablation {n}: not yet available")
            out.append(rec)
            continue
        fn = (ab.quick_run or ab.run) if quick else ab.run
        say(f"ablation {n}")
        try:
            if ab.prepare is not None:
                ab.prepare()
            t_off, r_off = _time_call(lambda f=fn: f(False), repeat)
            t_on, r_on = _time_call(lambda f=fn: f(True), repeat)
        except Exception as exc:  # reported, not hidden
            err = f"{type(exc).__name__}: {exc}"
            rec.update(available=False, waiting_on=f"failed: {err}", error=err)
            say(f"ablation {n}: FAILED {err}")
            out.append(rec)
            continue
        a, b = np.asarray(r_off, dtype=np.float64), np.asarray(r_on, dtype=np.float64)
        same_shape = a.shape == b.shape
        diff = (
            float(np.max(np.abs(a - b)))
            if same_shape and a.size
            else (0.0 if same_shape else math.inf)
        )
        if same_shape and a.size:
            scale = np.maximum(np.abs(a), np.max(np.abs(a)) * 1e-6)
            rel = float(np.max(np.abs(a - b) / np.where(scale > 0, scale, 1.0)))
        else:
            rel = 0.0 if same_shape else math.inf
        identical = bool(same_shape and np.array_equal(a, b))
        rec.update(
            available=True,
            waiting_on="",
            time_off_s=t_off,
            time_on_s=t_on,
            speedup=t_off / t_on if t_on > 0 else math.inf,
            identical=identical,
            max_abs_diff=diff,
            max_rel_diff=rel,
            rtol=ab.rtol,
            unchanged=identical or (ab.rtol > 0 and rel <= ab.rtol),
        )
        out.append(rec)
    return out


# --------------------------------------------------------------------------- outputs
def rows_csv(rows: Sequence[Mapping[str, Any]]) -> bytes:
    """The bench rows as CSV (columns: union of the rows' keys in first-seen order)."""
    cols: list[str] = []
    for r in rows:
        cols.extend(k for k in r if k not in cols)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(
            [
                ""
                if r.get(c) is None
                else (repr(r[c]) if isinstance(r.get(c), float) else r.get(c, ""))
                for c in cols
            ]
        )
    return buf.getvalue().encode()


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the (time, error) points no other point beats in both (ties kept)."""
    idx = []
    for i, (t, e) in enumerate(points):
        dominated = any(
            (t2 <= t and e2 <= e) and (t2 < t or e2 < e)
            for j, (t2, e2) in enumerate(points)
            if j != i
        )
        if not dominated:
            idx.append(i)
    return idx


def plot_pareto(report: Mapping[str, Any], path: str | os.PathLike) -> Path:
    """Time vs error per knob (log–log, one panel per primary error kind), PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from gonio.io.atomic import atomic_write_bytes

    rows = report["rows"]
    kinds = list(dict.fromkeys(r["primary"] for r in rows)) or ["rms_log_brdf"]
    fig, axes = plt.subplots(1, len(kinds), figsize=(5.5 * len(kinds), 4.5), squeeze=False)
    for ax, kind in zip(axes[0], kinds):
        sel = [r for r in rows if r["primary"] == kind]
        errs = [float(r["error"]) for r in sel]
        # a floor so that exact results (error 0 or 1e-14) do not squash the axis: drawn on
        # it with a downward marker
        span = 1e-15 if kind == "rel_err" else 1e-6  # quadrature errors span many decades
        floor = max(min([e for e in errs if e > 0] or [1e-17]), span * max(errs or [1.0]))
        for knob in dict.fromkeys(r["knob"] for r in sel):
            rs = [r for r in sel if r["knob"] == knob]
            by: dict[str, list] = {}  # mean over seeds per setting
            for r in rs:
                by.setdefault(json.dumps(r["setting"]), []).append(r)
            ts = [float(np.mean([x["time_s"] for x in v])) for v in by.values()]
            es = [float(np.mean([x["error"] for x in v])) for v in by.values()]
            shown = [max(e, floor) for e in es]
            (line,) = ax.plot(ts, shown, "o-", label=knob, alpha=0.8)
            low = [(t, y) for t, y, e in zip(ts, shown, es) if e < floor]
            if low:
                ax.plot(*zip(*low), "v", color=line.get_color(), ms=9)
            for t, y, lab in zip(ts, shown, by):
                ax.annotate(str(json.loads(lab)), (t, y), fontsize=6, color=line.get_color())
        if len({r["knob"] for r in sel}) == 1:  # a front only among settings of one knob
            pts = [(float(r["time_s"]), max(float(r["error"]), floor)) for r in sel]
            front = sorted((pts[i] for i in pareto_front(pts)), key=lambda p: p[0])
            if len(front) > 1:
                ax.step(*zip(*front), where="post", color="k", lw=0.8, ls=":", label="Pareto")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per run (s)")
        ax.set_ylabel(kind + (f" (▼: below {floor:.1g})" if min(errs or [1]) < floor else ""))
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(
        "gonio bench: run time against error" + (" (quick)" if report.get("quick") else "")
    )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


# --------------------------------------------------------------------------- built-in knobs
class _Memo:
    """Expensive references shared between the settings of a knob (computed once)."""

    def __init__(self) -> None:
        self.data: dict[str, Any] = {}

    def get(self, key: str, make: Callable[[], Any]) -> Any:
        if key not in self.data:
            self.data[key] = make()
        return self.data[key]


REFERENCES = _Memo()


def _albedo_models() -> list[Any]:
    from gonio import brdf, materials

    return [
        materials.get("rolled_brass"),
        brdf.create("ward", rho_d=0.05, rho_s=0.3, alpha_x=0.02, alpha_y=0.05),
    ]


_ALBEDO_THETAS = np.radians([0.0, 30.0, 60.0, 80.0, 85.0])


def _albedo_reference() -> list[NDArray]:
    wi = to_vector(_ALBEDO_THETAS, 0.0)
    return [np.asarray(m.albedo(wi, rtol=1e-10)) for m in _albedo_models()]


def _knob_albedo_rtol(rtol: float, seed: int) -> dict[str, float]:
    ref = REFERENCES.get("albedo", _albedo_reference)
    wi = to_vector(_ALBEDO_THETAS, 0.0)
    err = 0.0
    for m, r in zip(_albedo_models(), ref):
        a = np.asarray(m.albedo(wi, rtol=float(rtol)))
        err = max(err, float(np.max(np.abs(a - r) / np.abs(r))))
    return {"rel_err": err}


def _warm_fit() -> None:
    """Untimed, once: import and run gonio.fit (first-call costs are not the knob's)."""
    REFERENCES.get(
        "fit_warm",
        lambda: fit_preset({"material": "rolled_brass", "seed": 0, "settings": {}, "fixed": {}}),
    )


def _fit_knob(**settings: Any) -> Callable[[Any, int], dict[str, float]]:
    def run(value: Any, seed: int, _s: dict = settings) -> dict[str, float]:
        key, base = next(iter(_s.items()))
        task = {
            "material": base["material"],
            "seed": seed,
            "fixed": {k: v for k, v in base.items() if k != "material"},
            "settings": {key: value},
        }
        res = fit_preset(task)
        return {k: float(v) for k, v in res.items() if isinstance(v, float) and k != "chi2_dof"}

    return run


register_knob(
    Knob(
        "albedo_rtol",
        "relative tolerance of the adaptive quadrature albedo (BRDF.albedo(wi, rtol)); Ward "
        "rolled brass and a sharper Ward lobe at θi = 0…85°; error vs rtol = 1e-10",
        settings=(1e-1, 1e-2, 1e-3, 1e-4, 1e-6, 1e-8),
        quick_settings=(1e-1, 1e-3, 1e-6),
        run=_knob_albedo_rtol,
        prepare=lambda: REFERENCES.get("albedo", _albedo_reference),
        primary="rel_err",
        unit="rtol",
    )
)
register_knob(
    Knob(
        "fit_residual",
        "misfit minimised by gonio.fit (unweighted, 5 % noise, 400 samples, rolled brass)",
        settings=("absolute", "relative", "log", "li_torrance"),
        quick_settings=("absolute", "log"),
        run=_fit_knob(
            residual={
                "material": "rolled_brass",
                "noise": 0.05,
                "n_samples": 400,
                "weighted": False,
            }
        ),
        needs=("gonio.fit:fit",),
        waiting_on="fit: gonio.fit",
        prepare=_warm_fit,
    )
)
register_knob(
    Knob(
        "noise_level",
        "relative sensor noise σ/f of the simulated samples (400 samples, rolled brass, "
        "relative residual)",
        settings=(0.0, 0.01, 0.03, 0.1, 0.3),
        quick_settings=(0.0, 0.1),
        run=_fit_knob(noise={"material": "rolled_brass", "n_samples": 400}),
        needs=("gonio.fit:fit",),
        waiting_on="fit: gonio.fit",
        prepare=_warm_fit,
    )
)
register_knob(
    Knob(
        "sample_count",
        "number of BRDF samples fitted (a stand-in for thinning and plan density; 5 % noise, "
        "rolled brass)",
        settings=(25, 50, 100, 400, 1600, 6400),
        quick_settings=(50, 400),
        run=_fit_knob(n_samples={"material": "rolled_brass", "noise": 0.05}),
        needs=("gonio.fit:fit",),
        waiting_on="fit: gonio.fit",
        prepare=_warm_fit,
    )
)

# --------------------------------------------------------------------------- LBL pipeline knobs
_INSTRUMENTS: dict[tuple, Any] = {}

#: the LBL knobs' material: Ward rolled brass (Ward 1992, §6)
LBL_MATERIAL = "rolled_brass"
#: a sharper Ward lobe for the source-size knob (α well below 5× the beam divergence)
SHARP_WARD = {"rho_d": 0.05, "rho_s": 0.3, "alpha_x": 0.01, "alpha_y": 0.02}


def _instrument(
    mirror: str = "ellipsoid", width: int = 640, height: int = 480, sensor: Any = None,
    effects: Mapping[str, float] | None = None,
) -> Any:  # fmt: skip
    """A cached simulated LBL instrument (its traced geometry is kept between runs);
    ``sensor``: a :class:`~gonio.simulator.Sensor` (default: the instrument's default);
    ``effects``: its imperfections (:mod:`gonio.simulator.effects`, default none)."""
    fx = tuple(sorted((effects or {}).items()))
    key = (mirror, width, height, sensor, fx)
    if key not in _INSTRUMENTS:
        from gonio.simulator import LBLInstrument

        _INSTRUMENTS[key] = LBLInstrument(
            mirror=mirror, width=width, height=height, sensor=sensor, effects=dict(fx) or None
        )
    return _INSTRUMENTS[key]


def lbl_pipeline(
    material: str | Any = LBL_MATERIAL,
    *,
    theta_i_deg: Sequence[float] = (20.0, 50.0),
    mirror: str = "ellipsoid",
    size: tuple[int, int] = (640, 480),
    binning: tuple[int, int] | bool | None = None,
    source_samples: int | None = None,
    n_exposures: int | None = None,
    method: str = "eq3",
    thinning: bool | Mapping[str, Any] = True,
    noise: bool = True,
    seed: int = 0,
    residual: str = "absolute",
    sensor: Any = None,
    effects: Mapping[str, float] | None = None,
) -> dict[str, float]:
    """Capture → reduce → fit on the simulated LBL instrument; the errors of the fit.

    ``effects``: the instrument's imperfections (:mod:`gonio.simulator.effects`), not
    corrected (the reduction is a laboratory's that does not know them).

    For each incidence θi (at φi = 0): the sample, the diffuse standard and the background
    are captured at the f-stops :meth:`~gonio.simulator.LBLInstrument.plan_bracket` keeps for
    the sample (the first ``n_exposures`` of them, darkest first, if given), reduced with
    :func:`gonio.calibration.reduce.reduce_capture` (``method``, ``thinning``; a ``thinning``
    dict with ``select=True`` uses :func:`~gonio.calibration.reduce.reduce_selected` with the
    dict's other options) and the
    concatenated samples fitted with :func:`gonio.fit.fit`. ``sensor``: the camera's
    :class:`~gonio.simulator.Sensor` (default: the instrument's). Returns
    :func:`brdf_errors` plus ``n_samples``.
    """
    from gonio import fit, materials
    from gonio.brdf import BRDF, create
    from gonio.calibration.reduce import Capture, reduce_capture, reduce_selected
    from gonio.samples import BRDFSamples

    if isinstance(material, BRDF):
        truth = material
    elif isinstance(material, dict):
        truth = create("ward", **material)
    else:
        truth = materials.get(material)
    inst = _instrument(mirror, *size, sensor, effects=effects)
    tables = []
    for j, th in enumerate(theta_i_deg):
        ti = math.radians(th)
        stops = list(inst.plan_bracket(truth, ti, 0.0)["f_numbers"])
        if n_exposures is not None:
            stops = stops[: int(n_exposures)]
        shots = {}
        for kind, smp in (("measured", truth), ("standard", "standard"), ("background", None)):
            frames = []
            for k, fn in enumerate(stops):
                rng = int(seed) * 1_000_003 + 1000 * j + 10 * k + len(shots)
                frames.append(
                    inst.capture(
                        smp, ti, 0.0, f_number=fn, rng=rng, noise=noise, binning=binning,
                        source_samples=source_samples,
                    )
                )  # fmt: skip
            shots[kind] = Capture(frames)
        triple = (shots["measured"], shots["standard"], shots["background"])
        if isinstance(thinning, Mapping) and thinning.get("select"):
            opts = {k: v for k, v in thinning.items() if k != "select"}
            res = reduce_selected(*triple, method=method, rng=int(seed) + j, **opts)
        else:
            res = reduce_capture(*triple, method=method, thinning=thinning)
        tables.append(res.samples)
    samples = BRDFSamples.concatenate(tables)
    r = fit.fit(samples, truth.name, residual=residual)
    return {**brdf_errors(truth, r.model), "n_samples": float(len(samples))}


_SIZES = {
    "108x80 binned": {"binning": True},
    "216x160 binned": {"binning": (216, 160)},
    "160x120": {"size": (160, 120)},
    "320x240": {"size": (320, 240)},
    "640x480": {"size": (640, 480)},
    "1024x768": {"size": (1024, 768)},
}
_THINNING = {
    "off": False,
    "average coarse": {"base_level": 3, "max_level": 7, "peak_level": 5},
    "average default": True,
    "average fine": {"base_level": 5, "max_level": 10, "peak_level": 8},
    "select coarse": {"select": True, "base_level": 4, "peak_level": 7},
    "select default": {"select": True},
    "select fine": {"select": True, "base_level": 6, "peak_level": 9},
}
_MAPS = {
    "hemisphere eq3": {"mirror": "hemisphere", "method": "eq3"},
    "hemisphere exact": {"mirror": "hemisphere", "method": "exact"},
    "ellipsoid eq3": {"mirror": "ellipsoid", "method": "eq3"},
    "ellipsoid exact": {"mirror": "ellipsoid", "method": "exact"},
}
_LBL_NEEDS = (
    "gonio.simulator:LBLInstrument",
    "gonio.calibration.reduce:reduce_capture",
    "gonio.fit:fit",
)


def _warm_lbl() -> None:
    """Untimed, once: trace the default instrument's geometry and compile its kernels."""
    REFERENCES.get("lbl_warm", lambda: lbl_pipeline(theta_i_deg=(30.0,), noise=False))


def _lbl_knob(
    opts_of: Callable[[Any], dict[str, Any]], quick: bool = False
) -> Callable[[Any, int], dict]:
    def run(setting: Any, seed: int) -> dict[str, float]:
        opts = opts_of(setting)
        if quick:
            opts.setdefault("theta_i_deg", (30.0,))
        return lbl_pipeline(seed=seed, **opts)

    return run


def _exposure_opts(n: int | str) -> dict[str, Any]:
    return {"material": dict(SHARP_WARD), "n_exposures": None if n == "auto" else int(n)}


def _size_opts(s: str) -> dict[str, Any]:
    if s not in _SIZES:
        raise ValueError(f"image_resolution setting {s!r}; expected one of {list(_SIZES)}")
    return dict(_SIZES[s])


def _source_image(n: int) -> NDArray:
    from gonio.brdf import create

    return _instrument().electrons(
        create("ward", **SHARP_WARD), math.radians(30.0), source_samples=int(n)
    )


def _knob_source(n: int, seed: int) -> dict[str, float]:
    ref = REFERENCES.get("source_ref", lambda: (_source_image(241), _source_image(1)))
    img = _source_image(n)
    # lit pixels: signal above the background by 1 % of the peak signal
    sig_ref = ref[0] - np.min(ref[0])
    lit = sig_ref > 0.01 * sig_ref.max()
    d = (img[lit] - ref[0][lit]) / ref[0][lit]
    return {
        "image_rel_rms": float(np.sqrt(np.mean(d * d))),
        "image_rel_max": float(np.abs(d).max()),
    }


for _knob in (
    Knob(
        "image_resolution",
        "camera resolution of the simulated LBL capture (sensor size, or 640×480 binned by "
        "area averaging, incl. Ward's 108 × 80); rolled brass, θi = 20°, 50°",
        settings=tuple(_SIZES),
        quick_settings=("108x80 binned", "320x240"),
        run=_lbl_knob(_size_opts),
        quick_run=_lbl_knob(_size_opts, quick=True),
        needs=_LBL_NEEDS,
        prepare=_warm_lbl,
    ),
    Knob(
        "exposures",
        "number of bracketed f-stops merged per capture, darkest first, for a sharp Ward "
        "lobe (α = 0.01/0.02) whose automatic bracket keeps 6 stops ('auto')",
        settings=(1, 2, 3, 4, "auto"),
        quick_settings=(1, "auto"),
        run=_lbl_knob(_exposure_opts),
        quick_run=_lbl_knob(_exposure_opts, quick=True),
        needs=_LBL_NEEDS,
        prepare=_warm_lbl,
    ),
    Knob(
        "eq3_vs_traced",
        "reflection angles by Ward's eq. 3 (as printed for the hemisphere; the focal form "
        "for the ellipsoid) vs the exact traced mirror map",
        settings=tuple(_MAPS),
        quick_settings=("hemisphere eq3", "hemisphere exact"),
        run=_lbl_knob(lambda s: dict(_MAPS[s])),
        quick_run=_lbl_knob(lambda s: dict(_MAPS[s]), quick=True),
        needs=(*_LBL_NEEDS, "gonio.simulator:Mirror"),
        prepare=_warm_lbl,
    ),
    Knob(
        "thinning_density",
        "data thinning of the reduced pixels: off (every pixel), averaging in adaptive "
        "equal-solid-angle bins (coarse, default, fine), or selection of one pixel per "
        "equal-solid-angle cell (coarse, default, fine; the campaign's default)",
        settings=tuple(_THINNING),
        quick_settings=("average default", "select default"),
        run=_lbl_knob(lambda s: {"thinning": _THINNING[s]}),
        quick_run=_lbl_knob(lambda s: {"thinning": _THINNING[s]}, quick=True),
        needs=(*_LBL_NEEDS, "gonio.calibration.thinning:thin"),
        prepare=_warm_lbl,
    ),
    Knob(
        "source_convolution",
        "directions averaged over the source cone (1 = no convolution) in the simulated "
        "capture of a sharp Ward lobe (α = 0.01/0.02, below 5× the 0.25° beam divergence), "
        "θi = 30°, noise-free; error: RMS and max relative difference of the lit pixels' "
        "electrons from a 241-direction reference",
        settings=(1, 7, 19, 61),
        quick_settings=(1, 19),
        run=_knob_source,
        primary="image_rel_rms",
        needs=("gonio.simulator:LBLInstrument",),
        prepare=lambda: REFERENCES.get(
            "source_ref", lambda: (_source_image(241), _source_image(1))
        ),
    ),
):
    register_knob(_knob)


def _sensor_opts(setting: str) -> dict[str, Any]:
    """The sensor of a ``sensor_effects`` setting: the ideal sensor, one effect alone at its
    realistic magnitude (:data:`gonio.simulator.sensor.REALISTIC`), or all of them."""
    from gonio.simulator import Sensor
    from gonio.simulator.sensor import REALISTIC, REALISTIC_ARRAY_SHAPE

    if setting not in _SENSOR_EFFECTS:
        raise ValueError(
            f"sensor_effects setting {setting!r}; expected one of {list(_SENSOR_EFFECTS)}"
        )
    names = _SENSOR_EFFECTS[setting]
    opts: dict[str, Any] = {"material": dict(SHARP_WARD)}
    if names == ("all",):
        return {**opts, "sensor": Sensor.realistic()}
    kw = {n: REALISTIC[n] for n in names}
    if kw:
        kw["array_shape"] = REALISTIC_ARRAY_SHAPE
    return {**opts, "sensor": Sensor(**kw)}


_SENSOR_EFFECTS = {
    "ideal": (),
    "charge_clip": ("charge_clip",),
    "blooming": ("blooming",),
    "smear": ("smear",),
    "offsets": ("offset_dsnu", "row_dsnu", "column_dsnu"),
    "hot_pixels": ("hot_pixels", "hot_pixel_dark"),
    "realistic": ("all",),
}

register_knob(
    Knob(
        "sensor_effects",
        "the camera's sensor effects (EMVA 1288 terms), each alone at its realistic "
        "magnitude, and all of them (Sensor.realistic()): charge clipped at the full well "
        "before the read noise, blooming, smear, offset patterns, hot pixels; a sharp Ward "
        "lobe (α = 0.01/0.02, bracketed over 6 stops, the wider ones saturating the peak), "
        "θi = 20°, 50°, reduced without any sensor correction (time: the whole pipeline)",
        settings=tuple(_SENSOR_EFFECTS),
        quick_settings=("ideal", "realistic"),
        run=_lbl_knob(_sensor_opts),
        quick_run=_lbl_knob(lambda s: {**_sensor_opts(s), "size": (320, 240)}, quick=True),
        needs=(*_LBL_NEEDS, "gonio.simulator.sensor:REALISTIC"),
        prepare=_warm_lbl,
    )
)

#: the rays-per-pixel knob's image size (small pixels would hide the sub-pixel effect less)
_RAYS_SIZE = (160, 120)
_RAYS_REF = 64


def _rays_image(n: int) -> NDArray:
    from gonio.brdf import create

    inst = _instrument("ellipsoid", *_RAYS_SIZE)
    sharp = create("ward", **SHARP_WARD)
    ti = math.radians(30.0)
    return inst.electrons(sharp, ti, rays_per_pixel=int(n)) - inst.electrons(None, ti)


def _warm_rays() -> None:
    """Untimed: the reference image, and every setting's supersampled geometry traced (the
    knob times a render with cached geometry, as a campaign's captures are)."""
    REFERENCES.get("rays_ref", lambda: _rays_image(_RAYS_REF))
    for n in (1, 4, 9, 16, 25):
        _instrument("ellipsoid", *_RAYS_SIZE)._geometry(n)


def _knob_rays(n: int, seed: int) -> dict[str, float]:
    ref = REFERENCES.get("rays_ref", lambda: _rays_image(_RAYS_REF))
    img = _rays_image(n)
    lit = ref > 0.01 * ref.max()
    d = (img[lit] - ref[lit]) / ref[lit]
    return {
        "image_rel_rms": float(np.sqrt(np.mean(d * d))),
        "image_rel_max": float(np.abs(d).max()),
        "signal_rel_err": float(abs(img[lit].sum() - ref[lit].sum()) / ref[lit].sum()),
    }


register_knob(
    Knob(
        "rays_per_pixel",
        "sub-pixel supersampling of the simulated LBL capture (s × s rays per pixel, each "
        "traced through the mirror to the sample) for a sharp Ward lobe (α = 0.01/0.02), "
        f"{_RAYS_SIZE[0]}×{_RAYS_SIZE[1]}, θi = 30°, noise-free; error: RMS and max relative "
        f"difference of the lit pixels' signal from a {_RAYS_REF}-ray reference (time: one "
        "render, sub-pixel geometry traced beforehand)",
        settings=(1, 4, 9, 16, 25),
        quick_settings=(1, 4),
        run=_knob_rays,
        primary="image_rel_rms",
        unit="rays",
        needs=("gonio.simulator.lbl:_check_rays",),
        waiting_on="lbl: capture(rays_per_pixel=)",
        prepare=_warm_rays,
    )
)


# --------------------------------------------------------------------------- instrument effects
def _effect_settings() -> tuple[str, ...]:
    from gonio.simulator.effects import EFFECTS, PRESETS

    return ("ideal",) + tuple(n for n in EFFECTS if PRESETS["modern"][n].typical != 0.0)


def _effect_magnitudes(setting: str, ablate: bool) -> dict[str, float]:
    """``setting`` of the effect knobs: one effect alone at the modern preset's typical
    magnitude, or (``ablate``) the modern preset's typical instrument without it."""
    from gonio.simulator.effects import PRESETS

    typical = {n: d.typical for n, d in PRESETS["modern"].items()}
    if setting == "ideal":
        return dict(typical) if ablate else {}
    if setting not in typical:
        raise ValueError(f"unknown effect setting {setting!r}")
    if ablate:
        return {n: v for n, v in typical.items() if n != setting}
    return {setting: typical[setting]}


def _effect_knob(ablate: bool) -> Callable[[Any, int], dict[str, float]]:
    def run(setting: str, seed: int) -> dict[str, float]:
        return lbl_pipeline(seed=seed, effects=_effect_magnitudes(setting, ablate))

    return run


_EFFECT_NEEDS = (*_LBL_NEEDS, "gonio.simulator.effects:PRESETS")

for _name, _ablate, _what in (
    ("lbl_effect", False, "one imperfection of the LBL instrument at a time "
     "(gonio.simulator.effects, at the modern preset's typical magnitude; 'ideal' = none)"),
    ("lbl_effect_ablation", True, "the modern preset's typical LBL instrument with one "
     "imperfection removed ('ideal' = all of them on)"),
):  # fmt: skip
    register_knob(
        Knob(
            _name,
            f"{_what}, uncorrected, through capture → eq. 2 → fit (rolled brass, θi = 20, "
            "50°): the error it causes (or leaves) and what it costs",
            settings=_effect_settings(),
            quick_settings=("ideal", "veiling_glare", "standard_non_lambertian"),
            run=_effect_knob(_ablate),
            primary="max_rel_err",
            unit="effect",
            needs=_EFFECT_NEEDS,
            waiting_on="simulator: effects",
            prepare=_warm_lbl,
        )
    )


#: scales of an effect's typical magnitude in the magnitude knob's settings
EFFECT_SCALES = (0.5, 2.0)


def _magnitude_settings() -> tuple[str, ...]:
    """``"ideal"`` and ``"<effect>*<scale>"`` for every effect of the modern preset at each of
    :data:`EFFECT_SCALES` times its typical magnitude that lies in the effect's valid range
    (with ``"<effect>*1"``, the ``lbl_effect`` row, between them)."""
    from gonio.simulator.effects import PRESETS, check_magnitudes

    out = ["ideal"]
    for name in _effect_settings()[1:]:
        typical = PRESETS["modern"][name].typical
        for scale in EFFECT_SCALES:
            try:
                check_magnitudes({name: scale * typical})
            except ValueError:
                continue
            out.append(f"{name}*{scale:g}")
    return tuple(out)


def _knob_effect_magnitude(setting: str, seed: int) -> dict[str, float]:
    """One effect alone at ``scale`` times its typical magnitude (``"name*scale"``), through
    capture → eq. 2 → fit uncorrected: its error grows with the magnitude, its cost is the
    time of the pipeline with it."""
    from gonio.simulator.effects import PRESETS

    if setting == "ideal":
        return lbl_pipeline(seed=seed, effects={})
    name, _, scale = setting.partition("*")
    if name not in PRESETS["modern"] or not scale:
        raise ValueError(f"lbl_effect_magnitude setting {setting!r}; expected 'effect*scale'")
    magnitude = float(scale) * PRESETS["modern"][name].typical
    return {**lbl_pipeline(seed=seed, effects={name: magnitude}), "magnitude": magnitude}


try:  # the settings come from the effects' table
    _MAGNITUDE_SETTINGS = _magnitude_settings()
except ImportError:  # pragma: no cover - the simulator's effects are not there
    _MAGNITUDE_SETTINGS = ("ideal",)

register_knob(
    Knob(
        "lbl_effect_magnitude",
        "one imperfection of the LBL instrument alone at "
        + " and ".join(f"{x:g}" for x in EFFECT_SCALES)
        + " times the modern preset's typical magnitude (the lbl_effect rows are 1 times), "
        "uncorrected, through capture → eq. 2 → fit (rolled brass, θi = 20, 50°): how its "
        "error and its cost grow with its magnitude",
        settings=_MAGNITUDE_SETTINGS,
        quick_settings=("veiling_glare*2",),
        run=_knob_effect_magnitude,
        primary="max_rel_err",
        unit="effect*scale",
        needs=_EFFECT_NEEDS,
        waiting_on="simulator: effects",
        prepare=_warm_lbl,
    )
)

# --------------------------------------------------------------------------- Oren-Nayar quadrature
_ON_CASES = ({"rho": 0.5, "sigma": 0.3}, {"rho": 0.8, "sigma": 1.0})


def _on_model(nodes: int, **params: float) -> Any:
    from gonio.brdf import get_class

    return get_class("oren_nayar_numeric")(nodes=nodes, **params)


def _on_reference() -> list[NDArray]:
    wi, wo = error_directions()
    return [np.asarray(_on_model(64, **p)(wi, wo)) for p in _ON_CASES]


def _knob_on_nodes(nodes: int, seed: int) -> dict[str, float]:
    wi, wo = error_directions()
    err = 0.0
    for p, ref in zip(_ON_CASES, REFERENCES.get("oren_nayar", _on_reference)):
        f = np.asarray(_on_model(int(nodes), **p)(wi, wo))
        pos = ref > 0
        err = max(err, float(np.max(np.abs(f[pos] - ref[pos]) / ref[pos])))
    return {"rel_err": err}


register_knob(
    Knob(
        "oren_nayar_numeric_nodes",
        "Gauss-Legendre nodes per piece of oren_nayar_numeric's θa quadrature (eq. 25); "
        "σ = 0.3 and 1.0 rad over the error direction set; error vs 64 nodes",
        settings=(2, 4, 8, 16, 32),
        quick_settings=(4, 16),
        run=_knob_on_nodes,
        primary="rel_err",
        unit="nodes",
        needs=("gonio.brdf.oren_nayar:OrenNayarNumeric",),
        waiting_on="models-on: oren_nayar_numeric",
        prepare=lambda: REFERENCES.get("oren_nayar", _on_reference),
    )
)


# --------------------------------------------------------------------------- ablations
_ABL_THETA = math.radians(30.0)
#: relative shot noise of a full-well pixel of the default sensor (40 000 e⁻)
_SHOT_NOISE_FULL_WELL = 1.0 / math.sqrt(40000.0)


def _abl_visible(enabled: bool) -> NDArray:
    inst = _instrument()
    return inst.electrons(LBL_MATERIAL, _ABL_THETA, kernel=False, visible_only=enabled)


def _abl_kernel(enabled: bool) -> NDArray:
    return _instrument().electrons(LBL_MATERIAL, _ABL_THETA, kernel=enabled)


def _abl_grey_once(enabled: bool) -> NDArray:
    frames = _instrument().capture_bands(
        LBL_MATERIAL, _ABL_THETA, noise=False, evaluate_once=enabled
    )
    return np.stack([img for img, _ in frames]).astype(np.float64)


def _abl_geometry(enabled: bool) -> NDArray:
    from gonio.simulator import LBLInstrument, lbl

    if not enabled:
        lbl._GEOMETRY_CACHE.clear()  # the cache is shared by instruments of equal optics
    return LBLInstrument().electrons(LBL_MATERIAL, _ABL_THETA)


def _abl_convolution(enabled: bool) -> NDArray:
    # rolled brass: α = 0.05 rad ≥ 5 × the 0.25° divergence, so the rule renders 1 direction
    return _instrument().electrons(LBL_MATERIAL, _ABL_THETA, source_samples=None if enabled else 19)


def _warm_instrument() -> None:
    _instrument().electrons(LBL_MATERIAL, _ABL_THETA)


for _ab in (
    Ablation(
        "geometry_cache",
        "per-instrument pixel → mirror → sample geometry traced once and cached (off: the "
        "cache is emptied, so the capture traces it again)",
        _abl_geometry,
        needs=("gonio.simulator:LBLInstrument", "gonio.simulator.lbl:_GEOMETRY_CACHE"),
        prepare=_warm_instrument,
    ),
    Ablation(
        "visible_pixel_mask",
        "BRDF evaluated only at pixels that see the lit sample (off: at every in-field pixel, "
        "masked afterwards); numpy path",
        _abl_visible,
        needs=("gonio.simulator:LBLInstrument",),
        prepare=_warm_instrument,
    ),
    Ablation(
        "compiled_ward_kernel",
        "specialised numba kernel for Ward-type models (off: the generic numpy path); "
        "floating-point order differs, so equal to 1e-12 relative",
        _abl_kernel,
        needs=("gonio.simulator:LBLInstrument",),
        rtol=1e-12,
        prepare=_warm_instrument,
    ),
    Ablation(
        "grey_once",
        "a grey BRDF evaluated once for all filter bands (capture_bands, 3 filters)",
        _abl_grey_once,
        needs=("gonio.simulator:LBLInstrument",),
        prepare=_warm_instrument,
    ),
    Ablation(
        "convolution_skipping",
        "source-cone average skipped (1 direction instead of 19) when the lobe is ≥ 5× the "
        "beam divergence; an approximation by design, allowed the relative shot noise of a "
        "full-well pixel, 1/sqrt(40000 e⁻) = 0.5 %",
        _abl_convolution,
        needs=("gonio.simulator:LBLInstrument",),
        rtol=_SHOT_NOISE_FULL_WELL,
        prepare=_warm_instrument,
    ),
):
    register_ablation(_ab)


def _abl_noise_off(enabled: bool) -> NDArray:
    img, _ = _instrument().capture(LBL_MATERIAL, _ABL_THETA, noise=False, skip_noise_draws=enabled)
    return img.astype(np.float64)


def _usable_at(n: float) -> NDArray:
    """Lit pixels of the sharp lobe in the usable range at f/n (unsaturated with 10 %
    headroom, >= 16 DN of signal), from that stop's own noise-free electrons (cached)."""

    def make() -> NDArray:
        from gonio.brdf import create

        inst = _instrument()
        sharp = create("ward", **SHARP_WARD)
        e = inst.electrons(sharp, _ABL_THETA, f_number=n)
        b = inst.electrons(None, _ABL_THETA, f_number=n)
        sen = inst.sensor
        return (e <= 0.9 * sen.full_well) & (e - b >= 16.0 * sen.gain)

    return REFERENCES.get(f"usable_f{n:g}", make)


def _warm_skipping() -> None:
    from gonio.simulator.lbl import F_STOPS

    _warm_instrument()
    for n in F_STOPS:
        _usable_at(n)


def _abl_exposure_skipping(enabled: bool) -> NDArray:
    """Bracket (noise off) with and without the skipped stops; the result is the set of lit
    pixels measured in the usable range by at least one of the frames taken."""
    from gonio.brdf import create

    inst = _instrument()
    frames = inst.bracket(create("ward", **SHARP_WARD), _ABL_THETA, noise=False, skip_stops=enabled)
    covered = np.zeros((inst.lens.height, inst.lens.width), dtype=bool)
    for _img, meta in frames:
        covered |= _usable_at(meta["f_number"])
    return covered.astype(np.float64)


for _ab in (
    Ablation(
        "noise_off",
        "no random draws when noise is off (off: the shot and read noise are drawn and added "
        "with zero amplitude); capture of rolled brass, 640×480",
        _abl_noise_off,
        needs=("gonio.simulator.lbl:_check_rays",),
        prepare=_warm_instrument,
    ),
    Ablation(
        "exposure_skipping",
        "f-stops adding no usable pixel skipped by plan_bracket (off: every stop from the "
        "first unsaturated one is captured); sharp Ward lobe, θi = 30°, noise off; result: "
        "the lit pixels measured in the usable range (each stop's own noise-free render) by "
        "at least one frame taken",
        _abl_exposure_skipping,
        needs=("gonio.simulator.lbl:_check_rays",),
        prepare=_warm_skipping,
    ),
):
    register_ablation(_ab)


# --------------------------------------------------------------------------- Cornell plan density
def _knob_cornell(n: int, seed: int) -> dict[str, float]:
    from gonio import fit, materials
    from gonio.simulator.cornell import simulate_campaign
    from gonio.simulator.cornell_plans import hemispherical_plan

    truth = materials.get(LBL_MATERIAL)
    plan = hemispherical_plan(theta_i_deg=(20, 50), n=int(n))
    samples = simulate_campaign(plan, truth, rng=seed)
    # one Ward for all 31 bands (the truth is grey): 4 parameters
    r = fit.fit(samples, "ward", residual="absolute", per_band=())
    return {**brdf_errors(truth, r.model), "n_samples": float(len(samples))}


register_knob(
    Knob(
        "cornell_plan_density",
        "Cornell three-axis instrument, hemispherical plan of n × n viewing directions per "
        "θi (20°, 50°), rolled brass measured in 31 bands, one grey Ward fitted",
        settings=(3, 5, 9, 15, 21),
        quick_settings=(3, 9),
        run=_knob_cornell,
        unit="n",
        needs=(
            "gonio.simulator.cornell:simulate_campaign",
            "gonio.simulator.cornell_plans:hemispherical_plan",
            "gonio.fit:fit",
        ),
        waiting_on="cornell: simulate_campaign / hemispherical_plan",
        prepare=lambda: REFERENCES.get("cornell_warm", lambda: _knob_cornell(3, 0)),
    )
)


# --------------------------------------------------------------------------- laboratory corrections
#: the corrections knob's settings: all, each one left out, none
CORRECTION_SETTINGS = (
    "all", "-geometry", "-standard", "-exposure", "-glare", "none",
)  # fmt: skip


def _seven_angle_campaign(
    seed: int, out: str | None = None, **plan_kw: Any
) -> tuple[Any, dict[str, float]]:
    """A rolled-brass campaign on 7 incidences (0-78°) in one process, no plots (results
    folder ``out``, default none): its result and the fit's :func:`brdf_errors`."""
    from gonio import materials
    from gonio.campaign import Plan, run

    plan = Plan(material=LBL_MATERIAL, seed=seed, plots=False,
                theta_i_deg=tuple(float(a) for a in np.linspace(0.0, 78.0, 7)),
                **plan_kw)  # fmt: skip
    r = run(plan, out, workers=1)
    return r, brdf_errors(materials.get(LBL_MATERIAL), r.fit.model)


def _knob_corrections(setting: str, seed: int) -> dict[str, float]:
    """A realistic (``modern``) rolled-brass campaign on 7 incidences with the laboratory's
    corrections (:data:`gonio.campaign.knowledge.CORRECTIONS`) all on, one left out, or
    none: the fit's errors, and the largest error in units of the reported expanded
    uncertainty (``max_err_over_U`` <= 1: the budget covers the error)."""
    from gonio import materials
    from gonio.campaign.knowledge import CORRECTIONS

    if setting == "all":
        corr = CORRECTIONS
    elif setting == "none":
        corr = ()
    else:
        corr = tuple(c for c in CORRECTIONS if c != setting.lstrip("-"))
    r, out = _seven_angle_campaign(seed, preset="modern", corrections=corr)
    truth = materials.get(LBL_MATERIAL)
    u = r.summary["budget"]["expanded"]
    ratios = [abs(r.fit.params[k] - truth.params[k]) / u[k] for k in u if u[k] > 0]
    out["max_err_over_U"] = float(max(ratios))
    return out


register_knob(
    Knob(
        "lbl_corrections",
        "the laboratory's corrections of a realistic LBL instrument (modern preset, rolled "
        "brass, 7 θi): all, each one left out (its effect stays in the data and the budget "
        "carries it uncorrected), none",
        settings=CORRECTION_SETTINGS,
        # quick: the campaign without corrections only; the quick bench's campaign with all
        # of them is lbl_instrument's "modern" row (the same plan, seed and instrument)
        quick_settings=("none",),
        run=_knob_corrections,
        primary="max_rel_err",
        unit="corrections",
        needs=("gonio.simulator.effects", "gonio.campaign.knowledge"),
        waiting_on="the simulator's effects (gonio.simulator.effects)",
    )
)


# --------------------------------------------------------------------------- realistic vs ideal
#: the instrument knob's settings: the ideal instrument, the realistic one calibrated by its
#: own calibration captures (the default campaign), and the realistic one with a kept
#: calibration folder (what a laboratory does between campaigns)
INSTRUMENT_SETTINGS = ("ideal", "modern", "modern+calibration_folder")


def _bench_dir() -> str:
    """A temporary folder for the instrument knob's campaigns (removed at exit)."""

    def make() -> str:
        import atexit
        import shutil
        import tempfile

        d = tempfile.mkdtemp(prefix="gonio-bench-")
        atexit.register(shutil.rmtree, d, True)
        return d

    return REFERENCES.get("bench_dir", make)


def _knob_instrument(setting: str, seed: int) -> dict[str, float]:
    """A 7-θi rolled-brass campaign (one process) on the ideal or the realistic instrument;
    the time is the campaign's, the calibration captures and the budget included."""
    if setting not in INSTRUMENT_SETTINGS:
        raise ValueError(f"lbl_instrument setting {setting!r}; expected {INSTRUMENT_SETTINGS}")
    import shutil

    preset, _, folder = setting.partition("+")
    # the kept folder: the calibration the "modern" row's campaign of this seed (the same
    # physical instrument) wrote; the rows run in the order of the settings
    lab = os.path.join(_bench_dir(), f"lab-{seed}")
    if folder and not os.path.isdir(lab):
        raise ValueError("lbl_instrument: the calibration-folder row needs the modern row first")
    out_dir = os.path.join(_bench_dir(), f"{setting}-{seed}")
    shutil.rmtree(out_dir, ignore_errors=True)
    r, out = _seven_angle_campaign(seed, out_dir, preset=preset,
                                   calibration=lab if folder else None)  # fmt: skip
    if preset == "modern" and not folder and not os.path.isdir(lab):
        shutil.copytree(os.path.join(out_dir, "calibration"), lab)
    tim = r.summary["timings_s"]
    out["calibration_s"] = float(tim.get("calibration", 0.0))
    out["budget_s"] = float(tim.get("budget", 0.0))
    return out


register_knob(
    Knob(
        "lbl_instrument",
        "a 7-θi rolled-brass campaign in one process, results folder written, on the ideal "
        "instrument, on the realistic one (modern preset) with its calibration captures, "
        "and with the calibration folder that campaign wrote kept (what a laboratory does "
        "between campaigns): what realism costs, where (calibration_s, budget_s), and the "
        "error it brings",
        settings=INSTRUMENT_SETTINGS,
        quick_settings=("modern",),
        run=_knob_instrument,
        primary="max_rel_err",
        unit="instrument",
        needs=("gonio.simulator.effects", "gonio.campaign.knowledge"),
        waiting_on="the simulator's effects (gonio.simulator.effects)",
        prepare=_warm_lbl,
    )
)
