"""ChArUco fisheye calibration on rendered views (cv2.fisheye)."""

from __future__ import annotations

import pytest
from gonio.calibration.lens import board_poses, calibrate_fisheye, make_board, render_board_view
from gonio.simulator.lenses import make_lens


@pytest.mark.slow
def test_kannala_brandt_recovered():
    lens = make_lens("kannala_brandt", 640, 640, k=(0.02, -0.01, 0.002, 0.0), fill=0.97)
    board = make_board()
    imgs = [render_board_view(lens, board, r, t) for r, t in board_poses(lens, board, 16)]
    cal = calibrate_fisheye(imgs, board)
    assert cal.rms < 0.2
    assert abs(cal.lens.fx / lens.fx - 1) < 1e-3
    assert abs(cal.lens.fy / lens.fy - 1) < 1e-3
