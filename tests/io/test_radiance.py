"""Tests of the Radiance plastic2/metal2 export of Ward fits."""

from __future__ import annotations

import pytest

from gonio import materials
from gonio.io import radiance


def test_plastic2_maps_rho_d_through_one_minus_spec():
    p = materials.info("varnished_plywood")["params"]
    text = radiance.ward_material(p, "plastic2", "plywood")
    m = radiance.parse_material(text)
    assert m["type"] == "plastic2" and m["name"] == "plywood" and m["u"] == [1.0, 0.0, 0.0]
    assert m["spec"] == pytest.approx(0.025)
    # Radiance: diffuse = color * (1 - spec)
    assert m["color"][0] * (1 - m["spec"]) == pytest.approx(0.33, rel=1e-9)
    assert (m["urough"], m["vrough"]) == (0.04, 0.11)


def test_metal2_specular_is_coloured_by_the_material():
    p = materials.info("rolled_brass")["params"]
    m = radiance.parse_material(radiance.ward_material(p, "metal2", "brass"))
    assert m["color"] == pytest.approx([0.43] * 3)
    assert m["color"][0] * m["spec"] == pytest.approx(0.33, rel=1e-9)
    assert m["color"][0] * (1 - m["spec"]) == pytest.approx(0.1, rel=1e-9)


@pytest.mark.parametrize("name", ["rolled_brass", "white_ceramic_tile", "varnished_plywood"])
def test_round_trip_through_the_material_text(name):
    info = materials.info(name)
    mtype = radiance.material_type_for(info["class"])
    back = radiance.ward_params(radiance.ward_material(info["params"], mtype))
    for k, v in info["params"].items():
        assert back[k] == pytest.approx(v, rel=1e-8)


def test_material_type_for_class():
    assert radiance.material_type_for("metal") == "metal2"
    assert radiance.material_type_for("dielectric") == "plastic2"
    with pytest.raises(ValueError):
        radiance.material_type_for("")


def test_write_material_atomic(tmp_path):
    p = radiance.write_material(tmp_path / "m.rad", "void plastic2 x\n")
    assert p.read_text() == "void plastic2 x\n"
    assert [q.name for q in tmp_path.iterdir()] == ["m.rad"]


def test_bad_inputs():
    p = dict(rho_d=0.3, rho_s=0.05, alpha_x=0.1, alpha_y=0.1)
    with pytest.raises(ValueError, match="material_type"):
        radiance.ward_material(p, "plastic")
    with pytest.raises(ValueError, match="name"):
        radiance.ward_material(p, "plastic2", "has space")
    with pytest.raises(ValueError, match="missing"):
        radiance.ward_material({"rho_d": 0.1}, "plastic2")
    with pytest.raises(ValueError, match="alpha"):
        radiance.ward_material({**p, "alpha_x": 0.0}, "plastic2")
    with pytest.raises(ValueError, match="exceeds 1"):
        radiance.ward_material({**p, "rho_d": 0.98}, "plastic2")
    with pytest.raises(ValueError, match="grey"):
        radiance.ward_material({**p, "rho_s": [0.1, 0.2, 0.1]}, "plastic2")
    with pytest.raises(ValueError, match="one spec"):
        radiance.ward_material({**p, "rho_s": [0.1, 0.2, 0.1]}, "metal2")
    with pytest.raises(ValueError, match="6 real"):
        radiance.parse_material("void plastic2 x 4 1 0 0 . 0 5 1 1 1 0 0")
