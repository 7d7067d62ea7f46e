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
calibrates its instrument once, not for every campaign. It costs about 4 s (16 board views,
10 mirror spots) the first time.

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
from collections.abc import Mapping
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

_CACHE: dict[str, Any] = {}


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


def _board_views(inst: Any, seed: int) -> list[np.ndarray]:
    from gonio.calibration.lens import board_poses, make_board, render_board_view

    key = "board/" + _key(inst, lens_only=True) + f"/{seed}"
    views = _CACHE.get(key)
    if views is None:
        board = make_board()
        poses = board_poses(inst.lens, board, N_BOARD_VIEWS, distance=0.2,
                            max_field_angle=math.radians(75.0), rng=seed)  # fmt: skip
        views = [render_board_view(inst.lens, board, r, t, supersample=1, px_per_square=60)
                 for r, t in poses]  # fmt: skip
        _CACHE[key] = views
    return views


def take_captures(inst: Any, *, seed: int = 0) -> dict[str, Any]:
    """The calibration captures of a simulated instrument (the instrument's side).

    Returns ``{"board": [uint8 views], "mirror": [(theta_i, image, side-car)], "ladder":
    [[(image, side-car) per stop] per repeat]}``; the spot exposures keep the spot
    unsaturated, the ladder's exposure times (scaled with the marked N²) keep the standard
    near half the full well at every stop.
    """
    views = _board_views(inst, seed)
    target = FrontSurfaceMirror()
    spots = []
    gen = np.random.default_rng(seed)
    for a in MIRROR_ANGLES_DEG:
        img, meta = inst.capture(target, math.radians(a), 0.0, exposure=2e-5, f_number=32.0,
                                 rng=int(gen.integers(2**62)))  # fmt: skip
        spots.append((math.radians(a), img, meta))
    # the standard at normal incidence through every stop, ~half the full well, repeated:
    # one scene, so rendered once (capture_series; the same frames as one capture each)
    settings = [{"exposure": LADDER_EXPOSURE_S * (n / LADDER_STOPS[-1]) ** 2, "f_number": n,
                 "rng": int(gen.integers(2**62))}
                for _ in range(LADDER_REPEATS) for n in LADDER_STOPS]  # fmt: skip
    series = getattr(inst, "capture_series", None)
    if series is not None:
        frames = series("standard", 0.0, 0.0, settings=settings)
    else:  # an instrument without the series API: one capture a frame
        frames = [inst.capture("standard", 0.0, 0.0, **s) for s in settings]
    k = len(LADDER_STOPS)
    ladder = [frames[i : i + k] for i in range(0, len(frames), k)]
    return {"board": views, "mirror": spots, "ladder": ladder}


def calibrate(
    captures: Mapping[str, Any],
    nominal_mirror: Mapping[str, Any],
    *,
    certificate: Any = None,
    specification: Mapping[str, Mapping[str, Any]] | None = None,
    method: str = "eq3",
    arm_azimuth: float = 0.0,
    design: Mapping[str, float] | None = None,
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

    Returns
    -------
    LabCalibration
    """
    from gonio.calibration.angles import MirrorGeometry
    from gonio.calibration.laboratory import LabCalibration
    from gonio.calibration.lens import calibrate_fisheye, make_board
    from gonio.calibration.mirror import fit_mirror, spot_centroid
    from gonio.calibration.radiometry import SensorModel
    from gonio.geometry import to_vector

    h = hashlib.sha256()
    for v in captures["board"]:
        h.update(np.ascontiguousarray(v).tobytes())
    lens_cal = _CACHE.get("lens/" + h.hexdigest())
    if lens_cal is None:  # the same views give the same calibration
        lens_cal = _CACHE["lens/" + h.hexdigest()] = calibrate_fisheye(
            captures["board"], make_board()
        )
    lens_rec = lens_cal.to_dict()
    lens_rec.pop("seconds", None)  # a run time: the calibration file is the same every run
    lens_rec["fx_u_rel"] = _split_half_focal(captures["board"], lens_cal)
    lens = lens_cal.lens
    uv, dirs = [], []
    for theta_i, img, meta in captures["mirror"]:
        black = SensorModel.from_metadata(meta).black_level
        u, v, _ = spot_centroid(img, black)
        uv.append((u, v))
        # the mirror sends the beam (arm azimuth a) to azimuth a + π at the same polar angle
        dirs.append(to_vector(theta_i, arm_azimuth + math.pi))
    nominal = MirrorGeometry.from_metadata(dict(nominal_mirror))
    mirror = fit_mirror(uv, dirs, lens, nominal, method=method)
    fstops = None
    if captures.get("ladder"):
        from gonio.calibration.fstops import calibrate_fstops, overlap_ratios
        from gonio.calibration.reduce import Capture

        ov = [o for rep in captures["ladder"] for o in overlap_ratios(Capture(list(rep)))]
        fstops = calibrate_fstops(ov)
    info = {"lens_rms_px": lens_cal.rms, "lens_views": lens_cal.n_views,
            "mirror_rms_deg": mirror.rms_deg, "mirror_points": mirror.n_points}  # fmt: skip
    pitch = captures["mirror"][0][2].get("sensor", {}).get("pixel_pitch_m")
    if pitch is not None:  # the camera's data sheet
        info["pixel_pitch_m"] = float(pitch)
    if design:
        info["design"] = dict(design)
    return LabCalibration(
        lens=lens_rec,
        mirror=mirror,
        fstops=fstops,
        certificate=certificate,
        specification={k: dict(v) for k, v in (specification or {}).items()},
        info=info,
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


def _split_half_focal(views: list, full: Any) -> float:
    """Relative standard uncertainty of the calibrated focal length: half the difference of
    the calibrations on the even and the odd views (each half has √2 times the full set's
    error), at least 2e-4 (cached with the views)."""
    from gonio.calibration.lens import calibrate_fisheye, make_board

    h = hashlib.sha256(b"split")
    for v in views:
        h.update(np.ascontiguousarray(v).tobytes())
    key = "lens/" + h.hexdigest()
    got = _CACHE.get(key)
    if got is None:
        try:
            a = calibrate_fisheye(views[0::2], make_board()).lens.fx
            b = calibrate_fisheye(views[1::2], make_board()).lens.fx
            got = max(abs(a - b) / (2.0 * full.lens.fx), 2e-4)
        except ValueError:  # too few usable views in a half
            got = 1e-3
        _CACHE[key] = got
    return float(got)


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
):
    """The calibration of a simulated instrument, made once and kept.

    A ``folder`` holding a ``calibration.json`` made for this physical instrument (its
    ``info["instrument"]``, the instrument's identity) is read instead; otherwise the
    calibration is made (:func:`take_captures`, :func:`calibrate`), kept in memory for the
    same physical instrument, and written to ``folder`` if given (a folder copied from
    another instrument's campaign is calibrated anew).
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
        cal = calibrate(take_captures(inst, seed=seed), nominal_mirror, method=method,
                        design=design)  # fmt: skip
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
