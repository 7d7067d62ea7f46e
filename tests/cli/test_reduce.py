"""``gonio reduce`` on image files with side-cars."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio import materials
from gonio.cli import main
from gonio.io.samples_table import read_samples

sim = pytest.importorskip("gonio.simulator")


def test_reduce_cli_round_trip(tmp_path):
    from gonio.io.images import write_image

    inst = sim.LBLInstrument(mirror="ellipsoid", width=160, height=120, lens="equidistant")
    ti = np.radians(30)
    paths = {}
    for key, sample in (("m", "glossy_grey_paper"), ("s", "standard"), ("b", None)):
        img, meta = inst.capture(sample, ti, noise=False)
        paths[key] = write_image(tmp_path / f"{key}.png", img, meta)
    out = tmp_path / "samples.csv"
    rc = main(["reduce", str(paths["m"]), "--standard", str(paths["s"]), "--background",
               str(paths["b"]), "--out", str(out), "--json", str(tmp_path / "r.json")])  # fmt: skip
    assert rc == 0
    s = read_samples(out)
    rel = np.abs(s.value / materials.get("glossy_grey_paper")(s.wi, s.wo) - 1)
    assert np.median(rel) < 0.01
    stats = json.loads((tmp_path / "r.json").read_text())["stats"]
    assert stats["n_after"] == len(s) and stats["n_before"] >= len(s)


def test_reduce_cli_missing_file(tmp_path, capsys):
    rc = main(["reduce", str(tmp_path / "nope.png"), "--standard", "x.png", "--background",
               "y.png", "--out", str(tmp_path / "o.csv")])  # fmt: skip
    assert rc == 2
    assert not (tmp_path / "o.csv").exists()


def test_reduce_all_saturated_is_an_error(tmp_path):
    from gonio.io.images import write_image

    inst = sim.LBLInstrument(mirror="ellipsoid", width=80, height=60, lens="equidistant")
    paths = []
    for key, sample in (("m", "glossy_grey_paper"), ("s", "standard"), ("b", None)):
        img, meta = inst.capture(sample, 0.5, exposure=5.0, f_number=2.0, noise=False)
        paths.append(write_image(tmp_path / f"{key}.png", img, meta))
    rc = main(["reduce", str(paths[0]), "--standard", str(paths[1]), "--background",
               str(paths[2]), "--out", str(tmp_path / "o.csv")])  # fmt: skip
    assert rc == 2 and not (tmp_path / "o.csv").exists()
