"""One output-path rule for every command (issue 30, 3): an output is never one of the
command's inputs nor another output, checked before the work."""

from __future__ import annotations

import os

import pytest

from gonio.cli import main
from gonio.cli._common import check_outputs


@pytest.fixture
def table(tmp_path):
    """A real samples table (the commands of main's code read it and then overwrote it)."""
    import numpy as np

    from gonio import brdf
    from gonio.io.samples_table import write_samples
    from gonio.samples import BRDFSamples

    m = brdf.create("ward", rho_d=0.3, rho_s=0.05, alpha_x=0.15, alpha_y=0.15)
    rng = np.random.default_rng(0)
    n = 400
    s = BRDFSamples(rng.uniform(0, 1.2, n), 0 * np.ones(n), rng.uniform(0, 1.4, n),
                    rng.uniform(0, 6.2, n), 0 * np.ones(n), np.full(n, np.nan))  # fmt: skip
    s.value = m(s.wi, s.wo)
    return write_samples(s, tmp_path / "x.csv")


def _refused(argv, capsys, *files):
    before = [f.read_bytes() for f in files]
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert [f.read_bytes() for f in files] == before
    return err


def test_fit_json_over_its_samples_table(table, capsys):
    assert "replace that input" in _refused(["fit", table, "--json", table], capsys, table)


def test_an_output_that_is_a_hard_or_symbolic_link_to_an_input(table, tmp_path, capsys):
    os.link(table, tmp_path / "hard.json")
    os.symlink(table, tmp_path / "soft.json")
    for name in ("hard.json", "soft.json"):
        _refused(["fit", table, "--json", tmp_path / name], capsys, table)
    _refused(["fit", tmp_path / ".." / tmp_path.name / "x.csv", "--json", table], capsys, table)


def test_render_plot_or_json_over_its_own_image(tmp_path, capsys):
    img = tmp_path / "a.png"
    for extra in (["--plot", img], ["--json", tmp_path / "a.png.json"], ["--plot", img, "--json",
                                                                        img]):  # fmt: skip
        assert main(["render", "--out", str(img), *map(str, extra)]) == 2
        assert "same file" in capsys.readouterr().err
        assert not img.exists()
    assert (
        main(["render", "--bracket", "--out", str(img), "--plot", str(tmp_path / "a_f4.png")]) == 2
    )
    assert "--bracket" in capsys.readouterr().err


def test_reduce_json_over_an_input_side_car(tmp_path, capsys):
    files = []
    for name in ("m.tif", "s.tif", "b.tif"):
        (tmp_path / name).write_bytes(b"img")
        (tmp_path / (name + ".json")).write_text("{}")
        files.append(tmp_path / (name + ".json"))
    argv = ["reduce", tmp_path / "m.tif", "--standard", tmp_path / "s.tif", "--background",
            tmp_path / "b.tif", "--out", tmp_path / "o.csv"]  # fmt: skip
    for sc in files:
        assert "side-car" in _refused([*argv, "--json", sc], capsys, *files)


def test_bench_csv_folder_is_refused_before_the_work(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--quick", "--csv", str(tmp_path)])
    assert exc.value.code == 2 and "folder" in capsys.readouterr().err
    assert (
        main(["bench", "--quick", "--csv", str(tmp_path / "t"), "--json", str(tmp_path / "t")]) == 2
    )


def test_export_and_campaign_outputs_over_their_inputs(table, tmp_path, capsys):
    _refused(["export", "pabopto", table, tmp_path / "o", "--json", table], capsys, table)
    _refused(["export", "pabopto", table, table], capsys, table)
    cal = tmp_path / "cal"
    cal.mkdir()
    _refused(["campaign", "--angles", "30", "--calibration", cal, "--out", cal], capsys)
    _refused(["sweep", table, "--out", tmp_path / "s", "--json", table], capsys, table)


def test_check_outputs_names_both_options(tmp_path):
    check_outputs({"a": tmp_path / "in"}, {"--json": tmp_path / "out", "--plot": None})
    with pytest.raises(ValueError, match=r"--json .* is the input a"):
        check_outputs({"a": [tmp_path / "x", tmp_path / "in"]}, {"--json": tmp_path / "in"})
