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
        folder.check_out(out, plan.resolved(), resume=False)
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


def test_refused_options_write_nothing(tmp_path, capsys):
    assert main(["campaign", "--workers", "0", "--angles", "30", "--out", str(tmp_path / "w")]) == 2
    assert "workers" in capsys.readouterr().err
    assert not (tmp_path / "w" / "plan.json").exists()


def test_cornell_samples_of_two_identical_runs_are_identical_bytes(tmp_path):
    from gonio.campaign.cornell import run_cornell_campaign

    for name in ("a", "b"):
        run_cornell_campaign(out=tmp_path / name, max_geometries=20, fit=False)
    assert (tmp_path / "a" / "samples.csv").read_bytes() == (
        tmp_path / "b" / "samples.csv"
    ).read_bytes()
