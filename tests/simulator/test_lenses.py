"""Fisheye lens models: OpenCV agreement and round trips."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from gonio.simulator.lenses import LENS_MODELS, FisheyeLens, make_lens
from hypothesis import given
from hypothesis import strategies as st


def _dirs(n, theta_max=math.pi / 2 * 0.999, seed=0):
    rng = np.random.default_rng(seed)
    th = rng.uniform(0.0, theta_max, n)
    ph = rng.uniform(-math.pi, math.pi, n)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)


@pytest.mark.parametrize(
    "k, skew",
    [
        ((0.0, 0.0, 0.0, 0.0), 0.0),
        ((0.05, -0.01, 0.003, -0.0005), 0.0),
        ((-0.02, 0.004, -0.001, 0.0001), 0.002),
    ],
)
def test_kannala_brandt_matches_opencv(k, skew):
    lens = FisheyeLens("kannala_brandt", 301.5, 298.25, 320.3, 240.7, 640, 480, k=k, skew=skew)
    d = _dirs(2000)
    uv = lens.project(d)
    ref, _ = cv2.fisheye.projectPoints(
        d.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), lens.camera_matrix(), np.array(k),
        alpha=skew,
    )  # fmt: skip
    assert np.abs(ref.reshape(-1, 2) - uv).max() < 1e-6


@pytest.mark.parametrize("model", LENS_MODELS)
def test_round_trip(model):
    k = (0.03, -0.006, 0.001, -0.0001) if model == "kannala_brandt" else (0, 0, 0, 0)
    lens = make_lens(model, 640, 480, k=k)
    d = _dirs(5000, theta_max=lens.theta_max)
    back = lens.unproject(lens.project(d))
    ang = np.arctan2(np.linalg.norm(np.cross(d, back), axis=-1), np.sum(d * back, axis=-1))
    assert ang.max() < 1e-9
    assert np.allclose(np.linalg.norm(back, axis=-1), 1.0, atol=1e-14)


@given(
    st.floats(0.0, math.pi / 2 * 0.999),
    st.floats(-math.pi, math.pi),
    st.sampled_from(LENS_MODELS),
)
def test_round_trip_property(theta, phi, model):
    lens = make_lens(model, 320, 240)
    d = np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )
    back = lens.unproject(lens.project(d))
    assert np.linalg.norm(np.cross(d, back)) < 1e-9 and d @ back > 0


def test_radial_mappings():
    """Each model's textbook radius at 60 degrees (focal length f)."""
    t = math.radians(60)
    d = np.array([math.sin(t), 0.0, math.cos(t)])
    expect = {
        "equidistant": t,
        "equisolid": 2 * math.sin(t / 2),
        "stereographic": 2 * math.tan(t / 2),
        "orthographic": math.sin(t),
    }
    for model, r in expect.items():
        lens = FisheyeLens(model, 100.0, 100.0, 50.0, 40.0, 101, 81)
        u, v = lens.project(d)
        assert u == pytest.approx(50.0 + 100.0 * r, abs=1e-12)
        assert v == pytest.approx(40.0, abs=1e-12)


def test_image_circle_and_centre():
    lens = make_lens("equisolid", 640, 480, fill=1.0)
    assert lens.project([0.0, 0.0, 1.0]) == pytest.approx([319.5, 239.5])
    edge = lens.project([0.0, 1.0, 1e-18])
    assert edge[1] == pytest.approx(239.5 + 240.0)
    assert lens.in_field([[319.5, 0.0]])[0]
    assert not lens.in_field([[0.0, 0.0]])[0]
    assert lens.field_angle([[319.5, 239.5]])[0] == 0.0


def test_dict_round_trip_and_resize():
    lens = make_lens("kannala_brandt", 640, 480, k=(0.01, 0, 0, 0))
    assert FisheyeLens.from_dict(lens.to_dict()) == lens
    small = lens.resized(108, 80)
    d = _dirs(50)
    big_uv = lens.project(d)
    small_uv = small.project(d)
    # the same direction lands at the same place relative to the image edges
    assert np.allclose((small_uv + 0.5) / [108, 80], (big_uv + 0.5) / [640, 480], atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"model": "fishy"}, "lens model 'fishy' is unknown"),
        ({"model": "equidistant", "fx": -1.0}, "fx must be"),
        ({"model": "equidistant", "k": (0.1, 0, 0, 0)}, "k must be zeros"),
        ({"model": "kannala_brandt", "k": (-1.0, 0, 0, 0)}, "non-monotonic"),
        ({"model": "orthographic", "theta_max": 2.0}, "theta_max"),
        ({"model": "equidistant", "width": 0}, "width"),
    ],
)
def test_bad_lens(kwargs, match):
    args = dict(model="equidistant", fx=100.0, fy=100.0, cx=1.0, cy=1.0, width=3, height=3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        FisheyeLens(**args)


def test_make_lens_unknown():
    with pytest.raises(ValueError, match="unknown"):
        make_lens("pinhole", 10, 10)


@pytest.mark.parametrize("k", [(0.0037, -0.0045, 0.0025, -0.0005), (0.05, -0.01, 0.003, -0.0005)])
def test_kannala_brandt_inverse_compiled_equals_numpy(k):
    # the compiled inverse (large arrays) runs the numpy iteration's operations in the same
    # order with the same stopping rule: the same angles bit for bit, and a true inverse
    lens = FisheyeLens("kannala_brandt", 150.0, 150.0, 319.5, 239.5, 640, 480, k=k)
    v, u = np.mgrid[0:480, 0:640]
    r = np.hypot((u - lens.cx) / lens.fx, (v - lens.cy) / lens.fy)
    r = np.concatenate([r.ravel(), [0.0, 1e-300, 5.0, np.nan]])
    hi_t = min(lens.theta_max * 1.5, math.pi)
    got = lens._g_inv(r)
    assert r.size >= 4096  # the compiled path
    assert np.array_equal(got, lens._g_inv_numpy(r, hi_t), equal_nan=True)
    ok = r < lens.r_max
    assert np.abs(lens._g(got[ok]) - r[ok]).max() < 1e-12


@pytest.mark.parametrize("model", ["kannala_brandt", "equisolid"])
def test_unproject_with_angle_is_unproject_and_field_angle_bit_for_bit(model):
    kw = {"k": (0.05, -0.01, 0.003, -0.0005)} if model == "kannala_brandt" else {}
    lens = FisheyeLens(model, 150.0, 151.0, 319.5, 239.5, 640, 480, skew=1e-4, **kw)
    uv = lens.pixel_grid()
    dirs, theta = lens.unproject_with_angle(uv)
    assert np.array_equal(dirs, lens.unproject(uv))
    assert np.array_equal(theta, lens.field_angle(uv))
    # the flat grid (as the glare correction reads it): the same inverse, the same bits
    assert np.array_equal(theta.ravel(), lens.field_angle(uv.reshape(-1, 2)))
