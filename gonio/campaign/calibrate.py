"""The calibration captures of a simulated LBL instrument, and the laboratory's calibration.

Two sides, kept apart as in a laboratory:

* the *instrument* takes the calibration captures (:func:`take_captures`): ChArUco board
  views through its fisheye (rendered with the true lens by
  :func:`gonio.calibration.lens.render_board_view`) and the spots of a front-surface mirror
  placed in the sample holder, one per incidence of the source arm;
* the *laboratory* turns the captures into knowledge (:func:`calibrate`): the lens by
  ``cv2.fisheye`` (:func:`gonio.calibration.lens.calibrate_fisheye`), the dome geometry by
  :func:`gonio.calibration.mirror.fit_mirror` starting from the nominal design, the standard's
  certificate as delivered with the standard, the specification of the build. Nothing of the
  true instrument reaches :func:`calibrate` but the images and the side-car fields a real
  instrument writes.

:func:`laboratory_calibration` does both once per physical instrument and keeps the result
(in memory, and as ``calibration.json`` in a folder when one is given): a laboratory
calibrates its instrument once, not for every campaign (in one process; a new campaign
process calibrates anew unless the plan names a calibration folder). It runs the two sides
as three independent jobs, each one kind of capture followed by the laboratory's analysis of
those captures alone (board views -> lens; mirror spots -> dome geometry;
f-stop ladder -> f-stop table), which can run in parallel (``parallel``); the calibration is
:func:`calibrate` of :func:`take_captures`, bit for bit (a test).

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics (Proc.
SIGGRAPH '92), 26(2), 265-272. https://doi.org/10.1145/142920.134078, §3.2.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from gonio.brdf.lambert import Lambert

__all__ = [
    "MIRROR_ANGLES_DEG",
    "FrontSurfaceMirror",
    "calibrate",
    "laboratory_calibration",
    "specification",
    "take_captures",
]

#: incidences of the mirror-spot captures (degrees)
MIRROR_ANGLES_DEG = tuple(float(a) for a in np.arange(6.0, 80.0, 8.0))

#: board views for the lens calibration (poses from calibration.lens.board_poses)
N_BOARD_VIEWS = 16

#: the f-stop ladder: the standard through every marked stop, repeated (iris repeatability)
LADDER_STOPS = (32.0, 22.0, 16.0, 11.0, 8.0, 5.6, 4.0, 2.8, 2.0)
LADDER_REPEATS = 6
#: exposure at the widest ladder stop (the others scale with the marked N²)
LADDER_EXPOSURE_S = 0.004
#: photons per pixel of the saturated flat field: the sphere turned up far past any full well
#: (a few 10^5 electrons for the largest pixels), so that every pixel clips
SATURATING_PHOTONS = 1.0e7

_CACHE: dict[str, Any] = {}

#: runs a list of independent jobs and returns their results in order
Parallel = Callable[[Sequence[Callable[[], Any]]], list]
#: begins one job and returns the function that waits for its result
Start = Callable[[Callable[[], Any]], Callable[[], Any]]


class FrontSurfaceMirror(Lambert):
    """A front-surface (aluminised) flat mirror: no diffuse part, a mirror part of
    reflectance ``r`` (0.9 for aluminium in the visible)."""

    name = "front_surface_mirror"

    def __init__(self, r: float = 0.9) -> None:
        super().__init__(rho=0.0)
        self._r = float(r)

    def delta(self, wi: Any) -> tuple[np.ndarray, np.ndarray]:
        """The mirror direction of ``wi`` and the reflectance ``r``."""
        wi = np.asarray(wi, dtype=np.float64)
        return wi * np.array([-1.0, -1.0, 1.0]), np.full(wi.shape[:-1], self._r)


def _serial(jobs: Sequence[Callable[[], Any]]) -> list[Any]:
    return [job() for job in jobs]


def _render_views(inst: Any, board: Any, poses: Sequence[tuple]) -> list[np.ndarray]:
    from gonio.calibration.lens import render_board_views

    return render_board_views(inst.lens, board, poses, supersample=1, px_per_square=60)


def _spots(inst: Any, seeds: Sequence[int]) -> list[tuple[float, np.ndarray, dict]]:
    target = FrontSurfaceMirror()
    out = []
    for a, s in zip(MIRROR_ANGLES_DEG, seeds):
        img, meta = inst.capture(target, math.radians(a), 0.0, exposure=2e-5, f_number=32.0,
                                 rng=s)  # fmt: skip
        out.append((math.radians(a), img, meta))
    return out


def _ladder(inst: Any, settings: list[dict[str, Any]]) -> list[list[tuple[np.ndarray, dict]]]:
    # one scene (the standard at normal incidence), so rendered once (capture_series: the
    # same frames as one capture each)
    series = getattr(inst, "capture_series", None)
    if series is not None:
        frames = series("standard", 0.0, 0.0, settings=settings)
    else:  # an instrument without the series API: one capture a frame
        frames = [inst.capture("standard", 0.0, 0.0, **s) for s in settings]
    k = len(LADDER_STOPS)
    return [frames[i : i + k] for i in range(0, len(frames), k)]


def take_captures(inst: Any, *, seed: int = 0, parallel: Parallel | None = None) -> dict[str, Any]:
    """The calibration captures of a simulated instrument (the instrument's side).

    Returns ``{"board": [uint8 views], "mirror": [(theta_i, image, side-car)], "ladder":
    [[(image, side-car) per stop] per repeat]}``; the spot exposures keep the spot
    unsaturated, the ladder's exposure times (scaled with the marked N²) keep the standard
    near half the full well at every stop.

    ``parallel`` runs a list of independent jobs and returns their results in order
    (:meth:`gonio.campaign.executor.CampaignExecutor.parallel`; default: one after the
    other): the board views (in two halves), the mirror spots and the ladder. Every
    capture's seed is drawn here first, in the order of the captures, so the captures are
    the same however the jobs run.
    """
    run = parallel or _serial
    draws = _Draws(inst, seed)
    jobs: list[Callable[[], Any]] = []
    if draws.views is None:
        half = (len(draws.poses) + 1) // 2
        jobs += [partial(_render_views, inst, draws.board, draws.poses[:half]),
                 partial(_render_views, inst, draws.board, draws.poses[half:])]  # fmt: skip
    jobs += [partial(_spots, inst, draws.spot_seeds), partial(_ladder, inst, draws.settings)]
    got = run(jobs)
    if draws.views is None:
        draws.keep_views(got[0] + got[1])
        got = got[2:]
    spots, ladder = got
    out = {"board": draws.views, "mirror": spots, "ladder": ladder}
    pt = draws.photon_transfer()
    if pt is not None:
        out["photon_transfer"] = pt
    return out


class _Draws:
    """The calibration captures' seeds and poses, drawn in the order of the captures (so
    that the captures are the same however their jobs run), and the board views of this
    lens if they were rendered before."""

    def __init__(self, inst: Any, seed: int) -> None:
        from gonio.calibration.lens import board_poses, make_board

        self.inst = inst
        self.gen = gen = np.random.default_rng(seed)
        self.spot_seeds = [int(gen.integers(2**62)) for _ in MIRROR_ANGLES_DEG]
        # the standard through every marked stop, ~half the full well, repeated
        self.settings = [{"exposure": LADDER_EXPOSURE_S * (n / LADDER_STOPS[-1]) ** 2,
                          "f_number": n, "rng": int(gen.integers(2**62))}
                         for _ in range(LADDER_REPEATS) for n in LADDER_STOPS]  # fmt: skip
        self.key = "board/" + _key(inst, lens_only=True) + f"/{seed}"
        self.views = _CACHE.get(self.key)
        if self.views is None:
            self.board = make_board()
            self.poses = board_poses(inst.lens, self.board, N_BOARD_VIEWS, distance=0.2,
                                     max_field_angle=math.radians(75.0), rng=seed)  # fmt: skip

    def keep_views(self, views: list[np.ndarray]) -> None:
        self.views = _CACHE[self.key] = views

    def photon_transfer(self) -> dict[str, Any] | None:
        """A dark frame and a flat past full well (photon transfer), drawn last; None for
        an instrument without them."""
        inst = self.inst
        if not hasattr(inst, "capture_flat"):
            return None
        kw = {"exposure": LADDER_EXPOSURE_S}
        return {
            "dark": inst.capture_dark(rng=int(self.gen.integers(2**62)), **kw),
            "flat": inst.capture_flat(SATURATING_PHOTONS, rng=int(self.gen.integers(2**62)),
                                      **kw),
        }  # fmt: skip


def calibrate(
    captures: Mapping[str, Any],
    nominal_mirror: Mapping[str, Any],
    *,
    certificate: Any = None,
    specification: Mapping[str, Mapping[str, Any]] | None = None,
    method: str = "eq3",
    arm_azimuth: float = 0.0,
    design: Mapping[str, float] | None = None,
    parallel: Parallel | None = None,
):
    """The laboratory's calibration from its captures (the laboratory's side).

    Parameters
    ----------
    captures : mapping
        :func:`take_captures`' output (or the same read from files).
    nominal_mirror : mapping
        The dome's design values (``type``, ``radius``, ``half_separation``): the start of
        the mirror fit.
    certificate : object, optional
        The standard's certificate.
    specification : mapping, optional
        The build's effect magnitudes (typical, spread, unit).
    method : {"eq3", "exact"}
        The angle recovery the reduction uses.
    arm_azimuth : float
        Dome azimuth of the source arm's plane (radians; the design value).
    design : mapping, optional
        Other design values the budget uses (``sample_radius``, ``spot_radius``, metres).
    parallel : callable, optional
        Runs a list of independent jobs, results in order (see :func:`take_captures`): the
        ChArUco detection of the board views (in two halves) and the f-stop calibration;
        the lens calibrations from all views and from the even and the odd views (the focal
        length's uncertainty) follow here, from the same detections.

    Returns
    -------
    LabCalibration
    """
    views = captures["board"]
    key = _views_key(views, b"record")
    jobs: dict[str, Callable[[], Any]] = {}
    detect = key not in _CACHE  # the same views: the same lens
    if detect:  # each view detected once (in two halves), for all three calibrations
        half = (len(views) + 1) // 2
        jobs["first"] = partial(_detect, views[:half])
        jobs["second"] = partial(_detect, views[half:])
    if captures.get("ladder"):
        jobs["fstops"] = partial(_fstops, captures["ladder"])
    got = dict(zip(jobs, (parallel or _serial)(list(jobs.values()))))
    lens_rec = _lens_record(views, key, got["first"] + got["second"] if detect else None)
    points = _mirror_points(captures["mirror"], arm_azimuth)
    return _assemble(
        lens_rec, _mirror_fit(points, lens_rec, nominal_mirror, method), got.get("fstops"),
        captures.get("photon_transfer"), _pixel_pitch(captures["mirror"]),
        certificate=certificate, specification=specification, design=design,
    )  # fmt: skip


def _lens_record(views: Sequence[Any], key: str, detections: Sequence[Any] | None = None) -> dict:
    """The lens calibration from the board views (``cv2.fisheye`` on all views) with the
    focal length's relative uncertainty ``fx_u_rel`` (from the even and the odd views); the
    views' ChArUco ``detections`` if made already (else detected here); kept under ``key``
    (the views' :func:`_views_key`)."""
    rec = _CACHE.get(key)
    if rec is None:
        dets = list(detections) if detections is not None else _detect(views)
        full = _lens_calibration(views, dets)
        halves = (_half_fx(views[k::2], dets[k::2]) for k in (0, 1))
        rec = full.to_dict()
        rec.pop("seconds", None)  # a run time: the calibration file is the same every run
        rec["fx_u_rel"] = float(_split_half(*halves, full.lens.fx))
        _CACHE[key] = rec
    return rec


def _mirror_points(spots: Sequence[tuple], arm_azimuth: float = 0.0) -> tuple[list, list]:
    """The mirror spots' centroids (pixels) and the directions the mirror sends the beam to
    (the arm's azimuth a, the beam to a + π at the same polar angle)."""
    from gonio.calibration.mirror import spot_centroid
    from gonio.calibration.radiometry import SensorModel
    from gonio.geometry import to_vector

    uv, dirs = [], []
    for theta_i, img, meta in spots:
        black = SensorModel.from_metadata(meta).black_level
        u, v, _ = spot_centroid(img, black)
        uv.append((u, v))
        dirs.append(to_vector(theta_i, arm_azimuth + math.pi))
    return uv, dirs


def _mirror_fit(
    points: tuple[list, list], lens_rec: Mapping[str, Any], nominal_mirror: Mapping[str, Any],
    method: str,
) -> Any:  # fmt: skip
    """The dome geometry fitted to the spots through the calibrated lens, from the nominal
    design (:func:`gonio.calibration.mirror.fit_mirror`)."""
    from gonio.calibration.angles import MirrorGeometry
    from gonio.calibration.mirror import fit_mirror
    from gonio.calibration.reduce import load_lens

    nominal = MirrorGeometry.from_metadata(dict(nominal_mirror))
    return fit_mirror(*points, load_lens(dict(lens_rec)), nominal, method=method)


def _pixel_pitch(spots: Sequence[tuple]) -> float | None:
    pitch = spots[0][2].get("sensor", {}).get("pixel_pitch_m")
    return None if pitch is None else float(pitch)


def _assemble(
    lens_rec: Mapping[str, Any],
    mirror: Any,
    fstops: Any,
    photon_transfer: Mapping[str, Any] | None,
    pitch: float | None,
    *,
    certificate: Any,
    specification: Mapping[str, Mapping[str, Any]] | None,
    design: Mapping[str, float] | None,
):
    """The :class:`~gonio.calibration.laboratory.LabCalibration` from its parts (the
    mirror: :func:`_mirror_fit`)."""
    from gonio.calibration.laboratory import LabCalibration

    lens_rec = dict(lens_rec)
    sensor = None
    if photon_transfer:
        from gonio.calibration.photon_transfer import saturation_level

        (flat, flat_meta), (dark, _) = (photon_transfer[k] for k in ("flat", "dark"))
        sensor = saturation_level(flat, flat_meta, dark)
    info = {"lens_rms_px": lens_rec["rms_px"], "lens_views": lens_rec["n_views"],
            "mirror_rms_deg": mirror.rms_deg, "mirror_points": mirror.n_points}  # fmt: skip
    if pitch is not None:  # the camera's data sheet
        info["pixel_pitch_m"] = pitch
    if design:
        info["design"] = dict(design)
    return LabCalibration(
        lens=lens_rec,
        mirror=mirror,
        fstops=fstops,
        certificate=certificate,
        specification={k: dict(v) for k, v in (specification or {}).items()},
        info=info,
        sensor=sensor,
    )


def specification(preset: str) -> dict[str, dict[str, Any]]:
    """The maker's statement of a build: each effect of the preset that is not zero, as
    ``{"typical", "spread", "unit"}`` (:data:`gonio.simulator.effects.PRESETS`); what a
    laboratory knows of its instrument before calibrating it."""
    from gonio.simulator.effects import EFFECTS, PRESETS

    if preset not in PRESETS:
        raise ValueError(f"preset {preset!r} is unknown; expected one of {', '.join(PRESETS)}")
    return {k: {"typical": d.typical, "spread": d.spread, "unit": EFFECTS[k].unit}
            for k, d in PRESETS[preset].items() if d.typical or d.spread}  # fmt: skip


def _views_key(views: Sequence[Any], salt: bytes) -> str:
    h = hashlib.sha256(salt)
    for v in views:
        h.update(np.ascontiguousarray(v).tobytes())
    return "lens/" + h.hexdigest()


def _detect(views: Sequence[Any]) -> list[tuple[np.ndarray, np.ndarray]]:
    from gonio.calibration.lens import detect_views, make_board

    return detect_views(views, make_board())


def _lens_calibration(views: Sequence[Any], detections: Sequence[Any]) -> Any:
    from gonio.calibration.lens import calibrate_fisheye, make_board

    return calibrate_fisheye(views, make_board(), detections=detections)


def _half_fx(views: Sequence[Any], detections: Sequence[Any]) -> float | None:
    """The focal length calibrated from a half of the views (None: too few usable views)."""
    try:
        return float(_lens_calibration(views, detections).lens.fx)
    except ValueError:
        return None


def _split_half(a: float | None, b: float | None, fx: float) -> float:
    """Relative standard uncertainty of the calibrated focal length ``fx``: half the
    difference of the calibrations on the even and the odd views (each half has √2 times
    the full set's error), at least 2e-4; 1e-3 when a half has too few usable views."""
    if a is None or b is None:
        return 1e-3
    return max(abs(a - b) / (2.0 * fx), 2e-4)


def _fstops(ladder: Sequence[Sequence[Any]]) -> Any:
    from gonio.calibration.fstops import calibrate_fstops, overlap_ratios
    from gonio.calibration.reduce import Capture

    return calibrate_fstops([o for rep in ladder for o in overlap_ratios(Capture(list(rep)))])


def _key(inst: Any, lens_only: bool = False) -> str:
    """Identity of the physical instrument (its description, effects and instrument seed:
    the simulator's side, as a laboratory knows which instrument it calibrated)."""
    d: dict[str, Any] = {"lens": inst.lens.to_dict()}
    if not lens_only:
        d.update(inst.to_dict())
        d["effects"] = dict(getattr(inst, "effects", {}) or {})
        d["instrument_seed"] = getattr(inst, "instrument_seed", 0)
    return hashlib.sha256(json.dumps(d, sort_keys=True, default=repr).encode()).hexdigest()[:20]


def laboratory_calibration(
    inst: Any,
    nominal_mirror: Mapping[str, Any],
    *,
    folder: str | os.PathLike | None = None,
    certificate: Any = None,
    specification: Mapping[str, Mapping[str, Any]] | None = None,
    method: str = "eq3",
    seed: int = 0,
    parallel: Parallel | None = None,
    start: Start | None = None,
    warm: Callable[[], None] | None = None,
):
    """The calibration of a simulated instrument, made once and kept.

    A ``folder`` holding a ``calibration.json`` made for this physical instrument (its
    ``info["instrument"]``, the instrument's identity) is read instead; otherwise the
    calibration is made (the captures of :func:`take_captures` and the analysis of
    :func:`calibrate`, pipelined: see :func:`_pipelined`), kept in memory for the same
    physical instrument, and written to ``folder`` if given (a folder copied from another
    instrument's campaign is calibrated anew). ``parallel``: how the independent jobs run
    (default one after the other; a campaign gives
    :meth:`~gonio.campaign.executor.CampaignExecutor.parallel`). ``warm`` readies the
    instrument for the captures (traces its geometry, loads its kernels) once the job that
    needs none of it, the lens's, has been begun by ``start`` (default: run when its result
    is needed; a campaign gives :meth:`~gonio.campaign.executor.CampaignExecutor.start`);
    it is called only if captures are taken.
    """
    from gonio.calibration.laboratory import CALIBRATION_FILE, read_calibration

    key = _key(inst) + f"/{method}/{seed}"
    if folder is not None and (Path(folder) / CALIBRATION_FILE).is_file():
        got = read_calibration(folder)
        if got.info.get("instrument") == key:
            return got
    cal = _CACHE.get(key)
    if cal is None:
        design = {"sample_radius": float(inst.sample_radius),
                  "spot_radius": float(inst.source.spot_radius)}  # fmt: skip
        cal = _pipelined(inst, nominal_mirror, seed, method, design, parallel or _serial,
                         start or _later, warm)  # fmt: skip
        if len(_CACHE) > 64:
            for k in [k for k in _CACHE if not k.startswith(("board/", "lens/"))]:
                _CACHE.pop(k)
        _CACHE[key] = cal
    from dataclasses import replace

    cal = replace(cal, certificate=certificate, specification=dict(specification or {}),
                  info={**cal.info, "instrument": key})  # fmt: skip
    if folder is not None:
        cal.write(folder)
    return cal


def _later(job: Callable[[], Any]) -> Callable[[], Any]:
    return job


def _pipelined(
    inst: Any, nominal_mirror: Mapping[str, Any], seed: int, method: str,
    design: Mapping[str, float], parallel: Parallel, start: Start,
    warm: Callable[[], None] | None,
):  # fmt: skip
    """``calibrate(take_captures(inst))`` as three independent jobs, each the instrument's
    captures of one kind followed by the laboratory's analysis of those captures alone:
    board views -> lens, mirror spots -> centroids, f-stop ladder -> f-stop table. Only
    the analyses' results (and the views, kept for the next instrument with this lens) come
    back from a job; the ladder's 54 frames stay where they were taken. The lens's job needs
    the lens alone, so it is begun (``start``) before the instrument is warmed up
    (``warm``) for the other two. The captures are those of :func:`take_captures` (the
    same draws), so the calibration is :func:`calibrate`'s bit for bit.
    """
    draws = _Draws(inst, seed)
    lens = start(partial(_lens_part, inst, seed))
    if warm is not None:
        warm()
    (points, pitch), fstops = parallel([
        partial(_spots_job, inst, draws.spot_seeds),
        partial(_ladder_job, inst, draws.settings),
    ])  # fmt: skip
    views, key, lens_rec = lens()
    mirror = _mirror_fit(points, lens_rec, nominal_mirror, method)
    if draws.views is None:
        draws.keep_views(views)
    _CACHE.setdefault(key, lens_rec)  # (made in a job's process: kept here too)
    return _assemble(
        lens_rec, mirror, fstops, draws.photon_transfer(), pitch,
        certificate=None, specification=None, design=design,
    )  # fmt: skip


def _lens_part(inst: Any, seed: int = 0) -> tuple[list[np.ndarray], str, dict[str, Any]]:
    """The camera's part of :func:`laboratory_calibration`: the board views (the
    instrument's captures, as in :func:`take_captures`) and the lens calibrated from them
    (the laboratory's, as in :func:`calibrate`): ``(views, their key, lens record)``."""
    draws = _Draws(inst, seed)
    views = draws.views
    if views is None:
        views = _render_views(inst, draws.board, draws.poses)
    key = _views_key(views, b"record")
    return views, key, _lens_record(views, key)


def _spots_job(inst: Any, seeds: Sequence[int]) -> tuple[tuple[list, list], float | None]:
    spots = _spots(inst, seeds)
    return _mirror_points(spots), _pixel_pitch(spots)


def _ladder_job(inst: Any, settings: list[dict[str, Any]]) -> Any:
    return _fstops(_ladder(inst, settings))
