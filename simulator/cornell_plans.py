"""Sampling plans of the Cornell instrument, their ordering and run-time estimate.

* Incidence-plane plans (θi = 15°, 30°, 45°, 60°, 75°; 40-70 points per scan, denser near the
  specular direction) and hemispherical plans (θi = 10°…80° step 10°, 441 positions per θi,
  uniform in solid angle through the Shirley-Chiu map), as in Li and Torrance 2005, §5.1.
* User plans from a CSV file with degree columns ``theta_i, phi_i, theta_o, phi_o``.
* Ordering: greedy nearest neighbour in move time (axes move together, so a move lasts as long
  as its slowest axis) followed by 2-opt passes within each θi block.
* Run-time estimate of the real instrument from stage speeds, settling, integration times and
  overheads (:class:`Timing`), to compare with the paper's "about 11 hours for full
  hemispherical sampling".

The hemispherical grid is ``gonio.geometry.uniform_hemisphere_grid(21)``: 441 Shirley-Chiu cell
centres of equal solid angle 2π/441; its outermost cells sit at θ = 84.6° (``cos θ = 1 −
(20/21)²``), inside the instrument's 85°. ``cap_deg`` optionally maps the same cells uniformly
onto a smaller cap (``cos θ = 1 − r²(1 − cos cap)``, still equal-area).

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Here: §5.1, the 441-position hemispherical plan, the 85° range and the 7° cone about
   retro-reflection that the plans leave out.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from gonio.simulator.cornell_kinematics import Kinematics, inverse
from numpy.typing import ArrayLike, NDArray

from gonio.geometry import shirley_chiu_square_to_disk, to_vector, uniform_hemisphere_grid

__all__ = [
    "Plan",
    "Timing",
    "estimate_run_time",
    "hemispherical_plan",
    "incidence_plane_plan",
    "measurement_seconds",
    "n_rereferences",
    "order_plan",
    "read_plan_csv",
    "reference_seconds",
]

#: reads averaged for a reference when the caller does not say
#: (``gonio.simulator.cornell.CornellConfig.n_reference_reads``' default)
DEFAULT_REFERENCE_READS = 16


@dataclass
class Timing:
    """Speeds and overheads of the real instrument (assumed values; the paper gives none).

    Speeds in rad/s (arm, turntable, tilt), acceleration in rad/s², times in s.

    The paper (Li and Torrance 2005, §5.1) gives only the total: "about 11 hours for full
    hemispherical sampling" (8 × 441 positions, i.e. ≈ 11 s per position). With these values
    a position costs ≈ 1.1 s of motion (ordered plan), 2.8 s of fixed overhead (settling,
    preview, one polariser turn, four read-outs) and four integrations (a signal and a
    dark per polarisation) whose length the auto-exposure sets from the sample's brightness
    (70 % of full scale at the brightest pixel; the simulated detector's sensitivity,
    ``CornellConfig.standard_peak_rate``, is itself an assumption). Measured estimates for
    the 3499 reachable positions: laser paper 7.2 h (mean integration 0.89 s), aluminized
    ground glass 8.1 h (1.10 s), garnet red paint 18.2 h (3.7 s: dark in the blue and
    green), aluminized non-glare glass 30 h (6.8 s: its off-specular BRDF is low; the paper
    measured that sample with the incidence plan). So the paper's 11 h lies within the range
    for the samples it measured hemispherically; the gap for a given sample is set by the
    integration times, not by the stage speeds.

    The estimate's own uncertainty (:func:`estimate_run_time`, ``total_u_h``) comes from
    relative standard uncertainties of these assumptions: ``speed_u`` of the speeds and
    accelerations (a stage's data sheet against its use under load: 20 %), ``overhead_u``
    of the settling, preview, polariser and read-out times (30 %: none is published) and
    ``integration_u`` of the integration times (30 %: they scale inversely with the
    detector's sensitivity, itself an assumption).
    """

    speeds: tuple[float, float, float] = tuple(np.radians([5.0, 10.0, 10.0]))
    acceleration: tuple[float, float, float] = tuple(np.radians([10.0, 20.0, 20.0]))
    settle_s: float = 0.5
    polarizer_change_s: float = 1.5
    read_overhead_s: float = 0.15
    preview_s: float = 0.01
    default_integration_s: float = 1.0
    speed_u: float = 0.2
    overhead_u: float = 0.3
    integration_u: float = 0.3

    def __post_init__(self) -> None:
        for name in ("speed_u", "overhead_u", "integration_u"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0 <= v < 1):
                raise ValueError(
                    f"Timing.{name} = {v!r}: expected a relative uncertainty in [0, 1)"
                )

    def move_time(self, delta: NDArray) -> NDArray:
        """Trapezoidal-profile time of a move by ``delta`` (…, 3) rad; axes move together."""
        d = np.abs(np.asarray(delta, dtype=np.float64))
        v = np.asarray(self.speeds)
        a = np.asarray(self.acceleration)
        d_acc = v * v / a  # distance to reach full speed and stop again
        t = np.where(d < d_acc, 2.0 * np.sqrt(d / a), d / v + v / a)
        return np.max(t, axis=-1)


@dataclass
class Plan:
    """A list of measurement geometries.

    ``wi``, ``wo`` (N, 3): requested directions (sample frame); ``angles`` (N, 3): motor angles
    (rad); ``reachable`` (N,); ``group`` (N,) int (index of the θi block); ``meta`` a dict.
    """

    wi: NDArray[np.float64]
    wo: NDArray[np.float64]
    angles: NDArray[np.float64]
    reachable: NDArray[np.bool_]
    group: NDArray[np.int64]
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.wi.shape[0]

    def subset(self, idx: ArrayLike) -> Plan:
        i = np.asarray(idx)
        return Plan(
            self.wi[i],
            self.wo[i],
            self.angles[i],
            self.reachable[i],
            self.group[i],
            dict(self.meta),
        )

    def measurable(self) -> Plan:
        """Only the reachable rows."""
        return self.subset(np.flatnonzero(self.reachable))

    @classmethod
    def from_directions(
        cls,
        wi: ArrayLike,
        wo: ArrayLike,
        kin: Kinematics | None = None,
        group: ArrayLike | None = None,
        meta: dict | None = None,
    ) -> Plan:
        """Solve the inverse kinematics for requested directions."""
        kin = kin or Kinematics()
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        res = inverse(wi, wo, kin)
        g = np.zeros(len(wi), dtype=np.int64) if group is None else np.asarray(group, np.int64)
        return cls(wi, wo, res.angles, res.reachable, g, dict(meta or {}))


def _check_degrees(values: ArrayLike, name: str, lo: float, hi: float) -> NDArray:
    v = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if v.ndim != 1 or not np.isfinite(v).all() or np.any((v < lo) | (v > hi)):
        raise ValueError(f"{name} = {values!r}: expected degrees in [{lo}, {hi}]")
    return v


def incidence_plane_plan(
    theta_i_deg: ArrayLike = (15, 30, 45, 60, 75),
    *,
    coarse_step_deg: float = 5.0,
    fine_step_deg: float = 1.0,
    fine_half_width_deg: float = 10.0,
    kin: Kinematics | None = None,
) -> Plan:
    """Scans in the plane of incidence, denser near the specular direction (§5.1).

    For each θi the viewing angle runs over −85°…85° (negative = the specular side, φo = π)
    every ``coarse_step_deg``, plus every ``fine_step_deg`` within ``fine_half_width_deg`` of
    the specular direction; points inside the retro-reflection cone or beyond the stages are
    flagged unreachable. The defaults give 45-56 reachable points per scan.
    """
    kin = kin or Kinematics()
    tis = _check_degrees(theta_i_deg, "theta_i_deg", 0.0, 89.0)
    wi_all, wo_all, grp = [], [], []
    lim = np.degrees(kin.theta_max)
    for g, ti in enumerate(tis):
        coarse = np.arange(-lim, lim + 1e-9, coarse_step_deg)
        fine = np.arange(-fine_half_width_deg, fine_half_width_deg + 1e-9, fine_step_deg) - ti
        s = np.unique(np.round(np.concatenate([coarse, fine[np.abs(fine) <= lim]]), 9))
        wo = to_vector(np.radians(np.abs(s)), np.where(s < 0, np.pi, 0.0))
        wi = np.broadcast_to(to_vector(np.radians(ti), 0.0), wo.shape)
        wi_all.append(wi)
        wo_all.append(wo)
        grp.append(np.full(len(s), g))
    return Plan.from_directions(
        np.concatenate(wi_all),
        np.concatenate(wo_all),
        kin,
        np.concatenate(grp),
        {"kind": "incidence_plane", "theta_i_deg": tis.tolist()},
    )


def _cap_grid(n: int, cap_deg: float | None) -> NDArray:
    if cap_deg is None:
        return uniform_hemisphere_grid(n)
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c, indexing="ij")
    x, y = shirley_chiu_square_to_disk(u.ravel(), v.ravel())
    r2 = x * x + y * y
    z = 1.0 - r2 * (1.0 - np.cos(np.radians(cap_deg)))
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None)) / np.sqrt(np.where(r2 > 0, r2, 1.0))
    return np.stack([x * s, y * s, z], axis=-1)


def hemispherical_plan(
    theta_i_deg: ArrayLike = (10, 20, 30, 40, 50, 60, 70, 80),
    *,
    n: int = 21,
    cap_deg: float | None = None,
    kin: Kinematics | None = None,
) -> Plan:
    """``n × n`` (441) viewing directions uniform in solid angle per θi (§5.1).

    See the module docstring for ``cap_deg``. Rows in the retro-reflection cone are flagged
    unreachable (a handful per θi).
    """
    kin = kin or Kinematics()
    tis = _check_degrees(theta_i_deg, "theta_i_deg", 0.0, 89.0)
    if int(n) != n or n < 1:
        raise ValueError(f"n = {n!r}: expected a positive integer")
    if cap_deg is not None:
        _check_degrees(cap_deg, "cap_deg", 1.0, 90.0)
    grid = _cap_grid(int(n), cap_deg)
    wo = np.tile(grid, (len(tis), 1))
    wi = np.repeat(to_vector(np.radians(tis), 0.0), len(grid), axis=0)
    grp = np.repeat(np.arange(len(tis)), len(grid))
    meta = {"kind": "hemispherical", "theta_i_deg": tis.tolist(), "n": int(n), "cap_deg": cap_deg}
    return Plan.from_directions(wi, wo, kin, grp, meta)


def read_plan_csv(path: str | os.PathLike, kin: Kinematics | None = None) -> Plan:
    """A user plan: CSV with a header naming ``theta_i, phi_i, theta_o, phi_o`` (degrees).

    Lines starting with ``#`` are comments. Rows are grouped by θi.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"plan file {path!r} does not exist")
    with open(path, encoding="utf-8-sig") as f:  # -sig: a byte-order mark is not the header
        rows = [r for r in csv.reader(line for line in f if not line.lstrip().startswith("#"))]
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"{path}: empty plan file")
    header = [c.strip() for c in rows[0]]
    need = ["theta_i", "phi_i", "theta_o", "phi_o"]
    missing = [c for c in need if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; header is {header}")
    try:
        data = np.array([[float(r[header.index(c)]) for c in need] for r in rows[1:]])
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{path}: malformed row ({exc})") from None
    if data.size == 0:
        raise ValueError(f"{path}: no rows")
    if not np.isfinite(data).all():
        raise ValueError(f"{path}: non-finite angle")
    if np.any((data[:, [0, 2]] < 0) | (data[:, [0, 2]] > 90)):
        raise ValueError(f"{path}: theta_i and theta_o must lie in [0, 90] degrees")
    r = np.radians(data)
    wi, wo = to_vector(r[:, 0], r[:, 1]), to_vector(r[:, 2], r[:, 3])
    _, grp = np.unique(np.round(data[:, 0], 9), return_inverse=True)
    return Plan.from_directions(wi, wo, kin, grp, {"kind": "file", "path": path})


def order_plan(
    plan: Plan,
    timing: Timing | None = None,
    *,
    start: ArrayLike = (0.0, 0.0, 0.0),
    two_opt_passes: int = 2,
) -> Plan:
    """Reorder the reachable rows to shorten the total move time (unreachable rows dropped).

    θi blocks are measured one after the other (in plan order); within a block, greedy nearest
    neighbour from the previous position (``start`` for the first), then ``two_opt_passes``
    sweeps of 2-opt on the block's path (segment reversals that shorten it).
    """
    timing = timing or Timing()
    p = plan.measurable()
    if len(p) == 0:
        return p
    cur = np.asarray(start, dtype=np.float64)
    pieces = []
    for g in dict.fromkeys(p.group.tolist()):  # blocks in order of first appearance
        rows = np.flatnonzero(p.group == g)
        ang = p.angles[rows]
        n = len(rows)
        left = np.ones(n, bool)
        order = np.empty(n, np.int64)
        for k in range(n):
            t = timing.move_time(ang - cur)
            t[~left] = np.inf
            j = int(np.argmin(t))
            order[k] = j
            left[j] = False
            cur = ang[j]
        order = _two_opt(ang, order, timing, two_opt_passes)
        cur = ang[order[-1]]
        pieces.append(rows[order])
    out = p.subset(np.concatenate(pieces))
    out.meta = {**p.meta, "ordered": True}
    return out


def _two_opt(ang: NDArray, order: NDArray, timing: Timing, passes: int) -> NDArray:
    n = len(order)
    if n < 4 or passes <= 0:
        return order
    order = order.copy()
    for _ in range(passes):
        improved = False
        for i in range(1, n - 2):
            a, b = ang[order[i - 1]], ang[order[i]]
            c = ang[order[i + 1 : n - 1]]
            d = ang[order[i + 2 : n]]
            old = timing.move_time(b - a) + timing.move_time(d - c)
            new = timing.move_time(c - a) + timing.move_time(d - b)
            gain = old - new
            j = int(np.argmax(gain))
            if gain[j] > 1e-9:
                jj = i + 1 + j
                order[i : jj + 1] = order[i : jj + 1][::-1]
                improved = True
        if not improved:
            break
    return order


def reference_seconds(
    timing: Timing | None = None,
    integration_s: float | None = None,
    n_reads: int = DEFAULT_REFERENCE_READS,
) -> float:
    """Real-instrument time (s) of one re-measured reference (the white standard).

    The stages leave the sample's geometry for the reference's and come back (two moves,
    each bounded by a 90° move of every axis at once), then ``n_reads`` sets of the four reads
    of a measurement (signal and dark through each polariser) at the reference's integration
    time ``integration_s`` (its auto-exposure's; default ``timing.default_integration_s``),
    each with its read-out overhead. This is the campaign's lamp clock
    (``gonio.simulator.cornell.simulate_campaign``: the simulated lamp's warm-up and drift
    run on it) and the run-time estimate's (:func:`estimate_run_time` with
    ``reference_every``), so the two agree. The beam-trap reads of the first reference and
    the settling after the two moves are not counted (the clock's definition since the drift
    correction was added; kept so that its campaigns stay the same).

    Parameters
    ----------
    timing : Timing, optional
        The stages' speeds and the read-out overhead (default :class:`Timing`).
    integration_s : float, optional
        The reference's integration time (s), positive.
    n_reads : int
        Reads averaged per spectrum (``CornellConfig.n_reference_reads``; at least 1 is
        taken).

    Returns
    -------
    float
        Seconds.
    """
    tm = timing or Timing()
    t = tm.default_integration_s if integration_s is None else float(integration_s)
    if not (math.isfinite(t) and t > 0):
        raise ValueError(f"integration_s = {integration_s!r}: expected a positive time (s)")
    move = float(tm.move_time(np.radians([[90.0, 90.0, 90.0]]))[0])
    return 2 * move + max(1, int(n_reads)) * 4 * (t + tm.read_overhead_s)


def n_rereferences(n_measurements: int, reference_every: int) -> int:
    """References measured again in a campaign of ``n_measurements`` geometries: after every
    ``reference_every``-th and after the last (``gonio.simulator.cornell.simulate_campaign``);
    0 when ``reference_every`` is 0 (the first reference only)."""
    every = int(reference_every)
    if every != reference_every or every < 0:
        raise ValueError(f"reference_every = {reference_every!r}: expected an integer >= 0")
    if every == 0 or n_measurements <= 0:
        return 0
    return -(-int(n_measurements) // every)


def measurement_seconds(
    plan: Plan,
    timing: Timing | None = None,
    integration_s: ArrayLike | None = None,
    *,
    start: ArrayLike = (0.0, 0.0, 0.0),
) -> NDArray[np.float64]:
    """Real-instrument time (s) of each reachable row in the plan's order: its move from the
    previous row (``start`` for the first) and its reads, as in :func:`estimate_run_time`
    (whose total without references is their sum): the campaign's schedule."""
    timing = timing or Timing()
    p = plan.measurable()
    n = len(p)
    t_int = (np.full(n, timing.default_integration_s) if integration_s is None
             else np.asarray(integration_s, dtype=np.float64).ravel())  # fmt: skip
    if t_int.shape != (n,) or np.any(t_int <= 0) or not np.isfinite(t_int).all():
        raise ValueError(f"integration_s must hold {n} positive times (one per reachable row)")
    path = np.concatenate([np.asarray(start, float)[None], p.angles])
    per = timing.settle_s + timing.preview_s + timing.read_overhead_s + timing.polarizer_change_s
    return timing.move_time(np.diff(path, axis=0)) + per + 4.0 * (t_int + timing.read_overhead_s)


def estimate_run_time(
    plan: Plan,
    timing: Timing | None = None,
    integration_s: ArrayLike | None = None,
    *,
    start: ArrayLike = (0.0, 0.0, 0.0),
    reference_every: int = 0,
    reference_s: float | None = None,
) -> dict[str, float]:
    """Estimated real-instrument time (s) for the reachable rows in the plan's order.

    Per measurement: the move (slowest axis, trapezoidal profile), settling, a preview read for
    the exposure, then a signal and a dark read through the polariser in place, one
    polariser change, a dark and a signal read through the other one (integration time +
    read overhead each; ``gonio.simulator.cornell.read_sequence``). ``integration_s`` gives one
    integration time per reachable row (e.g. from a simulation's auto-exposure); default
    ``timing.default_integration_s``.

    ``reference_every = N > 0``: the reference measured again after every N-th measurement
    and after the last (:func:`n_rereferences`), each taking ``reference_s`` (default
    :func:`reference_seconds` at the default integration time); the total is then the
    campaign's lamp clock at its end. The first reference, before the first measurement (the
    clock's zero), is not counted, with or without re-measurements. Reported as
    ``n_references`` (the re-measured ones) and ``reference_s`` (their time, in
    ``overhead_s`` and in the total; its uncertainty with the overheads').
    """
    timing = timing or Timing()
    n_ref = n_rereferences(len(plan.measurable()), reference_every)
    t_ref = reference_seconds(timing) if reference_s is None else float(reference_s)
    if not (math.isfinite(t_ref) and t_ref >= 0):
        raise ValueError(f"reference_s = {reference_s!r}: expected a time >= 0 (s)")
    p = plan.measurable()
    n = len(p)
    if integration_s is None:
        t_int = np.full(n, timing.default_integration_s)
    else:
        t_int = np.asarray(integration_s, dtype=np.float64).ravel()
        if t_int.shape != (n,) or np.any(t_int <= 0) or not np.isfinite(t_int).all():
            raise ValueError(
                f"integration_s must hold {n} positive times (one per reachable row), "
                f"got shape {t_int.shape}"
            )
    path = np.concatenate([np.asarray(start, float)[None], p.angles])
    steps = np.diff(path, axis=0)
    moves = timing.move_time(steps)
    per = (
        timing.settle_s
        + timing.preview_s
        + timing.read_overhead_s
        + timing.polarizer_change_s
        + 4.0 * (t_int + timing.read_overhead_s)
    )
    total = float(moves.sum() + per.sum())
    integ = float(4.0 * t_int.sum())
    fixed = float(per.sum()) - integ
    refs = n_ref * t_ref
    if n_ref:
        total += refs
        fixed += refs
    # the estimate's uncertainty: each group of assumptions scaled by its relative
    # uncertainty (the moves through the speeds and accelerations), in quadrature
    f = 1.0 + timing.speed_u
    faster = replace(timing, speeds=tuple(np.multiply(timing.speeds, f)),
                     acceleration=tuple(np.multiply(timing.acceleration, f)))  # fmt: skip
    du_move = float(moves.sum() - faster.move_time(steps).sum())
    u = math.sqrt(
        du_move**2 + (timing.overhead_u * fixed) ** 2 + (timing.integration_u * integ) ** 2
    )
    return {
        "n_measurements": float(n),
        "move_s": float(moves.sum()),
        "integration_s": integ,
        "overhead_s": fixed,
        "total_s": total,
        "total_h": total / 3600.0,
        "total_u_h": u / 3600.0,
        "per_measurement_s": total / max(n, 1),
        "n_references": float(n_ref),
        "reference_s": float(refs),
    }
