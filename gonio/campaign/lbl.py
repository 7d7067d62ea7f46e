"""End-to-end measurement campaigns: capture → merge → reduce → fit → report.

A :class:`Plan` names the instrument, material, incidence angles, sample rotations,
exposures, noise and seed. :func:`run` drives the (simulated) LBL imaging
gonioreflectometer through it and writes a results directory::

    OUT/plan.json                       the resolved plan
    OUT/raw/t40.00/standard_00.tif      raw 16-bit frames + ``.tif.json`` side-cars
    OUT/raw/t40.00/background_00.tif       (standard and background once per θi)
    OUT/raw/t40.00_r090/measured_00.tif    (the sample, per θi and sample rotation)
    OUT/raw/<key>/done.json             written last: the capture is complete
    OUT/samples.csv                     reduced BRDF samples (all incidences)
    OUT/fit.json                        the fit (``FitResult.to_dict()``) + compared models
    OUT/material.rad                    Radiance ``plastic2``/``metal2`` (Ward fits)
    OUT/plots/incidence_plane.png, hemisphere.png, residuals.png
    OUT/summary.json                    truth vs fit, errors, rms, counts, timings, seed

Every file is written to a temporary name and renamed, so an interrupted run leaves only
complete files. With ``resume=True`` a capture whose ``done.json`` exists is read back from
disk instead of being taken again; each capture draws its noise from a seed derived from
the campaign seed and the capture's name alone (:func:`capture_seed`), so a resumed run
gives bit-for-bit the same images, samples and fit as an uninterrupted one.

Ward's protocol (Ward 1992, §4-5): 21 incidence angles from 0° to 80°; an
anisotropic sample is also measured after rotating it by 90° about its normal so that both
principal directions lie in the plane of incidence once (``rotations_deg=(0, 90)``).

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign.progress import Progress
from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = [
    "DEFAULT_ANGLES_DEG",
    "CampaignResult",
    "Plan",
    "capture_seed",
    "default_plan",
    "run",
    "summary_table",
]

#: Ward's 21 incidence angles, 0° to 80° in 4° steps.
DEFAULT_ANGLES_DEG: tuple[float, ...] = tuple(float(x) for x in np.linspace(0.0, 80.0, 21))

#: Models with separate x and y coefficients that φi = 0 alone cannot separate.
_XY_MODELS = frozenset({"lafortune"})

#: Thinning modes and their default options (Plan.thinning).
_THINNING: dict[str, dict[str, float]] = {
    "select": {"base_level": 5, "peak_level": 8, "peak_fraction": 0.1},
    "average": {"rel_tol": 0.002, "min_split": 2},
}

#: Models compared with the main fit by default (fitted to the same samples).
DEFAULT_COMPARE: dict[str, tuple[str, ...]] = {}

_RAW_SUFFIX = ".tif"


# ----------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class Plan:
    """What a campaign measures and how.

    Parameters
    ----------
    material : str
        Preset name (``gonio.materials``); its model and parameters are the truth.
    model : str, optional
        Model to fit (default: the preset's model). A sum ``"lambert + ward"`` is allowed.
    instrument : {"lbl"}
        The imaging gonioreflectometer (the only campaign instrument so far).
    mirror : {"ellipsoid", "hemisphere"}
        The dome of the LBL instrument.
    theta_i_deg : sequence of float
        Incidence angles in degrees.
    rotations_deg : sequence of float, optional
        Sample rotations about the normal (the incidence azimuth φi in the sample frame);
        default ``(0, 90)`` for an anisotropic truth (α_x ≠ α_y) or a fitted model whose
        x and y coefficients only a second rotation separates (Lafortune's C_x, C_y),
        ``(0,)`` otherwise.
    exposures_s : sequence of float, optional
        Fixed exposure bracket; default the instrument's automatic bracket.
    noise : float
        0 = noise off, 1 = the instrument's default noise; another factor ``f`` scales every
        relative noise of the camera (shot, read, dark) by ``f`` by dividing the sensor's
        full well, gain and dark current by ``f²`` and its read noise by ``f``.
    seed : int
        Campaign seed; every capture's seed derives from it (:func:`capture_seed`).
    residual : str
        Residual of the fit (``gonio.fit.RESIDUALS``).
    compare : sequence of str, optional
        Other models fitted to the same samples and reported beside the main fit (e.g.
        ``("cook_torrance", "lafortune")`` for a Ward material); default none.
    plots : bool
        Write the PNG plots.
    thinning_mode : {"select", "average"}
        How each capture's pixels become samples. ``"select"`` (default): one pixel per
        equal-solid-angle cell, finer cells in the specular peak, each reduced alone with a σ
        from its neighbours (:func:`gonio.calibration.reduce.reduce_selected`) — unbiased
        point values, and only the selected pixels are merged. ``"average"``: the averaging
        thinning of :func:`gonio.calibration.thinning.thin` on every pixel, which widens
        fitted lobes. Measured (rolled brass, 21 θi × 2 rotations, default noise, seed 0):
        select 120,876 samples, every parameter within 1.5 s.e. (ρd 0.050 %, α_y 0.004 %);
        average 323,690 samples, α_x +0.053 % (+13 s.e.), α_y +0.058 % (+15 s.e.).
    thinning : pairs (name, value), optional
        Keyword arguments of the thinning: for ``"select"`` ``base_level`` (5),
        ``peak_level`` (8), ``peak_fraction`` (0.1); for ``"average"`` those of
        :func:`~gonio.calibration.thinning.thin` (default ``rel_tol=0.002, min_split=2``).
    d_over_r : float, optional
        The LBL dome's D/R (half the source-sample separation over the mirror radius); default
        the instrument's (0.01 m / 0.15 m).
    debias : bool
        Remove the second-order bias of eq. 2's ratio of noisy readings
        (:func:`gonio.calibration.radiometry.eq2`, ``debias``) when the captures are noisy
        (``noise > 0``). Measured (rolled brass, default plan, default noise): mean ρs pull
        +1.03 ± 0.15 over 49 seeds without, −0.02 ± 0.14 over 60 seeds with it.
    """

    material: str = "rolled_brass"
    model: str | None = None
    instrument: str = "lbl"
    mirror: str = "ellipsoid"
    theta_i_deg: tuple[float, ...] = DEFAULT_ANGLES_DEG
    rotations_deg: tuple[float, ...] | None = None
    exposures_s: tuple[float, ...] | None = None
    noise: float = 1.0
    seed: int = 0
    residual: str = "absolute"
    compare: tuple[str, ...] | None = None
    plots: bool = True
    thinning: tuple[tuple[str, float], ...] | None = None
    thinning_mode: str = "select"
    d_over_r: float | None = None
    debias: bool = True

    def resolved(self, truth: Any = None) -> Plan:
        """The plan with defaults filled in and every field validated.

        ``truth`` (a BRDF measured instead of a preset, see :func:`run`) lets ``material``
        be a free label.
        """
        from gonio.fit import RESIDUALS, parse_model

        info = _material_info(self.material, truth)  # ValueError listing the presets
        model = self.model or info["model"]
        parse_model(model)  # unknown model -> ValueError listing the registered names
        if self.instrument != "lbl":
            raise ValueError(f"instrument {self.instrument!r}; expected 'lbl'")
        if self.mirror not in ("ellipsoid", "hemisphere"):
            raise ValueError(f"mirror {self.mirror!r}; expected 'ellipsoid' or 'hemisphere'")
        angles = tuple(float(a) for a in self.theta_i_deg)
        if not angles or any(not (0.0 <= a < 90.0) or not math.isfinite(a) for a in angles):
            raise ValueError(f"theta_i_deg {self.theta_i_deg!r}: expected angles in [0, 90)")
        if len(set(angles)) != len(angles):
            raise ValueError(f"theta_i_deg {self.theta_i_deg!r} has repeated angles")
        rot = self.rotations_deg
        if rot is None:
            p = info["params"]
            aniso = "alpha_x" in p and "alpha_y" in p and p["alpha_x"] != p["alpha_y"]
            # a Lafortune lobe's C_y multiplies y_i·y_o, which is 0 whenever φi = 0 in the
            # sample frame: without a second rotation C_y is not measured at all
            xy = any(c.strip() in _XY_MODELS for c in model.split("+"))
            rot = (0.0, 90.0) if aniso or xy else (0.0,)
        rot = tuple(float(r) for r in rot)
        if not rot or any(not math.isfinite(r) for r in rot) or len(set(rot)) != len(rot):
            raise ValueError(f"rotations_deg {self.rotations_deg!r}: expected distinct angles")
        exp = self.exposures_s
        if exp is not None:
            exp = tuple(float(e) for e in exp)
            if not exp or any(not (e > 0 and math.isfinite(e)) for e in exp):
                raise ValueError(f"exposures_s {self.exposures_s!r}: expected positive seconds")
        noise = float(self.noise)
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise {self.noise!r}: expected 0 (off), 1 (on) or a factor > 0")
        if not isinstance(self.seed, int | np.integer) or self.seed < 0:
            raise ValueError(f"seed {self.seed!r}: expected a non-negative integer")
        if self.residual not in RESIDUALS:
            raise ValueError(f"residual {self.residual!r}; expected one of {list(RESIDUALS)}")
        compare = self.compare
        if compare is None:  # the defaults that are registered in this installation
            from gonio.brdf import names

            compare = tuple(c for c in DEFAULT_COMPARE.get(model, ()) if c in names())
        compare = tuple(c for c in compare if c != model)
        for c in compare:
            parse_model(c)
        if self.thinning_mode not in _THINNING:
            raise ValueError(
                f"thinning_mode {self.thinning_mode!r}; expected one of {sorted(_THINNING)}"
            )
        allowed = _THINNING[self.thinning_mode]
        given = dict(allowed if self.thinning is None else self.thinning)
        bad = sorted(set(given) - set(allowed))
        if bad:
            raise ValueError(
                f"thinning {bad} not options of thinning_mode {self.thinning_mode!r}; "
                f"expected some of {sorted(allowed)}"
            )
        thinning = tuple((str(k), v) for k, v in given.items())
        if not isinstance(self.debias, bool | np.bool_):
            raise ValueError(f"debias {self.debias!r}: expected True or False")
        d_over_r = self.d_over_r
        if d_over_r is not None:
            d_over_r = float(d_over_r)
            if not (math.isfinite(d_over_r) and 0.0 < d_over_r < 0.5):
                raise ValueError(f"d_over_r {self.d_over_r!r}: expected a ratio in (0, 0.5)")
        return replace(
            self,
            thinning=thinning,
            model=model,
            theta_i_deg=angles,
            rotations_deg=rot,
            exposures_s=exp,
            noise=noise,
            seed=int(self.seed),
            compare=compare,
            d_over_r=d_over_r,
            debias=bool(self.debias),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (tuples as lists)."""
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Plan:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        names = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown plan field(s) {unknown}; expected some of {sorted(names)}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        if "thinning" in kw:
            kw["thinning"] = tuple(tuple(x) for x in kw["thinning"])
        return cls(**kw)


def _material_info(material: str, truth: Any = None) -> dict[str, Any]:
    """The preset record, or one made from ``truth`` (a BRDF) for a label that is no preset."""
    from gonio import materials

    if truth is None or material in materials.names():
        info = materials.info(material)
        if truth is not None:
            info = {**info, "model": truth.name, "params": dict(truth.params)}
        return info
    if not isinstance(material, str) or not material.strip() or any(c.isspace() for c in material):
        raise ValueError(f"material {material!r} must be a name without white space")
    return {"model": truth.name, "params": dict(truth.params), "class": "dielectric",
            "source": "user BRDF"}  # fmt: skip


def default_plan(**overrides: Any) -> Plan:
    """The built-in campaign (rolled brass, LBL, ellipsoid, default noise, seed 0), resolved."""
    return Plan(**overrides).resolved()


def capture_seed(seed: int, key: str) -> int:
    """The seed of one capture: a function of the campaign seed and the capture name only.

    ``SeedSequence(seed, spawn_key=(h,))`` with ``h`` the first 8 bytes of SHA-256(key), so
    that captures do not depend on the order in which they are taken (or skipped on resume).
    """
    h = int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "little")
    ss = np.random.SeedSequence(int(seed), spawn_key=(h,))
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


# ----------------------------------------------------------------------------- instrument
Frames = list[tuple[np.ndarray, dict[str, Any]]]


class _SimulatedLBL:
    """Adapter from a plan to ``gonio.simulator``'s LBL instrument."""

    def __init__(self, plan: Plan) -> None:
        try:
            from gonio.simulator import LBLInstrument
        except ImportError as exc:  # the simulator is a separate part of the package
            raise ValueError(
                f"the campaign needs gonio.simulator.LBLInstrument, which is not available ({exc})"
            ) from None
        self.plan = plan
        kw: dict[str, Any] = {}
        f = plan.noise
        if f > 0 and f != 1.0:
            # noise factor f: every relative noise (shot, read, dark) times f, the DN scale
            # unchanged: full well, gain and dark current / f², read noise / f
            from gonio.simulator import Sensor

            s = Sensor()
            kw["sensor"] = replace(
                s,
                full_well=s.full_well / f**2,
                gain=s.gain / f**2,
                read_noise=s.read_noise / f,
                dark_current=s.dark_current / f**2,
            )
        if plan.d_over_r is not None:  # D = (D/R) · R at the instrument's mirror radius
            import inspect

            radius = inspect.signature(LBLInstrument).parameters["radius"].default
            kw["half_separation"] = plan.d_over_r * radius
        self.inst = LBLInstrument(mirror=plan.mirror, **kw)

    def prepare(self, sample: Any = "standard") -> None:
        """Trace the pixel geometry and load the compiled kernels now (both are kept), e.g.
        before forking workers, which then inherit them instead of each loading them."""
        from gonio.calibration.reduce import Capture, reduce_selected

        _ = self.inst.geometry
        # one throw-away bracket each (~10 ms) and their reduction: loads the kernels and
        # fills the reduction's pixel-geometry caches
        std, bg, meas = (Capture(self.shoot(x, 0.5, 0.0, 0)) for x in ("standard", None, sample))
        reduce_selected(meas, std, bg, rng=0)

    def shoot(self, sample: Any, theta_i: float, phi_i: float, seed: int) -> Frames:
        kw: dict[str, Any] = {"rng": seed, "noise": self.plan.noise > 0}
        if self.plan.exposures_s:
            frames = []
            rng = np.random.default_rng(seed)
            for e in self.plan.exposures_s:
                sub = {**kw, "rng": int(rng.integers(2**62))}
                frames.append(self.inst.capture(sample, theta_i, phi_i, exposure=e, **sub))
            return frames
        return list(self.inst.bracket(sample, theta_i, phi_i, **kw))


# ----------------------------------------------------------------------------- results
@dataclass
class CampaignResult:
    """What :func:`run` returns: the plan, the samples, the fits and the summary."""

    plan: Plan
    out: Path | None
    samples: BRDFSamples
    fit: Any
    compare: dict[str, Any]
    summary: dict[str, Any]
    timings_s: dict[str, float] = field(default_factory=dict)


def _write_json(path: Path, obj: Any, durable: bool = True) -> None:
    from gonio.cli._common import to_json

    atomic_write_bytes(path, (to_json(obj) + "\n").encode(), durable=durable)


def _fmt_key(theta_deg: float, rot_deg: float | None = None) -> str:
    k = f"t{theta_deg:05.2f}"
    return k if rot_deg is None else f"{k}_r{rot_deg % 360:05.1f}"


def _save_frames(folder: Path, kind: str, frames: Frames) -> list[str]:
    from gonio.io.images import write_image

    names = []
    for k, (img, meta) in enumerate(frames):
        name = f"{kind}_{k:02d}{_RAW_SUFFIX}"
        # raw frames: speed over size; flushed to the disk together after the captures
        # (_flush_raw), a group whose files do not read back is taken again on resume
        write_image(folder / name, img, meta, compress=False, durable=False)
        names.append(name)
    return names


def _load_group(folder: Path) -> dict[str, Frames] | None:
    """Frames of a completed capture group, or ``None`` if it is absent or incomplete."""
    from gonio.io.images import read_image

    done = folder / "done.json"
    if not done.is_file():
        return None
    try:
        rec = json.loads(done.read_text())
        out: dict[str, Frames] = {}
        for kind, names in rec["files"].items():
            out[kind] = [read_image(folder / n, require_metadata=True) for n in names]
        return out
    except (ValueError, KeyError, OSError):
        return None  # damaged: take it again


class _Writer:
    """Writes completed capture groups on a background thread (OpenCV encodes without the
    GIL), so saving overlaps with the next captures and the reduction. Each group's images
    are written before its ``done.json``; :meth:`wait` re-raises the first error."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gonio-writer")
        self.futures: list[Any] = []
        self.busy_s = 0.0

    def submit(self, folder: Path, frames: dict[str, Frames], seed: int) -> None:
        self.futures.append(self.pool.submit(self._write, folder, frames, seed))

    def _write(self, folder: Path, frames: dict[str, Frames], seed: int) -> None:
        t = time.perf_counter()
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "done.json").unlink(missing_ok=True)
        files = {kind: _save_frames(folder, kind, fr) for kind, fr in frames.items()}
        _write_json(folder / "done.json", {"files": files, "seed": seed}, durable=False)
        self.busy_s += time.perf_counter() - t

    def wait(self) -> float:
        """Block until every group is written; return the seconds spent waiting."""
        t = time.perf_counter()
        try:
            for f in self.futures:
                f.result()
        finally:
            self.pool.shutdown(wait=True)
        return time.perf_counter() - t


def _take_group(
    folder: Path | None,
    shots: Mapping[str, Callable[[], Frames]],
    resume: bool,
    seed: int,
    writer: _Writer | None,
) -> tuple[dict[str, Frames], bool, float, float]:
    """Capture (or, when resuming, load) one group; returns frames, loaded?, t_cap, t_load."""
    if resume and folder is not None:
        t = time.perf_counter()
        got = _load_group(folder)
        if got is not None:
            return got, True, 0.0, time.perf_counter() - t
    t = time.perf_counter()
    frames = {kind: f() for kind, f in shots.items()}
    t_cap = time.perf_counter() - t
    if folder is not None and writer is not None:
        writer.submit(folder, frames, seed)
    return frames, False, t_cap, 0.0


# ----------------------------------------------------------------------------- run
def run(
    plan: Plan | None = None,
    out: str | os.PathLike | None = None,
    *,
    resume: bool = False,
    quiet: bool = True,
    stream: Any = None,
    instrument: Any = None,
    truth: Any = None,
    workers: int | None = None,
) -> CampaignResult:
    """Run a campaign and (if ``out`` is given) write its results directory.

    Parameters
    ----------
    plan : Plan, optional
        Default :func:`default_plan`.
    out : path, optional
        Results directory (created). ``None`` keeps everything in memory.
    resume : bool
        Reuse completed captures found in ``out`` (the plan must match ``out/plan.json``).
    quiet : bool
        No progress bars (they appear on a terminal for stages longer than 1 s).
    stream : text stream, optional
        Where progress bars go (default stderr).
    instrument : object, optional
        Something with ``shoot(sample, theta_i, phi_i, seed) -> [(image, meta), ...]``;
        default the simulated LBL instrument of the plan.
    truth : BRDF, optional
        Measure this model instead of the preset's (``plan.material`` is then a label; the
        summary compares the fit with this truth). Resuming checks the plan, not ``truth``.
    workers : int, optional
        Processes that capture, save and reduce incidence angles in parallel; with more
        than one, the plots are drawn by one more process (:mod:`gonio.campaign.plot_worker`).
        Default: the CPU count (at most 4), for the simulated instrument and a plan of at
        least 8 incidence angles; 1 runs everything in this process. The result does not
        depend on it: every capture draws from its own seed (:func:`capture_seed`).

    Returns
    -------
    CampaignResult

    Notes
    -----
    The campaign runs numpy's and scipy's BLAS on one thread (``threadpoolctl``; the
    previous limits are restored on return). Its processes already fill the cores, and an
    OpenBLAS thread spins for a while after each call: with the default two threads per
    process the default campaign took 2.8 s and 4.3 s of CPU here, with one 2.3 s and 2.9 s.
    One thread also makes the fit's sums, so its result, the same in every process.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # numpy's BLAS (workers inherit it)
        return _run(plan, out, resume, quiet, stream, instrument, truth, workers)


def _run(
    plan: Plan | None, out: str | os.PathLike | None, resume: bool, quiet: bool, stream: Any,
    instrument: Any, truth: Any, workers: int | None,
) -> CampaignResult:  # fmt: skip
    """:func:`run`'s body."""
    from gonio import materials

    t_start = time.perf_counter()
    if truth is not None:
        from gonio.brdf import BRDF

        if not isinstance(truth, BRDF):
            raise ValueError(f"truth must be a BRDF model, got {type(truth).__name__}")
    plan = (plan or Plan()).resolved(truth)
    outp = Path(out) if out is not None else None
    if outp is not None:
        _check_out(outp, plan, resume, truth)
    info = _material_info(plan.material, truth)
    truth_model = truth if truth is not None else materials.get(plan.material)
    inst = instrument if instrument is not None else _SimulatedLBL(plan)
    timings: dict[str, float] = {}

    # ------------------------------------------------------------------ capture + reduce
    raw = outp / "raw" if outp is not None else None
    n_workers = _n_workers(workers, plan, instrument)
    pool = plotter = None
    if n_workers > 1 and outp is not None and plan.plots:
        from gonio.campaign.plot_worker import PlotWorker, warm_matplotlib

        # forked first: it loads matplotlib while this process prepares the instrument
        plotter = PlotWorker(warm_matplotlib)
    try:
        if n_workers > 1:
            pool = _start_pool(n_workers, inst, truth_model)
        per_angle, t_write = _capture_and_reduce(
            plan, raw, resume, truth_model, inst, pool, quiet=quiet, stream=stream
        )
        tables = [tb for r in per_angle for tb in r["tables"]]
        samples = BRDFSamples.concatenate(
            tables,
            metadata={
                "material": plan.material,
                "instrument": plan.instrument,
                "mirror": plan.mirror,
                "seed": plan.seed,
            },
        )
        n_pixels = sum(r["n_pixels"] for r in per_angle)
        n_loaded = sum(r["n_loaded"] for r in per_angle)
        timings["capture"] = sum(r["t_capture"] for r in per_angle)
        t_io = sum(r["t_load"] for r in per_angle)
        if t_io:
            timings["load_raw"] = t_io
        timings["reduce"] = sum(r["t_reduce"] for r in per_angle)
        if raw is not None:
            timings["save_raw_background"] = t_write
        timings["capture_reduce_wall"] = time.perf_counter() - t_start
        if pool is not None:
            pool.shutdown(wait=True)
            pool = None
        # the hemisphere map needs no fit: drawn (by the plot worker) while this process fits
        _plot_jobs(plan, outp, samples, None, plotter)
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(1, thread_name_prefix="gonio-csv") as io_thread:
            saved = flushed = None
            if outp is not None:  # rows formatted per angle where they were reduced
                parts = [p for r in per_angle for p in r["csv_rows"]]
                saved = io_thread.submit(_save_samples, outp, samples, parts)
            if raw is not None:
                flushed = io_thread.submit(_flush_raw, raw)
            from gonio.campaign.blas import SingleThreadBLAS

            with SingleThreadBLAS():  # scipy's BLAS too (the outer limit predates its import)
                result, compare = _fit_all(plan, samples, truth_model, timings, quiet, stream)
            if saved is not None:
                timings["save_samples"] = saved.result()
            if flushed is not None:
                timings["flush_raw"] = flushed.result()

        # -------------------------------------------------------------- report
        summary = _summary(plan, info, truth_model, result, compare, samples, n_pixels, n_loaded)
        t = time.perf_counter()
        _plot_jobs(plan, outp, samples, result.model, plotter)
        if plotter is not None:
            plotter.wait()
        if outp is not None and plan.plots:
            summary["files"]["plots"] = [f"plots/{n}.png" for n in _PLOTS]
        timings["plots"] = time.perf_counter() - t
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if plotter is not None:
            plotter.close()
    t = time.perf_counter()
    if outp is not None:
        fitd = result.to_dict()
        fitd["compare"] = {
            k: (v.to_dict() if not isinstance(v, Exception) else {"error": str(v)})
            for k, v in compare.items()
        }
        _write_json(outp / "fit.json", fitd)
        rad = _radiance(plan, info, result)
        if rad is not None:
            from gonio.io.radiance import write_material

            write_material(outp / "material.rad", rad)
            summary["files"]["radiance"] = "material.rad"
    timings["report"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    summary["timings_s"] = {k: round(v, 4) for k, v in timings.items()}
    if outp is not None:
        _write_json(outp / "summary.json", summary)
    return CampaignResult(plan, outp, samples, result, compare, summary, timings)


# ----------------------------------------------------------------------------- stages
#: The campaign's plots (``OUT/plots/<name>.png``).
_PLOTS = ("incidence_plane", "hemisphere", "residuals")

#: What a pool process inherits from the parent (fork): the instrument and the truth model.
_POOL_STATE: dict[str, Any] = {}


def _n_workers(workers: int | None, plan: Plan, instrument: Any) -> int:
    if workers is not None:
        if not isinstance(workers, int | np.integer) or workers < 1:
            raise ValueError(f"workers {workers!r}: expected a positive integer")
        return int(workers) if instrument is None else 1
    if instrument is not None or len(plan.theta_i_deg) < 8:
        return 1
    import multiprocessing as mp

    if "fork" not in mp.get_all_start_methods():
        return 1
    return max(1, min(os.cpu_count() or 1, 4))


def _start_pool(n: int, inst: Any, truth_model: Any) -> Any:
    """A process pool forked from this process, so that the workers inherit the imported
    modules, the instrument with its cached geometry and the truth model."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    if hasattr(inst, "prepare"):
        inst.prepare(truth_model)
    # with the fork start method the initializer's arguments are inherited, not pickled
    return ProcessPoolExecutor(
        n, mp_context=mp.get_context("fork"), initializer=_init_worker,
        initargs=(inst, truth_model),
    )  # fmt: skip


def _init_worker(inst: Any, truth_model: Any) -> None:
    _POOL_STATE.update(inst=inst, truth=truth_model)


def _capture_and_reduce(
    plan: Plan, raw: Path | None, resume: bool, truth_model: Any, inst: Any, pool: Any, *,
    quiet: bool, stream: Any,
) -> tuple[list[dict[str, Any]], float]:  # fmt: skip
    """Every incidence angle captured (or loaded), saved and reduced; results in plan order
    and the seconds the raw-frame writers were busy."""
    angles = plan.theta_i_deg
    out: list[dict[str, Any] | None] = [None] * len(angles)
    csv = raw is not None  # format each angle's samples.csv rows where it is reduced
    with Progress(len(angles), "capture + reduce", quiet=quiet, stream=stream) as bar:
        if pool is None:
            writer = _Writer() if raw is not None else None
            try:
                for k, th in enumerate(angles):
                    out[k] = _incidence(plan, th, raw, resume, truth_model, inst, writer, csv)
                    bar.update(label=f"θi {th:g}°")
            finally:
                if writer is not None:  # finish what was captured, also on an error
                    writer.wait()
            t_write = writer.busy_s if writer is not None else 0.0
        else:
            from concurrent.futures import as_completed

            futs = {pool.submit(_incidence_worker, plan, th, raw, resume): k
                    for k, th in enumerate(angles)}  # fmt: skip
            import scipy.optimize  # noqa: F401  (loads here while the workers capture)

            for f in as_completed(futs):
                k = futs[f]
                out[k] = f.result()
                bar.update(label=f"θi {angles[k]:g}°")
            t_write = sum(r.pop("t_write") for r in out)
    return out, t_write  # type: ignore[return-value]


def _incidence_worker(plan: Plan, th: float, raw: Path | None, resume: bool) -> dict[str, Any]:
    """:func:`_incidence` in a pool process, with its own background writer."""
    inst, truth_model = _POOL_STATE["inst"], _POOL_STATE["truth"]
    writer = _Writer() if raw is not None else None
    try:
        res = _incidence(plan, th, raw, resume, truth_model, inst, writer, csv=raw is not None)
    finally:
        if writer is not None:
            writer.wait()
    res["t_write"] = writer.busy_s if writer is not None else 0.0
    return res


def _incidence(
    plan: Plan, th: float, raw: Path | None, resume: bool, truth_model: Any, inst: Any,
    writer: _Writer | None, csv: bool = False,
) -> dict[str, Any]:  # fmt: skip
    """One incidence angle: standard and background, the sample at every rotation, reduced."""
    from gonio.calibration.reduce import Capture, reduce_capture, reduce_selected

    ti = math.radians(th)
    res: dict[str, Any] = {"tables": [], "n_pixels": 0, "n_loaded": 0, "t_capture": 0.0,
                           "t_load": 0.0, "t_reduce": 0.0}  # fmt: skip
    groups: list[tuple[str, float | None]] = [(_fmt_key(th), None)]
    groups += [(_fmt_key(th, rot), rot) for rot in plan.rotations_deg]
    captured: dict[str, dict[str, Frames]] = {}
    for key, rot in groups:
        seed = capture_seed(plan.seed, key)
        if rot is None:
            shots = {
                "standard": lambda s=seed: inst.shoot("standard", ti, 0.0, s),
                "background": lambda s=seed: inst.shoot(None, ti, 0.0, s + 1),
            }
        else:
            pr = math.radians(rot)
            shots = {"measured": lambda pr=pr, s=seed: inst.shoot(truth_model, ti, pr, s)}
        folder = raw / key if raw is not None else None
        frames, loaded, tc, tio = _take_group(folder, shots, resume, seed, writer)
        captured[key] = frames
        res["n_loaded"] += loaded
        res["t_capture"] += tc
        res["t_load"] += tio
    t = time.perf_counter()
    ref = captured[_fmt_key(th)]
    std, bg = Capture(ref["standard"]), Capture(ref["background"])
    for rot in plan.rotations_deg:
        meas = Capture(captured[_fmt_key(th, rot)]["measured"])
        opts = dict(plan.thinning)
        debias = plan.debias and plan.noise > 0
        if plan.thinning_mode == "select":
            sel_seed = capture_seed(plan.seed, _fmt_key(th, rot) + "/select")
            red = reduce_selected(meas, std, bg, rng=sel_seed, debias=debias, **opts)
        else:
            red = reduce_capture(meas, std, bg, thinning=opts, debias=debias)
        res["tables"].append(red.samples)
        res["n_pixels"] += int(red.stats.get("n_before", len(red.samples)))
        if csv:  # format this table's samples.csv rows here (in a worker: in parallel)
            from gonio.io.samples_table import csv_rows

            res.setdefault("csv_rows", []).append(csv_rows(red.samples))
    res["t_reduce"] = time.perf_counter() - t
    return res


def _plot_jobs(
    plan: Plan, outp: Path | None, samples: BRDFSamples, model: Any, plotter: Any
) -> None:
    """Draw (in this process) or send to the plot worker the plots: with ``model=None``
    the hemisphere map, which needs no fit, else the two that show the fitted model (in
    the plot worker, in parallel)."""
    if outp is None or not plan.plots:
        return
    names = ("hemisphere",) if model is None else ("incidence_plane", "residuals")
    args = (samples, model, outp / "plots", f"{plan.material} ({plan.model})")
    if plotter is not None:
        plotter.submit(_draw, *args, each=names)
        return
    for name in names:
        _draw(name, *args)


def _flush_raw(raw: Path) -> float:
    """Flush every raw frame, side-car and group marker to the disk; return the seconds.

    The frames are written without a flush each (``durable=False``): one ``fsync`` per
    frame made every capture task wait for the disk (measured, default campaign wall clock:
    1.99-2.15 s in 8 runs with a flush per file, 1.84-1.93 s in 6 runs with this one pass);
    flushing them all here, on a thread while the fit runs, keeps a finished campaign's
    files safe from a power failure all the same.
    """
    from gonio.io.atomic import fsync_files

    t = time.perf_counter()
    if raw.is_dir():
        fsync_files(p for p in sorted(raw.rglob("*")) if p.is_file())
    return time.perf_counter() - t


def _save_samples(outp: Path, samples: BRDFSamples, parts: list[str]) -> float:
    """Write ``samples.csv`` from its pre-formatted parts; return the seconds it took."""
    from gonio.io.samples_table import write_csv_parts

    t = time.perf_counter()
    write_csv_parts(outp / "samples.csv", samples.metadata, samples.columns, parts)
    return time.perf_counter() - t


def _draw(name: str, samples: BRDFSamples, model: Any, folder: Path, title: str) -> None:
    from gonio import plots

    path = folder / f"{name}.png"
    if name == "hemisphere":
        plots.plot_hemisphere(samples, path, title=title, max_panels=12)
    elif name == "incidence_plane":
        plots.plot_incidence_plane(samples, model, path, title=title)
    else:
        plots.plot_residuals(samples, model, path, title=title)


def _fit_all(
    plan: Plan, samples: BRDFSamples, truth_model: Any, timings: dict[str, float],
    quiet: bool, stream: Any,
) -> tuple[Any, dict[str, Any]]:  # fmt: skip
    """The main fit and the compared models."""
    from gonio import fit as _fit

    # ------------------------------------------------------------------ fit
    t = time.perf_counter()
    bar = Progress(1 + len(plan.compare), f"fit {plan.model}", quiet=quiet, stream=stream,
                   min_time=0.0)  # fmt: skip
    bar.update(0)
    template, fit_kw = _fit_setup(plan.model, truth_model)
    result = _fit.fit(samples, template, residual=plan.residual, **fit_kw)
    timings["fit"] = time.perf_counter() - t
    t = time.perf_counter()
    compare = {}
    for name in plan.compare:
        bar.update(label=f"fit {name}")
        try:
            compare[name] = _fit.fit(samples, name, residual=plan.residual)
        except ValueError as exc:  # report, do not abort the campaign
            compare[name] = exc
    bar.update()
    bar.close()
    timings["compare"] = time.perf_counter() - t
    return result, compare


def _check_out(outp: Path, plan: Plan, resume: bool, truth: Any = None) -> None:
    outp.mkdir(parents=True, exist_ok=True)
    pfile = outp / "plan.json"
    if resume and pfile.is_file():
        try:
            old = Plan.from_dict(json.loads(pfile.read_text())).resolved(truth)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{pfile}: cannot resume, unreadable plan ({exc})") from None
        if _capture_fields(old) != _capture_fields(plan):
            raise ValueError(
                f"cannot resume in {outp}: its plan.json differs from this plan in what is "
                f"captured ({_capture_fields(old)} vs {_capture_fields(plan)}); use another --out"
            )
    _write_json(pfile, plan.to_dict())


def _capture_fields(plan: Plan) -> dict[str, Any]:
    d = plan.to_dict()
    keys = ("material", "instrument", "mirror", "exposures_s", "noise", "seed")
    # (thinning is not part of it: raw captures can be reduced again with another thinning)
    return {k: d[k] for k in keys}


def _fit_setup(model: str, truth: Any) -> tuple[Any, dict[str, Any]]:
    """The model to fit (a template) and fit options, from the plan's model name.

    Only model *structure* is taken from the truth, never start values: for a Li-Torrance
    truth fitted with ``li_torrance``, the components that are off in the truth stay off
    (Li and Torrance choose the components per material, Li and Torrance 2005, §5),
    the Fresnel data (``f0``/``n_ior``, fixed by the authors too) and the switches
    (specular, shadowing, ...) are the truth's, and, because the LBL camera sees the band
    average of a spectral BRDF, one grey band at the mean wavelength is fitted. For a
    Lafortune truth the number of lobes is the truth's.
    """
    from gonio import brdf
    from gonio.fit import parse_model

    tname = getattr(truth, "name", "")
    if model == "li_torrance" and tname == "li_torrance":
        spec = brdf.spec("li_torrance").params
        tp = truth.params
        params: dict[str, Any] = {}
        fixed = {}
        for k, p in spec.items():
            v = tp[k]
            if p.kind == "object":
                params[k] = v
            elif k in ("f0", "n_ior", "wavelength_nm", "tau_x", "tau_y", "d_omega_i"):
                params[k] = None if v is None else float(np.mean(v))
            elif k.startswith("k_") and np.all(np.asarray(v) == 0):
                params[k] = 0.0
                fixed[k] = 0.0
        return brdf.create("li_torrance", **params), {"fixed": fixed} if fixed else {}
    if model == "lafortune" and tname == "lafortune":
        n = len(truth.params["lobes"])
        template = brdf.create("lafortune", lobes=[(-1.0, -1.0, 1.0, 10.0)] * n)
        return template, {}
    return parse_model(model), {}


def _truth_params(truth: Any) -> dict[str, float]:
    """Float parameters of the truth; per-band arrays by their band mean (what a grey
    camera sees of a spectral coefficient that enters the BRDF linearly)."""
    out = {}
    for k, v in truth.params.items():
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, int | float) and math.isfinite(v):
            out[k] = float(v)
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f" and v.ndim == 1:
            out[k] = float(np.mean(v))
    return out


def _summary(plan, info, truth, result, compare, samples, n_pixels, n_loaded) -> dict:
    truth_p = _truth_params(truth) if plan.model == truth.name else {}
    fitp = {k: float(v) for k, v in result.params.items()}
    stderr = {k: (float(v) if math.isfinite(v) else None) for k, v in result.stderr.items()}
    rel = {}
    within = {}
    for k, tv in truth_p.items():
        if k in fitp and k in result.free:
            rel[k] = abs(fitp[k] - tv) / abs(tv) if tv != 0 else abs(fitp[k])
            s = result.stderr[k]
            within[k] = bool(abs(fitp[k] - tv) <= 3 * s) if math.isfinite(s) else None
    comp = {}
    for k, v in compare.items():
        if isinstance(v, Exception):
            comp[k] = {"error": str(v)}
        else:
            comp[k] = {
                "rms": v.rms,
                "chi2_dof": v.chi2_dof,
                "converged": v.converged,
                "params": v.params,
            }
    extra = {}
    if truth.name == "lafortune" and result.model.name == "lafortune":
        # lobes are an object parameter: list them (sorted by exponent n) side by side
        def lobes(m: Any) -> list[list[float]]:
            return sorted(([float(x) for x in lb[:4]] for lb in m.params["lobes"]),
                          key=lambda lb: lb[3])  # fmt: skip

        extra["lobes"] = {"truth": lobes(truth), "fit": lobes(result.model)}
    return {
        **extra,
        "material": plan.material,
        "class": info.get("class"),
        "model": plan.model,
        "truth_model": truth.name,
        "truth": _truth_params(truth),
        "fit": fitp,
        "stderr": stderr,
        "relative_error": rel,
        "within_3_sigma": within,
        "rms": result.rms,
        "rms_relative": result.rms_relative,
        "chi2_dof": result.chi2_dof if math.isfinite(result.chi2_dof) else None,
        "converged": result.converged,
        "n_samples": len(samples),
        "n_pixels": n_pixels,
        "n_captures": {
            "incidence_angles": len(plan.theta_i_deg),
            "rotations": len(plan.rotations_deg),
            "resumed_groups": n_loaded,
        },
        "compare": comp,
        "seed": plan.seed,
        "noise": plan.noise,
        "plan": plan.to_dict(),
        "files": {"samples": "samples.csv", "fit": "fit.json"},
    }


def _radiance(plan: Plan, info: Mapping[str, Any], result: Any) -> str | None:
    if plan.model not in ("ward", "ward_approx"):
        return None
    from gonio.io.radiance import material_type_for, ward_material

    mtype = material_type_for(str(info.get("class", "dielectric")))
    try:
        return ward_material(
            result.params,
            mtype,
            name=f"gonio_{plan.material}",
            comment=f"gonio campaign fit of {plan.material} ({plan.model}, seed {plan.seed})\n"
            f"rho_d {result.params['rho_d']:.5g} rho_s {result.params['rho_s']:.5g} "
            f"alpha_x {result.params['alpha_x']:.5g} alpha_y {result.params['alpha_y']:.5g}",
        )
    except ValueError:
        return None


def summary_table(summary: Mapping[str, Any]) -> str:
    """The short text report: true vs fitted parameters, errors, counts, stage times."""
    from gonio.cli._common import format_table

    rows = []
    truth = summary.get("truth", {})
    for k, v in summary["fit"].items():
        t = truth.get(k) if summary["model"] == summary.get("truth_model") else None
        s = summary["stderr"].get(k)
        rel = summary["relative_error"].get(k)
        rows.append(
            (
                k,
                "" if t is None else f"{t:.5g}",
                f"{v:.5g}",
                "" if s is None else f"{s:.2g}",
                "" if rel is None else f"{100 * rel:.2f}%",
                "" if t is None or s in (None, 0) else f"{(v - t) / s:+.2f}",
            )
        )
    lines = [
        f"{summary['material']} fitted with {summary['model']}: "
        f"{'converged' if summary['converged'] else 'NOT converged'}, "
        f"{summary['n_samples']} samples from {summary['n_pixels']} pixels, "
        f"rms {summary['rms']:.4g} sr^-1",
        format_table(("param", "truth", "fit", "stderr", "rel.err", "pull"), rows),
    ]
    if summary.get("compare"):
        crow = [(summary["model"], f"{summary['rms']:.4g}", summary.get("chi2_dof") or "")]
        for k, v in summary["compare"].items():
            crow.append(
                (
                    k,
                    f"{v['rms']:.4g}" if "rms" in v else v.get("error", ""),
                    v.get("chi2_dof") or "",
                )
            )
        lines.append(format_table(("model", "rms (sr^-1)", "chi2/dof"), crow))
    tm = summary.get("timings_s", {})
    lines.append("time (s): " + ", ".join(f"{k} {v:.2f}" for k, v in tm.items()))
    return "\n".join(lines)
