import json

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
