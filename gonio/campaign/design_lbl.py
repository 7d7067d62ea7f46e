"""Measurement design for the LBL imaging gonioreflectometer: incidence angles and rotations.

The LBL instrument captures the whole reflected hemisphere at once, so its plan is a set of
incidence angles crossed with a set of sample rotations (:class:`gonio.campaign.plan.Plan`);
its real-instrument time is :func:`gonio.simulator.lbl_timing.estimate_run_time` of that
plan (the standard swept over every angle, the background, one sample sweep per rotation,
the manual swaps and rotations).

The prediction is the campaign's budget (:mod:`gonio.campaign.budget`,
:func:`gonio.campaign.knowledge.campaign_budget`), decomposed by capture: one *candidate
campaign* (every candidate angle and rotation, the prior's material, a physical instrument of
the preset that is not the one to be measured: ``design_instrument_seed``) gives the reduced
samples of each capture, the fit's Jacobian over them and every budget term's perturbation
``δy`` of them. A plan is a subset of those captures; its predicted budget is

* statistical: ``(Σ_g F_g)⁻¹`` scaled by the candidate fit's ``χ²/dof`` (as the campaign's
  fit scales its covariance), ``F_g = J_gᵀ W_g J_g`` of capture group ``g`` = (θi, rotation);
* each systematic term ``u · C Σ_g J_gᵀ W_g δy_g`` (one realisation shared by the plan's
  captures);
* each random term ``Σ_c (u · C Σ_g J_gᵀ W_g δy_{c,g})²`` over its independent realisations
  ``c`` (one capture's exposure, one incidence angle's standard);

combined in quadrature and expanded at k = 2, exactly as :func:`gonio.campaign.budget.build_budget`
combines them. The search: for every non-empty set of the candidate rotations, greedy forward
selection of incidence angles (the largest decrease of the logarithmic hinge of
:mod:`gonio.campaign.design` per second of instrument time), then a backward pass that drops
angles while every target stays met; the quickest plan that meets every target wins.

What the decomposition leaves out: terms whose pattern depends on the whole plan (the lamp's
warm-up and drift follow the capture times of the candidate campaign's schedule, not the
designed one's). The prior is the material preset; a prior range would need one candidate
campaign per point and is not done for this instrument.

Measured (rolled brass, modern preset, targets the default plan's predicted U, three design
instruments): 9 angles x 2 rotations, 0.036 h against the default's 21 x 3 in 0.078 h; run
with the default plan on instruments 0-19: truth within the achieved U 78/80, achieved /
predicted U 0.85-1.27, the designed plan's U at or below the default plan's on the same
instrument for ρs, α_x, α_y every time (ratios 0.74-0.93) and for ρd 13/20 times (0.91-1.08).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992, §3.1 (the protocol and its time), §4 (the
   rotations).
.. [JCGM100] JCGM 100:2008, §5.1-5.2, §6: the budget predicted.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.campaign.design import DesignError, _objective

__all__ = ["LBLDesign", "design_lbl", "lbl_candidates", "write_lbl_plan"]


@dataclasses.dataclass
class _LBLCandidates:
    angles: NDArray  # candidate incidence angles (deg)
    rotations: NDArray  # candidate rotations (deg)
    names: list[str]
    F: NDArray  # (A, R, P, P)
    B: NDArray  # (A, R, P, E) systematic, u included
    rand: list[tuple[NDArray, NDArray, NDArray]]  # per random term: (c, (a, r), P-vectors)
    cov_scale: float
    params: dict[str, float]
    preset: str
    material: str
    term_names: list[str]
    expanded: dict[str, float] = dataclasses.field(default_factory=dict)  # the campaign's U


def lbl_candidates(
    material: str = "rolled_brass",
    *,
    preset: str = "modern",
    angles_deg: tuple[float, ...] | None = None,
    rotations_deg: tuple[float, ...] | None = None,
    design_instrument_seed: int = 1000,
    seed: int = 1000,
) -> _LBLCandidates:
    """Run the candidate campaign and decompose its budget by capture (module docstring)."""
    from gonio import campaign
    from gonio.campaign.budget import Sensitivity
    from gonio.fit import predict

    plan = campaign.Plan(
        material=material, plots=False, seed=seed, instrument_seed=design_instrument_seed,
        preset=preset, **({"theta_i_deg": tuple(angles_deg)} if angles_deg else {}),
        **({"rotations_deg": tuple(rotations_deg)} if rotations_deg else {}),
    )  # fmt: skip
    # in memory (no folder): no raw frames, samples.csv or calibration files written, the
    # same samples and budget (compared: the budget's U and every perturbation identical)
    res = campaign.run(plan, None, quiet=True, workers=1)
    # the budget's inputs as the campaign built it (knowledge.CampaignBudget)
    r, s, perts = res.fit, res.budget.samples, list(res.budget.perturbations)
    if r.residual != "absolute":
        raise DesignError(f"residual {r.residual!r}: the LBL design covers 'absolute' fits")
    names = list(r.free)
    sig = np.where(s.sigma > 0, s.sigma, np.inf) if s.has_sigma else np.ones(len(s))
    w = 1.0 / sig
    jr = np.stack([Sensitivity._column(r, s, k, predict) for k in names], axis=1) * w[:, None]
    rp = res.plan
    angles = np.asarray(rp.theta_i_deg, float)
    rots = np.asarray(rp.rotations_deg, float)
    ai = np.abs(np.degrees(s.theta_i)[:, None] - angles[None]).argmin(axis=1)
    phi = np.degrees(s.phi_i) % 360.0
    ri = np.abs(((phi[:, None] - rots[None]) + 180.0) % 360.0 - 180.0).argmin(axis=1)
    gid = ai * len(rots) + ri
    ng = len(angles) * len(rots)
    P = len(names)
    F = np.zeros((ng, P, P))
    for g in range(ng):
        rows = gid == g
        F[g] = jr[rows].T @ jr[rows]
    sysp = [p for p in perts if p.kind == "systematic"]
    B = np.zeros((ng, P, len(sysp)))
    for e, p in enumerate(sysp):
        v = jr * (w * p.u * np.nan_to_num(p.dy))[:, None]  # (n, P)
        for j in range(P):
            B[:, j, e] = np.bincount(gid, weights=v[:, j], minlength=ng)
    rand = []
    for p in perts:
        if p.kind != "random":
            continue
        v = jr * (w * p.u * np.nan_to_num(p.dy))[:, None]
        key = np.asarray(p.groups, np.int64) * ng + gid
        uk, inv = np.unique(key, return_inverse=True)
        vec = np.stack([np.bincount(inv, weights=v[:, j]) for j in range(P)], axis=1)
        rand.append((uk // ng, uk % ng, vec))
    return _LBLCandidates(
        angles, rots, names, F.reshape(len(angles), len(rots), P, P),
        B.reshape(len(angles), len(rots), P, -1), rand, float(r.cov_scale),
        {k: float(r.params[k]) for k in names}, preset, material,
        [p.name for p in sysp] + [p.name for p in perts if p.kind == "random"],
        dict(res.summary["budget"]["expanded"]),
    )  # fmt: skip


def _u2(c: _LBLCandidates, amask: NDArray, rmask: NDArray, ridge: NDArray) -> NDArray:
    """Predicted squared standard uncertainty (P,) of the plan ``amask`` x ``rmask``."""
    sel = amask[:, None] & rmask[None, :]
    F = c.F[sel].sum(axis=0) + np.diag(ridge)
    C = np.linalg.inv(F)
    out = np.diag(C) * c.cov_scale + np.sum((C @ c.B[sel].sum(axis=0)) ** 2, axis=1)
    flat = sel.reshape(-1)
    for grp, g, vec in c.rand:
        keep = flat[g]
        if not keep.any():
            continue
        n_c = int(grp.max()) + 1
        R = np.zeros((n_c, vec.shape[1]))
        np.add.at(R, grp[keep], vec[keep])
        out += np.sum((R @ C.T) ** 2, axis=0)
    return out


def _u2_worst(cs: list[_LBLCandidates], amask: NDArray, rmask: NDArray, ridge: NDArray):
    """:func:`_u2` on every design instrument, each parameter's worst (largest)."""
    return np.max([_u2(c, amask, rmask, ridge) for c in cs], axis=0)


def _hours(c: _LBLCandidates, amask: NDArray, rmask: NDArray) -> float:
    from gonio.simulator.lbl_timing import TIMINGS, estimate_run_time

    if not amask.any() or not rmask.any():
        return 0.0
    timing = TIMINGS.get(c.preset, TIMINGS["modern"])
    return estimate_run_time(c.angles[amask], c.rotations[rmask], 3, timing)["total_s"] / 3600.0


@dataclasses.dataclass
class LBLDesign:
    """A designed LBL plan and its prediction beside the default plan's."""

    material: str
    theta_i_deg: tuple[float, ...]
    rotations_deg: tuple[float, ...]
    targets: dict[str, float]
    predicted: dict[str, float]  # U per parameter
    hours: float
    default: dict[str, Any]
    design_s: float
    not_met: list[str]

    def table(self) -> str:
        lines = [
            f"{self.material} (lbl): designed {len(self.theta_i_deg)} incidence angles x "
            f"{len(self.rotations_deg)} rotations, {self.hours:.3f} h; default "
            f"{self.default['n_angles']} x {self.default['n_rotations']}, "
            f"{self.default['hours']:.3f} h (real instrument, estimated)",
            f"  angles {list(self.theta_i_deg)}, rotations {list(self.rotations_deg)}",
            f"  {'parameter':<10}{'target U':>12}{'designed U':>12}{'default U':>12}",
        ]
        for p, u in self.predicted.items():
            t = self.targets.get(p, math.nan)
            lines.append(f"  {p:<10}{t:>12.4g}{u:>12.4g}{self.default['predicted'][p]:>12.4g}")
        lines.append(
            f"  targets met (predicted): {len(self.targets) - len(self.not_met)}/"
            f"{len(self.targets)}; design {self.design_s:.1f} s"
        )
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def design_lbl(
    material: str = "rolled_brass",
    targets: dict[str, tuple[float, bool]] | None = None,
    *,
    preset: str = "modern",
    time_limit_h: float | None = None,
    default_factor: float | None = None,
    margin: float = 0.1,
    n_instruments: int = 3,
    candidates: _LBLCandidates | list[_LBLCandidates] | None = None,
) -> LBLDesign:
    """Design an LBL plan (module docstring). ``targets`` as :func:`gonio.campaign.design.
    parse_targets` gives them; ``default_factor = f`` sets every target to ``f`` times the
    default plan's predicted U instead (``1``: the default plan's uncertainty).

    The calibration of each physical instrument leaves it its own uncertainties, so the
    candidate campaign runs on ``n_instruments`` instruments of the preset (instrument seeds
    1000, 1001, ...; never those of the campaigns to come) and every prediction is the worst
    of them per parameter (measured, rolled brass, one design instrument: achieved U on 20
    other instruments up to 1.38 times the prediction for ρd)."""
    from gonio.campaign.design import parse_targets

    t0 = time.perf_counter()
    if time_limit_h is not None and not (math.isfinite(time_limit_h) and time_limit_h > 0):
        raise DesignError(f"time limit {time_limit_h!r} h: expected a positive number of hours")
    tg = parse_targets(None) if targets is None else targets
    if candidates is None:  # the cheap checks before the candidate campaign
        _precheck(material, tg, preset, time_limit_h)
    if candidates is None:
        cs = [lbl_candidates(material, preset=preset, design_instrument_seed=1000 + k)
              for k in range(max(1, int(n_instruments)))]  # fmt: skip
    else:
        cs = list(candidates) if isinstance(candidates, list | tuple) else [candidates]
    c = cs[0]
    valid = set(c.names) | {"all"}
    for name in tg:
        if name not in valid:
            raise DesignError(
                f"target {name!r} is not a fitted parameter; expected one of {c.names} or all"
            )
    P = len(c.names)
    ridge = np.array([1e-6 / (100 * max(abs(v), 1e-3)) ** 2 for v in c.params.values()])
    all_a = np.ones(len(c.angles), bool)
    all_r = np.ones(len(c.rotations), bool)
    u_def = 2.0 * np.sqrt(_u2_worst(cs, all_a, all_r, np.zeros(P)))
    default = {"n_angles": len(c.angles), "n_rotations": len(c.rotations),
               "hours": _hours(c, all_a, all_r),
               "predicted": dict(zip(c.names, map(float, u_def)))}  # fmt: skip
    tabs: dict[str, float] = {}
    for i, p in enumerate(c.names):
        if default_factor is not None:
            tabs[p] = float(default_factor * u_def[i])
            continue
        spec = tg.get(p) or tg.get("all")
        if spec is not None:
            v, rel = spec
            tabs[p] = v * abs(c.params[p]) if rel else v
    t2 = np.array([tabs.get(p, math.inf) ** 2 for p in c.names]) * (1 - margin) ** 2
    limit = math.inf if time_limit_h is None else time_limit_h
    quickest = min(_hours(c, np.eye(len(c.angles), dtype=bool)[0], np.eye(len(c.rotations),
                   dtype=bool)[0]), math.inf)  # fmt: skip
    if quickest > limit:
        raise DesignError(
            f"time limit {time_limit_h} h: no plan can meet it (one angle at one rotation "
            f"takes {quickest:.3g} h)"
        )
    zero = np.zeros(P)
    best = None
    for k in range(1, len(c.rotations) + 1):
        for rsel in itertools.combinations(range(len(c.rotations)), k):
            rmask = np.zeros(len(c.rotations), bool)
            rmask[list(rsel)] = True
            amask = _greedy_angles(cs, rmask, t2, ridge, limit)
            if not amask.any():
                continue
            u2 = _u2_worst(cs, amask, rmask, zero)
            phi = float(_objective(u2, np.zeros(P), t2))
            h = _hours(c, amask, rmask)
            cand = (phi > 0, h if phi <= 0 else phi, amask, rmask, u2)
            if best is None or cand[:2] < best[:2]:
                best = cand
    if best is None:
        raise DesignError("no plan within the time limit identifies every parameter")
    _, _, amask, rmask, u2 = best
    u = 2.0 * np.sqrt(u2)
    pred = dict(zip(c.names, map(float, u)))
    return LBLDesign(
        material, tuple(map(float, c.angles[amask])), tuple(map(float, c.rotations[rmask])),
        tabs, pred, _hours(c, amask, rmask), default, time.perf_counter() - t0,
        [p for p in tabs if pred[p] > tabs[p]],
    )  # fmt: skip


def _precheck(material: str, tg: dict, preset: str, time_limit_h: float | None) -> None:
    """Target names against the material's model's parameters, the time limit against the
    quickest plan (one angle, one rotation), before any simulation."""
    from gonio import brdf, materials
    from gonio.simulator.lbl_timing import TIMINGS, estimate_run_time

    model = materials.get(material)
    names = set(brdf.spec(model.name).bounds)
    for name in tg:
        if name != "all" and name not in names:
            raise DesignError(
                f"target {name!r} is not a parameter of {model.name}; expected one of "
                f"{sorted(names)} or all"
            )
    if time_limit_h is not None:
        timing = TIMINGS.get(preset, TIMINGS["modern"])
        quickest = estimate_run_time([0.0], [0.0], 3, timing)["total_s"] / 3600.0
        if quickest > time_limit_h:
            raise DesignError(
                f"time limit {time_limit_h} h: no plan can meet it (one angle at one rotation "
                f"takes {quickest:.3g} h)"
            )


def _greedy_angles(
    cs: list[_LBLCandidates], rmask: NDArray, t2: NDArray, ridge: NDArray, limit_h: float
) -> NDArray:
    """Forward selection of incidence angles at rotations ``rmask``, then backward pruning
    (the worst of the design instruments)."""
    c = cs[0]
    P = len(c.names)
    zero = np.zeros(P)
    amask = np.zeros(len(c.angles), bool)

    def phi_of(m: NDArray, rid: NDArray = ridge) -> float:
        if not m.any():
            return math.inf
        return float(_objective(_u2_worst(cs, m, rmask, rid), zero, t2))

    cur = math.inf
    while True:
        best, gain = None, 0.0
        h0 = _hours(c, amask, rmask)
        for a in np.flatnonzero(~amask):
            m = amask.copy()
            m[a] = True
            h = _hours(c, m, rmask)
            if h > limit_h:
                continue
            ph = phi_of(m)
            g = (min(cur, 1e6) - ph) / max(h - h0, 1e-9)
            if best is None or g > gain:
                best, gain = a, g
        if best is None or (gain <= 0 and amask.any()):
            break
        amask[best] = True
        cur = phi_of(amask)
        if cur <= 0 and np.linalg.matrix_rank(c.F[amask][:, rmask].sum(axis=(0, 1))) == P:
            break
    # backward: drop angles (those whose loss costs least) while every target stays met
    if phi_of(amask, zero) <= 0:
        for a in np.flatnonzero(amask)[::-1]:
            m = amask.copy()
            m[a] = False
            if m.any() and np.linalg.matrix_rank(c.F[m][:, rmask].sum(axis=(0, 1))) == P:
                if phi_of(m, zero) <= 0:
                    amask = m
    return amask


def write_lbl_plan(path: Any, d: LBLDesign) -> None:
    """The designed plan as an LBL plan file (JSON; ``gonio campaign --plan FILE``), written
    atomically."""
    import json

    from gonio.io.atomic import atomic_write_bytes

    obj = {"instrument": "lbl", "material": d.material, "theta_i_deg": list(d.theta_i_deg),
           "rotations_deg": list(d.rotations_deg), "restandard_every": 0,
           "estimated_real_instrument_h": round(d.hours, 5),
           "predicted_U": d.predicted, "targets_U": d.targets}  # fmt: skip
    atomic_write_bytes(path, (json.dumps(obj, indent=1) + "\n").encode())
