"""The ``gonio campaign`` and ``gonio fit`` command lines."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio import brdf
from gonio.cli import main
from gonio.cli.campaign import parse_angles, parse_noise
from gonio.samples import BRDFSamples


def test_campaign_command_writes_summary_and_prints_table(tmp_path, capsys):
    out = tmp_path / "run"
    js = tmp_path / "s.json"
    rc = main(["campaign", "--angles", "20,50", "--rotations", "0,90", "--no-plots",
               "--out", str(out), "--json", str(js), "--seed", "3"])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    assert "rolled_brass fitted with ward" in text and "alpha_x" in text and "time (s)" in text
    s = json.loads(js.read_text())
    for key in ("material", "model", "truth", "fit", "stderr", "relative_error", "rms",
                "n_samples", "converged", "timings_s", "seed"):  # fmt: skip
        assert key in s
    assert s["seed"] == 3 and s["plan"]["theta_i_deg"] == [20.0, 50.0]
    assert json.loads((out / "summary.json").read_text())["fit"] == s["fit"]
    # --resume reuses every capture and reproduces the fit
    js2 = tmp_path / "s2.json"
    rc = main(["campaign", "--angles", "20,50", "--rotations", "0,90", "--no-plots", "--quiet",
               "--out", str(out), "--json", str(js2), "--seed", "3", "--resume"])  # fmt: skip
    assert rc == 0 and capsys.readouterr().out == ""
    s2 = json.loads(js2.read_text())
    assert s2["n_captures"]["resumed_groups"] == 2 * 3
    assert s2["fit"] == s["fit"]


def test_campaign_command_bad_options(tmp_path, capsys):
    assert main(["campaign", "--material", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown material" in capsys.readouterr().err
    assert main(["campaign", "--noise", "loud", "--out", str(tmp_path)]) == 2
    assert "--noise" in capsys.readouterr().err


def test_parse_angles_and_noise():
    assert parse_angles("0:80:21")[1] == pytest.approx(4.0)
    assert len(parse_angles("0:80:21")) == 21
    assert parse_angles("10, 20") == (10.0, 20.0)
    with pytest.raises(ValueError, match="--angles"):
        parse_angles("a:b")
    assert parse_noise("off") == 0.0 and parse_noise("on") == 1.0 and parse_noise("2") == 2.0
    with pytest.raises(ValueError):
        parse_noise("-1")


def test_fit_command(tmp_path, capsys):
    rng = np.random.default_rng(0)
    n = 600
    ti, to = rng.uniform(0, 1.3, n), rng.uniform(0, 1.3, n)
    pi, po = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2 * np.pi, n)
    s = BRDFSamples(ti, pi, to, po, np.zeros(n), np.full(n, np.nan))
    s.value = brdf.create("ward", rho_d=0.2, rho_s=0.1, alpha_x=0.2, alpha_y=0.3)(s.wi, s.wo)
    path = s.write(tmp_path / "s.csv")
    js = tmp_path / "f.json"
    assert main(["fit", str(path), "--model", "ward", "--json", str(js)]) == 0
    d = json.loads(js.read_text())
    assert d["model"] == "ward" and d["converged"]
    assert d["params"]["alpha_y"] == pytest.approx(0.3, rel=1e-6)
    assert "alpha_x" in capsys.readouterr().out
    assert main(["fit", str(path), "--model", "ward", "--fixed", "rho_d=0.2"]) == 0
    assert main(["fit", str(path), "--init", "rho_d"]) == 2
    assert main(["fit", str(tmp_path / "missing.csv")]) == 2


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (
            ["--instrument", "cornell", "--mirror", "hemisphere"],
            "--mirror: option(s) of --instrument lbl only",
        ),
        (["--instrument", "cornell", "--angles", "30"], "--angles: option(s) of --instrument lbl"),
        (["--plan", "hemispherical"], "plan file 'hemispherical' does not exist"),  # lbl: JSON
        (["--through-drivers"], "--through-drivers: option(s) of --instrument cornell only"),
    ],
)
def test_options_of_the_other_instrument_are_refused(tmp_path, capsys, argv, expected):
    assert main(["campaign", *argv, "--out", str(tmp_path / "c"), "--quiet"]) == 2
    assert expected in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_negative_seed_names_the_option(capsys):
    with pytest.raises(SystemExit):
        main(["campaign", "--seed", "-1"])
    assert "argument --seed: -1 is outside [0, " in capsys.readouterr().err


def _options_named(text: str) -> tuple[set[str], set[str]]:
    """The options ``text`` names: ``gonio fit``'s (after "gonio fit") and the others."""
    import re

    fit = set(re.findall(r"gonio fit ((?:--[a-z][a-z-]*(?: \S+)?(?: or )?)+)", text))
    fit_opts = {o for part in fit for o in re.findall(r"--[a-z][a-z-]*", part)}
    rest = re.sub(r"gonio fit ((?:--[a-z][a-z-]*(?: \S+)?(?: or )?)+)", "", text)
    return fit_opts, set(re.findall(r"--[a-z][a-z-]*", rest))


@pytest.mark.parametrize("instrument", ["lbl", "cornell"])
def test_the_campaigns_hints_name_its_own_options(instrument):
    """The fit's notes (fixed=, n_starts=, init=) printed by a campaign, which has none of
    those options: every option they name is the campaign's, or gonio fit's after its name."""
    from gonio.cli import build_parser
    from gonio.cli.campaign import campaign_text
    from gonio.fit.core import _chi2_note, _identifiability_note
    from gonio.hints import _HINT

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices
    mine = {s for a in sub["campaign"]._actions for s in a.option_strings}
    fits = {s for a in sub["fit"]._actions for s in a.option_strings}
    text = "warning: x" + _chi2_note(50.0, True) + _identifiability_note(False, ["k.rho"])
    assert _HINT.search(text)  # the library's keyword hints
    got = campaign_text(text, instrument)
    assert not _HINT.search(got), got
    fit_named, named = _options_named(got)
    assert named and named <= mine and fit_named == {"--fixed", "--starts", "--init"} <= fits
    assert ("--model" in named) == (instrument == "lbl")  # Cornell fits li_torrance only
    assert "(k.rho unconstrained)" in got


def test_an_unidentifiable_campaign_prints_hints_in_option_syntax(tmp_path, capsys):
    rc = main(["campaign", "--model", "lambert+lambert", "--angles", "30", "--rotations", "0",
               "--no-plots", "--preset", "ideal", "--out", str(tmp_path / "ll")])  # fmt: skip
    text = capsys.readouterr().out
    assert rc == 0 and "warning: not identifiable" in text
    assert "fit a --model with fewer free parameters" in text
    assert "fixed=" not in text and "n_starts=" not in text and "init=" not in text


def test_a_cornell_campaign_refuses_another_campaigns_folder_without_overwrite(
    tmp_path, capsys, monkeypatch
):
    """As the LBL campaign: a re-run of the same settings replaces the results, one of other
    settings (another material here) needs overwrite, and a folder of results without a
    plan.json too; the command line passes --overwrite on."""
    from gonio.campaign import cornell

    out = tmp_path / "c"
    small = dict(plan="incidence", plan_kw={"theta_i_deg": (30.0,)}, max_geometries=8,
                 fit=False, budget=False, effects=None, noise=False, out=out)  # fmt: skip
    cornell.run_cornell_campaign("laser_paper", **small)
    cornell.run_cornell_campaign("laser_paper", **small)  # the same settings: replaced
    with pytest.raises(ValueError, match="holds the results of another campaign") as exc:
        cornell.run_cornell_campaign("garnet_red_paint", **small)
    assert "material: 'laser_paper' vs 'garnet_red_paint'" in str(exc.value)
    assert "--overwrite" in str(exc.value)
    assert json.loads((out / "plan.json").read_text())["material"] == "laser_paper"
    assert (out / "samples.csv").is_file()  # nothing of the refused run's
    cornell.run_cornell_campaign("garnet_red_paint", **small, overwrite=True)
    assert json.loads((out / "plan.json").read_text())["material"] == "garnet_red_paint"
    (out / "plan.json").unlink()
    with pytest.raises(ValueError, match=r"without a plan\.json"):
        cornell.run_cornell_campaign("garnet_red_paint", **small)
    # the command line: refused without --overwrite (exit 2), passed on with it
    base = ["campaign", "--instrument", "cornell", "--quiet", "--out", str(out)]
    assert main(base) == 2 and "--overwrite" in capsys.readouterr().err
    seen = {}

    def fake(material, **kw):
        seen.update(kw)
        return {"converged": True}

    monkeypatch.setattr(cornell, "run_cornell_campaign", fake)
    assert main([*base, "--overwrite"]) == 0 and seen["overwrite"] is True
