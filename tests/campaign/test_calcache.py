"""The calibration cache: a made calibration read by the next campaign of the same
instrument, never by another's."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from gonio import campaign
from gonio.campaign import calcache
from gonio.campaign import calibrate as calibrate_mod

SMALL = dict(theta_i_deg=(30.0,), rotations_deg=(0.0,), plots=False)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GONIO_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "calibrations"


def _refuse(*args, **kwargs):
    raise AssertionError("calibrated anew")


def test_cache_dir_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("GONIO_CACHE_DIR", str(tmp_path / "a"))
    assert calcache.cache_dir() == tmp_path / "a" / "calibrations"
    monkeypatch.delenv("GONIO_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert calcache.cache_dir() == tmp_path / "x" / "gonio" / "calibrations"


def test_the_key_changes_with_every_input():
    inputs = {"nominal_mirror": {"radius": 0.15}, "seed": 0, "certificate": {"rho": 0.99}}
    key, made_of = calcache.calibration_key("abc/eq3/0", inputs)
    assert calcache.calibration_key("abc/eq3/0", dict(inputs)) == (key, made_of)
    assert made_of["code"] == calcache.code_digest() and made_of["versions"]["numpy"]
    others = [
        calcache.calibration_key("abd/eq3/0", inputs)[0],
        calcache.calibration_key("abc/eq3/0", {**inputs, "seed": 1})[0],
        calcache.calibration_key("abc/eq3/0", {**inputs, "nominal_mirror": {"radius": 0.1501}})[0],
        calcache.calibration_key("abc/eq3/0", {**inputs, "certificate": {"rho": 0.98}})[0],
    ]
    assert len({key, *others}) == 5


def test_an_entry_is_served_only_to_its_own_key_file(cache):
    from gonio.calibration.laboratory import LabCalibration

    lab = LabCalibration(info={"instrument": "abc/eq3/0"})
    key, made_of = calcache.calibration_key("abc/eq3/0", {"seed": 0})
    assert calcache.load(key, made_of) is None  # nothing kept yet
    assert calcache.store(key, made_of, lab)
    got = calcache.load(key, made_of)
    assert got is not None and got.to_dict() == lab.to_dict()
    # another instrument's inputs under this key (a collision, an edited file): not served
    assert calcache.load(key, {**made_of, "instrument": "abd/eq3/0"}) is None
    (cache / key / "calibration.json").write_text("{not json")  # a damaged entry: a miss
    assert calcache.load(key, made_of) is None


def test_the_next_campaign_of_the_instrument_reads_the_kept_calibration(
    cache, tmp_path, monkeypatch
):
    first = campaign.run(campaign.Plan(**SMALL, seed=4), tmp_path / "a", workers=1)
    (entry,) = cache.iterdir()  # one calibration kept
    assert (
        json.loads((entry / "key.json").read_text())["instrument"]
        == (first.summary["calibration"]["instrument"])
    )
    monkeypatch.setattr(calibrate_mod, "laboratory_calibration", _refuse)
    second = campaign.run(campaign.Plan(**SMALL, seed=4), tmp_path / "b", workers=1)
    assert second.summary["calibration"] == first.summary["calibration"]
    assert first.summary["calibration"]["cache"] == {"key": entry.name[:20]}
    for f in ("calibration/calibration.json", "samples.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    np.testing.assert_array_equal(second.samples.value, first.samples.value)
    # another realisation of the instrument is calibrated anew, not served this one's
    with pytest.raises(AssertionError, match="calibrated anew"):
        campaign.run(campaign.Plan(**SMALL, seed=4, instrument_seed=5), workers=1)
    # without the cache nothing is read (nor kept)
    with pytest.raises(AssertionError, match="calibrated anew"):
        campaign.run(campaign.Plan(**SMALL, seed=4), workers=1, calibration_cache=False)


def test_no_cache_keeps_nothing_and_the_summary_has_no_key(cache):
    res = campaign.run(campaign.Plan(**SMALL, seed=4), workers=1, calibration_cache=False)
    assert not cache.exists()
    assert "cache" not in res.summary["calibration"]


def test_the_oldest_entries_beyond_the_limit_are_removed(cache, monkeypatch):
    from gonio.calibration.laboratory import LabCalibration

    monkeypatch.setattr(calcache, "MAX_ENTRIES", 3)
    keys = []
    for k in range(5):
        key, made_of = calcache.calibration_key(f"inst{k}/eq3/0", {})
        assert calcache.store(key, made_of, LabCalibration(info={"k": k}))
        os.utime(cache / key, (1000.0 + k, 1000.0 + k))  # stored one after the other
        keys.append(key)
    assert sorted(p.name for p in cache.iterdir()) == sorted(keys[2:])


def test_the_budgets_direction_fields_are_kept_with_the_calibration(cache, tmp_path, monkeypatch):
    """The first campaign of an instrument adds its budget's direction fields to the
    calibration's entry; the next reads them instead of tracing the dome figures again,
    with the same budget to the bit. A damaged or foreign fields file is not served."""
    from gonio.campaign import budget_terms

    first = campaign.run(campaign.Plan(**SMALL, seed=4), tmp_path / "a", workers=1)
    (entry,) = cache.iterdir()
    assert (entry / calcache.FIELDS_FILE).is_file()
    key, made_of = entry.name, json.loads((entry / calcache.KEY_FILE).read_text())
    lab = calcache.load(key, made_of)
    assert calcache.has_fields(lab)
    fields = budget_terms.direction_fields(lab)
    n_fig = sum(f[0].startswith("dome_figure[") for f in fields)
    assert n_fig == budget_terms.FIGURE_REALISATIONS

    def refuse(*args, **kwargs):
        raise AssertionError("figures traced anew")

    monkeypatch.setattr(budget_terms, "_figure_fields", refuse)
    second = campaign.run(campaign.Plan(**SMALL, seed=4), tmp_path / "b", workers=1)
    assert second.summary["budget"] == first.summary["budget"]
    # one row for the dome figure's realisations: their root sum of squares
    assert "dome_figure" in first.summary["budget"]["terms"]
    assert not any(t.startswith("dome_figure[") for t in first.summary["budget"]["terms"])
    # a fields file that is not one (damaged, or of other shapes): read as none
    (entry / calcache.FIELDS_FILE).write_bytes(b"not an npz")
    assert not calcache.has_fields(calcache.load(key, made_of))
    assert not calcache.store_fields(key, {**made_of, "seed": "other"}, fields)
    assert calcache.store_fields(key, made_of, fields)
    again = calcache.load(key, made_of)
    for a, b in zip(budget_terms.direction_fields(again), fields, strict=True):
        assert a[0] == b[0] and a[1] == b[1] and a[2] == b[2] and a[4] == b[4]
        np.testing.assert_array_equal(a[3], b[3])
