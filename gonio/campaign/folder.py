"""A campaign's results folder: the raw capture groups, the plan, the samples table.

Layout (written by :func:`gonio.campaign.run`)::

    OUT/plan.json                       the resolved plan
    OUT/raw/t40.00/standard_00.tif      raw 16-bit frames + ``.tif.json`` side-cars
    OUT/raw/t40.00/background_00.tif       (standard and background once per θi)
    OUT/raw/t40.00_r090/measured_00.tif    (the sample, per θi and sample rotation)
    OUT/raw/<key>/done.json             written last: the capture group is complete
    OUT/samples.csv                     reduced BRDF samples (all incidences)

Every file is written to a temporary name and renamed (:mod:`gonio.io.atomic`), so an
interrupted run leaves only complete files; a group without its ``done.json`` (or whose files
do not read back) is taken again on resume.

What made a group is recorded in its ``done.json`` (:func:`group_record`: every plan field
that shapes a frame — all but the reduction's, the fit's and the report's,
:data:`NOT_FRAME_FIELDS` — the group's exact angles, kinds of frames and seed, the measured
BRDF and the code that rendered it, :func:`code_version`) and compared when it is loaded: a
group another plan, instrument, seed, material or code made is taken again, never reported as
this plan's data. A resumed plan must share those fields with ``plan.json``; a run without
``resume`` into a folder holding another plan's results needs ``overwrite``. Group names keep
θi to 0.01° and the rotation to 0.1°: a plan whose angles would share a name is refused
(:meth:`Plan.resolved`). While a campaign writes the folder it holds an exclusive lock on
``OUT/.lock`` (:func:`locked`; released by the kernel when the process ends, even by SIGKILL);
a second campaign into the same folder is refused. The folder is opened (:func:`check_out`,
under the lock) only after every input is checked; opening it removes what an earlier run
left: its derived outputs (including plots the new run will not draw), temporary files of
unfinished atomic writes in gonio's own folders, and capture groups the plan does not have.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import re
import shutil
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign.plan import Plan
from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = [
    "FolderBusy",
    "Frames",
    "check_out",
    "check_settings",
    "discard_outputs",
    "flush_raw",
    "group_key",
    "group_record",
    "load_group",
    "locked",
    "save_group",
    "save_samples",
    "write_json",
]

_RAW_SUFFIX = ".tif"


Frames = list[tuple[np.ndarray, dict[str, Any]]]


def write_json(path: Path, obj: Any, durable: bool = True) -> None:
    from gonio.io.jsonfile import to_json

    atomic_write_bytes(path, (to_json(obj) + "\n").encode(), durable=durable)


def group_key(theta_deg: float, rot_deg: float | None = None) -> str:
    k = f"t{theta_deg:05.2f}"
    return k if rot_deg is None else f"{k}_r{rot_deg % 360:05.1f}"


def _save_frames(folder: Path, kind: str, frames: Frames) -> list[str]:
    from gonio.io.images import write_image

    names = []
    for k, (img, meta) in enumerate(frames):
        name = f"{kind}_{k:02d}{_RAW_SUFFIX}"
        # raw frames: speed over size; flushed to the disk together after the captures
        # (:func:`flush_raw`), a group whose files do not read back is taken again on resume
        write_image(folder / name, img, meta, compress=False, durable=False)
        names.append(name)
    return names


def group_record(
    plan: Plan, key: str, seed: int, theta_deg: float | None = None,
    rot_deg: float | None = None, kinds: Any = None, truth: Any = None,
) -> dict[str, Any]:  # fmt: skip
    """What makes a capture group's frames: recorded in its ``done.json``, checked on load.

    Every plan field that shapes a frame (:func:`frame_fields`: all but those of the
    reduction, fit and report), the group's exact incidence and rotation, its kinds of
    frames, its seed, the measured BRDF (``truth``: its class and parameters) and the code
    that rendered it (:func:`code_version`).
    """
    rec = {**frame_fields(plan), "group": key, "group_seed": int(seed),
           "gonio": code_version()}  # fmt: skip
    if theta_deg is not None:
        rec["theta_i_deg"] = float(theta_deg)
        rec["rotation_deg"] = None if rot_deg is None else float(rot_deg)
    if kinds is not None:
        rec["kinds"] = sorted(kinds)
    if truth is not None:
        rec["truth"] = truth_id(truth)
    return rec


def load_group(folder: Path, made_by: dict[str, Any]) -> dict[str, Frames] | None:
    """Frames of a completed capture group that ``made_by`` (:func:`group_record`) made, or
    ``None`` if it is absent, incomplete or made by something else (then it is taken again)."""
    from gonio.io.images import read_image
    from gonio.io.jsonfile import get_mapping, read_json, require_mapping

    done = folder / "done.json"
    if not done.is_file():
        return None
    try:
        src = repr(str(done))
        rec = require_mapping(read_json(done), src)
        if _canonical(rec.get("made_by")) != _canonical(made_by):
            return None
        files = get_mapping(rec, "files", src)
        if "kinds" in made_by and sorted(files) != made_by["kinds"]:
            return None
        out: dict[str, Frames] = {}
        for kind, names in files.items():
            ok = isinstance(names, list) and names
            if not (ok and all(isinstance(n, str) and _FRAME.fullmatch(n) for n in names)):
                return None
            out[kind] = [read_image(folder / n, require_metadata=True) for n in names]
        return out
    except (ValueError, KeyError, OSError):
        return None  # damaged: take it again


def save_group(folder: Path, frames: dict[str, Frames], made_by: dict[str, Any]) -> None:
    """Write one capture group: its frames, then its ``done.json`` (the group is complete)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "done.json").unlink(missing_ok=True)
    files = {kind: _save_frames(folder, kind, fr) for kind, fr in frames.items()}
    write_json(folder / "done.json", {"files": files, "made_by": made_by}, durable=False)


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


#: Plan fields that do not shape a frame: the reduction's, the fit's and the report's (and
#: the plan's lists of angles, recorded per group as the group's own angles).
NOT_FRAME_FIELDS = frozenset({"model", "residual", "compare", "plots", "thinning",
                              "thinning_mode", "debias", "corrections", "calibration",
                              "theta_i_deg", "rotations_deg"})  # fmt: skip


def frame_fields(plan: Plan) -> dict[str, Any]:
    """Every field of the resolved ``plan`` that shapes a raw frame: all but
    :data:`NOT_FRAME_FIELDS` (so a field added to :class:`Plan` counts unless it is listed
    there as the reduction's, the fit's or the report's)."""
    d = plan.to_dict()
    return {k: v for k, v in d.items() if k not in NOT_FRAME_FIELDS}


@functools.cache
def code_version() -> str:
    """gonio's version and a digest of the source that renders a frame (the simulator's
    modules, the image writer, the campaign's instrument): an edited simulator makes new
    groups, never resumes old ones."""
    from gonio import __version__, simulator
    from gonio.campaign import lbl
    from gonio.io import images

    h = hashlib.sha256()
    files = sorted(Path(simulator.__file__).parent.glob("*.py"))
    for f in [*files, Path(images.__file__), Path(lbl.__file__)]:
        with contextlib.suppress(OSError):
            h.update(f.name.encode() + b"\0" + f.read_bytes())
    return f"{__version__}+{h.hexdigest()[:16]}"


def truth_id(truth: Any) -> str:
    """The measured BRDF as a digest of its class, name and parameters (arrays by bytes)."""
    h = hashlib.sha256(f"{type(truth).__module__}.{type(truth).__qualname__}".encode())
    h.update(str(getattr(truth, "name", "")).encode())
    for k, v in sorted(dict(getattr(truth, "params", {}) or {}).items()):
        h.update(str(k).encode())
        a = np.asarray(v)
        h.update(a.tobytes() if a.dtype != object else repr(v).encode())
    return h.hexdigest()[:16]


class FolderBusy(ValueError):
    """Another campaign holds the results folder's lock."""


@contextlib.contextmanager
def locked(outp: Path | None) -> Iterator[None]:
    """Hold an exclusive lock on ``outp/.lock`` (``None``: nothing to lock).

    ``fcntl.flock`` on an open file: the kernel drops it when the process ends however it
    ends, so a killed campaign never leaves a stale lock. Raises :class:`FolderBusy` (a
    ``ValueError``) if another process holds it. A folder this call created is removed
    again if the body fails leaving nothing in it but the lock (a refused run leaves no
    trace).
    """
    if outp is None:
        yield
        return
    import fcntl

    made = [q for q in (outp, *outp.parents) if not q.exists()]
    outp.mkdir(parents=True, exist_ok=True)
    lock = outp / ".lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            made = []  # (another run's folder now)
            raise FolderBusy(
                f"results folder {str(outp)!r} is in use by another campaign (its .lock is "
                "held); wait for it or use another --out"
            ) from None
        yield
    except BaseException:
        if made and [p.name for p in outp.iterdir()] == [".lock"]:
            lock.unlink(missing_ok=True)
            for q in made:  # innermost first
                with contextlib.suppress(OSError):
                    q.rmdir()
        raise
    finally:
        os.close(fd)  # releases the lock


#: Names of a capture group folder (:func:`group_key`), of a raw frame in it, and of an
#: unfinished atomic write (:func:`gonio.io.atomic.atomic_write_bytes`: ``.NAME.XXXXXXXX.tmp``).
_GROUP = re.compile(r"t\d+\.\d\d(_r\d+\.\d)?")
_FRAME = re.compile(r"[A-Za-z]+_\d+\.tif")
_TMP = re.compile(r"\..+\.[A-Za-z0-9_]+\.tmp")


#: A campaign's derived outputs (made from the raw groups; removed when a run starts or fails;
#: ``samples.astm``: the Cornell campaign's ASTM E1392 table).
OUTPUTS = ("samples.csv", "samples.astm", "summary.json", "fit.json", "material.rad")
#: Its plots (``OUT/plots/NAME.png``, LBL and Cornell), also derived outputs.
PLOT_NAMES = ("incidence_plane", "hemisphere", "residuals", "budget", "preview")
#: Its Radiance function file (``OUT/gonio_MATERIAL.cal``, beside ``material.rad``).
_CAL = re.compile(r"gonio_[A-Za-z0-9_.-]*\.cal")


def discard_outputs(outp: Path) -> None:
    """Remove the derived outputs (:data:`OUTPUTS`, the plots, the Radiance ``.cal``) and
    unfinished writes from ``outp``: gonio's own names in gonio's own folders only."""
    with contextlib.suppress(OSError):
        for name in OUTPUTS:
            (outp / name).unlink(missing_ok=True)
        for p in outp.glob("gonio_*.cal"):
            if _CAL.fullmatch(p.name) and p.is_file():
                p.unlink(missing_ok=True)
        plots = outp / "plots"
        if plots.is_dir() and not plots.is_symlink():
            for name in PLOT_NAMES:
                (plots / f"{name}.png").unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                plots.rmdir()  # (only if the user keeps nothing of theirs there)
    with contextlib.suppress(OSError):
        _remove_tmp(outp)


def _gonio_folders(outp: Path) -> list[Path]:
    """The folders gonio writes in ``outp``: itself, ``plots``, ``calibration``, ``raw`` and
    its capture groups."""
    out = [outp, outp / "plots", outp / "calibration", outp / "raw"]
    raw = outp / "raw"
    if raw.is_dir() and not raw.is_symlink():
        out += [d for d in sorted(raw.iterdir()) if _GROUP.fullmatch(d.name)]
    return [d for d in out if d.is_dir() and not (d != outp and d.is_symlink())]


def _remove_tmp(outp: Path) -> None:
    for d in _gonio_folders(outp):
        for p in sorted(d.glob(".*.tmp")):
            if _TMP.fullmatch(p.name) and p.is_file() and not p.is_symlink():
                p.unlink(missing_ok=True)


def _tidy(outp: Path, plan: Plan) -> None:
    """Remove an earlier run's derived outputs and temporary files, the capture groups this
    plan does not have, and a calibration this plan will not make."""
    keys = {group_key(th) for th in plan.theta_i_deg}
    keys |= {group_key(th, r) for th in plan.theta_i_deg for r in plan.rotations_deg}
    discard_outputs(outp)
    raw = outp / "raw"
    if raw.is_dir() and not raw.is_symlink():
        for d in sorted(raw.iterdir()):
            if d.is_dir() and _GROUP.fullmatch(d.name) and d.name not in keys:
                shutil.rmtree(d)
    cal = outp / "calibration" / "calibration.json"
    given = (
        plan.calibration is not None and cal.parent.resolve() == Path(plan.calibration).resolve()
    )
    if (plan.calibration is not None or plan.preset == "ideal") and not given:  # none made
        cal.unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            cal.parent.rmdir()


def _old_plan(pfile: Path, truth: Any) -> Plan:
    from gonio.io.jsonfile import read_document

    return read_document(pfile, lambda d: Plan.from_dict(d).resolved(truth), what="a plan")


def check_out(
    outp: Path, plan: Plan, resume: bool, truth: Any = None, overwrite: bool = False
) -> None:
    """Open the results folder for ``plan`` (call under :func:`locked`, after every input
    is checked): check a resumed plan against ``plan.json`` (the same :func:`frame_fields`),
    refuse to replace another plan's results without ``overwrite``, then remove an earlier
    run's leftovers and write ``plan.json``."""
    outp.mkdir(parents=True, exist_ok=True)
    pfile = outp / "plan.json"
    if pfile.is_file():
        try:
            old = _old_plan(pfile, truth)
        except ValueError as exc:
            if not overwrite:
                what = "resume" if resume else "replace"
                raise ValueError(f"{exc}; cannot {what} its results without --overwrite") from None
            old = None
        if old is not None and resume:
            a, b = frame_fields(old), frame_fields(plan)
            diff = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
            if diff:
                raise ValueError(
                    f"cannot resume in {str(outp)!r}: its plan.json differs from this plan in "
                    "what shapes the captures ("
                    + ", ".join(f"{k}: {a.get(k)!r} vs {b.get(k)!r}" for k in diff)
                    + "); use another --out, or --overwrite without --resume"
                )
        elif old is not None and not overwrite and _differs(old, plan):
            raise ValueError(
                f"{str(outp)!r} holds the results of another plan (its plan.json); use "
                "--overwrite to replace them, --resume to continue that plan, or another --out"
            )
    elif not overwrite and not resume and _has_results(outp):
        raise ValueError(
            f"{str(outp)!r} holds campaign results without a plan.json; use --overwrite to "
            "replace them or another --out"
        )
    _tidy(outp, plan)
    write_json(pfile, plan.to_dict())


def check_settings(
    outp: Path, settings: Mapping[str, Any], resume: bool = False, overwrite: bool = False
) -> None:
    """The Cornell campaign's :func:`check_out`: refuse to replace the results of other
    settings (``plan.json`` differs from ``settings``, or is not readable, or results without
    one) unless ``overwrite``; a resumed run needs the same settings whatever ``overwrite``."""
    from gonio.io.jsonfile import FileFormatError, read_json, to_json

    new = json.loads(to_json(settings))  # as plan.json will hold it
    pfile = outp / "plan.json"
    if pfile.is_file():
        try:
            old = read_json(pfile)
        except (FileFormatError, ValueError) as exc:
            if overwrite and not resume:
                return
            raise ValueError(f"{exc}; cannot replace its results without --overwrite") from None
        if not isinstance(old, dict):
            old = {"plan.json": old}
        if _canonical(old) == _canonical(new):
            return
        diff = sorted(k for k in old.keys() | new.keys()
                      if _canonical(old.get(k)) != _canonical(new.get(k)))  # fmt: skip
        shown = ", ".join(f"{k}: {old.get(k)!r} vs {new.get(k)!r}" for k in diff[:4])
        if resume:
            raise ValueError(
                f"cannot resume in {str(outp)!r}: its plan.json differs from this campaign "
                f"({shown}); use another --out, or --overwrite without --resume"
            )
        if not overwrite:
            raise ValueError(
                f"{str(outp)!r} holds the results of another campaign (its plan.json: "
                f"{shown}); use --overwrite to replace them, or another --out"
            )
    elif not overwrite and not resume and _has_results(outp):
        raise ValueError(
            f"{str(outp)!r} holds campaign results without a plan.json; use --overwrite to "
            "replace them or another --out"
        )


def _differs(old: Plan, new: Plan) -> bool:
    """Whether ``new`` is another plan than ``old`` (the plots aside: a re-run without them
    replaces the same results)."""
    a, b = old.to_dict(), new.to_dict()
    a.pop("plots"), b.pop("plots")
    return _canonical(a) != _canonical(b)


def _has_results(outp: Path) -> bool:
    raw = outp / "raw"
    groups = raw.is_dir() and any(_GROUP.fullmatch(d.name) and (d / "done.json").is_file()
                                  for d in raw.iterdir())  # fmt: skip
    return groups or any((outp / n).exists() for n in OUTPUTS)


def capture_fields(plan: Plan) -> dict[str, Any]:
    """The fields a resumed plan must share with ``plan.json`` (:func:`frame_fields`)."""
    return frame_fields(plan)


def flush_raw(raw: Path) -> float:
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


def save_samples(outp: Path, samples: BRDFSamples, parts: list[str]) -> float:
    """Write ``samples.csv`` from its pre-formatted parts; return the seconds it took."""
    from gonio.io.samples_table import write_csv_parts

    t = time.perf_counter()
    write_csv_parts(outp / "samples.csv", samples.metadata, samples.columns, parts)
    return time.perf_counter() - t
