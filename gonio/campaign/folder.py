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

What made a group is recorded in its ``done.json`` (:func:`group_record`: the plan's capture
fields — material, instrument, mirror, exposures, noise, campaign seed — the group's key and
seed, and the gonio version) and checked when it is loaded: a group another plan, seed or
material made is taken again, never reported as this plan's data. While a campaign writes the
folder it holds an exclusive lock on ``OUT/.lock`` (:func:`locked`; released by the kernel
when the process ends, even by SIGKILL); a second campaign into the same folder is refused.
Opening the folder (:func:`check_out`, under the lock) removes what an interrupted run left:
temporary files of unfinished atomic writes and capture groups the plan does not have.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import time
from collections.abc import Iterator
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
    from gonio.cli._common import to_json

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


def group_record(plan: Plan, key: str, seed: int) -> dict[str, Any]:
    """What makes a capture group's frames: recorded in its ``done.json``, checked on load."""
    from gonio import __version__

    return {**capture_fields(plan), "group": key, "group_seed": int(seed), "gonio": __version__}


def load_group(folder: Path, made_by: dict[str, Any]) -> dict[str, Frames] | None:
    """Frames of a completed capture group that ``made_by`` (:func:`group_record`) made, or
    ``None`` if it is absent, incomplete or made by something else (then it is taken again)."""
    from gonio.io.images import read_image

    done = folder / "done.json"
    if not done.is_file():
        return None
    try:
        rec = json.loads(done.read_text())
        if _canonical(rec.get("made_by")) != _canonical(made_by):
            return None
        out: dict[str, Frames] = {}
        for kind, names in rec["files"].items():
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


class FolderBusy(ValueError):
    """Another campaign holds the results folder's lock."""


@contextlib.contextmanager
def locked(outp: Path | None) -> Iterator[None]:
    """Hold an exclusive lock on ``outp/.lock`` (``None``: nothing to lock).

    ``fcntl.flock`` on an open file: the kernel drops it when the process ends however it
    ends, so a killed campaign never leaves a stale lock. Raises :class:`FolderBusy` (a
    ``ValueError``) if another process holds it.
    """
    if outp is None:
        yield
        return
    import fcntl

    outp.mkdir(parents=True, exist_ok=True)
    fd = os.open(outp / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderBusy(
                f"results folder {str(outp)!r} is in use by another campaign (its .lock is "
                "held); wait for it or use another --out"
            ) from None
        yield
    finally:
        os.close(fd)  # releases the lock


#: Names of a capture group folder (:func:`group_key`) and of an unfinished atomic write
#: (:func:`gonio.io.atomic.atomic_write_bytes`: ``.NAME.XXXXXXXX.tmp``).
_GROUP = re.compile(r"t\d+\.\d\d(_r\d+\.\d)?")
_TMP = re.compile(r"\..+\.[A-Za-z0-9_]+\.tmp")


#: A campaign's derived outputs (made from the raw groups; removed when a run starts or fails).
OUTPUTS = ("samples.csv", "summary.json", "fit.json", "material.rad")


def discard_outputs(outp: Path) -> None:
    """Remove the derived outputs (:data:`OUTPUTS`) and unfinished writes from ``outp``."""
    for name in OUTPUTS:
        with contextlib.suppress(OSError):
            (outp / name).unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        _remove_tmp(outp)


def _remove_tmp(outp: Path) -> None:
    for p in sorted(outp.rglob("*.tmp")):
        if p.is_file() and _TMP.fullmatch(p.name):
            p.unlink(missing_ok=True)


def _tidy(outp: Path, plan: Plan) -> None:
    """Remove an earlier run's derived outputs and temporary files, and the capture groups
    this plan does not have."""
    keys = {group_key(th) for th in plan.theta_i_deg}
    keys |= {group_key(th, r) for th in plan.theta_i_deg for r in plan.rotations_deg}
    discard_outputs(outp)
    raw = outp / "raw"
    if raw.is_dir():
        for d in sorted(raw.iterdir()):
            if d.is_dir() and _GROUP.fullmatch(d.name) and d.name not in keys:
                shutil.rmtree(d)


def check_out(outp: Path, plan: Plan, resume: bool, truth: Any = None) -> None:
    """Open the results folder for ``plan`` (call under :func:`locked`): check a resumed
    plan against ``plan.json``, remove an earlier run's leftovers, write ``plan.json``."""
    outp.mkdir(parents=True, exist_ok=True)
    pfile = outp / "plan.json"
    if resume and pfile.is_file():
        try:
            old = Plan.from_dict(json.loads(pfile.read_text())).resolved(truth)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{pfile}: cannot resume, unreadable plan ({exc})") from None
        if capture_fields(old) != capture_fields(plan):
            raise ValueError(
                f"cannot resume in {outp}: its plan.json differs from this plan in what is "
                f"captured ({capture_fields(old)} vs {capture_fields(plan)}); use another --out"
            )
    _tidy(outp, plan)
    write_json(pfile, plan.to_dict())


def capture_fields(plan: Plan) -> dict[str, Any]:
    d = plan.to_dict()
    keys = ("material", "instrument", "mirror", "exposures_s", "noise", "seed", "preset")
    # (thinning is not part of it: raw captures can be reduced again with another thinning)
    return {k: d[k] for k in keys}


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
