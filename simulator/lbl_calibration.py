"""The LBL camera's calibration captures: a shutter-closed dark frame and a flat field, the
EMVA 1288 set-ups a laboratory uses for the sensor's dark signal, gain, PRNU and photon
transfer curve.

This part knows the pixels and their read-out
(:class:`~gonio.simulator.lbl_readout.Readout`) and the instrument's description for the side-car;
no light passes the dome, the lens or the sample.

References
----------
.. [EMVA1288] European Machine Vision Association, "EMVA Standard 1288: Standard for
   Characterization of Image Sensors and Cameras", Release 4.0, 2021: Sec. 6.1 and 6.5
   (the flat field: photon transfer, gain, PRNU) and Sec. 6-8 (dark measurements).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gonio.simulator.lbl_config import _rng_and_seed, calibration_metadata, check_binning
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lenses import _pos_finite as _check_positive
from numpy.typing import NDArray

__all__ = ["calibration_capture"]


def calibration_capture(
    readout: Readout, instrument: dict[str, Any], kind: str, photons: float, exposure,
    rng, noise: bool, binning,
) -> tuple[NDArray[np.uint16], dict[str, Any]]:  # fmt: skip
    """A ``kind`` = "dark" (``photons`` 0) or "flat_field" frame of ``photons`` photons
    per pixel, read out, with its side-car (``instrument``: the instrument's description)."""
    exposure = _check_positive(exposure, "exposure")
    binning = check_binning(binning)
    gen, seed = _rng_and_seed(rng) if noise else (None, None)
    h, w = readout.lens.height, readout.lens.width
    dark_e = readout.dark() * exposure
    e = dark_e
    if photons > 0.0:
        prnu, _ = readout.sensor.maps(h, w)
        e = (readout.sensor.qe * photons) * prnu.ravel() + dark_e
    img, lens = readout.finish(e, noise, gen, binning, dark_e=dark_e)
    meta = calibration_metadata(
        instrument, kind, photons, exposure, seed, noise, binning, lens, img
    )
    return img, meta
