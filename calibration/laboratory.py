"""What a laboratory knows about its LBL instrument: the calibration folder.

A reduction that does not know the truth needs, besides each image's side-car (exposure,
marked f-number, sensor read-out parameters, incidence and rotation), the results of the
laboratory's own calibrations:

* the fisheye lens, from ChArUco board views through ``cv2.fisheye``
  (:func:`gonio.calibration.lens.calibrate_fisheye`);
* the dome geometry (``D/R`` and the camera tilt the angle recovery uses), from the spots a
  front-surface mirror sends to known directions (:func:`gonio.calibration.mirror.fit_mirror`);
* the diffuse standard's certificate (its certified reflectance factor and uncertainty);
* the instrument's specification: the typical magnitude and spread of each imperfection
  (its maker's data sheet), which the uncertainty budget uses for what no calibration
  measures.

:class:`LabCalibration` holds them; :meth:`LabCalibration.write` / :func:`read_calibration`
keep them as ``calibration.json`` in a folder (a user may point a campaign to one), and
:meth:`LabCalibration.reduction_options` gives the keyword arguments of
:func:`gonio.calibration.reduce.reduce_selected`. Per-campaign calibrations (exposure ratios
from the bracket overlaps, glare from dark regions) are made from the campaign's own
captures, not stored here.

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics (Proc.
SIGGRAPH '92), 26(2), 265-272. https://doi.org/10.1145/142920.134078, §3.2 (the lens
mapping "easily measured"; eq. 2's standard; eq. 3's mirror geometry).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gonio.calibration.fstops import FStopCalibration
from gonio.calibration.mirror import MirrorCalibration

__all__ = ["CALIBRATION_FILE", "LabCalibration", "read_calibration"]

#: the file of a calibration folder
CALIBRATION_FILE = "calibration.json"


@dataclass
class LabCalibration:
    """A laboratory's calibration of its instrument.

    Attributes
    ----------
    lens : dict or None
        The lens-calibration record (:meth:`LensCalibration.to_dict`: ``lens``, ``rms_px``,
        ...); None: the side-cars' lens.
    mirror : MirrorCalibration or None
        None: the side-cars' mirror.
    fstops : FStopCalibration or None
        Relative exposure of each marked stop and the iris repeatability, from the f-stop
        ladder (:mod:`gonio.calibration.fstops`); None: the marked f-numbers.
    certificate : object or None
        The standard's certificate (``rho``, ``factor_at``, ``check_covers``,
        ``expanded_uncertainty``); None: a Lambertian standard of the side-cars'
        ``rho_standard``.
    specification : dict
        Effect name -> ``{"typical": ..., "spread": ..., "unit": ...}`` (the maker's
        statement of the build; empty for an ideal instrument).
    info : dict
        Provenance (what was captured, times).
    sensor : dict or None
        The sensor's saturation threshold from the photon-transfer captures
        (:func:`gonio.calibration.photon_transfer.saturation_level`); None: the side-cars'
        ``saturation_dn``.
    """

    lens: dict[str, Any] | None = None
    mirror: MirrorCalibration | None = None
    fstops: FStopCalibration | None = None
    certificate: Any = None
    specification: dict[str, dict[str, Any]] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    sensor: dict[str, Any] | None = None

    def lens_model(self) -> Any:
        """The calibrated :class:`~gonio.simulator.lenses.FisheyeLens` (or None)."""
        if self.lens is None:
            return None
        from gonio.calibration.reduce import load_lens

        return load_lens(self.lens)

    def reduction_options(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~gonio.calibration.reduce.reduce_selected`."""
        out: dict[str, Any] = {}
        if self.lens is not None:
            out["lens"] = self.lens_model()
        if self.mirror is not None:
            out["mirror"] = self.mirror.geometry
            out["method"] = self.mirror.method
        if self.certificate is not None:
            out["certificate"] = self.certificate
        return out

    def spec_u(self, name: str) -> float:
        """Standard uncertainty of an effect from the specification alone: the RMS of its
        stated distribution, ``√(typical² + spread²)`` (GUM §4.3: a Type B evaluation from
        the maker's data); 0 for an effect the specification does not name."""
        s = self.specification.get(name)
        if not s:
            return 0.0
        return float((float(s["typical"]) ** 2 + float(s.get("spread", 0.0)) ** 2) ** 0.5)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content of ``calibration.json``."""
        cert = None
        if self.certificate is not None:
            cert = self.certificate.to_dict()
        return {
            "kind": "gonio.lab_calibration",
            "lens": self.lens,
            "mirror": None if self.mirror is None else self.mirror.to_dict(),
            "fstops": None if self.fstops is None else self.fstops.to_dict(),
            "certificate": cert,
            "specification": self.specification,
            "info": self.info,
            "sensor": self.sensor,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LabCalibration:
        """Inverse of :meth:`to_dict`."""
        if d.get("kind") != "gonio.lab_calibration":
            raise ValueError(f"not a gonio laboratory calibration (kind {d.get('kind')!r})")
        cert = d.get("certificate")
        if cert is not None:
            from gonio.io.certificate import Certificate

            cert = Certificate.from_dict(cert)
        mirror = d.get("mirror")
        fst = d.get("fstops")
        return cls(
            lens=d.get("lens"),
            mirror=None if mirror is None else MirrorCalibration.from_dict(mirror),
            fstops=None if fst is None else FStopCalibration.from_dict(fst),
            certificate=cert,
            specification=dict(d.get("specification") or {}),
            info=dict(d.get("info") or {}),
            sensor=None if d.get("sensor") is None else dict(d["sensor"]),
        )

    def write(self, folder: str | os.PathLike) -> Path:
        """Write ``folder/calibration.json`` atomically; returns its path."""
        from gonio.io.atomic import atomic_write_bytes

        p = Path(folder)
        p.mkdir(parents=True, exist_ok=True)
        text = json.dumps(self.to_dict(), indent=2, default=_plain, allow_nan=False)
        return atomic_write_bytes(p / CALIBRATION_FILE, (text + "\n").encode())


def _plain(obj: Any) -> Any:
    """numpy scalars and arrays as JSON numbers and lists."""
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def read_calibration(folder: str | os.PathLike) -> LabCalibration:
    """The :class:`LabCalibration` of a calibration folder (or of its ``calibration.json``)."""
    p = Path(folder)
    f = p / CALIBRATION_FILE if p.is_dir() else p
    if not f.is_file():
        raise ValueError(f"calibration folder {str(p)!r} has no {CALIBRATION_FILE}")
    from gonio.io.jsonfile import read_document

    return read_document(f, LabCalibration.from_dict, what="a gonio laboratory calibration")
