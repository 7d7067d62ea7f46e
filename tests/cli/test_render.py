"""``gonio render``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.cli import main
from gonio.io.images import read_image


def test_render_png_with_sidecar_json_and_plot(tmp_path, capsys):
    out = tmp_path / "img.png"
    rc = main(
        [
            "render", "--material", "rolled_brass", "--theta-i", "30", "--out", str(out),
            "--width", "160", "--height", "120", "--seed", "7",
            "--json", str(tmp_path / "r.json"), "--plot", str(tmp_path / "p.png"),
        ]
    )  # fmt: skip
    assert rc == 0
    img, meta = read_image(out, require_metadata=True)
    assert img.dtype == np.uint16 and img.shape == (120, 160)
    assert meta["brdf"]["material"] == "rolled_brass" and meta["seed"] == 7
    assert meta["theta_i"] == pytest.approx(np.radians(30))
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["images"][0]["stats"]["max"] == int(img.max())
    assert res["metadata"][0]["mirror"]["type"] == "ellipsoid"
    assert (tmp_path / "p.png").stat().st_size > 1000
    assert "img.png" in capsys.readouterr().out


def test_render_options(tmp_path):
    out = tmp_path / "b.tif"
    rc = main(
        [
            "render", "--model", "ward", "--param", "alpha_x=0.08", "--param", "alpha_y=0.08",
            "--mirror", "hemisphere", "--lens", "equisolid", "--exposure", "0.005",
            "--width", "128", "--height", "96", "--no-noise", "--binning", "108x80",
            "--out", str(out),
        ]
    )  # fmt: skip
    assert rc == 0
    img, meta = read_image(out)
    assert img.shape == (80, 108) and meta["mirror"]["type"] == "hemisphere"
    assert meta["brdf"]["params"]["alpha_x"] == 0.08 and meta["exposure_s"] == 0.005
    assert main(["render", "--sample", "none", "--width", "64", "--height", "48",
                 "--out", str(tmp_path / "bg.png")]) == 0  # fmt: skip
    assert read_image(tmp_path / "bg.png")[1]["sample"] == "none"


def test_render_binning_is_wxh_as_in_campaign(tmp_path, capsys):
    """``--binning`` takes WxH as ``gonio campaign --binning`` does; 0x0 is none; the bare
    flag of earlier versions still means Ward's 108x80 and says the new form."""
    base = ["render", "--sample", "standard", "--width", "128", "--height", "96", "--no-noise"]
    assert main([*base, "--binning", "64x48", "--out", str(tmp_path / "a.png")]) == 0
    img, meta = read_image(tmp_path / "a.png")
    assert img.shape == (48, 64) and tuple(meta["binning"]) == (64, 48)
    assert main([*base, "--binning", "0x0", "--out", str(tmp_path / "b.png")]) == 0
    assert read_image(tmp_path / "b.png")[0].shape == (96, 128)
    capsys.readouterr()
    assert main([*base, "--binning", "--out", str(tmp_path / "c.png")]) == 0
    assert read_image(tmp_path / "c.png")[0].shape == (80, 108)
    assert "write --binning 108x80" in capsys.readouterr().err


@pytest.mark.parametrize(
    "value, match",
    [("108", "expected WxH, e.g. 108x80"), ("200x80", "the image's 128x96"), ("0x5", "1x1")],
)
def test_render_bad_binning(tmp_path, capsys, value, match):
    argv = ["render", "--sample", "none", "--width", "128", "--height", "96"]
    rc = main([*argv, "--binning", value, "--out", str(tmp_path / "x.png")])
    assert rc == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_render_bracket(tmp_path):
    rc = main(
        [
            "render", "--material", "rolled_brass", "--bracket", "--no-noise",
            "--width", "96", "--height", "72", "--out", str(tmp_path / "s.png"),
        ]
    )  # fmt: skip
    assert rc == 0
    files = sorted(p.name for p in tmp_path.glob("s_f*.png"))
    assert files and all((tmp_path / (f + ".json")).exists() for f in files)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--theta-i", "90"], "theta-i"),
        (["--lens", "pinhole"], "lens 'pinhole' is unknown"),
        (["--exposure", "-1"], "exposure"),
        (["--half-separation", "0.2"], "half_separation"),
        (["--param", "rho"], "NAME=VALUE"),
    ],
)
def test_render_bad_input(tmp_path, capsys, argv, match):
    rc = main(
        ["render", "--out", str(tmp_path / "x.png"), "--width", "32", "--height", "24", *argv]
    )
    assert rc == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("opt", ["--width", "--height"])
def test_render_size_is_bounded(tmp_path, capsys, opt):
    with pytest.raises(SystemExit):
        main(["render", opt, "100000", "--out", str(tmp_path / "x.tif")])
    assert f"argument {opt}: 100000 is outside [2, 4096]" in capsys.readouterr().err
