"""ChArUco fisheye calibration on rendered views (cv2.fisheye)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.calibration.lens import (
    board_poses,
    calibrate_fisheye,
    make_board,
    render_board_view,
    render_board_views,
)
from gonio.simulator.lenses import make_lens


@pytest.mark.slow
def test_kannala_brandt_recovered():
    lens = make_lens("kannala_brandt", 640, 640, k=(0.02, -0.01, 0.002, 0.0), fill=0.97)
    board = make_board()
    # the views of render_board_view, rendered together (the rays once for all 16: 5x cheaper)
    imgs = render_board_views(lens, board, board_poses(lens, board, 16))
    cal = calibrate_fisheye(imgs, board)
    assert cal.rms < 0.2
    assert abs(cal.lens.fx / lens.fx - 1) < 1e-3
    assert abs(cal.lens.fy / lens.fy - 1) < 1e-3


@pytest.fixture(scope="module")
def views():
    lens = make_lens("equisolid", 640, 480, fill=0.95)
    board = make_board()
    poses = board_poses(lens, board, 4)
    return board, render_board_views(lens, board, poses), lens, poses


def test_a_view_rendered_alone_is_the_same_as_among_others(views):
    board, imgs, lens, poses = views
    assert np.array_equal(render_board_view(lens, board, *poses[2]), imgs[2])


def test_the_same_view_three_times_is_refused(views):
    # issue 15 item 7: accepted before with fx -3.4 % and rms 0.048 px
    board, imgs, _lens, _poses = views
    with pytest.raises(ValueError, match=r"only 1 of 3 views show the board at distinct poses"):
        calibrate_fisheye([imgs[1]] * 3, board)
    with pytest.raises(ValueError, match=r"only 2 of 3 .*; view 2 repeats view 0"):
        calibrate_fisheye([imgs[1], imgs[2], imgs[1]], board)


def test_a_repeated_view_among_distinct_ones_is_skipped(views):
    board, imgs, _lens, _poses = views
    cal = calibrate_fisheye([*imgs, imgs[0]], board)
    assert cal.n_views == 4 and cal.info["views_repeated"] == [4]


def test_board_larger_than_its_dictionary_is_refused_before_allocating():
    with pytest.raises(ValueError, match=r"need 5000000000 ArUco markers, more than the 250"):
        make_board(100000, 100000)
    assert make_board(22, 22) is not None  # 242 markers: the largest square board of 4x4_250
