"""The saturation threshold from the laboratory's photon-transfer captures
(calibration/photon_transfer.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.calibration.photon_transfer import saturation_level

sim = pytest.importorskip("gonio.simulator")


def test_charge_clipped_readings_lie_above_the_measured_threshold():
    """The realistic sensor clips the charge before the read noise and its offsets: about a
    quarter of the clipped readings lie below the side-car's nominal saturation_dn, almost
    none below the threshold measured on a saturated flat field."""
    inst = sim.LBLInstrument(width=320, height=240, sensor=sim.Sensor.realistic())
    dark = inst.capture_dark(exposure=0.004, rng=1)
    flat = inst.capture_flat(1e7, exposure=0.004, rng=2)
    rec = saturation_level(flat[0], flat[1], dark[0])
    nominal = flat[1]["sensor"]["saturation_dn"]
    again = inst.capture_flat(1e7, exposure=0.004, rng=3)[0]
    assert np.mean(again < nominal) > 0.1
    assert np.mean(again < rec["saturation_dn"]) < 1e-3
    assert nominal - 0.02 * 4000 < rec["saturation_dn"] < nominal  # at most 2 % of the range lost
    # the full well above the dark level: 40000 e- at 10 e-/DN
    assert rec["full_well_dn"] == pytest.approx(4000.0, abs=2.0)


def test_an_ideal_sensor_clips_at_its_nominal_level():
    inst = sim.LBLInstrument(width=160, height=120)
    flat = inst.capture_flat(1e7, exposure=0.004, rng=2)
    assert saturation_level(*flat)["saturation_dn"] == flat[1]["sensor"]["saturation_dn"]


def test_bad_input():
    inst = sim.LBLInstrument(width=160, height=120)
    flat = inst.capture_flat(1e7, exposure=0.004, rng=2)
    dark = inst.capture_dark(exposure=0.004, rng=1)
    with pytest.raises(ValueError, match="z must"):
        saturation_level(*flat, z=-1.0)
    with pytest.raises(ValueError, match="2-D image"):
        saturation_level(flat[0][0], flat[1])
    with pytest.raises(ValueError, match="no saturated flat"):
        saturation_level(dark[0], dark[1], dark[0])
