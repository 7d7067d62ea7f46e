"""Bounds on every user-supplied size (issue 30, 6), each named in the option's help and in
the error: binning, frame pixels, workers and processes, model terms."""

from __future__ import annotations

import os

import numpy as np
import pytest

from gonio import campaign
from gonio.cli import build_parser, main
from gonio.cli._common import MAX_MODEL_TERMS, max_workers


def test_binning_beyond_the_camera_is_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="640 x 480"):
        campaign.Plan(binning=(100000, 100000)).resolved()
    argv = [
        "campaign",
        "--angles",
        "30",
        "--binning",
        "100000x100000",
        "--out",
        str(tmp_path / "o"),
    ]
    assert main(argv) == 2
    assert "640 x 480" in capsys.readouterr().err and not (tmp_path / "o").exists()
    assert campaign.Plan(binning=(640, 480)).resolved().binning == (640, 480)


@pytest.mark.parametrize(
    "argv",
    [["campaign", "--workers", "64"], ["sweep", "s.toml", "--processes", "64"],
     ["sweep", "s.toml", "--dask-local", "64"], ["export", "bsdf", "x.csv", "o", "--nproc", "64"]],
)  # fmt: skip
def test_workers_beyond_a_small_multiple_of_the_cpus_are_refused(argv, capsys):
    if 64 <= max_workers():
        pytest.skip("a machine of 16 or more CPUs")
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and "per CPU" in capsys.readouterr().err
    with pytest.raises(ValueError, match="workers 64"):
        campaign.run(campaign.Plan(theta_i_deg=(30.0,)), None, workers=64)


def test_the_bounds_are_in_the_help():
    p = build_parser()
    sub = p._subparsers._group_actions[0].choices
    helps = {c: " ".join(a.help or "" for a in sub[c]._actions) for c in sub}
    assert "4 per CPU" in helps["campaign"] and "640x480" in helps["campaign"]
    assert "4 per CPU" in helps["sweep"] and "4 per CPU" in helps["export"]
    assert "4096 x 4096" in helps["reduce"]


def test_a_model_of_too_many_terms_is_refused(tmp_path, capsys):
    model = " + ".join(["lambert"] * 300)
    with pytest.raises(ValueError, match=f"at most {MAX_MODEL_TERMS}"):
        campaign.Plan(model=model).resolved()
    (tmp_path / "x.csv").write_text("")
    assert main(["fit", str(tmp_path / "x.csv"), "--model", model]) == 2
    assert "300 terms" in capsys.readouterr().err


def test_a_huge_frame_is_refused_before_it_is_decoded(tmp_path, capsys):
    import cv2

    buf = cv2.imencode(".png", np.zeros((12000, 12000), np.uint8))[1]  # 161 kB
    paths = []
    for name in ("m", "s", "b"):
        p = tmp_path / f"{name}.png"
        p.write_bytes(buf.tobytes())
        (tmp_path / f"{name}.png.json").write_text('{"exposure_s": 0.01, "f_number": 8}')
        paths.append(str(p))
    argv = ["reduce", paths[0], "--standard", paths[1], "--background", paths[2],
            "--out", str(tmp_path / "o.csv")]  # fmt: skip
    assert main(argv) == 2
    assert "12000 x 12000" in capsys.readouterr().err
    assert os.path.getsize(paths[0]) < 200_000  # (decoded: 144 MB)
