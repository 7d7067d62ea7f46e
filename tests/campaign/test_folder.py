"""The results folder (issue 15 items 1 and 9): what made every group is checked on resume,
the folder is locked while a campaign writes it, leftovers and partial output are removed."""

from __future__ import annotations

import json

import pytest

from gonio import campaign
from gonio.campaign import folder
from gonio.cli import main

ONE = dict(theta_i_deg=(30.0,), rotations_deg=(0.0,), plots=False)


@pytest.fixture(scope="module")
def brass(tmp_path_factory):
    out = tmp_path_factory.mktemp("brass")
    return campaign.run(campaign.Plan(**ONE), out), out


def test_resume_never_reports_another_material_or_seed(tmp_path, brass):
    import shutil

    for other in (dict(material="varnished_plywood"), dict(seed=8)):
        out = tmp_path / str(sorted(other.values())[0])
        shutil.copytree(brass[1], out)
        plan = campaign.Plan(**ONE, **other)
        # the sequence: a run of the other plan without --resume, killed at start
        # (it has rewritten plan.json, the finished groups are still there), then --resume
        folder.check_out(out, plan.resolved(), resume=False, overwrite=True)
        res = campaign.run(plan, out, resume=True)
        assert res.summary["n_captures"]["resumed_groups"] == 0
        fresh = campaign.run(plan, tmp_path / f"fresh{len(other)}{res.plan.seed}")
        assert res.fit.params == fresh.fit.params
        done = json.loads((out / "raw" / "t30.00" / "done.json").read_text())
        assert done["made_by"]["material"] == plan.material
        assert done["made_by"]["seed"] == plan.seed


def test_resume_of_the_same_plan_loads_every_group(tmp_path, brass):
    import shutil

    shutil.copytree(brass[1], tmp_path / "again")
    res = campaign.run(campaign.Plan(**ONE), tmp_path / "again", resume=True)
    assert res.summary["n_captures"]["resumed_groups"] == 2
    assert res.fit.params == brass[0].fit.params


def test_a_second_campaign_into_a_locked_folder_is_refused(tmp_path):
    with folder.locked(tmp_path), pytest.raises(folder.FolderBusy, match="in use by another"):
        campaign.run(campaign.Plan(**ONE), tmp_path)
    assert not (tmp_path / "plan.json").exists()
    with folder.locked(tmp_path):  # released: the next holder gets it
        pass


def test_opening_the_folder_removes_an_earlier_runs_leftovers(tmp_path):
    plan = campaign.Plan(**ONE).resolved()
    stale = tmp_path / "raw" / "t70.00_r000.0"
    stale.mkdir(parents=True)
    (stale / "done.json").write_text("{}")
    tmp = tmp_path / "raw" / "t30.00" / ".measured_03.tif.k2j3h4.tmp"
    tmp.parent.mkdir(parents=True)
    tmp.write_bytes(b"half")
    (tmp_path / "samples.csv").write_text("old")
    keep = tmp_path / "notes.txt"
    keep.write_text("mine")
    folder.check_out(tmp_path, plan, resume=True)
    assert not stale.exists() and not tmp.exists() and not (tmp_path / "samples.csv").exists()
    assert keep.read_text() == "mine" and (tmp_path / "plan.json").is_file()


def test_a_failed_fit_leaves_no_derived_output(tmp_path, monkeypatch):
    def broken(*a, **k):
        raise ValueError("fit exploded")

    monkeypatch.setattr(campaign.lbl, "_fit", broken)
    with pytest.raises(ValueError, match="fit exploded"):
        campaign.run(campaign.Plan(**ONE), tmp_path / "lbl")
    assert not (tmp_path / "lbl" / "samples.csv").exists()
    assert len(list((tmp_path / "lbl").glob("raw/*/done.json"))) == 2  # the captures stay

    from gonio.campaign import cornell

    monkeypatch.setattr(cornell, "fit_li_torrance", broken)
    with pytest.raises(ValueError, match="fit exploded"):
        cornell.run_cornell_campaign(out=tmp_path / "cornell", max_geometries=20)
    assert not (tmp_path / "cornell" / "samples.csv").exists()
    assert not (tmp_path / "cornell" / "samples.astm").exists()  # (its ASTM table too)


def test_refused_options_write_nothing(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:  # (refused as the options are parsed)
        main(["campaign", "--workers", "0", "--angles", "30", "--out", str(tmp_path / "w")])
    assert exc.value.code == 2 and "workers" in capsys.readouterr().err
    assert not (tmp_path / "w" / "plan.json").exists()


def test_cornell_samples_of_two_identical_runs_are_identical_bytes(tmp_path):
    from gonio.campaign.cornell import run_cornell_campaign

    for name in ("a", "b"):
        run_cornell_campaign(out=tmp_path / name, max_geometries=20, fit=False)
    assert (tmp_path / "a" / "samples.csv").read_bytes() == (
        tmp_path / "b" / "samples.csv"
    ).read_bytes()


# ----------------------------------------------------------------------------- issue 30, 1
@pytest.mark.parametrize(
    "other",
    [
        dict(instrument_seed=5),
        dict(binning=(108, 80)),
        dict(d_over_r=0.05),
        dict(restandard_every=1),
        dict(preset="ideal"),
    ],
)
def test_resume_refuses_a_plan_of_another_instrument(tmp_path, other):
    folder.check_out(tmp_path, campaign.Plan(**ONE).resolved(), resume=False)
    with pytest.raises(ValueError, match=f"cannot resume.*{next(iter(other))}"):
        folder.check_out(tmp_path, campaign.Plan(**ONE, **other).resolved(), resume=True)


def test_the_group_record_holds_every_field_that_shapes_a_frame():
    plan = campaign.Plan(**ONE).resolved()
    rec = folder.group_record(plan, "t30.00", 1, 30.0, None, ["standard", "background"])
    frame = set(plan.to_dict()) - folder.NOT_FRAME_FIELDS
    assert frame <= set(rec)
    assert {"instrument_seed", "binning", "d_over_r", "restandard_every", "preset"} <= frame
    assert rec["theta_i_deg"] == 30.0 and rec["kinds"] == ["background", "standard"]
    assert rec["gonio"] == folder.code_version() and "+" in rec["gonio"]


def test_resume_never_reuses_groups_of_another_instrument(tmp_path, brass):
    import shutil

    out = tmp_path / "other"
    shutil.copytree(brass[1], out)
    plan = campaign.Plan(**ONE, instrument_seed=5)
    # a run of the other instrument killed at start (plan.json rewritten), then --resume
    folder.check_out(out, plan.resolved(), resume=False, overwrite=True)
    res = campaign.run(plan, out, resume=True)
    assert res.summary["n_captures"]["resumed_groups"] == 0
    done = json.loads((out / "raw" / "t30.00" / "done.json").read_text())
    assert done["made_by"]["instrument_seed"] == 5


def test_a_group_of_another_exact_angle_is_taken_again(brass):
    plan = brass[0].plan
    d = brass[1] / "raw" / "t30.00"
    rec = json.loads((d / "done.json").read_text())["made_by"]
    assert folder.load_group(d, rec) is not None
    assert folder.load_group(d, {**rec, "theta_i_deg": 30.001}) is None
    assert folder.load_group(d, {**rec, "kinds": ["background", "restandard", "standard"]}) is None
    assert plan.theta_i_deg == (30.0,)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(theta_i_deg=(10.0, 10.001)), "share the raw group folder 't10.00'"),
        (dict(rotations_deg=(0.0, 360.0)), "equal modulo 360"),
        (dict(rotations_deg=(90.0, -270.0)), "equal modulo 360"),
        (dict(rotations_deg=(0.0, 0.02)), "share the raw group folder"),
    ],
)
def test_angles_that_would_share_a_group_folder_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        campaign.Plan(**{**ONE, **kw}).resolved()


def test_the_default_group_names_are_unchanged():
    plan = campaign.Plan().resolved()
    assert folder.group_key(plan.theta_i_deg[1]) == "t04.00"
    assert folder.group_key(12.0, 45.0) == "t12.00_r045.0"


# ----------------------------------------------------------------------------- issue 30, 2
def test_a_refused_resume_deletes_nothing(tmp_path, brass):
    import shutil

    out = tmp_path / "kept"
    shutil.copytree(brass[1], out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    plan = campaign.Plan(**ONE, calibration=str(tmp_path / "mistyped"))
    with pytest.raises((ValueError, OSError)):
        campaign.run(plan, out, resume=True)
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert after == before and "samples.csv" in after and "summary.json" in after


@pytest.mark.parametrize(
    "kw", [dict(workers=0), dict(plan=campaign.Plan(**ONE, calibration="/nonexistent/cal"))]
)
def test_a_refused_run_leaves_no_trace(tmp_path, kw):
    out = tmp_path / "new" / "deeper"
    with pytest.raises((ValueError, OSError)):
        campaign.run(kw.pop("plan", campaign.Plan(**ONE)), out, **kw)
    assert not (tmp_path / "new").exists()


def test_a_folder_refused_at_open_is_removed_if_the_run_made_it(tmp_path):
    out = tmp_path / "made"
    with pytest.raises(RuntimeError), folder.locked(out):
        raise RuntimeError("refused")
    assert not out.exists()
    with pytest.raises(RuntimeError), folder.locked(tmp_path):  # not made by it: kept
        raise RuntimeError("refused")
    assert tmp_path.is_dir()


def test_tidying_touches_only_gonios_names_in_gonios_folders(tmp_path):
    plan = campaign.Plan(**ONE).resolved()
    mine = tmp_path / "notes" / ".draft.k2j3h4.tmp"
    mine.parent.mkdir()
    mine.write_text("mine")
    ours = tmp_path / "raw" / "t30.00" / ".measured_00.tif.k2j3h4.tmp"
    ours.parent.mkdir(parents=True)
    ours.write_text("half")
    user_plot = tmp_path / "plots" / "mine.png"
    user_plot.parent.mkdir()
    user_plot.write_text("mine")
    (tmp_path / "plots" / "hemisphere.png").write_text("old")
    (tmp_path / "gonio_rolled_brass.cal").write_text("old")
    folder.check_out(tmp_path, plan, resume=False)
    assert mine.read_text() == "mine" and user_plot.read_text() == "mine"
    assert not ours.exists() and not (tmp_path / "plots" / "hemisphere.png").exists()
    assert not (tmp_path / "gonio_rolled_brass.cal").exists()


def test_a_rerun_without_plots_removes_the_old_plots(tmp_path, brass):
    import shutil

    out = tmp_path / "plots"
    shutil.copytree(brass[1], out)
    (out / "plots").mkdir()
    (out / "plots" / "residuals.png").write_bytes(b"old")
    folder.check_out(out, campaign.Plan(**ONE).resolved(), resume=True)
    assert not (out / "plots").exists()


def test_a_rerun_over_another_plans_results_needs_overwrite(tmp_path, capsys):
    folder.check_out(tmp_path, campaign.Plan(**ONE).resolved(), resume=False)
    other = campaign.Plan(**ONE, seed=3).resolved()
    with pytest.raises(ValueError, match="--overwrite"):
        folder.check_out(tmp_path, other, resume=False)
    folder.check_out(tmp_path, campaign.Plan(**ONE).resolved(), resume=False)  # same: fine
    folder.check_out(tmp_path, other, resume=False, overwrite=True)
    assert json.loads((tmp_path / "plan.json").read_text())["seed"] == 3
    argv = ["campaign", "--angles", "30", "--seed", "4", "--no-plots", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "--overwrite" in capsys.readouterr().err
