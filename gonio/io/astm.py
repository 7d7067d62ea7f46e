"""BRDF tables in the layout of ASTM E1392 (angle-resolved scatter), as Cornell distributes them.

The Cornell laboratory distributes its gonioreflectometer measurements as MATLAB files and as
text tables after ASTM E1392, one row per geometry with its spectral channels. gonio's text
file (suffix ``.astm``) holds, in this order:

* a first line ``ASTM E1392 BRDF``;
* header lines ``KEY<TAB>value`` with the items ASTM E1392 asks a report to state: ``SAMPLE``
  (the sample's identification), ``DATE``, ``INSTRUMENT``, ``MEASUREMENT`` (``BRDF``),
  ``UNITS`` (``1/sr``), ``ANGLE_UNITS`` (``deg``), ``COORDINATES`` (the angles' convention:
  θ from the sample normal, φ from the sample's x axis, incident angles towards the source,
  scatter angles towards the receiver), ``INCIDENT_POLARIZATION`` and
  ``RECEIVER_POLARIZATION`` (``U``: unpolarised; the Cornell instrument averages its two
  polarisations), ``WAVELENGTHS_NM`` and ``BANDWIDTH_NM`` (the spectral channels),
  ``SOURCE_SOLID_ANGLE_SR`` and ``RECEIVER_SOLID_ANGLE_SR`` when known, ``NUM_POINTS``, and
  ``GONIO`` (the samples' metadata as JSON, so a round trip keeps it);
* ``DATA`` followed by the column names: ``THETA_I PHI_I THETA_S PHI_S`` (degrees), one
  ``BRDF_<nm>`` column per channel (``BRDF`` for grey data) and, when the standard errors
  are known, as many ``SIGMA_<nm>`` (``SIGMA``) columns;
* the rows, whitespace-separated: angles with :data:`ANGLE_DIGITS` decimals, BRDF and sigma
  with :data:`VALUE_DIGITS` significant digits (``%.*e``).

Reading gives a :class:`~gonio.samples.BRDFSamples` equal to the printed digits (angles
converted to radians); writing that table again gives the same text. The reader also takes
``#`` comment lines and keys in any case; an unknown key is kept in the metadata
(``astm_<key>``).

References
----------
ASTM E1392-96, "Standard Practice for Angle Resolved Optical Scatter Measurements on Specular
or Diffuse Surfaces", ASTM International: the quantities a scatter report states (sample,
instrument, wavelength, incident and receiver polarisation, receiver solid angle, angles in
the sample's coordinate system, BRDF in sr⁻¹). The Cornell Program of Computer Graphics'
reflectance data pages: one row per geometry with 31 channels 400-700 nm.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = ["ANGLE_DIGITS", "MAGIC", "VALUE_DIGITS", "read_astm", "write_astm", "write_cornell_astm"]

MAGIC = "ASTM E1392 BRDF"
#: decimals of the angles (deg): 1e-6 deg, below any goniometer's resolution
ANGLE_DIGITS = 6
#: significant digits of BRDF and sigma values
VALUE_DIGITS = 9
_COORDS = (
    "theta from the sample normal, phi from the sample x axis towards y; "
    "THETA_I PHI_I towards the source, THETA_S PHI_S towards the receiver"
)


def _band_label(wl: float) -> str:
    return f"{wl:g}"


def write_astm(
    samples: BRDFSamples,
    path: str | os.PathLike,
    *,
    sample: str | None = None,
    instrument: str | None = None,
    date: str | None = None,
    bandwidth_nm: float | None = None,
    source_solid_angle_sr: float | None = None,
    receiver_solid_angle_sr: float | None = None,
) -> Path:
    """Write ``samples`` as an ASTM E1392 table (atomic); one row per geometry.

    A spectral table needs every band at every geometry. ``sample`` defaults to the
    samples' ``material`` metadata, ``date`` to today (UTC), ``instrument`` to ``gonio``;
    header items of a table read from an ASTM file (metadata ``astm_<key>``) are kept.
    """
    if len(samples) == 0:
        raise ValueError("write_astm: the samples table is empty")
    geo = np.stack([samples.theta_i, samples.phi_i, samples.theta_o, samples.phi_o], -1)
    if samples.wavelength_nm is None:
        wl = None
        key, inv = np.unique(geo, axis=0, return_inverse=True)
        inv = inv.ravel()
        if len(key) != len(samples):
            raise ValueError(
                f"write_astm: {len(samples) - len(key)} repeated geometries; an ASTM table "
                "has one row per geometry (average them first)"
            )
        vals = np.empty((len(key), 1))
        sig = np.empty((len(key), 1))
        vals[inv, 0], sig[inv, 0] = samples.value, samples.sigma
    else:
        wl, band = np.unique(samples.wavelength_nm, return_inverse=True)
        key, inv = np.unique(geo, axis=0, return_inverse=True)
        inv, band = inv.ravel(), band.ravel()
        count = np.zeros((len(key), len(wl)), int)
        np.add.at(count, (inv, band), 1)
        if (count != 1).any():
            raise ValueError(
                "write_astm: a spectral table needs each band exactly once at every geometry; "
                f"{int(np.count_nonzero((count != 1).any(axis=1)))} geometries do not"
            )
        vals = np.empty((len(key), len(wl)))
        sig = np.empty_like(vals)
        vals[inv, band], sig[inv, band] = samples.value, samples.sigma
    # geometries in the order of first appearance (the measurement's order)
    first = np.full(len(key), len(samples))
    np.minimum.at(first, inv, np.arange(len(samples)))
    order = np.argsort(first, kind="stable")
    key, vals, sig = key[order], vals[order], sig[order]
    meta = {k: v for k, v in samples.metadata.items() if not k.startswith("astm_")}
    # header items read from an ASTM file (astm_<key>) are written back as they were
    prev = {k[5:].upper(): str(v) for k, v in samples.metadata.items() if k.startswith("astm_")}
    name = sample or prev.pop("SAMPLE", None) or meta.get("material") or "unknown"
    date = date or prev.pop("DATE", None) or _dt.datetime.now(_dt.UTC).date().isoformat()
    instrument = instrument or prev.pop("INSTRUMENT", None) or "gonio"
    for k in ("SAMPLE", "DATE", "INSTRUMENT", "MEASUREMENT", "UNITS", "ANGLE_UNITS"):
        prev.pop(k, None)
    for k in ("COORDINATES", "INCIDENT_POLARIZATION", "RECEIVER_POLARIZATION"):
        prev.pop(k, None)
    head = [
        MAGIC,
        f"SAMPLE\t{name}",
        f"DATE\t{date}",
        f"INSTRUMENT\t{instrument}",
        "MEASUREMENT\tBRDF",
        "UNITS\t1/sr",
        "ANGLE_UNITS\tdeg",
        f"COORDINATES\t{_COORDS}",
        "INCIDENT_POLARIZATION\tU",
        "RECEIVER_POLARIZATION\tU",
    ]
    if wl is not None:
        head.append("WAVELENGTHS_NM\t" + " ".join(_band_label(w) for w in wl))
    for k, v in (
        ("BANDWIDTH_NM", bandwidth_nm),
        ("SOURCE_SOLID_ANGLE_SR", source_solid_angle_sr),
        ("RECEIVER_SOLID_ANGLE_SR", receiver_solid_angle_sr),
    ):
        if v is not None:
            prev[k] = f"{float(v):.{VALUE_DIGITS - 1}e}"
    head += [f"{k}\t{v}" for k, v in prev.items()]
    head.append(f"NUM_POINTS\t{len(key)}")
    head.append("GONIO\t" + json.dumps(meta, sort_keys=True))
    labels = ["BRDF"] if wl is None else [f"BRDF_{_band_label(w)}" for w in wl]
    cols = ["THETA_I", "PHI_I", "THETA_S", "PHI_S", *labels]
    known = samples.has_sigma
    if known:
        cols += [c.replace("BRDF", "SIGMA") for c in labels]
    head.append("DATA\t" + " ".join(cols))
    ang = np.degrees(key)
    data = np.concatenate([ang, vals] + ([sig] if known else []), axis=1)
    fmt = " ".join([f"%.{ANGLE_DIGITS}f"] * 4 + [f"%.{VALUE_DIGITS - 1}e"] * (data.shape[1] - 4))
    rows = "\n".join(fmt % tuple(r) for r in data.tolist())
    text = "\n".join(head) + "\n" + rows + "\n"
    return atomic_write_bytes(path, text.encode())


def write_cornell_astm(samples: BRDFSamples, path: str | os.PathLike, lab: Any) -> Path:
    """A Cornell campaign's samples as the laboratory distributes them (``samples.astm``).

    ``lab`` is the laboratory's nominal configuration (what it knows, not the true
    instrument): its ``source_solid_angle_nominal`` (else ``source_solid_angle``) and
    ``detector_solid_angle`` (sr) go into the header.
    """
    nominal = getattr(lab, "source_solid_angle_nominal", None)
    return write_astm(
        samples,
        path,
        instrument="Cornell three-axis gonioreflectometer (gonio)",
        source_solid_angle_sr=nominal or getattr(lab, "source_solid_angle", None),
        receiver_solid_angle_sr=getattr(lab, "detector_solid_angle", None),
    )


def read_astm(path: str | os.PathLike) -> BRDFSamples:
    """Read an ASTM E1392 table written by :func:`write_astm` (or laid out the same way)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"ASTM file {str(path)!r} does not exist")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text file ({exc})") from None
    lines = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines or not lines[0].strip().upper().startswith("ASTM E1392"):
        raise ValueError(f"{path}: not an ASTM E1392 table (first line {lines[:1]!r})")
    header: dict[str, str] = {}
    cols: list[str] | None = None
    start = 0
    for i, ln in enumerate(lines[1:], 1):
        k, _, v = ln.strip().partition("\t") if "\t" in ln else ln.strip().partition(" ")
        k = k.strip().upper()
        if k == "DATA":
            cols = [c.upper() for c in v.split()]
            start = i + 1
            break
        header[k] = v.strip()
    if cols is None:
        raise ValueError(f"{path}: no DATA line with the column names")
    angles = ["THETA_I", "PHI_I", "THETA_S", "PHI_S"]
    if cols[:4] != angles:
        raise ValueError(f"{path}: the first columns must be {angles}, got {cols[:4]}")
    brdf = [c for c in cols[4:] if c.startswith("BRDF")]
    sigmas = [c for c in cols[4:] if c.startswith("SIGMA")]
    if not brdf or len(brdf) + len(sigmas) != len(cols) - 4:
        raise ValueError(f"{path}: expected BRDF[_<nm>] and optional SIGMA[_<nm>] columns")
    if sigmas and [s.replace("SIGMA", "BRDF") for s in sigmas] != brdf:
        raise ValueError(f"{path}: the SIGMA columns {sigmas} do not match BRDF {brdf}")
    spectral = brdf != ["BRDF"]
    try:
        wl = np.array([float(c.split("_", 1)[1]) for c in brdf]) if spectral else None
    except (IndexError, ValueError):
        raise ValueError(f"{path}: BRDF columns must be BRDF or BRDF_<nm>, got {brdf}") from None
    try:
        data = np.array(
            [[float(x) for x in ln.split()] for ln in lines[start:]], dtype=np.float64
        ).reshape(-1, len(cols))
    except ValueError as exc:
        raise ValueError(f"{path}: a data row is not {len(cols)} numbers ({exc})") from None
    n = data.shape[0]
    if "NUM_POINTS" in header and header["NUM_POINTS"].strip() != str(n):
        raise ValueError(f"{path}: NUM_POINTS {header['NUM_POINTS']} but {n} data rows")
    if header.get("ANGLE_UNITS", "deg").lower() not in ("deg", "degrees"):
        raise ValueError(f"{path}: ANGLE_UNITS {header['ANGLE_UNITS']!r}; expected deg")
    meta: dict[str, Any] = {}
    if "GONIO" in header:
        from gonio.io.jsonfile import loads

        doc = loads(header.pop("GONIO"), f"{path}: GONIO header")  # (depth-limited)
        if not isinstance(doc, dict):
            raise ValueError(f"{path}: GONIO header is not a JSON object")
        meta = dict(doc)
    for k, v in header.items():
        if k not in ("WAVELENGTHS_NM", "NUM_POINTS", "GONIO"):
            meta.setdefault(f"astm_{k.lower()}", v)
    ang = np.radians(data[:, :4])
    nb = len(brdf)
    vals = data[:, 4 : 4 + nb]
    sig = data[:, 4 + nb :] if sigmas else np.full_like(vals, np.nan)
    rep = (lambda a: np.repeat(a, nb)) if spectral else (lambda a: a)
    try:
        return BRDFSamples(
            *(rep(ang[:, j]) for j in range(4)),
            vals.ravel(),
            sig.ravel(),
            np.tile(wl, n) if spectral else None,
            meta,
        )
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
