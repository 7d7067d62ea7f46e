import json

import numpy as np
import pytest

from gonio.cli import main


def test_models_and_materials_json(tmp_path, capsys):
    assert main(["models", "--json", str(tmp_path / "m.json")]) == 0
    data = json.loads((tmp_path / "m.json").read_text())
    assert "ward" in data["models"]
    assert data["models"]["ward"]["params"]["alpha_x"]["lower"] > 0
    assert main(["materials", "--json", str(tmp_path / "mat.json")]) == 0
    mats = json.loads((tmp_path / "mat.json").read_text())["materials"]
    assert mats["rolled_brass"]["params"]["rho_s"] == 0.33
    assert main(["models", "nope"]) == 2
    assert "registered models are" in capsys.readouterr().err


# -- output paths checked before any work, OSError as one line (issue 15 item 6) -------------
def _usage_error(argv, capsys) -> str:
    with pytest.raises(SystemExit) as ei:
        main(argv)
    assert ei.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["campaign", "--out", "{file}"], "argument --out: '{file}' exists and is not a folder"),
        (["campaign", "--out", "{file}/sub"], "'{file}' is a file, not a folder"),
        (["campaign", "--json", "{dir}"], "argument --json: '{dir}' is a folder"),
        (["sweep", "spec.toml", "-o", "{file}"], "argument -o/--out: '{file}' exists and is"),
        (["calibrate-lens", "a.png", "--out", "."], "argument --out: '.' is a folder"),
        (["render", "--out", "{file}/x.tif"], "'{file}' is a file, not a folder"),
        (["reduce", "m", "--standard", "s", "--background", "b", "--out", "{dir}"], "is a folder"),
        (["devices", "serve", "--tcp-port", "70000"], "70000 is outside the port range"),
    ],
)
def test_output_paths_and_ports_refused_before_any_work(tmp_path, capsys, argv, expected):
    f = tmp_path / "afile"
    f.write_text("x")
    sub = {"{file}": str(f), "{dir}": str(tmp_path)}
    for k, v in sub.items():
        argv = [a.replace(k, v) for a in argv]
        expected = expected.replace(k, v)
    assert expected in _usage_error(argv, capsys)
    assert f.read_text() == "x"


def test_os_error_is_one_line_naming_the_path(tmp_path, capsys, monkeypatch):
    from gonio.cli import os_error_text

    e = IsADirectoryError(21, "Is a directory")
    e.filename, e.filename2 = "/x/.j.tmp", "/x/j"
    assert os_error_text(e) == "'/x/j': Is a directory"
    assert os_error_text(OSError("Timed out trying to connect")) == "Timed out trying to connect"

    import gonio.cli.models as models

    def full_disk(args):
        raise OSError(28, "No space left on device", str(tmp_path / "m.json"))

    monkeypatch.setattr(models, "run", full_disk)
    assert main(["models"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"gonio models: error: '{tmp_path / 'm.json'}': No space left on device"]


def test_materials_of_an_unknown_model(capsys):
    assert main(["materials", "--model", "nosuch"]) == 2
    assert "unknown model 'nosuch'; registered models are:" in capsys.readouterr().err


def test_fit_exit_status_and_notes(tmp_path, capsys):
    from gonio import brdf
    from gonio.geometry import to_vector
    from gonio.samples import BRDFSamples

    rng = np.random.default_rng(1)
    n = 300
    ti, to = rng.uniform(0.1, 1.2, n), rng.uniform(0.1, 1.2, n)
    pi, po = np.zeros(n), rng.uniform(-np.pi, np.pi, n)
    v = brdf.create("lambert", rho=0.4)(to_vector(ti, pi), to_vector(to, po))
    BRDFSamples(ti, pi, to, po, v, 0.01 * v).write(tmp_path / "t.csv")
    assert main(["fit", str(tmp_path / "t.csv"), "--model", "lambert + lambert"]) == 1
    out = capsys.readouterr().out
    assert "NOT identifiable" in out and "note: not identifiable" in out
