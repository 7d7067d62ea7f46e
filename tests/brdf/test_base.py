import numpy as np
import pytest

from gonio import brdf, materials


def test_registry_and_dispatch_errors():
    assert {"lambert", "ward", "ward_approx"} <= set(brdf.names())
    with pytest.raises(ValueError, match=r"registered models are: .*ward"):
        brdf.create("no_such_model")
    with pytest.raises(ValueError, match="alpha_x"):
        brdf.create("ward", alpha_x=-1.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        brdf.create("ward", alpha=0.1)
    with pytest.raises(ValueError, match="rho_d"):
        brdf.create("ward", rho_d=float("nan"))
    s = brdf.spec("ward")
    assert list(s.params) == ["rho_d", "rho_s", "alpha_x", "alpha_y"]
    assert s.bounds["alpha_x"][0] > 0
    assert "diverges" in s.known_issues[0]


def test_bad_directions():
    m = brdf.create("ward")
    with pytest.raises(ValueError, match=r"wi must have shape \(\.\.\., 3\)"):
        m(np.zeros((4, 2)), [0, 0, 1.0])
    with pytest.raises(ValueError, match="wo contains 1 non-finite"):
        m([0, 0, 1.0], [0, np.nan, 1.0])
    with pytest.raises(ValueError, match="do not broadcast"):
        m(np.ones((4, 3)) / 3**0.5, np.ones((5, 3)) / 3**0.5)


def test_ward_at_normal_matches_eq4_by_hand():
    m = materials.get("rolled_brass")
    v = m([0, 0, 1.0], [0, 0, 1.0])
    assert v == pytest.approx(0.10 / np.pi + 0.33 / (4 * np.pi * 0.05 * 0.16), rel=1e-14)


def test_lambert_albedo_analytic_equals_quadrature():
    m = brdf.create("lambert", rho=0.7)
    wi = np.array([[0, 0, 1.0], [0.6, 0, 0.8], [0, 0, -1.0]])
    np.testing.assert_allclose(m.albedo(wi), [0.7, 0.7, 0.0])
    q = [m._quadrature_albedo(w, 1e-8) for w in wi]
    np.testing.assert_allclose(q, [0.7, 0.7, 0.0], rtol=1e-10)


def test_sum_and_callable():
    lam = brdf.create("lambert", rho=0.2)
    w = brdf.create("ward", rho_d=0.0, rho_s=0.1)
    s = lam + w
    wi, wo = np.array([0.3, 0.1, 0.9486832980505138]), np.array([-0.2, 0.0, 0.9797958971132712])
    assert s(wi, wo) == pytest.approx(lam(wi, wo) + w(wi, wo))
    assert set(s.params) == {
        "lambert.rho",
        "ward.rho_d",
        "ward.rho_s",
        "ward.alpha_x",
        "ward.alpha_y",
    }
    s2 = s.with_params(**{"lambert.rho": 0.4})
    assert s2.params["lambert.rho"] == 0.4
    c = brdf.as_brdf(lambda a, b: np.full(np.broadcast_shapes(a.shape, b.shape)[:-1], 0.1))
    assert c(wi, [0, 0, -1.0]) == 0.0 and c(wi, wo) == pytest.approx(0.1)
    bad = brdf.as_brdf(lambda a, b: np.nan * a[..., 0])
    with pytest.raises(ValueError, match="non-finite"):
        bad(wi, wo)


def test_materials_presets():
    assert len(materials.names("ward")) >= 10 + 18
    rec = materials.info("rolled_brass")
    assert rec["source"].startswith("Ward 1992")
    with pytest.raises(ValueError, match="unknown material"):
        materials.get("unobtainium")


_WI = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
_WO = np.array([-np.sin(0.6), 0.0, np.cos(0.6)])


@pytest.mark.parametrize("name", [n for n in brdf.names() if n not in ("tabulated", "measured")])
def test_every_model_refuses_non_unit_directions(name):
    # issue 15 item 3: ward at 10 wi gave 0.032 instead of 3.82, cook_torrance 1e-10
    m = brdf.create(name)
    assert np.isfinite(m(_WI, _WO)).all()
    for wi, wo in ((10 * _WI, _WO), (_WI, 0.5 * _WO), (np.zeros(3), _WO)):
        with pytest.raises(ValueError, match="unit vectors"):
            m(wi, wo)
    batch_wi = np.stack([_WI, _WI, 1.01 * _WI])
    with pytest.raises(ValueError, match=r"1 of 3 are not, e\.g\. wi\[2\]"):
        m(batch_wi, np.stack([_WO] * 3))
    with pytest.raises(ValueError, match="unit vectors"):
        m.albedo(3 * _WI)
    with pytest.raises(ValueError, match="unit vectors"):
        m.delta(3 * _WI)


def test_unit_tolerance_accepts_float32_directions():
    w32 = (_WI.astype(np.float32)).astype(np.float64)
    m = brdf.create("ward")
    assert m(w32, _WO) == pytest.approx(m(_WI, _WO), rel=1e-5)
