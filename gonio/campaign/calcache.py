"""The laboratory's calibration kept for the next campaign of the same instrument.

A laboratory calibrates its physical instrument once and measures many samples with it; a
simulated campaign made its calibration captures and their analysis anew in every process
(0.8-1.0 s of processor time on the default instrument). A made calibration is kept here,
and the next campaign of the same instrument realisation reads it instead.

Where: ``$GONIO_CACHE_DIR/calibrations/KEY/`` (default ``$XDG_CACHE_HOME/gonio``, else
``~/.cache/gonio``): the ``calibration.json`` of
:meth:`gonio.calibration.laboratory.LabCalibration.write`, ``key.json``, what the key
was made of, and ``direction_fields.npz``, the uncertainty budget's direction fields of
that calibration (:func:`gonio.campaign.budget_terms.direction_fields`: made from the
calibration and the specification alone, 1-2 s of processor time for the dome figure's
64 realisations), added by the first campaign that made them (:func:`store_fields`).
``gonio campaign --no-calibration-cache`` (``run(..., calibration_cache=False)``) neither
reads nor writes it.

The key (:func:`calibration_key`) is the SHA-256 of everything that determines the
calibration: the instrument's identity as the calibration records it (its description,
effects, instrument seed and lens: :func:`gonio.campaign.calibrate.laboratory_calibration`),
the nominal mirror the dome fit starts from, the method, the seed of the captures, the
standard's certificate, the specification, a digest of the source of every module of
gonio (its simulator and calibration included: an edited renderer or fit makes another
key) and the versions of Python, numpy, SciPy, OpenCV and numba. A hit is served only when
the stored ``key.json`` equals the inputs in full, so neither a collision nor a file of
another instrument is ever read as this one's. A file that cannot be read is a miss (the
calibration is made again and the entry rewritten).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import shutil
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["cache_dir", "calibration_key", "load", "store", "store_fields"]

#: the environment variable naming the cache's folder
ENV = "GONIO_CACHE_DIR"
#: the file of an entry that holds what its key was made of
KEY_FILE = "key.json"
#: the file of an entry that holds its calibration's direction fields
FIELDS_FILE = "direction_fields.npz"


def cache_dir() -> Path:
    """The folder of the cached calibrations: ``$GONIO_CACHE_DIR/calibrations`` (default
    ``$XDG_CACHE_HOME/gonio``, else ``~/.cache/gonio``)."""
    root = os.environ.get(ENV)
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = str(Path(xdg) / "gonio") if xdg else str(Path.home() / ".cache" / "gonio")
    return Path(root) / "calibrations"


@functools.cache
def code_digest() -> str:
    """SHA-256 of the source of every module of gonio's packages (the calibration's code
    among them), read once per process (129 files, 1.9 MB: about 30 ms)."""
    import gonio
    from gonio import calibration, simulator

    h = hashlib.sha256()
    for pkg in (gonio, simulator, calibration):
        root = Path(pkg.__file__).parent
        for f in sorted(root.rglob("*.py")):
            h.update(f"{pkg.__name__}/{f.relative_to(root).as_posix()}".encode() + b"\0")
            h.update(f.read_bytes())
    return h.hexdigest()


def _versions() -> dict[str, str | None]:
    """The libraries' versions, from their installed metadata (importing OpenCV or numba
    only for its version would cost a campaign that reads its calibration 0.1-0.4 s)."""
    from importlib import metadata

    def installed(*names: str) -> str | None:
        for name in names:
            try:
                return f"{name} {metadata.version(name)}"
            except metadata.PackageNotFoundError:
                continue
        return None

    opencv = ("opencv-contrib-python-headless", "opencv-python-headless",
              "opencv-contrib-python", "opencv-python")  # fmt: skip
    return {
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "numpy": installed("numpy"),
        "scipy": installed("scipy"),
        "opencv": installed(*opencv),
        "numba": installed("numba"),
    }


def calibration_key(identity: str, inputs: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """``(key, what it is made of)`` for a calibration of the instrument ``identity`` (as
    :func:`gonio.campaign.calibrate.laboratory_calibration` records it) made from
    ``inputs`` (the nominal mirror, method, seed, certificate, specification: JSON values,
    others by their ``repr``), the code digest and the libraries' versions."""
    made_of = json.loads(json.dumps(
        {"instrument": identity, **inputs, "code": code_digest(), "versions": _versions()},
        sort_keys=True, default=repr,
    ))  # fmt: skip
    text = json.dumps(made_of, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest(), made_of


def load(key: str, made_of: Mapping[str, Any]) -> Any:
    """The cached :class:`~gonio.calibration.laboratory.LabCalibration` of ``key``, or None
    (none, another's ``key.json``, or a file that cannot be read)."""
    entry = cache_dir() / key
    try:
        if not _is_entry_of(entry, made_of):
            return None
        from gonio.calibration.laboratory import read_calibration

        lab = read_calibration(entry)
    except (OSError, ValueError):
        return None
    fields = _read_fields(entry / FIELDS_FILE)
    if fields is not None:
        from gonio.campaign.budget_terms import keep_direction_fields

        keep_direction_fields(lab, fields)
    return lab


def _is_entry_of(entry: Path, made_of: Mapping[str, Any]) -> bool:
    """Whether the entry's ``key.json`` holds exactly ``made_of`` (raises OSError or
    ValueError when it cannot be read)."""
    return json.loads((entry / KEY_FILE).read_text()) == made_of


def has_fields(lab: Any) -> bool:
    """Whether ``lab`` came with its direction fields (read from its entry)."""
    from gonio.campaign.budget_terms import has_direction_fields

    return has_direction_fields(lab)


def store_fields(key: str, made_of: Mapping[str, Any], fields: list) -> bool:
    """Add the direction fields ``fields`` (:func:`gonio.campaign.budget_terms.direction_fields`
    of the calibration kept under ``key``) to its entry, written atomically; False when the
    entry is not that calibration's (another ``key.json``, or none) or cannot be written."""
    import io

    import numpy as np

    from gonio.io.atomic import atomic_write_bytes

    entry = cache_dir() / key
    try:
        if not _is_entry_of(entry, made_of):
            return False
        buf = io.BytesIO()
        np.savez(
            buf,
            name=np.array([f[0] for f in fields], dtype=str),
            u=np.array([f[1] for f in fields], dtype=np.float64),
            unit=np.array([f[2] for f in fields], dtype=str),
            cells=np.stack([f[3] for f in fields]) if fields else np.zeros((0, 0, 3)),
            corrected=np.array([f[4] for f in fields], dtype=bool),
        )  # fmt: skip
        atomic_write_bytes(entry / FIELDS_FILE, buf.getvalue(), durable=False)
    except (OSError, ValueError):
        return False
    return True


def _read_fields(path: Path) -> list | None:
    """The direction fields of :func:`store_fields`, or None (no file, or one that cannot
    be read as such: the fields are then made again)."""
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            name, u, unit, cells, corr = (z[k] for k in ("name", "u", "unit", "cells",
                                                         "corrected"))  # fmt: skip
    except (OSError, ValueError, KeyError, EOFError):
        return None
    n = len(name)
    if not (len(u) == len(unit) == len(corr) == cells.shape[0] == n) or (
        n and (cells.ndim != 3 or cells.shape[2] != 3 or not np.isfinite(cells).all())
    ):
        return None
    return [(str(name[i]), float(u[i]), str(unit[i]), cells[i], bool(corr[i]))
            for i in range(n)]  # fmt: skip


#: entries kept (the oldest beyond it removed when one is stored; each about 0.15 MB)
MAX_ENTRIES = 32


def store(key: str, made_of: Mapping[str, Any], lab: Any) -> bool:
    """Keep ``lab`` under ``key`` (each file written atomically, the key last, so an entry
    without its key file is never read), then remove the oldest entries beyond
    :data:`MAX_ENTRIES` (each code change makes new keys); False when the folder cannot be
    written."""
    from gonio.io.atomic import atomic_write_bytes

    entry = cache_dir() / key
    try:
        lab.write(entry)
        text = json.dumps(made_of, sort_keys=True, indent=1)
        atomic_write_bytes(entry / KEY_FILE, text.encode(), durable=False)
        _prune(cache_dir(), keep=entry)
    except OSError:
        return False
    return True


def _prune(root: Path, keep: Path) -> None:
    def age(p: Path) -> float:
        try:
            return p.stat().st_mtime
        except OSError:  # (removed meanwhile by another campaign)
            return 0.0

    entries = sorted((p for p in root.iterdir() if p.is_dir() and p != keep), key=age)
    for old in entries[: max(0, len(entries) + 1 - MAX_ENTRIES)]:
        shutil.rmtree(old, ignore_errors=True)
