"""Numerical stress tests: every model and pipeline stage on adversarial input.

``gonio stress`` (issue 8) runs the registered *stages* in :data:`STAGES`. Each stage takes a
:class:`StressConfig` and returns a :class:`StageResult`: how many cases it ran and, per
subject (a model name, an image kind, a fit …), how many violations of each kind it saw.
The ``models`` stage is built in; the pipeline stages (``images``: saturated, black and
constant images through eq. 2; ``geometry``: mirror geometry as D → 0 and D → R; ``fits``:
fits started far from the truth) live in :mod:`gonio.diagnostics.stress_stages`, registered with
:func:`register_stage` when this module is imported. Besides the kinds below they count
``warning`` (a ``RuntimeWarning`` that reached the caller) and ``norm`` (a non-unit
direction).

Violation kinds (:data:`KINDS`):

``nan`` / ``inf``
    a non-finite value;
``negative``
    a value below 0;
``horizon``
    a non-zero value with a direction at or below the horizon (z ≤ 0);
``reciprocity``
    ``|f(wi, wo) − f(wo, wi)| > RECIPROCITY_RTOL · max(|f|)``;
``energy``
    the directional-hemispherical albedo above ``1 + ENERGY_TOL`` at a sampled ``wi``;
``error``
    an exception other than a parameter-validation ``ValueError``.

A violation is *known* — reported under ``"known"`` with its figures, not counted as
unexpected — when it is a documented property of the model: a ``spec.known_issues`` entry
containing one of :data:`KNOWN_KEYWORDS` for its kind (e.g. Ward's "albedo diverges at grazing
incidence", Neumann §7.4), or ``spec.reciprocal`` / ``spec.energy_conserving`` being false.

Inputs of the model stage:

* directions exactly normal, at 1e-12 and 1e-8 from the normal, at 90° − 1e-9 and 90° − 1e-12,
  exactly on the horizon (z = +0 and −0), below it, generic; all pairs of them, plus
  ``wi = wo``, ``wi`` = the mirror of ``wo``, ``wi = −wo``, and uniform random pairs; each set
  once in float64 and once rounded to float32 (slightly non-unit vectors);
* parameter sets generated from ``brdf.spec(name)``: the defaults; each float parameter in
  turn at its bounds, just inside them (relative 1e-6), log-spaced between them when they span
  decades, and at large values when unbounded; random combinations; plus per-parameter-name
  extremes (:data:`EXTRA_VALUES`: Phong ``n`` up to 1e8, σ from 0 to 1.5 rad, α from 1e-4 to
  1) and per-model extras (:data:`MODEL_EXTRAS`: Li-Torrance τ/σ from 1 to 100, a measured
  table for ``tabulated``). Sets a model rejects with ``ValueError`` are counted as
  ``rejected``, not as violations.
* Energy is checked at the default reflectances (parameters named ``rho*``, ``k_*``,
  ``a_d``, ``a_s``, ``c_n``, ``r_m``: the albedo scales with them, so pushing them to their
  bounds only leaves the physical domain) while the shape parameters (α, n, σ, τ …) sweep
  their bounds; ``wi`` at :data:`ENERGY_THETA_DEG`. The albedo is the model's analytic one
  where it has one, otherwise a product Gauss-Legendre quadrature at two resolutions; when
  they disagree by more than 1 % the case is counted as ``energy_unresolved`` (not a
  violation).

>>> from gonio import stress
>>> r = stress.run("small", models=["lambert"])
>>> r["unexpected"], r["models"]["lambert"]["nan"]
(0, 0)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ENERGY_THETA_DEG",
    "ENERGY_TOL",
    "EXTRA_VALUES",
    "KINDS",
    "KNOWN_KEYWORDS",
    "MODEL_EXTRAS",
    "RECIPROCITY_RTOL",
    "SIZES",
    "STAGES",
    "StageResult",
    "StressConfig",
    "adversarial_pairs",
    "register_stage",
    "run",
]

KINDS = ("nan", "inf", "negative", "horizon", "reciprocity", "energy", "error")
#: keywords in ``spec.known_issues`` that make a violation of a kind "known"
KNOWN_KEYWORDS: dict[str, tuple[str, ...]] = {
    "nan": ("nan",),
    "inf": ("infinite", "overflow"),
    "negative": ("negative",),
    "horizon": ("horizon",),
    "reciprocity": ("reciproc",),
    "energy": ("albedo", "energy"),
    "error": (),
}
RECIPROCITY_RTOL = 1e-9
ENERGY_TOL = 1e-3
ENERGY_THETA_DEG = (0.0, 45.0, 75.0, 85.0, 89.0, 89.9, 89.99, 89.999, 89.99999)
_WEIGHT_PREFIXES = ("rho", "k_", "a_d", "a_s", "c_n", "r_m")

#: extra values tried for a parameter of this name (clipped to the model's bounds)
EXTRA_VALUES: dict[str, tuple[float, ...]] = {
    "n": (1e4, 1e6, 1e8),
    "sigma": (0.0, 1e-6, 1e-3, 0.5, 1.0, 1.5),
    "alpha_x": (1e-4, 1e-3, 0.01, 1.0),
    "alpha_y": (1e-4, 1e-3, 0.01, 1.0),
    "m": (1e-4, 1e-3, 1.0),
}


@dataclass(frozen=True)
class StressConfig:
    """Sizes and seeds of one stress run (see :data:`SIZES`)."""

    size: str = "default"
    n_random: int = 200  # random direction pairs per parameter set
    n_random_sets: int = 4  # random parameter combinations per model
    energy: bool = True
    energy_nodes: tuple[int, int] = (24, 48)  # coarse (n_s, n_phi); fine is twice that
    analytic_albedo: bool = True  # use a model's own analytic albedo (else quadrature only)
    max_sets: int = 80  # cap on parameter sets per model
    model_seconds: float = 3.0  # evaluation budget per model (random pairs are trimmed)
    models: tuple[str, ...] | None = None
    rng: int = 0


SIZES: dict[str, StressConfig] = {
    "small": StressConfig(
        "small",
        n_random=20,
        n_random_sets=1,
        max_sets=25,
        model_seconds=0.3,
        analytic_albedo=False,
    ),
    "default": StressConfig("default", model_seconds=2.0),
    "full": StressConfig("full", n_random=4000, n_random_sets=12, max_sets=80, model_seconds=60.0),
}


@dataclass
class StageResult:
    """What a stage reports: cases run, violation counts per subject, known issues."""

    name: str
    cases: int = 0
    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    known: list[dict[str, Any]] = field(default_factory=list)
    examples: list[dict[str, Any]] = field(default_factory=list)  # first unexpected cases
    info: dict[str, Any] = field(default_factory=dict)
    unexpected: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "cases": self.cases,
            "unexpected": self.unexpected,
            "counts": self.counts,
            "known": self.known,
            "examples": self.examples,
            "info": self.info,
        }


#: registered stages, run in order: name -> function(StressConfig) -> StageResult
STAGES: dict[str, Callable[[StressConfig], StageResult]] = {}


def register_stage(name: str) -> Callable:
    """Decorator registering ``func(cfg) -> StageResult`` as stress stage ``name``."""

    def deco(func: Callable[[StressConfig], StageResult]) -> Callable:
        if name in STAGES and STAGES[name] is not func:
            raise ValueError(f"stress stage {name!r} registered twice")
        STAGES[name] = func
        return func

    return deco


# --------------------------------------------------------------------------- directions


def _vec(theta: float, phi: float) -> NDArray:
    return np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )


def _adversarial_directions() -> NDArray:
    ds = [np.array([0.0, 0.0, 1.0])]
    for th in (1e-12, 1e-8, 0.3, 0.8, 1.2, 1.5, math.pi / 2 - 1e-9, math.pi / 2 - 1e-12):
        for ph in (0.0, 2.0, math.pi, -math.pi / 2):
            ds.append(_vec(th, ph))
    ds += [
        np.array([1.0, 0.0, 0.0]),
        np.array([0.0, 1.0, -0.0]),
        np.array([0.6, 0.0, -0.8]),
        np.array([0.0, 0.0, -1.0]),
    ]
    return np.array(ds)


def adversarial_pairs(n_random: int, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
    """``(wi, wo)`` arrays of shape ``(n, 3)``: all pairs of the adversarial directions,
    related pairs (equal, mirrored, opposite) and ``n_random`` uniform random pairs."""
    d = _adversarial_directions()
    a, b = np.meshgrid(np.arange(len(d)), np.arange(len(d)), indexing="ij")
    wi = [d[a.ravel()]]
    wo = [d[b.ravel()]]
    mirror = d * np.array([-1.0, -1.0, 1.0])
    wi += [d, d, d]
    wo += [d, mirror, -d]
    if n_random > 0:
        u = rng.normal(size=(2, n_random, 3))
        u[..., 2] = np.abs(u[..., 2])
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        wi.append(u[0])
        wo.append(u[1])
    return np.concatenate(wi), np.concatenate(wo)


# --------------------------------------------------------------------------- parameter sets


def _is_weight(name: str) -> bool:
    return name.startswith(_WEIGHT_PREFIXES)


def _float_params(spec) -> list:
    return [p for p in spec.params.values() if p.kind == "float"]


def _one_param_values(p, default: float | None) -> list[float]:
    lo, hi = p.lower, p.upper
    vals: list[float] = []
    if math.isfinite(lo):
        vals += [lo, lo + max(abs(lo), 1.0) * 1e-6 if lo == 0 else lo * (1 + 1e-6)]
    if math.isfinite(hi):
        vals += [hi, hi * (1 - 1e-6) if hi != 0 else -1e-6]
    if math.isfinite(lo) and math.isfinite(hi) and lo > 0 and hi / lo >= 100:
        vals += list(np.geomspace(lo, hi, 5)[1:-1])
    if not math.isfinite(hi):
        base = default if default not in (None, 0) else 1.0
        vals += [abs(base) * 10, abs(base) * 1e3, abs(base) * 1e6]
    vals += list(EXTRA_VALUES.get(p.name, ()))
    out = []
    for v in vals:
        v = float(v)
        if lo <= v <= hi and v not in out:
            out.append(v)
    return out


def _li_torrance_extras(spec, cfg: StressConfig) -> list[dict]:
    names = set(spec.params)
    d = spec.defaults()
    out = []
    if "sigma" in names:
        sig = float(d.get("sigma", 0.1) or 0.1)
        for r in (1.0, 3.0, 10.0, 30.0, 100.0):
            for taus in (("tau",), ("tau_x", "tau_y"), ("tau_x",)):
                if all(t in names for t in taus):
                    out.append({**{t: sig * r for t in taus}})
    return out


def _tabulated_extras(spec, cfg: StressConfig) -> list[dict]:
    from gonio.io.merl import SHAPE

    g = np.random.default_rng(cfg.rng)
    t = g.random(SHAPE) * 0.5
    t2 = t.copy()
    t2[::7] = -1.0  # MERL's "unmeasured" marker
    return [{"data": t}, {"data": t2}, {"data": np.stack([t, 0.5 * t, 0.25 * t])}]


#: per-model extra parameter sets (merged over the defaults): name -> f(spec, cfg) -> [dict]
MODEL_EXTRAS: dict[str, Callable[[Any, StressConfig], list[dict]]] = {
    "li_torrance": _li_torrance_extras,
    "tabulated": _tabulated_extras,
}


def parameter_sets(name: str, cfg: StressConfig) -> list[tuple[dict, bool]]:
    """``(params, check_energy)`` pairs for model ``name`` (see the module docstring)."""
    from gonio import brdf

    spec = brdf.spec(name)
    d = spec.defaults()
    required = [k for k, p in spec.params.items() if p.default is None and not p.optional]
    extras = MODEL_EXTRAS.get(name, lambda s, c: [])(spec, cfg)
    if required:
        return [({**d, **e}, True) for e in extras if all(k in e for k in required)]
    sets: list[tuple[dict, bool]] = [(dict(d), True)]
    for p in _float_params(spec):
        for v in _one_param_values(p, d.get(p.name)):
            sets.append(({**d, p.name: v}, not _is_weight(p.name)))
        if p.optional and d.get(p.name) is not None:
            sets.append(({**d, p.name: None}, True))
    # all shape parameters together at their lower / upper bounds (e.g. α_x = α_y = 1)
    shape = [p for p in _float_params(spec) if not _is_weight(p.name)]
    for side in ("lower", "upper"):
        joint = {p.name: getattr(p, side) for p in shape if math.isfinite(getattr(p, side))}
        if len(joint) > 1:
            sets.append(({**d, **joint}, True))
    sets += [({**d, **e}, True) for e in extras]
    g = np.random.default_rng(cfg.rng)
    for _ in range(cfg.n_random_sets):
        s = dict(d)
        for p in _float_params(spec):
            lo, hi = p.lower, p.upper
            dv = d.get(p.name)
            if not math.isfinite(lo):
                lo = -abs(dv or 1.0) * 10
            if not math.isfinite(hi):
                hi = max(lo, 0.0) + abs(dv or 1.0) * 100
            if lo > 0 and hi / lo >= 100:
                s[p.name] = float(np.exp(g.uniform(math.log(lo), math.log(hi))))
            else:
                s[p.name] = float(g.uniform(lo, hi))
        sets.append((s, False))
    unique: list[tuple[dict, bool]] = []
    for ps, e in sets:
        if not any(_same(ps, q) for q, _ in unique):
            unique.append((ps, e))
    sets = unique
    if len(sets) > cfg.max_sets:
        keep = np.linspace(0, len(sets) - 1, cfg.max_sets).round().astype(int)
        sets = [sets[i] for i in sorted(set(keep.tolist()))]
    return sets


def _same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = a[k], b[k]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if x is not y:
                return False
        elif x != y:
            return False
    return True


# --------------------------------------------------------------------------- checks


def _flat(v: NDArray, n: int) -> NDArray:
    """Reduce a spectral ``(n, nb)`` result to per-pair ``(n, nb)`` / grey ``(n, 1)``."""
    v = np.asarray(v, dtype=np.float64)
    return v.reshape(n, -1)


def _short_params(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        if isinstance(v, np.ndarray):
            out[k] = f"array{v.shape}"
        elif isinstance(v, float | int | str) or v is None:
            out[k] = v
        else:
            out[k] = repr(v)[:60]
    return out


def _albedo_estimate(
    model, wi: NDArray, nodes: tuple[int, int], analytic: bool, max_seconds: float = np.inf
) -> tuple[NDArray, NDArray]:
    """``(albedo, resolved)`` per ``wi`` (max over bands), delta (mirror) part included.

    The model's analytic albedo when ``analytic``; otherwise product Gauss-Legendre at
    ``nodes``, doubled up to three times until two successive levels agree to 1 %
    ("resolved"), while ``max_seconds`` lasts.
    """
    from gonio.brdf.base import hemisphere_integral

    if analytic:
        a = np.zeros(len(wi))
        ok = np.zeros(len(wi), bool)
        t0 = time.perf_counter()
        for k, w in enumerate(wi):
            a[k] = np.max(np.asarray(model.albedo(w), dtype=np.float64))
            ok[k] = True
            if time.perf_counter() - t0 > max_seconds:
                break
        return a, ok
    mirror = np.asarray(model.delta(wi)[1], dtype=np.float64).reshape(len(wi), -1)
    out = np.zeros(len(wi))
    ok = np.zeros(len(wi), bool)
    t0 = time.perf_counter()
    for k, w in enumerate(wi):
        n_s, n_phi = nodes
        prev = None
        for _ in range(4):  # refine (doubling) until two levels agree to 1 %
            est = hemisphere_integral(lambda o, w=w: model.evaluate_unchecked(w, o), n_s, n_phi)
            est = float(np.max(est + mirror[k]))
            if prev is not None:
                out[k] = est
                ok[k] = math.isfinite(est) and abs(est - prev) <= 0.01 * max(abs(est), 1e-12)
                if ok[k] or time.perf_counter() - t0 > max_seconds:
                    break
            prev = est
            n_s, n_phi = 2 * n_s, 2 * n_phi
    return out, ok


def _known_issue(spec, kind: str) -> str | None:
    if kind == "reciprocity" and not spec.reciprocal:
        return "declared non-reciprocal (spec.reciprocal = False)"
    words = KNOWN_KEYWORDS.get(kind, ())
    for issue in spec.known_issues:
        low = issue.lower()
        if any(w in low for w in words):
            return issue
    if kind == "energy" and not spec.energy_conserving:
        return "declared not energy conserving (spec.energy_conserving = False)"
    return None


def _check_model(name: str, cfg: StressConfig, res: StageResult) -> None:
    """Stress one model: values of every parameter set on adversarial direction pairs
    (NaN, inf, negative, non-zero below the horizon, reciprocity), then energy (albedo
    <= 1), both within the time budget; the counts split into known issues and unexpected."""
    from gonio import brdf

    spec = brdf.spec(name)
    check = _ModelCheck(name, cfg, res)
    deadline = time.perf_counter() + cfg.model_seconds
    models = check.values(parameter_sets(name, cfg), deadline)
    check.energy(spec, models, deadline + 0.5 * cfg.model_seconds)
    check.classify(spec)


class _ModelCheck:
    """The counts, notes and worst cases of :func:`_check_model` for one model."""

    def __init__(self, name: str, cfg: StressConfig, res: StageResult) -> None:
        self.name, self.cfg, self.res = name, cfg, res
        self.counts = dict.fromkeys(KINDS, 0)
        self.info: dict[str, Any] = {
            "parameter_sets": 0,
            "rejected": 0,
            "sets_skipped_for_time": 0,
            "energy_sets": 0,
            "energy_skipped_for_time": 0,
            "energy_unresolved": 0,
            "slowest_set_seconds": 0.0,
        }
        self.worst: dict[str, dict] = {}
        self.max_recip = 0.0

    def values(self, sets: list, deadline: float) -> list:
        """Value checks: the defaults first, then the other sets while the time budget
        lasts; returns the models made, with their parameters and energy flag."""
        from gonio import brdf

        cfg, info = self.cfg, self.info
        g = np.random.default_rng(cfg.rng)
        models = []
        n_rand = cfg.n_random
        for k, (params, check_energy) in enumerate(sets):
            if k > 0 and time.perf_counter() > deadline:
                info["sets_skipped_for_time"] = len(sets) - k
                break
            t_set = time.perf_counter()
            try:
                model = brdf.create(self.name, **params)
            except ValueError:
                info["rejected"] += 1
                continue
            models.append((model, params, check_energy))
            info["parameter_sets"] += 1
            wi, wo = adversarial_pairs(n_rand, g)
            for dtype in (np.float64, np.float32):
                self._pairs(model, params, wi.astype(dtype), wo.astype(dtype), dtype)
            dt = time.perf_counter() - t_set
            info["slowest_set_seconds"] = round(max(info["slowest_set_seconds"], dt), 4)
            if k == 0 and len(sets) > 1:
                # trim the random pairs so that every set fits in half the budget
                per_pair = dt / max(len(wi), 1)
                room = 0.5 * cfg.model_seconds / (len(sets) * per_pair) - (len(wi) - n_rand)
                n_rand = int(min(cfg.n_random, max(0.0, room)))
        info["random_pairs_per_set"] = n_rand
        return models

    def _pairs(self, model: Any, params: dict, a: np.ndarray, b: np.ndarray, dtype: Any) -> None:
        """One model on the pairs ``(a, b)`` and ``(b, a)``: counts of each kind of failure."""
        counts, res = self.counts, self.res
        try:
            v = _flat(model(a, b), len(a))
            vs = _flat(model(b, a), len(a))
        except Exception as exc:
            counts["error"] += 1
            _example(res, self.name, "error", params, repr(exc))
            return
        res.cases += 2 * len(a)
        fin = np.isfinite(v) & np.isfinite(vs)
        c = {
            "nan": int(np.count_nonzero(np.isnan(v).any(-1))),
            "inf": int(np.count_nonzero(np.isinf(v).any(-1))),
            "negative": int(np.count_nonzero((v < 0).any(-1))),
        }
        below = (a[:, 2].astype(np.float64) <= 0) | (b[:, 2].astype(np.float64) <= 0)
        c["horizon"] = int(np.count_nonzero((v[below] != 0).any(-1)))
        scale = np.maximum(np.abs(v), np.abs(vs))
        diff = np.where(fin, np.abs(v - vs), 0.0)
        bad_r = (diff > RECIPROCITY_RTOL * scale + 1e-300).any(-1)
        rel = np.where(scale > 0, diff / np.where(scale > 0, scale, 1.0), 0.0)
        self.max_recip = max(self.max_recip, float(rel.max(initial=0.0)))
        c["reciprocity"] = int(np.count_nonzero(bad_r))
        for kind, n in c.items():
            if n:
                counts[kind] += n
                _note_worst(self.worst, kind, params, a, b, v, vs, dtype)

    def energy(self, spec: Any, models: list, deadline: float) -> None:
        """Albedo <= 1 at the default weights, shape parameters swept, while time lasts."""
        cfg, info, counts, res, worst = self.cfg, self.info, self.counts, self.res, self.worst
        energy_wi = np.array([_vec(math.radians(t), 0.7) for t in ENERGY_THETA_DEG])
        todo = [(m, p) for m, p, e in models if e] if cfg.energy else []
        use_analytic = spec.analytic_albedo and cfg.analytic_albedo
        for k, (model, params) in enumerate(todo):
            if k > 0 and time.perf_counter() > deadline:
                info["energy_skipped_for_time"] = len(todo) - k
                break
            try:
                t_alb = time.perf_counter()
                alb, ok = _albedo_estimate(
                    model, energy_wi, cfg.energy_nodes, use_analytic, 0.05 * cfg.model_seconds
                )
                if use_analytic and time.perf_counter() - t_alb > 0.05 * cfg.model_seconds:
                    use_analytic = False  # the model's own albedo is slow: use the quadrature
                    info["albedo"] = "quadrature (model's analytic albedo too slow)"
            except Exception as exc:
                counts["error"] += 1
                _example(res, self.name, "error", params, f"albedo: {exc!r}")
                continue
            info["energy_sets"] += 1
            res.cases += len(energy_wi)
            nonfinite = ok & ~np.isfinite(alb)
            if nonfinite.any():
                counts["nan"] += int(np.count_nonzero(nonfinite))
                _example(res, self.name, "nan", params,
                         f"albedo {alb.tolist()} at {ENERGY_THETA_DEG}")  # fmt: skip
                ok &= np.isfinite(alb)
            info["energy_unresolved"] += int(np.count_nonzero(~ok))
            over = ok & (alb > 1.0 + ENERGY_TOL)
            if over.any():
                counts["energy"] += int(np.count_nonzero(over))
                i = int(np.argmax(np.where(over, alb, -np.inf)))
                w = worst.get("energy")
                if w is None or alb[i] > w["albedo"]:
                    worst["energy"] = {
                        "params": _short_params(params),
                        "theta_i_deg": ENERGY_THETA_DEG[i],
                        "albedo": float(alb[i]),
                    }

    def classify(self, spec: Any) -> None:
        """Record the counts; a kind the model documents as a known issue is listed as known,
        any other counts as unexpected (with its worst example)."""
        name, res, counts, worst = self.name, self.res, self.counts, self.worst
        res.counts[name] = dict(counts)
        res.info[name] = {**self.info, "max_reciprocity_rel": self.max_recip}
        for kind in KINDS:
            n = counts[kind]
            if not n:
                continue
            issue = _known_issue(spec, kind)
            if issue is not None:
                entry = {"model": name, "kind": kind, "count": n, "issue": issue}
                if kind in worst:
                    entry["worst"] = worst[kind]
                res.known.append(entry)
            else:
                res.unexpected += n
                if kind in worst:
                    _example(res, name, kind, worst[kind].get("params", {}), worst[kind])


def _note_worst(worst, kind, params, a, b, v, vs, dtype) -> None:
    if kind in worst:
        return
    if kind == "reciprocity":
        scale = np.maximum(np.abs(v), np.abs(vs)).max(-1)
        rel = np.where(scale > 0, np.abs(v - vs).max(-1) / np.where(scale > 0, scale, 1), 0)
        rel = np.where(np.isfinite(rel), rel, 0)
        i = int(np.argmax(rel))
        extra = {"relative_difference": float(rel[i]), "f_swapped": vs[i].tolist()}
    else:
        m = {
            "nan": np.isnan(v).any(-1),
            "inf": np.isinf(v).any(-1),
            "negative": (v < 0).any(-1),
            "horizon": ((a[:, 2] <= 0) | (b[:, 2] <= 0)) & (v != 0).any(-1),
        }[kind]
        i = int(np.argmax(m))
        extra = {}
    worst[kind] = {
        "params": _short_params(params),
        "wi": np.asarray(a[i], np.float64).tolist(),
        "wo": np.asarray(b[i], np.float64).tolist(),
        "dtype": np.dtype(dtype).name,
        "f": np.asarray(v[i]).tolist(),
        **extra,
    }


def _example(res: StageResult, subject: str, kind: str, params: dict, detail: Any) -> None:
    if len(res.examples) < 50:
        res.examples.append(
            {"subject": subject, "kind": kind, "params": _short_params(params), "detail": detail}
        )


@register_stage("models")
def model_stage(cfg: StressConfig) -> StageResult:
    """Every registered BRDF model over adversarial directions and parameters."""
    from gonio import brdf

    res = StageResult("models")
    names = list(cfg.models) if cfg.models else brdf.names()
    for n in names:
        brdf.get_class(n)  # unknown names raise ValueError listing the valid ones
    for n in names:
        t0 = time.perf_counter()
        _check_model(n, cfg, res)
        res.info[n]["seconds"] = round(time.perf_counter() - t0, 3)
    return res


# --------------------------------------------------------------------------- driver


def run(
    size: str | StressConfig = "default",
    models: Iterable[str] | None = None,
    rng: int = 0,
    stages: Iterable[str] | None = None,
) -> dict[str, Any]:
    """Run the stress stages and return the report.

    Parameters
    ----------
    size : {"small", "default", "full"} or StressConfig
        ``small`` runs in seconds (tests), ``default`` in under a minute, ``full`` aims at
        10⁷ evaluations.
    models : iterable of str, optional
        Restrict the model stage to these names.
    rng : int
        Seed of the random directions and parameter sets.
    stages : iterable of str, optional
        Stage names to run (default: all of :data:`STAGES`).

    Returns
    -------
    dict
        ``{"cases", "unexpected", "models": {name: {kind: count}}, "known": [...],
        "stages": {stage: {...}}, "size", "seconds"}``.
    """
    if isinstance(size, StressConfig):
        cfg = size
    else:
        if size not in SIZES:
            raise ValueError(f"unknown stress size {size!r}; expected one of {sorted(SIZES)}")
        cfg = SIZES[size]
    if not isinstance(rng, int | np.integer):
        raise ValueError(f"rng must be an integer seed, got {rng!r}")
    cfg = StressConfig(
        **{**cfg.__dict__, "models": tuple(models) if models else cfg.models, "rng": int(rng)}
    )
    chosen = list(stages) if stages else list(STAGES)
    for s in chosen:
        if s not in STAGES:
            raise ValueError(f"unknown stress stage {s!r}; registered stages: {list(STAGES)}")
    t0 = time.perf_counter()
    out: dict[str, Any] = {
        "size": cfg.size,
        "cases": 0,
        "unexpected": 0,
        "models": {},
        "known": [],
        "stages": {},
    }
    for s in chosen:
        r = STAGES[s](cfg)
        out["cases"] += r.cases
        out["unexpected"] += r.unexpected
        out["known"] += r.known
        out["stages"][s] = r.to_dict()
        if s == "models":
            out["models"] = r.counts
    out["seconds"] = round(time.perf_counter() - t0, 3)
    return out


# the pipeline stages register themselves (they import this module's StageResult)
from gonio.diagnostics import stress_stages  # noqa: E402, F401
