"""BRDF sample table files: CSV with a commented metadata header, and ``.npz``.

Columns (``docs/architecture.md``, File formats): ``theta_i, phi_i, theta_o, phi_o`` (radians),
``value`` (sr⁻¹), ``sigma`` (its standard error), optional ``wavelength_nm``. Files: CSV with a
commented ``# key: json-value`` metadata header whose first line, ``# units: {...}``, gives
each column's unit (:data:`UNITS`; read back, it is not metadata), and ``.npz`` (read with
``allow_pickle=False``). Writes go to a temporary file renamed into place, so a failure never
leaves a half-written table; malformed files raise :class:`ValueError` naming the problem.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from gonio.io.atomic import atomic_write_bytes
from gonio.io.jsonfile import loads
from gonio.samples import COLUMNS, BRDFSamples

__all__ = ["UNITS", "csv_rows", "read_samples", "write_csv_parts", "write_samples"]

#: the unit of each column, written as a CSV's first header line (``# units: {...}``)
UNITS = {
    "theta_i": "rad",
    "phi_i": "rad",
    "theta_o": "rad",
    "phi_o": "rad",
    "value": "sr^-1",
    "sigma": "sr^-1",
    "wavelength_nm": "nm",
}


def _units(columns: tuple[str, ...] | list[str]) -> dict[str, str]:
    return {c: UNITS[c] for c in columns if c in UNITS}


def write_samples(samples: BRDFSamples, path: str | os.PathLike) -> Path:
    """Write ``samples`` to ``path`` (``.csv`` or ``.npz``) atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return write_csv_parts(path, samples.metadata, samples.columns, [csv_rows(samples)])
    if suffix == ".npz":
        buf = io.BytesIO()
        arrays = {c: getattr(samples, c) for c in samples.columns}
        np.savez(buf, **arrays, metadata=np.array(json.dumps(samples.metadata)))
        return atomic_write_bytes(path, buf.getvalue())
    if suffix == ".astm":
        from gonio.io.astm import write_astm

        return write_astm(samples, path)
    raise ValueError(
        f"unsupported samples file suffix {path.suffix!r}; expected .csv, .npz or .astm"
    )


def csv_rows(samples: BRDFSamples) -> str:
    """The data rows of ``samples`` as :func:`write_samples` writes them to a CSV file.

    Every value is written ``%.17g`` (it reads back bit for bit), the same text as
    ``numpy.savetxt(fmt="%.17g", delimiter=",")``. Formatting is the costly part of a large
    CSV (~0.4 µs per number), so a column whose values are all the same (bit for bit: the
    incidence angles of one capture) is formatted once and pasted into the row template,
    and the rest go through one ``%`` operation per block of rows. Tables formatted
    separately (e.g. in worker processes) and joined with :func:`write_csv_parts` give the
    same file as one table.
    """
    arr = samples.to_array()
    n = arr.shape[0]
    if n == 0:
        return ""
    parts: list[str] = []
    varying: list[int] = []
    for j in range(arr.shape[1]):
        bits = np.ascontiguousarray(arr[:, j]).view(np.int64)
        if bool((bits == bits[0]).all()):
            parts.append(f"{float(arr[0, j]):.17g}")  # (the same text as "%.17g")
        else:
            parts.append("%.17g")
            varying.append(j)
    row = ",".join(parts) + "\n"
    if not varying:
        return (row % ()) * n
    vals = arr[:, varying]
    out = []
    block = 65536
    for a in range(0, n, block):
        v = vals[a : a + block]
        out.append((row * v.shape[0]) % tuple(v.ravel().tolist()))
    return "".join(out)


def write_csv_parts(
    path: str | os.PathLike, metadata: dict, columns: tuple[str, ...], parts: list[str]
) -> Path:
    """Write a samples CSV from its metadata, column names and :func:`csv_rows` parts."""
    head = f"# units: {json.dumps(_units(columns))}\n"
    head += "".join(f"# {k}: {json.dumps(v)}\n" for k, v in metadata.items())
    text = head + ",".join(columns) + "\n" + "".join(parts)
    return atomic_write_bytes(path, text.encode())


def read_samples(path: str | os.PathLike) -> BRDFSamples:
    """Read a samples table (``.csv``, ``.npz``, or an ASTM E1392 ``.astm`` table:
    :mod:`gonio.io.astm`); raise ``ValueError`` naming the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"samples file {str(path)!r} does not exist")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            return _read_csv(path)
        if suffix == ".npz":
            return _read_npz(path)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    if suffix == ".astm":  # (its errors name the file)
        from gonio.io.astm import read_astm

        return read_astm(path)
    raise ValueError(
        f"unsupported samples file suffix {path.suffix!r}; expected .csv, .npz or .astm"
    )


def _read_csv(path: Path) -> BRDFSamples:
    meta: dict[str, Any] = {}
    header: list[str] | None = None
    rows: list[str] = []
    with open(path, encoding="utf-8-sig") as f:  # -sig: a byte-order mark is not the header
        for line in f:
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                key, sep, val = s[1:].partition(":")
                if sep:
                    try:
                        meta[key.strip()] = loads(val, repr(str(path)))
                    except ValueError:
                        meta[key.strip()] = val.strip()
                continue
            if header is None:
                header = [c.strip() for c in s.split(",")]
                continue
            rows.append(s)
    if header is None:
        raise ValueError("no header line with column names")
    if meta.get("units") == _units(header):  # the writer's units line, not metadata
        del meta["units"]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(f"missing column(s) {missing}; header is {header}")
    unknown = [c for c in header if c not in (*COLUMNS, "wavelength_nm")]
    if unknown:
        raise ValueError(f"unknown column(s) {unknown}")
    data = np.empty((len(rows), len(header)))
    for i, r in enumerate(rows):
        parts = r.split(",")
        if len(parts) != len(header):
            raise ValueError(f"row {i + 1} has {len(parts)} fields, expected {len(header)}")
        try:
            data[i] = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"row {i + 1} has a non-numeric field: {r!r}") from None
    col = {c: data[:, header.index(c)] for c in header}
    return BRDFSamples(
        *(col[c] for c in COLUMNS), wavelength_nm=col.get("wavelength_nm"), metadata=meta
    )


def _read_npz(path: Path) -> BRDFSamples:
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            missing = [c for c in COLUMNS if c not in files]
            if missing:
                raise ValueError(f"missing array(s) {missing}")
            cols = [np.array(z[c]) for c in COLUMNS]
            wl = np.array(z["wavelength_nm"]) if "wavelength_nm" in files else None
            meta = loads(str(z["metadata"]), repr(str(path))) if "metadata" in files else {}
    except (OSError, EOFError) as exc:
        raise ValueError(f"not a readable .npz file ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile and friends
        if isinstance(exc, ValueError):
            raise
        raise ValueError(f"not a readable .npz file ({type(exc).__name__}: {exc})") from None
    return BRDFSamples(*cols, wavelength_nm=wl, metadata=meta)
