"""Typed side-cars (issue 30, 4): every field the reduction reads has a type and a range; a
boolean is not a number; an unknown response model is an error naming the file and the
field; the same frame twice in a bracket is refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.cli import main
from gonio.io.images import ImageFormatError, check_sidecar, read_metadata, write_image

sim = pytest.importorskip("gonio.simulator")


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("frames")
    inst = sim.LBLInstrument(mirror="ellipsoid", width=96, height=72, lens="equidistant")
    paths = {}
    for key, sample in (("m", "glossy_grey_paper"), ("s", "standard"), ("b", None)):
        img, meta = inst.capture(sample, np.radians(30), noise=True, rng=1)
        paths[key] = write_image(tmp / f"{key}.tif", img, meta)
    return paths


def _reduce(paths, tmp_path, m=None):
    out = tmp_path / "o.csv"
    m = m or [paths["m"]]
    argv = ["reduce", *map(str, m), "--standard", str(paths["s"]), "--background",
            str(paths["b"]), "--out", str(out)]  # fmt: skip
    return main(argv), out


def _edited(paths, tmp_path, where, field, value):
    """A copy of the measured frame whose side-car's ``field`` (in ``where``) is ``value``."""
    img = tmp_path / "m.tif"
    img.write_bytes(paths["m"].read_bytes())
    meta = json.loads((paths["m"].parent / "m.tif.json").read_text())
    (meta[where] if where else meta)[field] = value
    (tmp_path / "m.tif.json").write_text(json.dumps(meta))
    return {**paths, "m": img}


@pytest.mark.parametrize(
    "where, field, value",
    [
        ("", "exposure_s", True),
        ("", "f_number", False),
        ("", "exposure_s", "0.01"),
        ("", "theta_i", None),
        ("sensor", "response_gamma", "abc"),
        ("sensor", "response_gamma", 0),
        ("sensor", "response_gamma", True),
        ("sensor", "response", "lineer"),
        ("", "response", 3),
        ("sensor", "adc_bits", 12.5),
        ("sensor", "gain_e_per_dn", -1),
        ("sensor", "read_noise_e", [8]),
        ("", "shape", [72, True]),
    ],
)
def test_a_side_car_field_of_the_wrong_type_is_an_error_naming_file_and_field(
    frames, tmp_path, capsys, where, field, value
):
    paths = _edited(frames, tmp_path, where, field, value)
    rc, out = _reduce(paths, tmp_path)
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists(), err
    assert "m.tif" in err and field in err


def test_the_reduction_of_valid_side_cars_still_runs(frames, tmp_path):
    rc, out = _reduce(frames, tmp_path)
    assert rc == 0 and out.exists()
    paths = _edited(frames, tmp_path, "sensor", "response", "linear")
    assert _reduce(paths, tmp_path)[0] == 0


def test_the_same_frame_twice_in_a_bracket_is_refused(frames, tmp_path, capsys):
    rc, out = _reduce(frames, tmp_path, m=[frames["m"], frames["m"]])
    assert rc == 2 and not out.exists()
    assert "twice" in capsys.readouterr().err
    copy = tmp_path / "copy.tif"  # another file, the same exposure, stop and pixels
    copy.write_bytes(frames["m"].read_bytes())
    (tmp_path / "copy.tif.json").write_bytes((frames["m"].parent / "m.tif.json").read_bytes())
    rc, out = _reduce(frames, tmp_path, m=[frames["m"], copy])
    assert rc == 2 and "same frame twice" in capsys.readouterr().err


def test_check_sidecar_and_read_metadata(tmp_path):
    check_sidecar({"exposure_s": 0.01, "sensor": {"response": "nonlinear"}}, "x")
    with pytest.raises(ImageFormatError, match=r"'sensor\.response_gamma'"):
        check_sidecar({"sensor": {"response_gamma": float("nan")}}, "x")
    (tmp_path / "a.png.json").write_text("[" * 900 + "]" * 900)
    with pytest.raises(ImageFormatError, match="nested deeper"):
        read_metadata(tmp_path / "a.png")
