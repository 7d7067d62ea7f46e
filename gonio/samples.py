"""BRDF sample tables: the tidy one-row-per-sample format and its files.

Columns (``../shared/DESIGN.md``, File formats): ``theta_i, phi_i, theta_o, phi_o`` (radians),
``value`` (sr⁻¹), ``sigma`` (its standard error), optional ``wavelength_nm``. Files: CSV with a
commented ``# key: json-value`` metadata header, and ``.npz`` (read with
``allow_pickle=False``). Writes go to a temporary file renamed into place, so a failure never
leaves a half-written table; malformed files raise :class:`ValueError` naming the problem.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.geometry import to_spherical, to_vector

__all__ = ["COLUMNS", "BRDFSamples", "atomic_write_bytes", "read_samples", "write_samples"]

COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o", "value", "sigma")


@dataclass
class BRDFSamples:
    """A table of BRDF samples; every column a 1-D float64 array of the same length.

    ``sigma`` may hold ``nan`` only if the whole column is unknown (then it is all ``nan``);
    ``wavelength_nm`` is ``None`` for grey data. ``metadata`` is a JSON-serialisable dict.
    """

    theta_i: NDArray[np.float64]
    phi_i: NDArray[np.float64]
    theta_o: NDArray[np.float64]
    phi_o: NDArray[np.float64]
    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    wavelength_nm: NDArray[np.float64] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = None
        for name in (*COLUMNS, "wavelength_nm"):
            col = getattr(self, name)
            if col is None and name == "wavelength_nm":
                continue
            arr = np.atleast_1d(np.asarray(col, dtype=np.float64))
            if arr.ndim != 1:
                raise ValueError(f"column {name} must be 1-D, got shape {arr.shape}")
            if n is None:
                n = arr.shape[0]
            elif arr.shape[0] != n:
                raise ValueError(f"column {name} has {arr.shape[0]} rows, expected {n}")
            if name == "sigma":
                if np.isnan(arr).any() and not np.isnan(arr).all():
                    raise ValueError("column sigma mixes known and unknown (nan) errors")
                if (arr < 0).any():
                    raise ValueError("column sigma has negative standard errors")
            elif not np.isfinite(arr).all():
                raise ValueError(f"column {name} contains non-finite values")
            setattr(self, name, arr)
        for name in ("theta_i", "theta_o"):
            a = getattr(self, name)
            if ((a < 0) | (a > np.pi / 2)).any():
                raise ValueError(f"column {name} must lie in [0, pi/2] radians")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_directions(
        cls,
        wi: ArrayLike,
        wo: ArrayLike,
        value: ArrayLike,
        sigma: ArrayLike | None = None,
        wavelength_nm: ArrayLike | None = None,
        metadata: dict | None = None,
    ) -> BRDFSamples:
        """Build a table from unit direction arrays ``(N, 3)`` (local sample frame)."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        ti, pi = to_spherical(wi.reshape(-1, 3))
        to, po = to_spherical(wo.reshape(-1, 3))
        value = np.asarray(value, float).ravel()
        sig = np.full(value.shape, np.nan) if sigma is None else np.asarray(sigma, float).ravel()
        return cls(ti, pi, to, po, value, sig, wavelength_nm, dict(metadata or {}))

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return self.value.shape[0]

    @property
    def wi(self) -> NDArray[np.float64]:
        """Incident directions, shape ``(N, 3)``."""
        return to_vector(self.theta_i, self.phi_i)

    @property
    def wo(self) -> NDArray[np.float64]:
        """Outgoing directions, shape ``(N, 3)``."""
        return to_vector(self.theta_o, self.phi_o)

    @property
    def has_sigma(self) -> bool:
        """Whether standard errors are known."""
        return not np.isnan(self.sigma).all() if len(self) else False

    def subset(self, mask: ArrayLike) -> BRDFSamples:
        """Rows selected by a boolean mask or index array."""
        m = np.asarray(mask)
        wl = None if self.wavelength_nm is None else self.wavelength_nm[m]
        return BRDFSamples(
            *(getattr(self, c)[m] for c in COLUMNS),
            wavelength_nm=wl,
            metadata=dict(self.metadata),
        )

    @classmethod
    def concatenate(cls, tables: list[BRDFSamples], metadata: dict | None = None) -> BRDFSamples:
        """Stack tables row-wise (all grey or all spectral)."""
        if not tables:
            raise ValueError("concatenate needs at least one table")
        spectral = {t.wavelength_nm is not None for t in tables}
        if len(spectral) > 1:
            raise ValueError("cannot concatenate grey and spectral tables")
        cols = [np.concatenate([getattr(t, c) for t in tables]) for c in COLUMNS]
        wl = np.concatenate([t.wavelength_nm for t in tables]) if spectral == {True} else None
        return cls(*cols, wavelength_nm=wl, metadata=dict(metadata or tables[0].metadata))

    def to_array(self) -> NDArray[np.float64]:
        """All columns stacked, shape ``(N, 6)`` or ``(N, 7)`` with ``wavelength_nm`` last."""
        cols = [getattr(self, c) for c in COLUMNS]
        if self.wavelength_nm is not None:
            cols.append(self.wavelength_nm)
        return np.stack(cols, axis=1)

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names in file order."""
        return COLUMNS + (("wavelength_nm",) if self.wavelength_nm is not None else ())

    # ------------------------------------------------------------------ files
    def write(self, path: str | os.PathLike) -> Path:
        """Write to ``.csv`` or ``.npz`` (by suffix) atomically; return the path."""
        return write_samples(self, path)

    @classmethod
    def read(cls, path: str | os.PathLike) -> BRDFSamples:
        """Read a ``.csv`` or ``.npz`` table written by :meth:`write` (or by hand)."""
        return read_samples(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and rename.

    The rename makes the write atomic: ``path`` holds its old content or all of ``data``,
    never a part, whatever happens to the process. ``durable`` also flushes the file to the
    disk (``fsync``) before the rename, so that it survives a power failure; bulk files
    written in a burst (a campaign's raw frames) pass ``False`` and are flushed together
    afterwards (:func:`fsync_files`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def fsync_files(paths: Iterable[str | os.PathLike]) -> int:
    """Flush files (and then their folders) to the disk; return how many files.

    One pass after a burst of ``durable=False`` writes: the disk writes of all of them are
    then in flight together, instead of one ``fsync`` waiting per file.
    """
    folders = set()
    n = 0
    for p in paths:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        folders.add(os.path.dirname(os.path.abspath(p)))
        n += 1
    for d in sorted(folders):
        try:
            fd = os.open(d, os.O_RDONLY)
        except OSError:  # (a platform that cannot open folders)
            continue
        try:
            os.fsync(fd)
        except OSError:
            pass
        finally:
            os.close(fd)
    return n


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
    raise ValueError(f"unsupported samples file suffix {path.suffix!r}; expected .csv or .npz")


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
    head = "".join(f"# {k}: {json.dumps(v)}\n" for k, v in metadata.items())
    text = head + ",".join(columns) + "\n" + "".join(parts)
    return atomic_write_bytes(path, text.encode())


def read_samples(path: str | os.PathLike) -> BRDFSamples:
    """Read a samples table; raise ``ValueError`` naming the file and the problem."""
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
    raise ValueError(f"unsupported samples file suffix {path.suffix!r}; expected .csv or .npz")


def _read_csv(path: Path) -> BRDFSamples:
    meta: dict[str, Any] = {}
    header: list[str] | None = None
    rows: list[str] = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                key, sep, val = s[1:].partition(":")
                if sep:
                    try:
                        meta[key.strip()] = json.loads(val)
                    except json.JSONDecodeError:
                        meta[key.strip()] = val.strip()
                continue
            if header is None:
                header = [c.strip() for c in s.split(",")]
                continue
            rows.append(s)
    if header is None:
        raise ValueError("no header line with column names")
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
            meta = json.loads(str(z["metadata"])) if "metadata" in files else {}
    except (OSError, EOFError) as exc:
        raise ValueError(f"not a readable .npz file ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile and friends
        if isinstance(exc, ValueError):
            raise
        raise ValueError(f"not a readable .npz file ({type(exc).__name__}: {exc})") from None
    return BRDFSamples(*cols, wavelength_nm=wl, metadata=meta)
