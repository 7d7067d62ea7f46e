"""``gonio export``: PAB-Opto files, BSDF XML and material.rad from the command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gonio import brdf
from gonio.cli import main
from gonio.io.samples_table import write_samples
from gonio.samples import BRDFSamples


def _samples(tmp_path, phis=(0.0,)):
    m = brdf.create("ward_gmd", rho_d=0.3, rho_s=0.05, alpha_x=0.15, alpha_y=0.15)
    to = np.radians(np.linspace(2.5, 87.5, 12))
    po = np.radians(np.arange(16) * 22.5)
    T, P = (a.ravel() for a in np.meshgrid(to, po, indexing="ij"))
    rows = [(math.radians(t), math.radians(p)) for t in (0.0, 30.0, 60.0) for p in phis]
    ti = np.concatenate([np.full(T.size, t) for t, _ in rows])
    pi = np.concatenate([np.full(T.size, p) for _, p in rows])
    s = BRDFSamples(ti, pi, np.tile(T, len(rows)), np.tile(P, len(rows)), 0 * ti, 0 * ti + np.nan)
    s.value = m(s.wi, s.wo)
    return write_samples(s, tmp_path / "samples.csv")


def test_export_pabopto(tmp_path, capsys):
    src = _samples(tmp_path)
    assert (
        main(
            [
                "export",
                "pabopto",
                str(src),
                str(tmp_path / "pab"),
                "--name",
                "tile",
                "--json",
                str(tmp_path / "r.json"),
            ]
        )
        == 0
    )
    assert "3 PAB-Opto files" in capsys.readouterr().out
    assert len(list((tmp_path / "pab").glob("tile_t*.dat"))) == 3
    assert json.loads((tmp_path / "r.json").read_text())["symmetry"] == "isotropic"


def test_export_refuses_boundary_rotations(tmp_path, capsys):
    src = _samples(tmp_path, phis=(0.0, 90.0))
    assert main(["export", "pabopto", str(src), str(tmp_path / "pab")]) == 2
    err = capsys.readouterr().err
    assert "quadrant boundaries" in err and "0, 45, 90" in err
    assert not (tmp_path / "pab").exists()


def test_export_refuses_bad_tables_and_writes_nothing(tmp_path, capsys):
    """Missing angles (a column, or a value), values below 0 and a bad --cells: exit 2 with
    the reason, and no output folder."""
    src = _samples(tmp_path, phis=(0.0,))
    lines = src.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("theta_i"))
    cols = lines[k].split(",")
    j = cols.index("phi_o")
    no_col = tmp_path / "no_phi_o.csv"
    no_col.write_text(
        "\n".join(
            lines[:k]
            + [",".join(c for i, c in enumerate(ln.split(",")) if i != j) for ln in lines[k:]]
        )
        + "\n"
    )
    empty = tmp_path / "empty_angle.csv"
    row = lines[k + 1].split(",")
    row[j] = ""
    empty.write_text("\n".join(lines[: k + 1] + [",".join(row)] + lines[k + 2 :]) + "\n")
    negative = tmp_path / "negative.csv"
    row = lines[k + 1].split(",")
    row[cols.index("value")] = "-0.01"
    negative.write_text("\n".join(lines[: k + 1] + [",".join(row)] + lines[k + 2 :]) + "\n")
    for bad, extra, reason in (
        (no_col, [], "missing column"),
        (empty, [], "row 1 has a non-numeric field"),
        (negative, [], "below 0"),
        (src, ["--cells", "12"], "cells 12"),
    ):
        out = tmp_path / f"out_{bad.stem}"
        assert main(["export", "pabopto", str(bad), str(out), *extra]) == 2, bad
        assert reason in capsys.readouterr().err
        assert not out.exists()
    assert main(["export", "pabopto", str(src), str(tmp_path / "all"), "--cells", "0"]) == 0
    data = (tmp_path / "all").glob("*_t030.000_*.dat")
    assert len(next(data).read_text().splitlines()) == 6 + 12 * 16  # every sample


def test_export_material_from_a_fit(tmp_path, capsys):
    fit = {
        "model": "ward",
        "params": {"rho_d": 0.1, "rho_s": 0.33, "alpha_x": 0.05, "alpha_y": 0.16},
    }
    (tmp_path / "fit.json").write_text(json.dumps(fit))
    assert (
        main(
            [
                "export",
                "material",
                str(tmp_path / "m"),
                "--fit",
                str(tmp_path / "fit.json"),
                "--name",
                "brass",
                "--class",
                "metal",
            ]
        )
        == 0
    )
    assert "BRTDfunc brass" in (tmp_path / "m" / "material.rad").read_text()
    assert (tmp_path / "m" / "brass.cal").exists()
    assert (
        main(
            [
                "export",
                "material",
                str(tmp_path / "g"),
                "--model",
                "ward_gmd",
                "--param",
                "rho_s=0.2",
                "--class",
                "metal",
            ]
        )
        == 0
    )
    assert "void metal2 gonio" in (tmp_path / "g" / "material.rad").read_text()
    assert main(["export", "material", str(tmp_path / "p"), "--model", "phong"]) == 2
    assert "no Radiance translation" in capsys.readouterr().err


def test_export_bsdf_klems(tmp_path, capsys):
    pytest.importorskip("pyradiance")
    src = _samples(tmp_path)
    assert (
        main(
            [
                "export",
                "bsdf",
                str(src),
                str(tmp_path / "b"),
                "--name",
                "tile",
                "--samples-per-patch",
                "4",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "klems BSDF (I)" in out and "checkBSDF: Lambertian 0.3" in out
    assert (tmp_path / "b" / "tile.xml").exists() and (tmp_path / "b" / "tile_bsdf.rad").exists()
