"""The laboratory's calibration folder (calibration/laboratory.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.calibration.angles import MirrorGeometry
from gonio.calibration.fstops import FStopCalibration
from gonio.calibration.laboratory import LabCalibration, read_calibration
from gonio.calibration.mirror import MirrorCalibration

sim = pytest.importorskip("gonio.simulator")


def _lab() -> LabCalibration:
    lens = sim.make_lens("equidistant", 320, 240)
    mirror = MirrorCalibration(MirrorGeometry("ellipsoid", 0.15, 0.0101, (1e-4, -2e-4)),
                               ["d_over_r", "tilt_x", "tilt_y"],
                               np.array([0.0101 / 0.15, 1e-4, -2e-4]), np.eye(3) * 1e-8,
                               0.01, 10)  # fmt: skip
    fst = FStopCalibration({4.0: 0.0, 5.6: 0.0213}, {4.0: 0.0, 5.6: 0.001}, 4.0, 0.004, 12)
    return LabCalibration(lens={"lens": lens.to_dict(), "rms_px": 0.2}, mirror=mirror,
                          fstops=fst, specification={"veiling_glare": {"typical": 0.01,
                          "spread": 0.003, "unit": "1"}})  # fmt: skip


def test_folder_round_trip(tmp_path):
    lab = _lab()
    lab.write(tmp_path / "cal")
    back = read_calibration(tmp_path / "cal")
    assert back.mirror.geometry == lab.mirror.geometry
    assert back.fstops.effective_f_number(5.6) == pytest.approx(5.6 * np.exp(-0.5 * 0.0213))
    assert back.spec_u("veiling_glare") == pytest.approx(np.hypot(0.01, 0.003))
    assert back.spec_u("lamp_drift") == 0.0
    opts = back.reduction_options()
    assert opts["mirror"] == lab.mirror.geometry and opts["lens"].width == 320
    assert "certificate" not in opts
    assert back.sensor is None
    lab.sensor = {"saturation_dn": 4040.0, "binning": None}
    lab.write(tmp_path / "cal2")
    assert read_calibration(tmp_path / "cal2").sensor == lab.sensor


def test_bad_folders(tmp_path):
    with pytest.raises(ValueError, match=r"calibration\.json"):
        read_calibration(tmp_path)
    (tmp_path / "calibration.json").write_text('{"kind": "other"}')
    with pytest.raises(ValueError, match="not a gonio laboratory calibration"):
        read_calibration(tmp_path)
