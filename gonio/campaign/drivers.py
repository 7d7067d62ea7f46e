"""Campaigns through the device drivers: the instruments driven only by ``gonio.drivers``
interfaces (:class:`~gonio.drivers.interfaces.Axis`, ``MotionController``, ``Camera``,
``Spectrometer``), with an atomic checkpoint of completed measurements.

Two instruments:

* :class:`CornellRig` + :func:`run_cornell_measurements` — the Cornell three-axis
  gonioreflectometer (Li and Torrance 2005, §5.1): three motor axes
  (``arm``, ``turntable``, ``tilt``, degrees), four accessory axes (``polarizer`` 0° = s /
  90° = p, the ``target`` slide, the ND ``filter`` wheel and the rotary ``shutter``; stations
  in :mod:`gonio.simulator.bench`) and a spectrometer. The read sequence is the simulator's
  (:meth:`gonio.simulator.cornell.CornellInstrument.calibrate` and ``measure_raw``: a preview
  for the integration time, then a signal and a dark read per polarisation in the order of
  ``gonio.simulator.cornell.read_sequence``: one polariser turn and two shutter moves per
  geometry), and the raw
  spectra are reduced with :func:`gonio.simulator.cornell.reduce_measurement`, so that
  against the fake devices the samples equal the in-process simulation's for the same seed.
* :func:`open_served_rig` — the same rig opened on the devices that ``gonio devices serve``
  runs in another process (every controller of the bench, :data:`CONTROLLER_GROUPS`), for
  external driver scripts; :func:`cornell_fake_bench` is the bench behind both.
* :class:`LBLDriverInstrument` — the LBL imaging gonioreflectometer (Ward 1992): ESP300 axes
  for the source arm and the sample rotation, a sample-changer axis and a PTP camera; it has
  the ``shoot(sample, theta_i, phi_i, seed)`` method of :func:`gonio.campaign.run`, which then
  reduces the 16-bit frames with :func:`gonio.calibration.reduce.reduce_capture` and fits.

Checkpoint and resume: :class:`Checkpoint` keeps the completed measurements (index → record)
in one ``.npz`` written atomically (temporary file + rename), flushed every ``every``
records or ``every_s`` seconds and whenever the run stops on an exception. A resumed run
skips the indices already there, so nothing is lost or measured twice; the reference
(standard/direct-beam and stray-light rates) is stored beside it and reused.

:func:`fake_cornell_rig` and :func:`fake_lbl_rig` set up the fake devices (ESP300s on
pseudo-terminals, the USB2000+ and PTP camera on the fake pyusb backend) on a simulated
bench and open the real drivers on them.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   Here: the LBL device of §3 as the driver campaign's ESP300-turned sample and camera.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Here: the three-axis gonioreflectometer of §5.1 driven through its motor and
   spectrometer drivers.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.drivers.interfaces import Axis, Camera, MotionController, Spectrometer
from gonio.io.atomic import atomic_write_bytes

__all__ = [
    "CONTROLLER_GROUPS",
    "CORNELL_ACCESSORIES",
    "CORNELL_MOTORS",
    "Checkpoint",
    "CornellRig",
    "LBLDriverInstrument",
    "cornell_fake_bench",
    "eeprom_coeffs",
    "fake_cornell_rig",
    "fake_lbl_rig",
    "fingerprint",
    "open_served_rig",
    "run_cornell_measurements",
    "run_lbl_through_drivers",
]

#: Motor axes of the Cornell instrument (degrees), in the order of the simulator's angles.
CORNELL_MOTORS = ("arm", "turntable", "tilt")
#: Accessory axes of the Cornell instrument.
CORNELL_ACCESSORIES = ("polarizer", "target", "filter", "shutter")
#: Stages of each fake bench, grouped by ESP300 controller (axes 1..3 of each, in order).
CONTROLLER_GROUPS: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "cornell": (
        ("motors", CORNELL_MOTORS),
        ("accessories", ("polarizer", "target", "filter")),
        ("shutter", ("shutter",)),
    ),
    "lbl": (("motors", ("source", "sample", "tilt")), ("changer", ("changer",))),
}


def eeprom_coeffs(coeffs: Sequence[float]) -> tuple[float, ...]:
    """Wavelength coefficients as a USB2000+ EEPROM holds them (``%.6e`` ASCII, 7 digits).

    The driver computes the pixel wavelengths from these; a simulation that is to match a
    campaign through the drivers bit for bit uses the same rounded coefficients.
    """
    return tuple(float(f"{float(c):.6e}") for c in coeffs)


# ----------------------------------------------------------------------------- checkpoint
def fingerprint(obj: Any) -> str:
    """SHA-256 (hex, 16 characters) of a JSON-able description or an array."""
    if isinstance(obj, np.ndarray):
        data = np.ascontiguousarray(obj).tobytes() + str(obj.shape).encode()
    else:
        data = json.dumps(obj, sort_keys=True, default=str).encode()
    return hashlib.sha256(data).hexdigest()[:16]


class Checkpoint:
    """Completed measurements of a campaign, kept in one atomically written ``.npz``.

    Parameters
    ----------
    path : path
        The checkpoint file (``.npz``).
    key : str
        Fingerprint of the campaign (plan, seed, instrument); resuming from a file written
        for another campaign raises ``ValueError``.
    every : int
        Write after this many new records ...
    every_s : float
        ... or when this many seconds passed since the last write (a run killed without
        warning loses at most that much work, which the resumed run measures again).

    Every record is a mapping of names to arrays (or numbers) of the same shapes for every
    index. The file holds ``index`` (n,) and one stacked array per name.
    """

    def __init__(
        self, path: str | Path, key: str, *, every: int = 50, every_s: float = 2.0
    ) -> None:
        if int(every) < 1:
            raise ValueError(f"every = {every!r}: expected an integer >= 1")
        if not (float(every_s) >= 0):
            raise ValueError(f"every_s = {every_s!r}: expected >= 0 seconds")
        self.path = Path(path)
        self.key = str(key)
        self.every = int(every)
        self.every_s = float(every_s)
        self.records: dict[int, dict[str, NDArray]] = {}
        self.meta: dict[str, Any] = {}
        self._dirty = 0
        self._last = time.monotonic()
        self.writes = 0

    def load(self) -> int:
        """Read the file if it exists; the number of completed records."""
        if not self.path.is_file():
            return 0
        with np.load(self.path, allow_pickle=False) as z:
            head = json.loads(str(z["__meta__"]))
            if head.get("key") != self.key:
                raise ValueError(
                    f"checkpoint {self.path} belongs to another campaign "
                    f"(key {head.get('key')!r}, expected {self.key!r}); use another directory"
                )
            names = [n for n in z.files if n not in ("__meta__", "index")]
            idx = z["index"]
            for j, i in enumerate(idx.tolist()):
                self.records[int(i)] = {n: np.array(z[n][j]) for n in names}
            self.meta = head.get("meta", {})
        return len(self.records)

    def __contains__(self, index: int) -> bool:
        return int(index) in self.records

    def __len__(self) -> int:
        return len(self.records)

    def add(self, index: int, record: Mapping[str, Any]) -> None:
        """Record measurement ``index`` (a second record of the same index is an error)."""
        index = int(index)
        if index in self.records:
            raise ValueError(f"index = {index}: already recorded (a duplicated measurement)")
        self.records[index] = {k: np.asarray(v) for k, v in record.items()}
        self._dirty += 1
        if self._dirty >= self.every or time.monotonic() - self._last >= self.every_s:
            self.flush()

    def flush(self) -> None:
        """Write the file now (atomically) if anything changed."""
        if not self._dirty and self.path.is_file():
            return
        idx = np.array(sorted(self.records), dtype=np.int64)
        arrays: dict[str, Any] = {"index": idx}
        if len(idx):
            for n in self.records[int(idx[0])]:
                arrays[n] = np.stack([self.records[int(i)][n] for i in idx])
        arrays["__meta__"] = np.array(json.dumps({"key": self.key, "meta": self.meta}))
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(self.path, buf.getvalue())
        self._dirty = 0
        self._last = time.monotonic()
        self.writes += 1


# ----------------------------------------------------------------------------- Cornell rig
@dataclass
class CornellRig:
    """The Cornell instrument as seen by the campaign: named axes and a spectrometer.

    Parameters
    ----------
    axes : mapping of str to Axis
        ``arm``, ``turntable``, ``tilt`` (degrees) and the accessories ``polarizer``
        (degrees: 0 = s, 90 = p), ``target`` (slide, stations ``target_stations``),
        ``filter`` (ND filter wheel, ``filter_stations``) and ``shutter``
        (``shutter_stations``); they may belong to any number of controllers.
    spectrometer : Spectrometer
    move_timeout : float
        Seconds allowed for one move.
    """

    axes: Mapping[str, Axis]
    spectrometer: Spectrometer
    target_stations: Mapping[str, float] = field(
        default_factory=lambda: {"sample": 0.0, "standard": 25.0, "beam_trap": 50.0, "direct": 75.0}
    )
    filter_stations: Mapping[str, float] = field(default_factory=lambda: {"open": 0.0, "nd": 60.0})
    shutter_stations: Mapping[str, float] = field(
        default_factory=lambda: {"open": 0.0, "closed": 90.0}
    )
    polarizer_deg: Mapping[str, float] = field(default_factory=lambda: {"s": 0.0, "p": 90.0})
    move_timeout: float = 600.0

    def __post_init__(self) -> None:
        missing = [a for a in (*CORNELL_MOTORS, *CORNELL_ACCESSORIES) if a not in self.axes]
        if missing:
            raise ValueError(
                f"axes lacks {missing}; expected {list(CORNELL_MOTORS + CORNELL_ACCESSORIES)}"
            )
        self._where: dict[str, float] = {}
        self._itime: float | None = None
        self.n_reads = 0
        self.n_moves = 0

    # -- motion ------------------------------------------------------------------------------
    def move(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Move several axes together (start all, then wait for each); read-back positions.

        An axis known to sit at its target already is not moved.
        """
        started = []
        for name, pos in targets.items():
            pos = float(pos)
            if self._where.get(name) == pos:
                continue
            self._where.pop(name, None)
            self.axes[name].move_to(pos)
            started.append((name, pos))
        out = {}
        for name, pos in started:
            out[name] = self.axes[name].wait(self.move_timeout)
            self._where[name] = pos
            self.n_moves += 1
        return out

    def move_motors(self, angles_deg: ArrayLike) -> NDArray[np.float64]:
        """Move the three motor axes to ``angles_deg``; the encoder positions (degrees)."""
        a = np.asarray(angles_deg, dtype=np.float64)
        got = self.move(dict(zip(CORNELL_MOTORS, a.tolist())))
        return np.array([got[n] if n in got else self.axes[n].position() for n in CORNELL_MOTORS])

    def forget_positions(self) -> None:
        """Forget where the axes are (after a reconnect: move them again before reading)."""
        self._where.clear()
        self._itime = None

    # -- reads -------------------------------------------------------------------------------
    def read(
        self,
        integration_time_s: float,
        *,
        polarizer: str | None = "s",
        shutter: bool = True,
        target: str = "sample",
        filter_in: bool = False,
    ) -> NDArray[np.float64]:
        """One spectrum with the accessories set as asked (the simulator's ``read``)."""
        if target not in self.target_stations:
            raise ValueError(f"target = {target!r}: expected one of {sorted(self.target_stations)}")
        mv = {
            "target": self.target_stations[target],
            "filter": self.filter_stations["nd" if filter_in else "open"],
            "shutter": self.shutter_stations["open" if shutter else "closed"],
        }
        if polarizer is not None:
            if polarizer not in self.polarizer_deg:
                raise ValueError(f"polarizer = {polarizer!r}: expected 's' or 'p'")
            mv["polarizer"] = self.polarizer_deg[polarizer]
        self.move(mv)
        t = float(integration_time_s)
        if self._itime != t:
            self.spectrometer.integration_time = t
            self._itime = t
        self.n_reads += 1
        return np.asarray(self.spectrometer.intensities(), dtype=np.float64)


class _CornellProcedures:
    """The simulator's measurement procedures, performed on a :class:`CornellRig`.

    Mirrors ``CornellInstrument.auto_exposure``, ``measure_raw`` and ``calibrate`` read for
    read (same targets, polarisations, integration times and order:
    ``gonio.simulator.cornell.read_sequence``, the preview's polariser alternating from
    geometry to geometry by ``first_polarizer(index)``, so that a resumed run reads exactly
    what an uninterrupted one does), so that keyed noise of the fake spectrometer matches
    the in-process simulation.
    """

    def __init__(self, rig: CornellRig, config: Any) -> None:
        self.rig = rig
        self.c = config

    def auto_exposure(self, target: str, polarizer: str = "s") -> tuple[float, bool]:
        from gonio.simulator.cornell import auto_exposure

        return auto_exposure(self.rig.read, self.c, target, polarizer)

    def measure_raw(
        self, target: str, n_reads: int = 1, first: str = "s"
    ) -> dict[str, dict[str, Any]]:
        from gonio.simulator.cornell import measure_raw

        return measure_raw(self.rig.read, self.c, target, n_reads, first)

    def calibrate(self, mode: str, wavelengths: NDArray, stray: Any = None) -> Any:
        """The reference at its pose (``gonio.simulator.cornell.reference_reads``; ``stray``:
        a re-measured reference keeps the first one's beam-trap stray light)."""
        from gonio.simulator.cornell import effective_cos, forward, reference_reads
        from gonio.simulator.spectra import spectralon_reflectance

        c = self.c
        if mode == "standard":
            pos = self.rig.move_motors(np.degrees(c.reference_angles()))
            target = "standard"
            cos_ref = float(effective_cos(forward(np.radians(pos), c.kinematics)[0], c))
            scale = spectralon_reflectance(wavelengths) / math.pi * cos_ref
        elif mode == "direct":
            self.rig.move_motors([180.0, 0.0, 0.0])
            target = "direct"
            scale = np.full(wavelengths.shape, 1.0 / c.omega_nominal)
        else:
            raise ValueError(f"reference = {mode!r}: expected 'standard' or 'direct'")
        return reference_reads(self.rig.read, c, mode, target, wavelengths, scale, stray)


def _save_reference(path: Path, ref: Any, key: str) -> None:
    buf = io.BytesIO()
    np.savez(
        buf,
        key=np.array(key),
        mode=np.array(ref.mode),
        wavelengths_nm=ref.wavelengths_nm,
        scale=ref.scale,
        rate_s=ref.rate["s"],
        rate_p=ref.rate["p"],
        stray_s=ref.stray["s"],
        stray_p=ref.stray["p"],
        meta=np.array(json.dumps(ref.meta)),
    )
    atomic_write_bytes(path, buf.getvalue())


def _load_reference(path: Path, key: str) -> Any:
    from gonio.simulator.cornell import Reference

    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if str(z["key"]) != key:
            raise ValueError(f"reference {path} belongs to another campaign; use another directory")
        return Reference(
            str(z["mode"]),
            z["wavelengths_nm"],
            {"s": z["rate_s"], "p": z["rate_p"]},
            {"s": z["stray_s"], "p": z["stray_p"]},
            z["scale"],
            json.loads(str(z["meta"])),
        )


def run_cornell_measurements(
    rig: CornellRig,
    angles_deg: ArrayLike,
    *,
    config: Any = None,
    reference: str = "standard",
    checkpoint: Checkpoint | None = None,
    reference_path: str | Path | None = None,
    on_measurement: Callable[[int, int], None] | None = None,
    retries: int = 1,
    reference_every: int = 0,
    drift_correction: bool = True,
    stray_correction: float = 0.0,
) -> dict[str, NDArray]:
    """Measure every geometry of ``angles_deg`` (N, 3 motor angles, degrees, in order).

    Calibrates first (or reloads the reference from ``reference_path``), then for each
    geometry not already in ``checkpoint``: move, read (preview, signal and dark per
    polarisation, the preview's polariser alternating by geometry index), reduce to 31
    bands, record. A device error on a geometry (after the drivers' own retries) is retried
    ``retries`` times from the move on; then it propagates (the checkpoint is flushed
    first, so a later call resumes).

    ``reference_every = N > 0``: the standard is measured again after every N geometries
    and after the last (without the beam trap; each saved beside ``reference_path`` as
    ``<stem>_<count>.npz``, reloaded on resume), and with ``drift_correction`` every
    geometry is reduced against the references interpolated linearly in the measurement
    sequence (the lamp's drift divided out; the records keep the raw spectra for that).
    ``stray_correction``: the laboratory's uniform stray-light fraction
    (:func:`gonio.simulator.cornell.reduce_measurement`).

    Returns arrays in plan order: ``value`` and ``sigma`` (N, 31), ``t`` (N,) integration
    times, ``filter`` (N,), ``saturated`` (N,), ``positions_deg`` (N, 3) read back from the
    axes, ``resumed`` (number of geometries taken from the checkpoint), ``reference`` (the
    first ``Reference``), ``references`` (``[(count, Reference), ...]``, the first at 0).
    """
    from gonio.simulator.cornell import CornellConfig

    c = config or CornellConfig()
    ang = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 3)
    n = len(ang)
    every = int(reference_every)
    if every != reference_every or every < 0:
        raise ValueError(f"reference_every = {reference_every!r}: expected an integer >= 0")
    key = checkpoint.key if checkpoint is not None else fingerprint(ang)
    proc = _CornellProcedures(rig, c)
    wl = np.asarray(rig.spectrometer.wavelengths(), dtype=np.float64)
    refs = _References(proc, reference, wl, key, reference_path)
    records: dict[int, dict[str, Any]] = dict(checkpoint.records) if checkpoint else {}
    resumed = len(records)
    keep_raw = bool(every) and drift_correction
    spectra = _spectra_folder(reference_path) if keep_raw else None
    _measure_missing(rig, proc, c, ang, records, refs, every=every, retries=retries,
                     stray_correction=stray_correction, keep_raw=keep_raw,
                     checkpoint=checkpoint, spectra=spectra,
                     on_measurement=on_measurement)  # fmt: skip
    if keep_raw:
        _reduce_against_drift(records, refs, c, stray_correction, spectra)
    out = _stack_records(records, n)
    out.update(resumed=np.array(resumed), reference=refs.first,
               reference_t=np.array(float(refs.first.meta.get("t", np.nan))),
               references=refs.pairs())  # fmt: skip
    return out


def _spectra_folder(reference_path: str | Path | None) -> Path | None:
    """Where the raw spectra the drift correction reduces again are kept: one file per
    geometry beside the references (written once; the checkpoint keeps only the reduced
    record); None without a reference path."""
    if reference_path is None:
        return None
    spectra = Path(reference_path).with_name("spectra")
    spectra.mkdir(exist_ok=True)
    return spectra


def _measure_missing(
    rig: CornellRig, proc: _CornellProcedures, c: Any, ang: NDArray, records: dict[int, Any],
    refs: _References, *, every: int, retries: int, stray_correction: float, keep_raw: bool,
    checkpoint: Checkpoint | None, spectra: Path | None,
    on_measurement: Callable[[int, int], None] | None,
) -> None:  # fmt: skip
    """Every geometry of ``ang`` not in ``records`` measured and recorded there (and in the
    checkpoint, flushed also on an error; its raw spectra in ``spectra``), the standard
    measured again every ``every`` geometries and after the last
    (:func:`run_cornell_measurements`)."""
    n = len(ang)
    # a resumed run is a new session of the instrument (the lamp lit again): its geometries
    # are reduced against its own references, the first measured where it starts
    session = 1 + max((int(r.get("session", 0)) for r in records.values()), default=-1)
    start = min((j for j in range(n) if j not in records), default=n)
    try:
        for j in range(start, n):
            if j in records:
                continue
            if every and ((j == start and session > 0) or (j and j % every == 0)):
                refs.at(j, session)  # measured, or reloaded when saved before a kill
            rec = _measure_geometry(rig, proc, c, ang[j], j, refs.latest(session), retries,
                                    stray_correction, keep_raw)  # fmt: skip
            if every:
                rec["session"] = session
            records[j] = rec
            if checkpoint is not None:
                raw = {k: rec.pop(k) for k in _RAW_KEYS if k in rec}
                if spectra is not None and raw:
                    _save_spectra(spectra / f"{j}.npz", raw)
                checkpoint.add(j, rec)
                rec.update(raw)
            if on_measurement is not None:
                on_measurement(j, n)
        if every and start < n:
            refs.at(n, session)
    finally:
        if checkpoint is not None:
            checkpoint.flush()


def _reduce_against_drift(
    records: dict[int, dict[str, Any]], refs: _References, c: Any, stray_correction: float,
    spectra: Path | None,
) -> None:  # fmt: skip
    """Every record reduced again against the references interpolated in the measurement
    sequence; the raw spectra of geometries measured before a resume read from ``spectra``."""
    for j, rec in records.items():
        if "signal_s" not in rec:  # measured before a resume: its spectra from disk
            if spectra is None:
                raise ValueError(f"geometry {j}: no raw spectra to reduce against drift")
            rec.update(_load_spectra(spectra / f"{j}.npz"))
    _reduce_against_interpolated(records, refs, c, stray_correction)


class _References:
    """The references of a campaign through the drivers, by session (a resumed run is a new
    one) and the number of geometries measured before each (session 0, count 0: the first,
    with the beam trap), saved beside ``path`` and reloaded."""

    def __init__(self, proc: Any, mode: str, wl: NDArray, key: str, path: Any) -> None:
        self.proc, self.mode, self.wl, self.key = proc, mode, wl, key
        self.path = Path(path) if path is not None else None
        self.by: dict[tuple[int, int], Any] = {}
        first = _load_reference(self.path, key) if self.path is not None else None
        if first is None:
            first = proc.calibrate(mode, wl)
            if self.path is not None:
                _save_reference(self.path, first, key)
        self.first = first
        self.by[(0, 0)] = first

    def _file(self, session: int, count: int) -> Path | None:
        if self.path is None:
            return None
        return self.path.with_name(f"{self.path.stem}_{session}_{count}{self.path.suffix}")

    def load(self, session: int, count: int) -> Any:
        """A saved reference of an earlier session (None if it was never measured)."""
        if (session, count) not in self.by:
            f = self._file(session, count)
            ref = _load_reference(f, self.key) if f is not None else None
            if ref is None:
                return None
            self.by[(session, count)] = ref
        return self.by[(session, count)]

    def at(self, count: int, session: int) -> Any:
        """The reference after ``count`` geometries in ``session``: reloaded if saved, else
        measured now (without the beam trap: the first's stray light)."""
        ref = self.load(session, count)
        if ref is None:
            ref = self.proc.calibrate(self.mode, self.wl, stray=self.first)
            f = self._file(session, count)
            if f is not None:
                _save_reference(f, ref, self.key)
            self.by[(session, count)] = ref
        return ref

    def session(self, session: int) -> list[tuple[float, Any]]:
        """``[(count, Reference), ...]`` of one session: those in memory and those an
        earlier run of it saved."""
        if self.path is not None:
            f = self.path
            for g in f.parent.glob(f"{f.stem}_{session}_*{f.suffix}"):
                tail = g.stem.rsplit("_", 1)[1]
                if tail.isdigit():
                    self.load(session, int(tail))
        return sorted((float(c), r) for (s, c), r in self.by.items() if s == session)

    def latest(self, session: int) -> Any:
        mine = [(c, r) for (s, c), r in self.by.items() if s == session]
        return max(mine, key=lambda cr: cr[0])[1] if mine else self.first

    def pairs(self) -> list[tuple[float, Any]]:
        """Every reference as ``(count, Reference)`` in the order measured."""
        return [(float(c), self.by[(s, c)]) for s, c in sorted(self.by)]


def _measure_geometry(
    rig: CornellRig, proc: Any, c: Any, ang: NDArray, j: int, ref: Any, retries: int,
    stray: float, keep_raw: bool,
) -> dict[str, Any]:  # fmt: skip
    """Move to geometry ``j``, read it and reduce it against ``ref``: its record."""
    from gonio.drivers.errors import DeviceError
    from gonio.simulator.cornell import (
        BANDS_NM,
        effective_cos,
        first_polarizer,
        forward,
        reduce_measurement,
    )

    for attempt in range(retries + 1):
        try:
            pos = rig.move_motors(ang)
            raws = proc.measure_raw("sample", first=first_polarizer(j))
            break
        except DeviceError:
            if attempt == retries:
                raise
            rig.forget_positions()
    ci = float(effective_cos(forward(np.radians(pos), c.kinematics)[0], c))
    v, s, sat = reduce_measurement(raws, ref, ci, c, BANDS_NM, stray)
    rec = {"value": v, "sigma": s, "t": float(raws["s"]["t"]),
           "filter": int(raws["s"]["filter"]), "saturated": bool(sat), "positions_deg": pos,
           "cos_i": ci}  # fmt: skip
    if keep_raw:
        for q in ("s", "p"):
            rec[f"signal_{q}"] = raws[q]["signal"]
            rec[f"dark_{q}"] = raws[q]["dark"]
    return rec


_RAW_KEYS = ("signal_s", "dark_s", "signal_p", "dark_p")


def _save_spectra(path: Path, raw: Mapping[str, NDArray]) -> None:
    """One geometry's raw spectra (whole counts as uint16, exactly; else float64)."""
    arrays = {}
    for k, v in raw.items():
        v = np.asarray(v, float)
        whole = np.all(v == np.rint(v)) and v.min() >= 0 and v.max() <= 65535
        arrays[k] = v.astype(np.uint16) if whole else v
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _load_spectra(path: Path) -> dict[str, NDArray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: np.asarray(z[k], dtype=np.float64) for k in _RAW_KEYS}


def _reduce_against_interpolated(
    records: dict[int, dict[str, Any]], refs: _References, c: Any, stray: float
) -> None:
    """Reduce each geometry again against its session's references interpolated at its
    place in the sequence (geometry ``j`` ends after ``j + 1`` geometries)."""
    from gonio.simulator.cornell import BANDS_NM, _interpolated_reference, reduce_measurement

    by_session: dict[int, list] = {}
    for j, rec in records.items():
        s = int(rec.get("session", 0))
        if s not in by_session:
            by_session[s] = refs.session(s)
        pairs = by_session[s]
        raws = {q: {"signal": rec[f"signal_{q}"], "dark": rec[f"dark_{q}"],
                    "t": float(rec["t"]), "filter": int(rec["filter"])}
                for q in ("s", "p")}  # fmt: skip
        ref = pairs[0][1] if len(pairs) == 1 else _interpolated_reference(pairs, float(j + 1))
        rec["value"], rec["sigma"], _sat = reduce_measurement(
            raws, ref, float(rec["cos_i"]), c, BANDS_NM, stray
        )


def _stack_records(records: dict[int, dict[str, Any]], n: int) -> dict[str, NDArray]:
    nb = len(records[0]["value"]) if n else 31
    return {
        "value": np.array([records[j]["value"] for j in range(n)]).reshape(n, nb),
        "sigma": np.array([records[j]["sigma"] for j in range(n)]).reshape(n, nb),
        "t": np.array([float(records[j]["t"]) for j in range(n)]),
        "filter": np.array([int(records[j]["filter"]) for j in range(n)]),
        "saturated": np.array([bool(records[j]["saturated"]) for j in range(n)]),
        "positions_deg": np.array([records[j]["positions_deg"] for j in range(n)]).reshape(n, 3),
    }


# ----------------------------------------------------------------------------- LBL through drivers
class LBLDriverInstrument:
    """The LBL imaging gonioreflectometer through drivers, for :func:`gonio.campaign.run`.

    Parameters
    ----------
    source, sample : Axis
        The source arm (θi, degrees) and the sample holder rotation ψ (degrees,
        ``φi = arm_azimuth − ψ``).
    changer : Axis
        Sample changer slide; ``stations`` maps ``"sample"``, ``"standard"``, ``"empty"`` to
        its positions.
    camera : Camera
    description : mapping
        The laboratory's record of the instrument for the reduction's side-cars: ``lens``,
        ``mirror``, ``sensor``, ``rho_standard``, ``source`` (with ``arm_azimuth``) and any
        other static keys; per-frame keys (θi, φi, sample rotation, exposure, f-number) are
        added from the axes and the camera.
    exposures_s : sequence of float
        Exposure bracket (seconds) at ``f_number``; default ``(0.01,)``.
    f_numbers : sequence of float, optional
        A bracket of f-stops at the first exposure instead.

    ``shoot(sample, theta_i, phi_i, seed)`` puts the standard (``sample == "standard"``),
    nothing (``None``) or the sample under the dome and captures the bracket; the seed is
    recorded but cannot steer a device's noise.
    """

    def __init__(
        self,
        source: Axis,
        sample: Axis,
        changer: Axis,
        camera: Camera,
        description: Mapping[str, Any],
        *,
        stations: Mapping[str, float] | None = None,
        exposures_s: Sequence[float] = (0.01,),
        f_number: float = 4.0,
        f_numbers: Sequence[float] | None = None,
        move_timeout: float = 120.0,
    ) -> None:
        self.source, self.sample, self.changer, self.camera = source, sample, changer, camera
        self.description = dict(description)
        self.stations = dict(stations or {"sample": 0.0, "standard": 25.0, "empty": 50.0})
        exp = tuple(float(e) for e in exposures_s)
        if not exp or any(not (e > 0 and math.isfinite(e)) for e in exp):
            raise ValueError(f"exposures_s = {exposures_s!r}: expected positive seconds")
        self.bracket = (
            [(exp[0], float(f)) for f in f_numbers]
            if f_numbers
            else [(e, float(f_number)) for e in exp]
        )
        self.move_timeout = float(move_timeout)
        self.arm_azimuth = float(self.description.get("source", {}).get("arm_azimuth", 0.0))
        self.n_frames = 0

    def _move(self, axis: Axis, pos: float) -> float:
        axis.move_to(float(pos))
        return axis.wait(self.move_timeout)

    def shoot(self, sample: Any, theta_i: float, phi_i: float, seed: int) -> list:
        """Frames ``[(uint16 image, metadata), ...]`` of one scene (see the class)."""
        kind = "empty" if sample is None else "standard" if sample == "standard" else "sample"
        psi = math.degrees(self.arm_azimuth - float(phi_i))
        psi = (psi + 180.0) % 360.0 - 180.0
        self.source.move_to(round(math.degrees(float(theta_i)), 6))
        self.sample.move_to(round(psi, 6))
        self.changer.move_to(self.stations[kind])
        th = self.source.wait(self.move_timeout)
        ps = self.sample.wait(self.move_timeout)
        self.changer.wait(self.move_timeout)
        rot = math.radians(ps)
        phi = self.arm_azimuth - rot
        phi = math.pi - (math.pi - phi) % (2 * math.pi)
        frames = []
        for e, f in self.bracket:
            self.camera.exposure = e
            self.camera.f_number = f
            img, cam_meta = self.camera.capture()
            meta = dict(self.description)
            meta.update(
                theta_i=math.radians(th),
                phi_i=phi,
                sample_rotation=rot,
                exposure_s=float(cam_meta.get("exposure_s", e)),
                f_number=float(cam_meta.get("f_number", f)),
                sample={"sample": "brdf", "standard": "standard", "empty": "none"}[kind],
                seed=int(seed),
                shape=list(img.shape),
                dtype=str(img.dtype),
                camera={k: v for k, v in cam_meta.items() if isinstance(v, int | float | str)},
            )
            frames.append((img, meta))
            self.n_frames += 1
        return frames


def run_lbl_through_drivers(
    plan: Any = None,
    out: str | Path | None = None,
    *,
    resume: bool = False,
    quiet: bool = True,
    time_scale: float = 1e4,
    f_number: float = 4.0,
) -> Any:
    """An LBL campaign (:func:`gonio.campaign.run`) on the fake devices through the drivers.

    The plan's instrument (``preset``, ``instrument_seed``) is simulated behind the fakes
    (``binning`` is not: the fake camera sends full frames). The plan's ``exposures_s``
    (default ``(0.01,)``) is the bracket at ``f_number``; the
    captures are checkpointed per group by ``gonio.campaign`` (``raw/<key>/done.json``), so
    ``resume=True`` continues an interrupted run without capturing a group twice.
    """
    from gonio import campaign
    from gonio.simulator.effects import realise

    plan = (plan or campaign.Plan()).resolved()
    exp = plan.exposures_s or (0.01,)
    with fake_lbl_rig(
        plan.material,
        seed=plan.seed,
        noise=plan.noise > 0,
        mirror=plan.mirror,
        time_scale=time_scale,
        exposures_s=exp,
        f_number=f_number,
        effects=realise(plan.preset, plan.instrument_seed),
        instrument_seed=plan.instrument_seed,
    ) as (dev, _parts):
        return campaign.run(plan, out, resume=resume, quiet=quiet, instrument=dev)


# ----------------------------------------------------------------------------- fake rigs
def cornell_fake_bench(
    material: Any = "garnet_red_paint",
    *,
    seed: int = 0,
    noise: bool = True,
    config: Any = None,
    time_scale: float = 1e4,
    prime: ArrayLike | None = None,
) -> tuple[Any, Any]:
    """The simulated bench behind the Cornell fakes: ``(bench, instrument)``.

    All seven stages of ``gonio.simulator.bench`` (the motors ``arm``, ``turntable``,
    ``tilt``; the accessories ``polarizer``, ``target``, ``filter``, ``shutter``), a
    1024-pixel spectrometer with the wavelength coefficients its EEPROM can hold
    (:func:`eeprom_coeffs`), rendering ``CornellInstrument(material, config, noise,
    rng=seed).spectrum_render`` through the accessory stations. ``material``: a preset
    name, a BRDF, or ``None`` (Lambertian). ``prime`` (N, 3 motor angles, radians)
    precomputes the simulator's cone-averaged BRDF there (speed only).

    The ideal instrument (``config.effects`` None): no backlash or positioning noise, and
    with the same ``seed`` a campaign on this bench reads the same keyed noise as
    :func:`gonio.simulator.cornell.simulate_campaign` in-process. A realistic one: the
    motor stages get the realised ``stage_backlash_deg`` and ``stage_noise_deg`` (the
    bench's :class:`~gonio.simulator.bench.Stage` physics, drawn from the instrument seed),
    so the spectrometer reads at the true (load) positions while the controllers report
    their encoders; the lamp's clock runs with the reads and moves the instrument sees
    (``CornellInstrument.event_clock``).
    """
    from gonio.simulator.bench import Bench, cornell_spectrum_render
    from gonio.simulator.cornell import CornellConfig, CornellInstrument

    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed = {seed!r}: expected a non-negative integer")
    cfg = config or CornellConfig()
    cfg = replace(cfg, wavelength_coeffs=eeprom_coeffs(cfg.wavelength_coeffs))
    sample = material
    if sample is None:
        from gonio import brdf

        sample = brdf.create("lambert")
    inst = CornellInstrument(sample, config=cfg, noise=noise, rng=int(seed))
    fx = inst.fx or {}
    moving = {"backlash": float(fx.get("stage_backlash_deg", 0.0)),
              "noise": float(fx.get("stage_noise_deg", 0.0))}  # fmt: skip
    if prime is not None and not any(moving.values()):  # (true poses unknown beforehand)
        inst.prime(np.asarray(prime, dtype=np.float64).reshape(-1, 3))
    inst.event_clock = inst.fx is not None
    bench = Bench(
        _bench_stages(int(cfg.instrument_seed), moving),
        time_scale=time_scale,
        spectrum_render=cornell_spectrum_render(inst.spectrum_render),
        wavelength_coeffs=tuple(cfg.wavelength_coeffs),
        instrument="cornell",
        material=material if isinstance(material, str) else None,
        n_pixels=int(cfg.n_pixels),
    )
    return bench, inst


def _bench_stages(instrument_seed: int, moving: Mapping[str, float]) -> list[Any]:
    """The Cornell bench's seven stages; the motors with the realised backlash and
    positioning noise (``moving``), each drawn from its own stream of the instrument seed."""
    from gonio.simulator.bench import _INSTRUMENT_STAGES as stage_table
    from gonio.simulator.bench import Stage

    stages = []
    for name, kw in stage_table["cornell"]:
        if name in CORNELL_MOTORS and any(moving.values()):
            from gonio.simulator.effects import effect_rng

            g = effect_rng(instrument_seed, "cornell", "bench", name)
            kw = {**kw, **moving, "rng": int(g.integers(2**63 - 1))}
        stages.append(Stage(name, **kw))
    return stages


def _serve_controllers(
    bench: Any, groups: Sequence[Sequence[str]], servers: list, ctls: list, *,
    faults: Sequence[Any] = (), timeout: float = 2.0,
) -> None:  # fmt: skip
    """Start a fake ESP300 on ``bench`` for each group of stage names (axes 1, 2, ... in
    order; ``faults[k]`` for the k-th, default none) and open it with the real driver,
    enabled; appended to ``servers`` and ``ctls`` as they come (so a failure half way
    leaves :func:`_close_fakes` everything to close)."""
    from gonio.drivers.esp300 import ESP300
    from gonio.drivers.fake.esp300 import FakeESP300Server
    from gonio.drivers.fake.faults import Faults

    for k, g in enumerate(groups):
        f = faults[k] if k < len(faults) and faults[k] is not None else Faults()
        srv = FakeESP300Server(bench, axes=list(g), faults=f).start()
        servers.append(srv)
        ctl = ESP300.open(srv.port, axes={n: i + 1 for i, n in enumerate(g)}, timeout=timeout)
        ctls.append(ctl)
        ctl.enable()


def _close_fakes(dev: Any, ctls: Sequence[Any], servers: Sequence[Any], usb: str) -> None:
    """Close the USB device and the controllers, stop the fake servers, remove the fake USB
    bus (each step whatever the others did)."""
    from gonio.drivers.fake import usb as fakeusb

    for x in (dev, *ctls):
        if x is not None:
            with contextlib.suppress(Exception):
                x.close()
    for srv in servers:
        with contextlib.suppress(Exception):
            srv.stop()
    fakeusb.uninstall(usb)


@contextlib.contextmanager
def fake_cornell_rig(
    material: Any = "garnet_red_paint",
    *,
    seed: int = 0,
    noise: bool = True,
    config: Any = None,
    time_scale: float = 1e4,
    faults: Mapping[str, Any] | None = None,
    prime: ArrayLike | None = None,
    device_timeout: float = 2.0,
) -> Iterator[tuple[CornellRig, dict[str, Any]]]:
    """The Cornell instrument on fake devices: ``(rig, parts)``.

    Three fake ESP300 controllers on pseudo-terminals (:data:`CONTROLLER_GROUPS`: motors;
    polariser, target slide and filter wheel; shutter) and a fake USB2000+ on the fake pyusb
    backend, all on :func:`cornell_fake_bench` (``material``, ``seed``, ``noise``,
    ``config``, ``time_scale``, ``prime``). The rig is opened with the real drivers.
    ``faults`` maps ``"esp300"`` (the motor controller) / ``"usb2000plus"`` to
    ``gonio.drivers.fake.faults.Faults`` objects. ``device_timeout``: the drivers' reply
    timeout (s). ``parts``: ``bench``, ``servers``, ``usb`` (backend name),
    ``instrument`` (the simulator behind the spectrometer), ``controllers``.
    """
    from gonio.drivers.fake import usb as fakeusb
    from gonio.drivers.usb2000 import USB2000Plus

    bench, inst = cornell_fake_bench(
        material, seed=seed, noise=noise, config=config, time_scale=time_scale, prime=prime
    )
    faults = dict(faults or {})
    servers: list[Any] = []
    ctls: list[Any] = []
    name = fakeusb.install(bench)
    spec = None
    try:
        if "usb2000plus" in faults:
            fakeusb.devices(name)["usb2000plus"].faults = faults["usb2000plus"]
        groups = [g for _role, g in CONTROLLER_GROUPS["cornell"]]
        _serve_controllers(bench, groups, servers, ctls, faults=[faults.get("esp300")],
                           timeout=device_timeout)  # fmt: skip
        spec = USB2000Plus.open(name, n_pixels=None, timeout=max(device_timeout, 0.5))
        axes: dict[str, Axis] = {}
        for ctl in ctls:
            axes.update(ctl.axes)
        rig = CornellRig(axes, spec)
        yield (
            rig,
            {
                "bench": bench,
                "servers": servers,
                "usb": name,
                "instrument": inst,
                "controllers": ctls,
            },
        )
    finally:
        _close_fakes(spec, ctls, servers, name)


@contextlib.contextmanager
def open_served_rig(
    records: Sequence[Mapping[str, Any]],
    *,
    via: str = "pty",
    device_timeout: float = 2.0,
) -> Iterator[tuple[Any, dict[str, Any]]]:
    """Open, with the real drivers, the devices that ``gonio devices serve --json`` printed.

    ``records``: the JSON objects of its output lines (one per device: every ``esp300``
    controller with its ``axes`` {"1": stage name, ...}, the ``usb2000plus`` and the
    ``ptp`` camera with the ``usb_server`` address of the fake USB bus). ``via``: reach the
    ESP300s by their pseudo-terminal (``"pty"``) or by TCP (``"tcp"``). Yields
    ``(rig, parts)``: for a Cornell bench (``arm`` among the axes) ``rig`` is a
    :class:`CornellRig` over all seven axes and the spectrometer, ready for
    :func:`run_cornell_measurements`; otherwise a dict ``{"axes": {name: Axis},
    "camera": PTPCamera}``. ``parts``: ``controllers``, ``usb`` (the pyusb backend name
    connected to the served bus). Everything is closed on exit.

    Example (an external driver script)::

        # shell: gonio devices serve --instrument cornell --material laser_paper --seed 2 --json
        with open_served_rig([json.loads(line) for line in lines]) as (rig, _):
            res = run_cornell_measurements(rig, angles_deg)
    """
    from gonio.drivers.fake import usb as fakeusb

    if via not in ("pty", "tcp"):
        raise ValueError(f"via = {via!r}: expected 'pty' or 'tcp'")
    recs = [dict(r) for r in records]
    esps = [r for r in recs if r.get("device") == "esp300"]
    usbs = [r for r in recs if r.get("device") in ("usb2000plus", "ptp")]
    if not esps:
        raise ValueError("records: expected at least one 'esp300' record")
    if not usbs:
        raise ValueError("records: expected a 'usb2000plus' or 'ptp' record (the USB bus)")
    ctls: list[Any] = []
    dev: Any = None
    name = fakeusb.connect(str(usbs[0]["usb_server"]))
    try:
        axes = _open_axes(esps, via, device_timeout, ctls)
        if "arm" in axes:
            from gonio.drivers.usb2000 import USB2000Plus

            dev = USB2000Plus.open(name, n_pixels=None, timeout=max(device_timeout, 0.5))
            rig: Any = CornellRig(axes, dev)
        else:
            from gonio.drivers.ptp import PTPCamera

            dev = PTPCamera.open(name)
            rig = {"axes": axes, "camera": dev}
        yield rig, {"controllers": ctls, "usb": name}
    finally:
        _close_fakes(dev, ctls, (), name)


def _open_axes(
    esps: Sequence[Mapping[str, Any]], via: str, timeout: float, ctls: list[Any]
) -> dict[str, Axis]:
    """The axes of the served ESP300s (``esps``: their records), each controller opened by
    its pseudo-terminal or TCP address (``via``), enabled and added to ``ctls`` (which the
    caller closes, also after an error here)."""
    from gonio.drivers.esp300 import ESP300

    axes: dict[str, Axis] = {}
    for r in esps:
        port = r["port"] if via == "pty" else r["url"]
        amap = {str(n): int(i) for i, n in r["axes"].items()}
        ctl = ESP300.open(port, axes=amap, timeout=timeout)
        ctls.append(ctl)
        ctl.enable()
        axes.update(ctl.axes)
    return axes


def lbl_description(inst: Any) -> dict[str, Any]:
    """The static part of an LBL side-car (lens, mirror, sensor, source, standard ...) from a
    simulated instrument: what a laboratory keeps in its calibration record."""
    _img, meta = inst.capture(None, 0.0, 0.0, noise=False, exposure=1e-4)
    drop = {
        "theta_i",
        "phi_i",
        "sample_rotation",
        "exposure_s",
        "f_number",
        "sample",
        "brdf",
        "seed",
        "noise",
        "shape",
        "dtype",
        "bracket",
        "band",
        "source_samples",
    }
    return {k: v for k, v in meta.items() if k not in drop}


@contextlib.contextmanager
def fake_lbl_rig(
    material: str = "rolled_brass",
    *,
    seed: int = 0,
    noise: bool = True,
    mirror: str = "ellipsoid",
    time_scale: float = 1e4,
    exposures_s: Sequence[float] = (0.01,),
    f_number: float = 4.0,
    effects: Mapping[str, float] | None = None,
    instrument_seed: int = 0,
) -> Iterator[tuple[LBLDriverInstrument, dict[str, Any]]]:
    """The LBL instrument on fake devices (an ESP300 with the source arm, sample rotation
    and tilt, a second one with the sample changer, the PTP camera on the fake pyusb
    backend), opened with the real drivers: ``(LBLDriverInstrument, parts)``. ``effects``
    and ``instrument_seed``: the simulated instrument's imperfections
    (:class:`gonio.simulator.LBLInstrument`; default none)."""
    from gonio import materials
    from gonio.drivers.fake import usb as fakeusb
    from gonio.drivers.ptp import PTPCamera
    from gonio.simulator import LBLInstrument
    from gonio.simulator.bench import _INSTRUMENT_STAGES as stage_table
    from gonio.simulator.bench import Bench, Stage, lbl_camera_render

    inst = LBLInstrument(mirror=mirror, effects=effects, instrument_seed=instrument_seed)
    gen = np.random.default_rng(seed)
    kw = dict(source_axis="source", sample_axis="sample", rng=gen, noise=noise)
    cams = {
        "sample": inst.camera_render(materials.get(material), **kw),
        "standard": inst.camera_render("standard", **kw),
        "empty": inst.camera_render(None, **kw),
    }
    stages = [Stage(name, **k) for name, k in stage_table["lbl"]]
    bench = Bench(
        stages,
        time_scale=time_scale,
        camera_render=lbl_camera_render(cams),
        instrument="lbl",
        material=material,
    )
    name = fakeusb.install(bench)
    servers, ctls = [], []
    cam = None
    try:
        groups = [g for _role, g in CONTROLLER_GROUPS["lbl"]]
        _serve_controllers(bench, groups, servers, ctls)
        cam = PTPCamera.open(name)
        mc: MotionController = ctls[0]
        dev = LBLDriverInstrument(
            mc.axis("source"),
            mc.axis("sample"),
            ctls[1].axis("changer"),
            cam,
            lbl_description(inst),
            exposures_s=exposures_s,
            f_number=f_number,
        )
        yield dev, {"bench": bench, "servers": servers, "usb": name, "instrument": inst}
    finally:
        _close_fakes(cam, ctls, servers, name)
