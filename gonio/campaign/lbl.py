"""The LBL campaign: capture → reduce → fit → report, as four named stages.

:func:`run` takes a :class:`~gonio.campaign.plan.Plan` through the (simulated) LBL imaging
gonioreflectometer and reads top to bottom:

1. **prepare** — the plan resolved and validated, the results folder checked and its
   ``plan.json`` written (:mod:`gonio.campaign.folder`), the instrument made;
2. **capture and reduce** — a realistic simulated instrument's calibration captures and the
   laboratory's calibration from them first (:func:`_calibration`, its independent jobs on
   the executor's processes), then each incidence angle captured (standard, background, the
   sample at every rotation), saved and reduced to samples (:func:`_incidence`, on the
   executor's worker processes);
3. **fit** — the plan's model and the compared ones fitted to all samples (:func:`_fit`),
   and the uncertainty budget (:func:`_budget`);
4. **report** — the summary against the truth, ``fit.json``, ``material.rad``, the plots and
   ``summary.json`` (:mod:`gonio.campaign.report`).

After the calibration the stages are declared as jobs (:func:`_jobs`): what each needs,
what it makes, and whether it is a stage, a plot, a write or a side job. How they use the
machine — when each runs, worker processes, the plot process, the I/O thread, BLAS threads,
timings — is :mod:`gonio.campaign.executor`'s business
(:meth:`~gonio.campaign.executor.CampaignExecutor.pipeline`). The results folder's layout
is described in :mod:`gonio.campaign.folder`. With ``resume=True`` a capture group whose
``done.json`` exists is read back instead of being taken again; each capture draws its noise
from a seed derived from the campaign seed and the capture's name alone
(:func:`~gonio.campaign.plan.capture_seed`), so a resumed run gives bit-for-bit the same
images, samples and fit as an uninterrupted one.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Here: the campaign of §3 (eq. 2 calibration, eq. 3 angles, thinning) and the models of
   eq. 4-5b fitted to it.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Here: §5, the components chosen per material when the Li-Torrance model is fitted.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign import folder as results
from gonio.campaign.executor import (
    CampaignExecutor,
    Job,
    check_workers_may_fork,
    default_workers,
    worker_state,
    write_behind,
)
from gonio.campaign.folder import Frames, group_key
from gonio.campaign.knowledge import budget_fields, correct_drift
from gonio.campaign.plan import (
    DEFAULT_ANGLES_DEG,
    Plan,
    _material_info,
    capture_seed,
    default_plan,
)
from gonio.campaign.progress import Progress
from gonio.campaign.report import (
    CampaignResult,
    draw,
    draw_budget,
    draw_preview,
    summary_table,
)
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
    overwrite: bool = False,
    calibration_cache: bool = True,
) -> CampaignResult:
    """Run a campaign and (if ``out`` is given) write its results directory.

    Parameters
    ----------
    plan : Plan, optional
        Default :func:`~gonio.campaign.plan.default_plan`.
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
    overwrite : bool
        Replace the results of another plan found in ``out`` (else refused).
    calibration_cache : bool
        Read the laboratory's calibration of a realistic simulated instrument from the
        calibration cache when this instrument was calibrated before, and keep a made one
        there (:mod:`gonio.campaign.calcache`; the summary's ``calibration.cache`` records
        its key). False: made anew, nothing kept.

    Returns
    -------
    CampaignResult
    """
    t_start = time.perf_counter()  # 1. prepare: every input checked, then the folder opened
    setup = _prepare(plan, out, resume, truth, instrument, workers)
    setup.calibration_cache = {} if calibration_cache else None
    with results.locked(setup.out):
        if setup.out is not None:
            results.check_out(setup.out, setup.plan, resume, truth, overwrite)
        return _run(setup, t_start, resume, quiet, stream)


def _run(setup: _Setup, t_start: float, resume: bool, quiet: bool, stream: Any) -> CampaignResult:
    """:func:`run` under the folder's lock: the stages."""
    try:
        return _stages(setup, t_start, resume, quiet, stream)
    except BaseException:
        if setup.out is not None:  # no derived output of a failed run (raw groups stay)
            results.discard_outputs(setup.out)
        raise


def _stages(
    setup: _Setup, t_start: float, resume: bool, quiet: bool, stream: Any
) -> CampaignResult:
    """Stages 2-4 of :func:`run` on a prepared setup: the laboratory's calibration, then the
    jobs of :func:`_jobs` (capture and reduce, fit, report), which the executor runs."""
    plan, outp = setup.plan, setup.out
    for w in () if quiet else setup.warnings:  # what the plan will not determine: said first
        print(f"warning: {w}", file=stream if stream is not None else sys.stderr, flush=True)
    with CampaignExecutor(setup.workers, plots=outp is not None and plan.plots) as ex:
        ex.compile_ahead(_kernel_groups(setup))  # (an empty numba cache only)
        _calibration(ex, setup, quiet, stream)
        got = ex.pipeline(
            _jobs(setup, resume, quiet, stream), ex=ex, setup=setup, plan=plan,
            truth=setup.truth, lab=setup.lab, corrections=plan.corrections, fields=None,
            t_start=t_start, title=f"{plan.material} ({plan.model})", info=setup.info,
            plots=outp / "plots" if outp is not None else None,
        )  # fmt: skip
    samples, result, compare, summary, budget = (
        got.get(k) for k in ("samples", "result", "compare", "summary", "budget")
    )
    with ex.stage("report"):
        from gonio.campaign.report import write_report

        write_report(outp, plan, setup.info, result, compare, summary)
    timings = {**ex.timings, "total": time.perf_counter() - t_start}
    summary["timings_s"] = {k: round(v, 4) for k, v in timings.items()}
    if outp is not None:
        results.write_json(outp / "summary.json", summary)
    brackets: dict[tuple, list] | None = {}
    for r in got.get("per_angle") or []:
        b = r.get("brackets")
        brackets = None if b is None or brackets is None else {**brackets, **b}
    return LBLCampaignResult(plan, outp, samples, result, compare, summary, timings, budget,
                             brackets)  # fmt: skip


@dataclass
class LBLCampaignResult(CampaignResult):
    """:class:`CampaignResult` with the budget
    (:class:`~gonio.campaign.knowledge.CampaignBudget`: its inputs too) and the brackets
    the instrument took: ``{(kind, θi, rotation): [(exposure_s, f_number), ...]}`` of
    every standard, background and sample capture, from the frames' metadata (None: an
    instrument whose frames do not record both), for
    :func:`gonio.simulator.lbl_timing.schedule`."""

    budget: Any = None
    brackets: dict[tuple, list] | None = None

    def real_instrument_h(self) -> float | None:
        """The campaign's time on the real instrument (h) with the brackets it took
        (:func:`gonio.campaign.design_lbl.plan_hours`); None without its brackets."""
        if self.brackets is None:
            return None
        from gonio.campaign.design_lbl import plan_hours

        p = self.plan
        return plan_hours(p.theta_i_deg, p.rotations_deg, p.preset, p.restandard_every,
                          brackets=self.brackets)  # fmt: skip


def _jobs(setup: _Setup, resume: bool, quiet: bool, stream: Any) -> list[Job]:
    """Stages 2-4 after the calibration as jobs: what each needs and what it makes (the
    values given by :func:`_stages` or made by an earlier job); the executor decides when
    each runs (:meth:`~gonio.campaign.executor.CampaignExecutor.pipeline`)."""
    plan, drawn = setup.plan, setup.out is not None and setup.plan.plots
    capture = partial(_capture_and_reduce, resume=resume, quiet=quiet, stream=stream)
    fit = partial(_fit, quiet=quiet, stream=stream)
    fitted = ("samples", "model", "plots", "title")
    jobs = [
        # 2. capture and reduce
        (True, Job("capture", capture, ("ex", "setup"), ("per_angle",))),
        (_fields_to_make(setup),  # the budget's direction fields: the calibration's alone
         Job("fields", budget_fields, ("lab", "corrections"), ("fields",), kind="side")),
        (_fields_to_keep(setup),  # and kept with it for its next campaign (calcache)
         Job("keep_fields", _keep_fields, ("setup", "fields"), kind="write")),
        (bool(plan.restandard_every),  # the lamp's drift from the re-measured standard
         Job("drift", correct_drift, ("per_angle", "corrections"))),
        (True, Job("merge", _merge, ("ex", "setup", "per_angle", "t_start"), ("samples",))),
        (drawn, Job("hemisphere", _draw_samples, ("samples", "plots", "title"), kind="plot")),
        (setup.out is not None,
         Job("save_samples", _save_samples, ("setup", "samples", "per_angle"), kind="write")),
        (setup.raw is not None, Job("flush_raw", _flush_raw, ("setup", "per_angle"), kind="write")),
        # 3. fit, and the GUM budget from the laboratory's knowledge
        (True, Job("fit", fit, ("ex", "plan", "samples", "truth"), ("result", "compare", "model"))),
        (drawn, Job("incidence_plane", draw, fitted, kind="plot")),
        (drawn, Job("residuals", draw, fitted, kind="plot")),
        (True, Job("budget", _budget, ("plan", "lab", "result", "samples", "per_angle", "fields"),
                   ("budget",), heavy=setup.lab is not None, timed=True)),
        # 4. report: the summary against the truth (written by _stages) and its plot
        (True, Job("summary", _report, ("plan", "setup", "result", "compare", "samples",
                                        "per_angle", "budget"), ("summary",))),
        (drawn, Job("budget", _draw_budget, ("summary", "plots", "title"), kind="plot")),
        (drawn and setup.preview, Job("preview", draw_preview, ("truth", "result", "plan", "info",
                                                              "plots", "title"), kind="plot")),
    ]  # fmt: skip
    return [job for wanted, job in jobs if wanted]


# ----------------------------------------------------------------------------- 1. prepare
@dataclass
class _Setup:
    """What the stages share: the resolved plan, the folder, the truth, the instrument."""

    plan: Plan
    out: Path | None
    info: dict[str, Any]
    truth: Any
    instrument: Any
    workers: int
    lab: Any = None  # the laboratory's calibration (None: the nominal design)
    t_calibration: float | None = None  # seconds to make (or read) it
    calibration_cache: dict | None = None  # a made calibration kept (calcache): its record
    warnings: list[str] = field(default_factory=list)  # what the plan will not determine

    @property
    def preview(self) -> bool:
        """Whether ``plots/preview.png`` can be rendered here (Radiance found)."""
        from gonio.plots.preview import unavailable

        return unavailable() is None

    @property
    def raw(self) -> Path | None:
        return self.out / "raw" if self.out is not None else None


def _prepare(
    plan: Plan | None, out: Any, resume: bool, truth: Any, instrument: Any, workers: int | None
) -> _Setup:
    """Resolve the plan, check the results folder (and write ``plan.json``), make the
    instrument; nothing is captured before every input is checked."""
    from gonio import materials

    if truth is not None:
        from gonio.brdf import BRDF

        if not isinstance(truth, BRDF):
            raise ValueError(f"truth must be a BRDF model, got {type(truth).__name__}")
    plan = (plan or Plan()).resolved(truth)
    n_workers = _n_workers(workers, plan, instrument)
    outp = Path(out) if out is not None else None
    info = _material_info(plan.material, truth)
    truth_model = truth if truth is not None else materials.get(plan.material)
    inst = instrument if instrument is not None else _SimulatedLBL(plan)
    from gonio.campaign.determined import lbl_preflight  # refuses a plan, warns (resolution)

    warnings = lbl_preflight(plan, *_fit_setup(plan.model, truth_model), truth_model, inst)
    t = time.perf_counter()  # a calibration folder is read now (made ones: in the stages)
    lab = _laboratory(plan, inst, outp) if plan.calibration is not None else None
    t_cal = time.perf_counter() - t if lab is not None else None
    return _Setup(plan, outp, info, truth_model, inst, n_workers, lab, t_cal, warnings=warnings)


def _laboratory(
    plan: Plan, inst: Any, outp: Path | None, ex: Any = None, cache: dict | None = None
) -> Any:
    """The laboratory's calibration: the plan's calibration folder, else (a realistic
    simulated instrument) its calibration from calibration captures, made once per physical
    instrument (:func:`gonio.campaign.calibrate.laboratory_calibration`, its independent
    jobs run by the executor ``ex``) and copied to ``OUT/calibration``; None for the ideal
    instrument, whose design is its truth. With ``cache`` (a dict, given the key under
    ``"key"``) a calibration made before for the same instrument is read from
    :mod:`gonio.campaign.calcache`, and a made one kept there."""
    if plan.calibration is not None:
        from gonio.calibration.laboratory import read_calibration

        lab = read_calibration(plan.calibration)
        if isinstance(inst, _SimulatedLBL) and lab.lens is not None and lab.mirror is not None:
            _warm(lab, inst.inst)
        return lab
    if not _calibrated(plan, inst):
        return None
    from gonio.campaign import calcache
    from gonio.campaign.calibrate import _key, laboratory_calibration, specification

    sim = inst.inst
    folder = None if outp is None else outp / "calibration"
    certificate, spec = sim.certificate(), specification(plan.preset)
    lab = None
    if cache is not None:  # kept for the next campaign of this instrument (calcache)
        plan_fields = {k: getattr(plan, k) for k in _INSTRUMENT_FIELDS}
        key, made_of = calcache.calibration_key(f"{_key(sim)}/eq3/0", {
            "nominal_mirror": sim.mirror.to_dict(), "certificate": certificate.to_dict(),
            "specification": spec, "plan": plan_fields,
        })  # fmt: skip
        lab = calcache.load(key, made_of)
        cache["key"] = key[:20]  # (not whether it was found: the summary stays the same)
        cache["_entry"] = (key, made_of)  # (for its direction fields: _keep_fields)
    if lab is None:
        lab = laboratory_calibration(
            sim, sim.mirror.to_dict(), folder=folder, certificate=certificate,
            specification=spec, parallel=ex and ex.parallel, start=ex and ex.start,
        )  # fmt: skip
        if cache is not None:
            calcache.store(key, made_of, lab)
    elif folder is not None:
        lab.write(folder)
    _warm(lab, sim)
    return lab


#: the plan's fields that make the simulated instrument (:class:`_SimulatedLBL`), in the
#: key of a cached calibration besides the instrument's own description
_INSTRUMENT_FIELDS = ("preset", "instrument_seed", "noise", "d_over_r", "mirror")


def _calibrated(plan: Plan, inst: Any) -> bool:
    """Whether the instrument is calibrated by the laboratory (a realistic simulated one)."""
    return plan.preset != "ideal" and isinstance(inst, _SimulatedLBL)


def _calibration(ex: CampaignExecutor, setup: _Setup, quiet: bool, stream: Any) -> None:
    """The laboratory's calibration made from the calibration captures (a realistic
    simulated instrument without the plan's calibration folder, which :func:`_prepare`
    read), their jobs forked from the instrument warmed up (:func:`_warm_instrument`)."""
    plan, inst = setup.plan, setup.instrument
    if plan.calibration is None and _calibrated(plan, inst):
        warm = partial(_warm_instrument, setup)
        bar = Progress(1, "warm-up + calibration", quiet=quiet, stream=stream, min_time=0.0)
        with bar, ex.stage("calibration"), ex.inheriting(warm, "warm_up"):
            setup.lab = _laboratory(plan, inst, setup.out, ex, setup.calibration_cache)
    elif setup.t_calibration is not None:
        ex.timings["calibration"] = setup.t_calibration


def _kernel_groups(setup: _Setup) -> list[list[tuple[Callable, Callable[[], Any]]]]:
    """The compiled kernels a simulated instrument's campaign loads, in two groups that
    share no compiled callee and take about as long to compile (processor seconds measured
    one by one on an empty cache, numba's contexts made: the noise kernels 2.4; the
    scene's 1.6, the lens's 0.6, Ward's 0.5), for
    :meth:`~gonio.campaign.executor.CampaignExecutor.compile_ahead`."""
    plan = setup.plan
    if not isinstance(setup.instrument, _SimulatedLBL) or os.environ.get("GONIO_NO_NUMBA"):
        return []
    from gonio.brdf import ward
    from gonio.simulator import _kernels, _lens_kernels

    def load(name: str) -> tuple[Callable, Callable[[], Any]]:
        k = getattr(_kernels, name)
        return k, partial(k.compile, _kernels.argument_types(_kernels.CAMPAIGN_SIGNATURES[name]))

    realistic = _calibrated(plan, setup.instrument)
    noise = [load("noise_u16")] if plan.noise > 0 else []
    noise += [load("noise_float"), load("digitise_linear")] if realistic else []
    scene = [load("ward_exponent"), load("plan_scene"), load("compose_float_runs")]
    if realistic:
        kb = _lens_kernels.kb_inverse
        kb_types = _kernels.argument_types(_lens_kernels.KB_INVERSE_SIGNATURE)
        scene.append((kb, partial(kb.compile, kb_types)))
    if plan.model in ward.KERNEL_MODELS:
        scene += [(ward._k_pre, partial(ward.kernel, "pre")),
                  (ward._k_post, partial(ward.kernel, "post"))]  # fmt: skip
    return [scene, noise]


def _warm_instrument(setup: _Setup) -> None:
    """A realistic simulated instrument's geometry traced and kernels loaded before its
    calibration captures (:meth:`_SimulatedLBL.prepare`), so that the calibration's jobs,
    forked from this process, inherit them instead of each tracing and loading them anew
    (and the capture's workers after them); the lens's calibration, which needs none of
    it, runs meanwhile."""
    setup.instrument.prepare(setup.truth, reduce=False)  # (reduced with the calibration, later)


def _warm(lab: Any, sim: Any) -> None:
    """The calibrated lens's pixel geometry and field angles computed here, before the
    workers fork (each would otherwise invert the Kannala-Brandt map of the whole grid)."""
    from gonio.calibration.reduce import load_lens, pixel_geometry
    from gonio.campaign.knowledge import field_angle

    lens = load_lens(lab.lens, sim.lens.width, sim.lens.height)
    pixel_geometry(lens, lab.mirror.geometry, lab.mirror.method)
    field_angle(lens)


def _n_workers(workers: int | None, plan: Plan, instrument: Any) -> int:
    """Worker processes: as asked (1 for a user's instrument, which may not fork), else
    :func:`~gonio.campaign.executor.default_workers` for the simulated one."""
    if workers is not None:
        from gonio._validate import max_workers

        if not isinstance(workers, int | np.integer) or not 1 <= workers <= max_workers():
            raise ValueError(f"workers {workers!r}: expected an integer in [1, {max_workers()}]")
        if instrument is None:
            check_workers_may_fork(int(workers))
        return int(workers) if instrument is None else 1
    if instrument is not None:
        return 1
    return default_workers(len(plan.theta_i_deg))


# ----------------------------------------------------------------------------- instrument
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
        from gonio.simulator.effects import realise

        #: the realised magnitudes of this campaign's instrument (the truth)
        self.effects = realise(plan.preset, plan.instrument_seed)
        self.inst = LBLInstrument(
            mirror=plan.mirror, effects=self.effects, instrument_seed=plan.instrument_seed, **kw
        )
        b = plan.binning
        self.binning = tuple(b) if b is not None and tuple(b) != (0, 0) else None
        self._clock: dict[tuple, float] | None = None

    def certificate(self) -> Any:
        """The certificate of the instrument's diffuse standard (what the laboratory knows):
        :class:`gonio.io.certificate.Certificate`."""
        return self.inst.certificate()

    def clock_s(self, sample: Any, theta_i: float, phi_i: float) -> float:
        """When the real instrument would take this capture
        (:func:`~gonio.simulator.lbl_timing.schedule` of the plan, three frames a capture): the
        lamp's clock."""
        if self._clock is None:
            from gonio.simulator.lbl_timing import TIMINGS, schedule

            timing = TIMINGS["ward1992" if self.plan.preset == "ward1992" else "modern"]
            sch = schedule(self.plan.theta_i_deg, self.plan.rotations_deg, 3, timing)
            self._clock = {
                (c["kind"], round(c["theta_i_deg"], 6), c["rotation_deg"]): c["start_s"]
                for c in sch
            }
        if sample is None:
            kind = "background"
        elif isinstance(sample, str) and sample == "standard":
            kind = "standard"
        else:
            kind = "measured"
        rot = round(math.degrees(phi_i) % 360.0, 6) if kind == "measured" else None
        return self._clock.get((kind, round(math.degrees(theta_i), 6), rot), 0.0)

    def shoot_restandard(self, theta_i: float, phi_i: float, seed: int) -> Frames:
        """The standard captured again after the sample's capture at (θi, φi): the sample
        swapped out and back by hand (:attr:`LBLTiming.swap_s` after the capture's end)."""
        kw: dict[str, Any] = {"rng": seed, "noise": self.plan.noise > 0}
        if self.binning is not None:
            kw["binning"] = self.binning
        if not self.inst._frame_fx:
            return self._shoot("standard", theta_i, 0.0, kw)
        from gonio.simulator.lbl_timing import TIMINGS

        timing = TIMINGS["ward1992" if self.plan.preset == "ward1992" else "modern"]
        t = self.clock_s(object(), theta_i, phi_i) + 1.0  # the sample's capture (~1 s)
        kw["clock_s"] = t + timing.swap_s
        return [(img, {**meta, "clock_s": kw["clock_s"]})
                for img, meta in self._shoot("standard", theta_i, 0.0, kw)]  # fmt: skip

    def prepare(self, sample: Any = "standard", lab: Any = None, reduce: bool = True) -> None:
        """Trace the pixel geometry and load the compiled kernels now (both are kept), e.g.
        before forking workers, which then inherit them instead of each loading them.

        With the laboratory's calibration ``lab``, its reduction too (the corrections' code
        and the pixel geometry the plan's corrections reduce with), else (``reduce``) the
        reduction with the nominal design; and the image codec (OpenCV) the raw frames are
        written with. Nothing of this changes a result: only modules and deterministic
        caches are loaded. Called again for the same sample (a realistic instrument is
        warmed before its calibration without a reduction, whose nominal geometry it would
        not use, then with the calibration), the throw-away brackets of the first call are
        reduced instead of being shot again.
        """
        import cv2  # noqa: F401  (the write-behind's TIFF encoder, once instead of per worker)

        warm = self.__dict__.pop("_warm_frames", None)
        if warm is None or warm[0] is not sample:
            _ = self.inst.geometry
            # one throw-away bracket each (~10 ms): loads the kernels, traces the scenes
            warm = (sample, tuple(self.shoot(x, 0.5, 0.0, 0) for x in ("standard", None, sample)))
        std, bg, meas = warm[1]
        if lab is not None:
            from gonio.campaign.knowledge import reduce_incidence

            reduce_incidence(std, bg, {0.0: meas}, lab, seeds={0.0: 0},
                             corrections=self.plan.corrections)  # fmt: skip
        elif reduce:  # fills the reduction's pixel-geometry caches (the nominal design)
            from gonio.calibration.reduce import Capture, reduce_selected

            reduce_selected(Capture(meas), Capture(std), Capture(bg), rng=0)
        else:  # kept for a call with the calibration
            self._warm_frames = warm

    def shoot(self, sample: Any, theta_i: float, phi_i: float, seed: int) -> Frames:
        kw: dict[str, Any] = {"rng": seed, "noise": self.plan.noise > 0}
        if self.binning is not None:
            kw["binning"] = self.binning
        if self.inst._frame_fx:  # the lamp's warm-up and drift follow the real schedule
            kw["clock_s"] = self.clock_s(sample, theta_i, phi_i)
            return [(img, {**meta, "clock_s": kw["clock_s"]})  # the capture's time stamp
                    for img, meta in self._shoot(sample, theta_i, phi_i, kw)]  # fmt: skip
        return self._shoot(sample, theta_i, phi_i, kw)

    def _shoot(self, sample: Any, theta_i: float, phi_i: float, kw: dict[str, Any]) -> Frames:
        if self.plan.exposures_s:
            frames = []
            rng = np.random.default_rng(kw["rng"])
            for e in self.plan.exposures_s:
                sub = {**kw, "rng": int(rng.integers(2**62))}
                frames.append(self.inst.capture(sample, theta_i, phi_i, exposure=e, **sub))
            return frames
        if self.plan.bracket_min_signal_dn is not None:  # the plan's threshold
            kw["min_signal_dn"] = self.plan.bracket_min_signal_dn
        return list(self.inst.bracket(sample, theta_i, phi_i, **kw))


# ----------------------------------------------------------------------------- 2. capture
def _capture_and_reduce(
    ex: CampaignExecutor, setup: _Setup, resume: bool, *, quiet: bool, stream: Any
) -> list[dict[str, Any]]:
    """Every incidence angle captured (or loaded), saved and reduced; results in plan order."""
    angles = setup.plan.theta_i_deg
    out: list[dict[str, Any] | None] = [None] * len(angles)
    calls = [(setup.plan, th, setup.raw, resume) for th in angles]
    state = {"inst": setup.instrument, "truth": setup.truth, "lab": setup.lab}
    prepare = getattr(setup.instrument, "prepare", None)
    if prepare is not None and isinstance(setup.instrument, _SimulatedLBL):
        prepare = partial(prepare, lab=setup.lab)  # the laboratory's reduction warmed too
    with Progress(len(angles), "capture + reduce", quiet=quiet, stream=stream) as bar:
        for k, res in ex.map(
            _incidence, calls, state=state, prepare=prepare and (lambda: prepare(setup.truth))
        ):
            out[k] = res
            bar.update(label=f"capture + reduce θi {angles[k]:g}°")
    return out  # type: ignore[return-value]


def _incidence(plan: Plan, th: float, raw: Path | None, resume: bool) -> dict[str, Any]:
    """One incidence angle: standard and background, the sample at every rotation, reduced.

    Runs in a worker process (or in the campaign's): the instrument and the truth come from
    the executor's :func:`~gonio.campaign.executor.worker_state`.
    """
    inst, truth_model = worker_state()["inst"], worker_state()["truth"]
    ti = math.radians(th)
    res: dict[str, Any] = {"tables": [], "n_pixels": 0, "n_loaded": 0, "t_capture": 0.0,
                           "t_load": 0.0, "t_reduce": 0.0, "brackets": {}}  # fmt: skip
    groups: list[tuple[str, float | None]] = [(group_key(th), None)]
    groups += [(group_key(th, rot), rot) for rot in plan.rotations_deg]
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
            if _restandard(plan, th) and hasattr(inst, "shoot_restandard"):
                shots["restandard"] = lambda pr=pr, s=seed: inst.shoot_restandard(ti, pr, s + 2)
        folder = raw / key if raw is not None else None
        made_by = results.group_record(plan, key, seed, th, rot, shots, truth_model)
        frames, loaded, tc, tio = _take_group(folder, shots, resume, made_by)
        captured[key] = frames
        for kind, shot in frames.items():  # the brackets taken (their time: lbl_timing)
            if kind in ("standard", "background", "measured") and res["brackets"] is not None:
                from gonio.simulator.lbl_timing import brackets_of

                key_ = (kind, float(th), None if rot is None else float(rot))
                try:
                    res["brackets"].update(brackets_of({key_: [m for _, m in shot]}))
                except ValueError:  # an instrument whose frames do not record both
                    res["brackets"] = None
        res["n_loaded"] += loaded
        res["t_capture"] += tc
        res["t_load"] += tio
    t = time.perf_counter()
    ref = captured[group_key(th)]
    measured = {rot: captured[group_key(th, rot)]["measured"] for rot in plan.rotations_deg}
    restd = {rot: captured[group_key(th, rot)]["restandard"] for rot in plan.rotations_deg
             if "restandard" in captured[group_key(th, rot)]}  # fmt: skip
    for table, info in _reduce(plan, th, ref["standard"], ref["background"], measured, restd):
        res["tables"].append(table)
        res.setdefault("infos", []).append(info)
        res["n_pixels"] += int(info["n_before"])
        if raw is not None:  # format this table's samples.csv rows here (in a worker: in parallel)
            from gonio.io.samples_table import csv_rows

            res.setdefault("csv_rows", []).append(csv_rows(table))
    res["t_reduce"] = time.perf_counter() - t
    return res


def _restandard(plan: Plan, th: float) -> bool:
    """Whether the standard is re-measured after the sample's capture at ``th``."""
    n = plan.restandard_every
    return bool(n) and list(plan.theta_i_deg).index(th) % n == 0


def _reduce(
    plan: Plan, th: float, standard: Frames, background: Frames,
    measured: Mapping[float, Frames], restandard: Mapping[float, Frames] | None = None,
) -> list[tuple[BRDFSamples, dict[str, Any]]]:  # fmt: skip
    """One incidence's captures reduced as the laboratory does it: side-cars cut to what a
    real instrument writes, its calibration and corrections
    (:func:`gonio.campaign.knowledge.reduce_incidence`); the averaging thinning with the
    same knowledge but no per-capture corrections."""
    from gonio.calibration.reduce import Capture, reduce_capture
    from gonio.campaign.knowledge import laboratory_view, reduce_incidence

    lab = worker_state().get("lab")
    opts = dict(plan.thinning)
    debias = plan.debias and plan.noise > 0
    if plan.thinning_mode == "select":
        seeds = {rot: capture_seed(plan.seed, group_key(th, rot) + "/select") for rot in measured}
        return reduce_incidence(standard, background, measured, lab, corrections=plan.corrections,
                                seeds=seeds, debias=debias, select=opts,
                                restandard=restandard)  # fmt: skip
    std, bg = Capture(laboratory_view(standard)), Capture(laboratory_view(background))
    geo = {} if lab is None else {k: v for k, v in lab.reduction_options().items()
                                  if k in ("lens", "mirror", "method")}  # fmt: skip
    out = []
    for rot, frames in measured.items():
        red = reduce_capture(Capture(laboratory_view(frames)), std, bg, thinning=opts,
                             debias=debias, **geo)  # fmt: skip
        n = red.stats.get("n_before", len(red.samples))
        out.append((red.samples, {"rotation_deg": float(rot), "n_frames": len(frames),
                                  "n_before": n}))  # fmt: skip
    return out


def _take_group(
    folder: Path | None, shots: Mapping[str, Callable[[], Frames]], resume: bool,
    made_by: dict[str, Any],
) -> tuple[dict[str, Frames], bool, float, float]:  # fmt: skip
    """Capture (or, when resuming, load) one group; returns frames, loaded?, t_cap, t_load.
    A captured group is written behind (on this process's writer thread)."""
    if resume and folder is not None:
        t = time.perf_counter()
        got = results.load_group(folder, made_by)
        if got is not None:
            return got, True, 0.0, time.perf_counter() - t
    t = time.perf_counter()
    frames = {kind: f() for kind, f in shots.items()}
    t_cap = time.perf_counter() - t
    if folder is not None:
        write_behind(results.save_group, folder, frames, made_by)
    return frames, False, t_cap, 0.0


def _merge(
    ex: CampaignExecutor, setup: _Setup, per_angle: list[dict[str, Any]], t_start: float
) -> BRDFSamples:
    """All angles' samples in one table (plan order), with the stage times added up."""
    plan = setup.plan
    tables = [tb for r in per_angle for tb in r["tables"]]
    meta = {"material": plan.material, "instrument": plan.instrument, "mirror": plan.mirror,
            "seed": plan.seed}  # fmt: skip
    ex.timings["capture"] = sum(r["t_capture"] for r in per_angle)
    t_io = sum(r["t_load"] for r in per_angle)
    if t_io:
        ex.timings["load_raw"] = t_io
    ex.timings["reduce"] = sum(r["t_reduce"] for r in per_angle)
    if setup.raw is not None:
        ex.timings["save_raw_background"] = ex.write_busy_s
    samples = BRDFSamples.concatenate(tables, metadata=meta)
    ex.timings["capture_reduce_wall"] = time.perf_counter() - t_start
    return samples


def _save_samples(setup: _Setup, samples: BRDFSamples, per_angle: list[dict[str, Any]]) -> float:
    """``samples.csv`` written from the rows formatted per angle where they were reduced;
    returns the seconds."""
    parts = [p for r in per_angle for p in r["csv_rows"]]
    return results.save_samples(setup.out, samples, parts)


def _flush_raw(setup: _Setup, per_angle: list[dict[str, Any]]) -> float:
    """The raw frames of the captures (``per_angle``) flushed to the disk; returns the
    seconds."""
    return results.flush_raw(setup.raw)


# ----------------------------------------------------------------------------- 3. fit
def _fit(
    ex: CampaignExecutor, plan: Plan, samples: BRDFSamples, truth_model: Any, quiet: bool,
    stream: Any,
) -> tuple[Any, dict[str, Any], Any]:  # fmt: skip
    """The main fit, its model (what the plots draw) and the compared models' fits (a
    compared model that fails is reported)."""
    from gonio import fit as _fit

    bar = Progress(1 + len(plan.compare), f"fit {plan.model}", quiet=quiet, stream=stream,
                   min_time=0.0)  # fmt: skip
    bar.update(0)
    with ex.stage("fit"):
        template, fit_kw = _fit_setup(plan.model, truth_model)
        result = _fit.fit(samples, template, residual=plan.residual, **fit_kw)
    compare = {}
    with ex.stage("compare"):
        for name in plan.compare:
            bar.update(label=f"fit {name}")
            try:
                compare[name] = _fit.fit(samples, name, residual=plan.residual)
            except ValueError as exc:  # report, do not abort the campaign
                compare[name] = exc
    bar.update()
    bar.close()
    return result, compare, result.model


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


# ----------------------------------------------------------------------------- 4. report
def _report(
    plan: Plan, setup: _Setup, result: Any, compare: dict[str, Any], samples: BRDFSamples,
    per_angle: list[dict[str, Any]], budget: Any = None,
) -> dict[str, Any]:  # fmt: skip
    """The summary: the truth against the fit and its budget (the one place where both
    meet)."""
    from gonio.campaign.report import PLOTS, add_budget, summarise
    from gonio.plots.preview import preview_notes

    n_pixels = sum(r["n_pixels"] for r in per_angle)
    n_loaded = sum(r["n_loaded"] for r in per_angle)
    summary = summarise(plan, setup.info, setup.truth, result, compare, samples, n_pixels,
                        n_loaded)  # fmt: skip
    summary["warnings"][:0] = setup.warnings  # the plan's, before the fit's and budget's
    if budget is not None:
        add_budget(summary, budget)
    summary["calibration"] = None if setup.lab is None else setup.lab.info
    if setup.lab is not None and setup.calibration_cache:  # (read from the cache or kept)
        summary["calibration"] = {**summary["calibration"],
                                  "cache": {"key": setup.calibration_cache["key"]}}  # fmt: skip
    if setup.out is not None and plan.plots:
        summary["files"]["plots"] = [f"plots/{n}.png" for n in PLOTS]
        if budget is not None:
            summary["files"]["plots"].append("plots/budget.png")
        cls = str(setup.info.get("class") or "dielectric")  # a preview (half) not drawn: why
        summary["warnings"] += preview_notes(setup.truth, result.model, cls)
        if setup.preview:
            summary["files"]["plots"].append("plots/preview.png")
    effects = getattr(setup.instrument, "effects", None)
    if effects is not None:  # the simulated instrument's truth, beside the fit's
        summary["instrument"] = {
            "preset": plan.preset,
            "instrument_seed": plan.instrument_seed,
            "binning": list(plan.binning) if plan.binning else None,
            "effects": {k: v for k, v in effects.items() if v != 0.0},
        }
    return summary


def _fields_to_make(setup: _Setup) -> bool:
    """Whether the budget's direction fields are made on a worker: a calibration that does
    not hold them yet (one read from the calibration cache may; the budget then takes
    them from it, ``fields`` None)."""
    from gonio.campaign.budget_terms import has_direction_fields

    return setup.lab is not None and not has_direction_fields(setup.lab)


def _fields_to_keep(setup: _Setup) -> bool:
    """Whether the campaign's direction fields are to be kept with its calibration in the
    calibration cache (one kept there, whose entry has none yet)."""
    entry = (setup.calibration_cache or {}).get("_entry")
    return entry is not None and _fields_to_make(setup)


def _keep_fields(setup: _Setup, fields: list) -> float:
    """The direction fields made by this campaign added to its calibration's cache entry
    (:func:`gonio.campaign.calcache.store_fields`; nothing when they are empty: no
    ``geometry`` correction); returns the seconds."""
    from gonio.campaign import calcache

    t = time.perf_counter()
    if fields:
        calcache.store_fields(*setup.calibration_cache["_entry"], fields)
    return time.perf_counter() - t


def _budget(
    plan: Plan, lab: Any, result: Any, samples: BRDFSamples, per_angle: list[dict[str, Any]],
    fields: Any,
) -> Any:  # fmt: skip
    """The GUM uncertainty budget from the laboratory's knowledge
    (:func:`gonio.campaign.knowledge.campaign_budget`; ``fields``: its direction fields,
    made from the calibration alone)."""
    from gonio.campaign.knowledge import campaign_budget

    infos = [i for r in per_angle for i in r.get("infos", [])]
    return campaign_budget(result, samples, lab, corrections=plan.corrections, infos=infos,
                           fields=fields)  # fmt: skip


def _draw_samples(name: str, samples: BRDFSamples, folder: Path, title: str) -> None:
    """A plot of the samples alone (the hemisphere map needs no fit): :func:`draw`."""
    draw(name, samples, None, folder, title)


def _draw_budget(name: str, summary: Mapping[str, Any], folder: Path, title: str) -> None:
    """``plots/budget.png`` (the statistical row alone for the ideal instrument)."""
    if summary.get("budget") is not None:
        draw_budget(name, summary["budget"], folder, title)
