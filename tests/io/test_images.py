"""Image files with JSON side-cars."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.io.images import ImageFormatError, read_image, read_metadata, sidecar_path, write_image


@pytest.mark.parametrize(
    "suffix, dtype, shape",
    [
        (".png", np.uint16, (7, 9)),
        (".png", np.uint8, (7, 9, 3)),
        (".tif", np.uint16, (5, 4)),
        (".tiff", np.uint16, (5, 4, 4)),
        (".tif", np.float32, (6, 3)),
        (".tiff", np.float32, (6, 3, 3)),
    ],
)
def test_round_trip(tmp_path, suffix, dtype, shape):
    rng = np.random.default_rng(0)
    if dtype == np.float32:
        img = rng.normal(size=shape).astype(np.float32) * 1e3
    else:
        img = rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)
    meta = {"exposure_s": np.float64(0.01), "lens": {"k": np.zeros(4)}, "shape": list(shape)}
    path = write_image(tmp_path / f"img{suffix}", img, meta)
    back, m = read_image(path)
    assert back.dtype == img.dtype and np.array_equal(back, img)
    assert m == {"exposure_s": 0.01, "lens": {"k": [0.0, 0.0, 0.0, 0.0]}, "shape": list(shape)}
    assert sidecar_path(path).name == f"img{suffix}.json"


@pytest.mark.parametrize("suffix", [".tif", ".png"])
def test_uncompressed_round_trip(tmp_path, suffix):
    img = np.random.default_rng(1).integers(0, 65535, size=(48, 64)).astype(np.uint16)
    a = write_image(tmp_path / f"a{suffix}", img, {"k": 1}, compress=False)
    b = write_image(tmp_path / f"b{suffix}", np.zeros_like(img), {"k": 1})
    back, meta = read_image(a)
    assert np.array_equal(back, img) and meta == {"k": 1}
    assert a.stat().st_size >= img.nbytes  # stored as is
    assert b.stat().st_size < img.nbytes / 10  # a flat image compresses by default


def test_rgb_channel_order(tmp_path):
    img = np.zeros((2, 2, 3), np.uint16)
    img[..., 0] = 1000  # red
    write_image(tmp_path / "c.png", img)
    import cv2

    raw = cv2.imread(str(tmp_path / "c.png"), cv2.IMREAD_UNCHANGED)
    assert raw[0, 0, 2] == 1000  # OpenCV stores BGR
    assert read_image(tmp_path / "c.png")[0][0, 0, 0] == 1000


def test_no_sidecar(tmp_path):
    write_image(tmp_path / "a.png", np.zeros((3, 3), np.uint16))
    assert not sidecar_path(tmp_path / "a.png").exists()
    assert read_image(tmp_path / "a.png")[1] == {}
    with pytest.raises(ImageFormatError, match="does not exist"):
        read_image(tmp_path / "a.png", require_metadata=True)


def test_malformed_files(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(ImageFormatError, match="not a readable"):
        read_image(bad)
    empty = tmp_path / "empty.tif"
    empty.write_bytes(b"")
    with pytest.raises(ImageFormatError):
        read_image(empty)
    with pytest.raises(ImageFormatError, match="does not exist"):
        read_image(tmp_path / "missing.png")
    write_image(tmp_path / "ok.png", np.zeros((2, 2), np.uint16))
    sidecar_path(tmp_path / "ok.png").write_text("{truncated")
    with pytest.raises(ImageFormatError, match="not valid JSON"):
        read_image(tmp_path / "ok.png")
    sidecar_path(tmp_path / "ok.png").write_text("[1, 2]")
    with pytest.raises(ImageFormatError, match="JSON object"):
        read_metadata(tmp_path / "ok.png")
    sidecar_path(tmp_path / "ok.png").write_text(json.dumps({"shape": [3, 3]}))
    with pytest.raises(ImageFormatError, match="says shape"):
        read_image(tmp_path / "ok.png")
    assert isinstance(ImageFormatError("x"), ValueError)


def test_bad_writes(tmp_path):
    with pytest.raises(ValueError, match="suffix"):
        write_image(tmp_path / "a.jpg", np.zeros((2, 2), np.uint16))
    with pytest.raises(ValueError, match=r"cannot be written as \.png"):
        write_image(tmp_path / "a.png", np.zeros((2, 2), np.float32))
    with pytest.raises(ValueError, match="NaN"):
        write_image(tmp_path / "a.tif", np.full((2, 2), np.nan, np.float32))
    with pytest.raises(ValueError, match="shape"):
        write_image(tmp_path / "a.png", np.zeros((2, 2, 2), np.uint16))
    with pytest.raises(ValueError, match="not JSON serialisable"):
        write_image(tmp_path / "a.png", np.zeros((2, 2), np.uint16), {"x": object()})
    assert not (tmp_path / "a.png").exists()


def test_atomic_overwrite_leaves_no_temp(tmp_path):
    p = tmp_path / "x.png"
    write_image(p, np.ones((4, 4), np.uint16), {"n": 1})
    write_image(p, np.full((4, 4), 7, np.uint16), {"n": 2})
    assert read_image(p)[1] == {"n": 2}
    assert sorted(f.name for f in tmp_path.iterdir()) == ["x.png", "x.png.json"]
