"""``gonio design``: bad input is a clear error with nothing written; a design writes a plan
that ``gonio campaign --plan`` reads."""

from __future__ import annotations

import pytest

from gonio.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--target", "alpha_x=1%"], "'alpha_x' is not a fitted parameter"),
        (["--target", "tau=0"], "expected a positive, finite uncertainty"),
        (["--target", "tau=-2%"], "expected a positive, finite uncertainty"),
        (["--prior", "tau=0:9"], "outside the model's bounds [0.0001, 10000.0]"),
        (["--time-limit", "-1"], "expected a positive number of hours"),
        (["--time-limit", "0.0001", "--grid", "3"], "no plan can meet it"),
        (["--material", "rolled_brass"], "expected a li_torrance preset"),
    ],
)
def test_bad_input_clear_error_nothing_written(tmp_path, capsys, argv, message):
    out = tmp_path / "plan.csv"
    js = tmp_path / "design.json"
    assert main(["design", *argv, "--out", str(out), "--json", str(js)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_design_writes_a_plan_the_campaign_reads(tmp_path, capsys):
    from gonio.campaign.cornell import build_plan

    out = tmp_path / "plan.csv"
    argv = ["design", "--target", "tau=5%", "--grid", "3", "--out", str(out)]
    assert main([*argv, "--json", str(tmp_path / "d.json")]) == 0
    text = capsys.readouterr().out
    assert "designed" in text and "default 212 geometries" in text
    assert out.read_text().startswith("# gonio design:")
    assert len(build_plan(str(out))) >= 2
    assert (tmp_path / "d.json").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--target", "alpha_q=1%"], "'alpha_q' is not a parameter of ward"),
        (["--time-limit", "0.0001"], "no plan can meet it"),
        (["--prior", "alpha_x=0.01:0.1"], "options of --instrument cornell only"),
        (["--default-u", "0"], "expected a positive factor"),
        (["--preset", "cornell2005"], "not an lbl preset"),
        (["--design-instruments", "0"], "--design-instruments 0: expected 1 to 10"),
        (["--design-instruments", "11"], "--design-instruments 11: expected 1 to 10"),
        (["--assurance", "1"], "--assurance 1.0: expected a fraction strictly between 0.5 and 1"),
        (["--assurance", "0.5"], "--assurance 0.5: expected a fraction strictly between 0.5"),
        (["--assurance", "nan"], "--assurance nan: expected a fraction strictly between 0.5"),
        (["--assurance", "95"], "--assurance 95.0: expected a fraction strictly between 0.5"),
    ],
)
def test_lbl_bad_input_clear_error_nothing_written(tmp_path, capsys, argv, message):
    out = tmp_path / "plan.json"
    assert main(["design", "--instrument", "lbl", *argv, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_campaign_runs_an_lbl_plan_file(tmp_path, capsys):
    import json

    plan = tmp_path / "p.json"
    plan.write_text(json.dumps({"instrument": "lbl", "theta_i_deg": [30], "rotations_deg": [0]}))
    out = tmp_path / "c"
    argv = ["campaign", "--plan", str(plan), "--material", "rolled_brass", "--no-plots"]
    assert main([*argv, "--quiet", "--workers", "1", "--out", str(out)]) == 0
    done = json.loads((out / "plan.json").read_text())
    assert done["theta_i_deg"] == [30.0] and done["rotations_deg"] == [0.0]
    bad = ["campaign", "--plan", str(plan), "--angles", "10", "--out", str(tmp_path / "d")]
    assert main(bad) == 2
    assert "the plan file sets what ['--angles']" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--adaptive", "--target", "alpha_x=1%"], "'alpha_x' is not a fitted parameter"),
        (["--adaptive", "--plan", "hemispherical"], "--adaptive: designs its own plan"),
        (["--target", "tau=1%"], "--target: an option of --adaptive"),
        (["--adaptive", "--assurance", "0.9"], "--assurance: option(s) of --instrument lbl"),
        (["--adaptive", "--design-instruments", "8"], "--design-instruments: option(s) of"),
    ],
)
def test_adaptive_campaign_bad_input(tmp_path, capsys, argv, message):
    out = tmp_path / "a"
    assert main(["campaign", "--instrument", "cornell", *argv, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--adaptive", "--target", "tau=1%"], "'tau' is not a parameter of ward"),
        (["--adaptive", "--target", "alpha_x=0"], "expected a positive, finite uncertainty"),
        (["--adaptive", "--angles", "10,20"], "--adaptive: designs its own plan (no --angles)"),
        (["--adaptive", "--restandard-every", "2"], "designs its own plan (no --restandard"),
        (["--target", "alpha_x=1%"], "--target: an option of --adaptive"),
        (["--adaptive", "--assurance", "1.2"], "assurance 1.2: expected a fraction"),
        (["--assurance", "0.9"], "--assurance: an option of --adaptive"),
        (["--adaptive", "--design-instruments", "11"], "n_instruments 11: expected 1 to 10"),
        (["--design-instruments", "8"], "--design-instruments: an option of --adaptive"),
    ],
)
def test_lbl_adaptive_campaign_bad_input(tmp_path, capsys, argv, message):
    out = tmp_path / "a"
    assert main(["campaign", "--instrument", "lbl", *argv, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("option", [["--design-instruments", "2"], ["--assurance", "0.99"]])
def test_cornell_design_refuses_lbl_options(tmp_path, capsys, option):
    argv = ["design", *option, "--out", str(tmp_path / "p.csv")]
    assert main(argv) == 2
    assert "options of --instrument lbl only" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
