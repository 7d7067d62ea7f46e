"""Shape-checked readers (issue 30, 5): every JSON/TOML file gonio writes and reads back, given
a random or mutated document, gives a result or a one-line ``ValueError`` naming the file,
never another exception (property tests), and refuses deep nesting."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gonio.io import jsonfile

DIR = Path(tempfile.mkdtemp(prefix="gonio-jsonfile-"))

scalars = (st.none() | st.booleans() | st.integers(-(2**70), 2**70)
           | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8))  # fmt: skip
values = st.recursive(
    scalars,
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
    max_leaves=16,
)


def _mutate(doc, data):
    """``doc`` with one value somewhere replaced by a random one, or one key removed."""
    if isinstance(doc, dict) and doc and data.draw(st.booleans()):
        key = data.draw(st.sampled_from(sorted(doc)))
        doc = dict(doc)
        action = data.draw(st.sampled_from(["replace", "delete", "descend"]))
        if action == "delete":
            del doc[key]
        elif action == "replace":
            doc[key] = data.draw(values)
        else:
            doc[key] = _mutate(doc[key], data)
        return doc
    if isinstance(doc, list) and doc and data.draw(st.booleans()):
        k = data.draw(st.integers(0, len(doc) - 1))
        doc = list(doc)
        doc[k] = _mutate(doc[k], data)
        return doc
    return data.draw(values) if data.draw(st.booleans()) else doc


# --------------------------------------------------------------------------- the readers
def _calibration(path):
    from gonio.calibration.laboratory import read_calibration

    return read_calibration(path)


def _done(path):
    from gonio.campaign import folder

    return folder.load_group(path.parent, {"group": "t30.00"})  # frames or None, never raises


def _plan(path):
    from gonio.campaign import folder

    return folder._old_plan(path, None)


def _fit(path):
    from gonio.cli.export import _model

    return _model(argparse.Namespace(fit=str(path), model=None, param=[]))


def _sweep(path):
    from gonio.campaign.sweep import load_spec

    return load_spec(path)


def _summary(path):
    from gonio.campaign.sweep import read_summary

    return read_summary(path.parent)


def _lens(path):
    from gonio.calibration.reduce import load_lens

    return load_lens(path)


def _sidecar(path):
    from gonio.io.images import read_metadata

    return read_metadata(path.with_name(path.name.removesuffix(".json")))


def _lbl_plan(path):
    from gonio.campaign.plan import read_plan_file

    return read_plan_file(path)


def _lens_doc():
    from gonio.simulator.lenses import FisheyeLens

    return {
        "lens": FisheyeLens(
            model="equidistant", width=64, height=48, fx=20.0, fy=20.0, cx=31.5, cy=23.5
        ).to_dict()
    }


def _plan_doc():
    from gonio.campaign import Plan

    return Plan(theta_i_deg=(30.0,), rotations_deg=(0.0,)).to_dict()


SEEDS = {
    "calibration.json": (_calibration, lambda: {"kind": "gonio.lab_calibration",
                                                "lens": _lens_doc()["lens"], "info": {}}),
    "done.json": (_done, lambda: {"files": {"standard": ["standard_00.tif"]},
                                  "made_by": {"group": "t30.00"}}),
    "plan.json": (_plan, _plan_doc),
    "fit.json": (_fit, lambda: {"model": "ward", "params": {"rho_d": 0.2, "rho_s": 0.05,
                                                             "alpha_x": 0.1, "alpha_y": 0.1}}),
    "spec.json": (_sweep, lambda: {"task": "fit_preset", "materials": ["rolled_brass"],
                                   "seeds": 2, "settings": {"noise": [0.01]},
                                   "fixed": {"n_samples": 300}}),
    "sweep_task.json": (_summary, lambda: {"complete": True, "task": {"a": 1}}),
    "lens.json": (_lens, _lens_doc),
    "designed_plan.json": (_lbl_plan, lambda: {"instrument": "lbl", "theta_i_deg": [10.0, 40.0],
                                               "rotations_deg": [0.0, 90.0],
                                               "restandard_every": 0}),
    "m.tif.json": (_sidecar, lambda: {"exposure_s": 0.01, "f_number": 8.0, "sensor": {
        "adc_bits": 12, "response_gamma": 1.0, "response": "linear"}}),
}  # fmt: skip


def _check(name, text):
    reader = SEEDS[name][0]
    d = DIR / name.split(".")[0]
    d.mkdir(exist_ok=True)
    path = d / name
    path.write_text(text)
    try:
        reader(path)
    except ValueError as exc:
        assert "\n" not in str(exc), str(exc)
        assert str(exc)


@pytest.mark.parametrize("name", sorted(SEEDS))
def test_the_seed_documents_read(name):
    _check(name, json.dumps(SEEDS[name][1]()))
    path = DIR / name.split(".")[0] / name
    got = SEEDS[name][0](path)  # no error for a well-formed document
    assert (got is None) == (name == "done.json")  # (its frames are absent: taken again)


@pytest.mark.parametrize("name", sorted(SEEDS))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(doc=values)
def test_a_random_document_gives_a_result_or_a_value_error(name, doc):
    _check(name, json.dumps(doc))


@pytest.mark.parametrize("name", sorted(SEEDS))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_mutated_document_gives_a_result_or_a_value_error(name, data):
    _check(name, json.dumps(_mutate(SEEDS[name][1](), data)))


@pytest.mark.parametrize("name", sorted(SEEDS))
def test_deep_nesting_is_refused(name):
    for text in ("[" * 900 + "]" * 900, '{"a":' * 900 + "1" + "}" * 900):
        _check(name, text)
    if name in ("calibration.json", "plan.json", "lens.json", "spec.json", "fit.json"):
        with pytest.raises(ValueError, match="nested deeper"):
            SEEDS[name][0](DIR / name.split(".")[0] / name)


def test_a_deep_toml_spec_is_refused(tmp_path):
    from gonio.campaign.sweep import load_spec

    p = tmp_path / "s.toml"
    p.write_text("a = " + "[" * 200 + "]" * 200 + "\n")
    with pytest.raises(ValueError, match=r"nested deeper|not valid TOML"):
        load_spec(p)


def test_get_refuses_a_boolean_for_a_number():
    with pytest.raises(jsonfile.FileFormatError, match="'x'"):
        jsonfile.get_number({"x": True}, "x", "f")
    assert jsonfile.get_number({"x": 2}, "x", "f", lo=0, hi=3) == 2
    with pytest.raises(jsonfile.FileFormatError, match="non-standard number"):
        jsonfile.loads('{"x": NaN}', "f")


def test_to_json_writes_numpy_values_and_paths_and_refuses_nan(tmp_path):
    import json
    from pathlib import Path

    import numpy as np
    import pytest

    from gonio.io.jsonfile import read_json, to_json, write_json

    obj = {"a": np.arange(3), "b": np.float32(0.5), "c": np.int64(7), "p": Path("x/y")}
    assert json.loads(to_json(obj)) == {"a": [0, 1, 2], "b": 0.5, "c": 7, "p": "x/y"}
    with pytest.raises(ValueError):
        to_json({"x": float("nan")})
    with pytest.raises(TypeError, match="set is not JSON serialisable"):
        to_json({"x": {1, 2}})
    out = write_json(tmp_path / "o.json", obj)
    assert read_json(out) == {"a": [0, 1, 2], "b": 0.5, "c": 7, "p": "x/y"}
    assert [p.name for p in tmp_path.iterdir()] == ["o.json"]  # no temporary left
