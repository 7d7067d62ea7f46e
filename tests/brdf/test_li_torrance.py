"""Tests of the Li-Torrance model (Li and Torrance 2005, eq. 3-14, 20-26) and its presets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio import brdf, materials
from gonio.brdf.li_torrance import (
    DEFAULT_WAVELENGTHS_NM,
    LiTorrance,
    shadowing,
    shadowing_shortcut_mask,
    smith_shadowing,
)
from gonio.geometry import sample_uniform_hemisphere, to_vector

PRESETS = [
    "aluminized_non_glare_glass",
    "aluminized_ground_glass",
    "garnet_red_paint",
    "laser_paper",
]


def _dirs(n, seed):
    return sample_uniform_hemisphere(n, seed)[0]


def test_default_create_and_spec():
    m = brdf.create("li_torrance")
    assert isinstance(m, LiTorrance)
    s = brdf.spec("li_torrance")
    assert {"k_dd", "k_udf", "k_uds", "k_fs", "sigma", "tau", "tau_x", "tau_y"} <= set(s.params)
    assert {"wavelength_nm", "f0", "n_ior", "d_omega_i"} <= set(s.params)
    assert s.params["k_dd"].spectral and s.params["sigma"].unit == "um"
    assert s.has_delta and not s.reciprocal
    v = m(to_vector(0.4, 0.0), to_vector(0.4, np.pi))
    assert np.isfinite(v) and v > 0


def test_eq6_against_smith_figure8():
    """Eq. 6 vs Smith's function for Figure 8's surface (σ = 0.5 μm, τ = 2.5 μm)."""
    th = np.radians(np.linspace(0.0, 85.0, 851))
    approx = shadowing(np.cos(th), 2.5 / 0.5)
    exact = smith_shadowing(th, 0.5, 2.5)
    diff = np.abs(approx - exact)
    # measured: 0.0342 at 82.1 deg; below 70 deg the relative error stays under 0.85 %
    assert diff.max() < 0.035
    assert (diff / exact)[th <= np.radians(70)].max() < 0.0086
    # Figure 8 plots S(θi) S(θr) against θr for several θi
    for ti in (0.0, 30.0, 60.0, 80.0):
        a = shadowing(np.cos(np.radians(ti)), 5.0) * approx
        b = smith_shadowing(np.radians(ti), 0.5, 2.5) * exact
        assert np.abs(a - b).max() < 0.04
    # both go to 1 at normal incidence and drop at grazing
    assert approx[0] == 1.0 and exact[0] == pytest.approx(1.0, abs=1e-12)
    assert approx[-1] < 0.7 and exact[-1] < 0.7


@pytest.mark.parametrize(
    "params",
    [
        dict(sigma=0.5, tau=2.5),
        dict(sigma=0.23, tau=9.9),
        dict(sigma=0.86, tau=4.99),
        dict(sigma=0.5, tau_x=2.5, tau_y=5.0),
    ],
)
def test_eq7_shortcut_changes_values_by_at_most_one_percent(params):
    base = dict(k_dd=1.0, k_uds=0.0, **params)
    fast = brdf.create("li_torrance", **base)
    slow = brdf.create("li_torrance", **base, shortcut=False)
    wi, wo = _dirs(20000, 1), _dirs(20000, 2)
    # add directions right at the thresholds, where the short-cut is worst
    k = params.get("tau", params.get("tau_x")) / params["sigma"]
    c = 1.0 - 0.005 ** (1.0 / k) + 1e-12
    edge = to_vector(np.arccos(c), np.linspace(0, 2 * np.pi, 50))
    wi = np.concatenate([wi, edge, edge])
    wo = np.concatenate([wo, edge[::-1], edge * [-1, -1, 1]])
    a, b = fast(wi, wo), slow(wi, wo)
    assert np.all(a >= b)
    rel_short = np.max((a - b) / np.where(a > 0, a, 1.0))
    # the paper's claim S > 0.99: the short-cut value is at most 1 % above the exact one
    assert rel_short < 0.01
    # relative to the exact value the bound is 1/0.995**2 - 1 = 1.0075 %
    assert np.max((a - b) / np.where(b > 0, b, 1.0)) <= 1 / 0.995**2 - 1 + 1e-12
    assert shadowing_shortcut_mask(wi[:, 2], wo[:, 2], k, k).any()


def test_cook_torrance_beckmann_equivalence_and_normalisation():
    """Eq. 9-10 with F = S = 1 equal Cook-Torrance with Beckmann slope 2σ/τ; albedo(0) = k_dd."""
    sigma, tau = 0.3, 6.0
    m = brdf.create(
        "li_torrance",
        k_dd=1.0,
        k_uds=0.0,
        f0=1.0,
        sigma=sigma,
        tau=tau,
        shadowing=False,
        effective_roughness=False,
        specular=False,
    )
    wi, wo = _dirs(5000, 3), _dirs(5000, 4)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    mb2 = (2 * sigma / tau) ** 2
    t2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / h[:, 2] ** 2
    d_b = np.exp(-t2 / mb2) / (np.pi * mb2 * h[:, 2] ** 4)
    ct = d_b / (4 * wi[:, 2] * wo[:, 2])
    np.testing.assert_allclose(m(wi, wo), ct, rtol=1e-12, atol=1e-300)
    assert m.albedo([0.0, 0.0, 1.0], rtol=1e-7) == pytest.approx(1.0, abs=1e-6)


def test_components_with_zero_coefficient_are_not_computed(monkeypatch):
    m = brdf.create("li_torrance", k_dd=0.0, k_uds=0.2, k_fs=0.0)
    assert m.components == ("uds",)

    def boom(*a, **k):
        raise AssertionError("computed a switched-off component")

    monkeypatch.setattr(LiTorrance, "_forward", boom)
    monkeypatch.setattr(LiTorrance, "_shadow", boom)
    v = m(_dirs(10, 5), _dirs(10, 6))
    assert np.all(v > 0)
    assert float(m([0, 0, 1.0], [0, 0, 1.0])) == pytest.approx(0.2 / np.pi * (1 - 0.04) ** 2)


def _reciprocal_models():
    return [
        brdf.create("li_torrance", k_dd=0.6, k_udf=0.1, k_uds=0.2),
        brdf.create("li_torrance", k_dd=0.6, k_uds=0.2, tau_x=2.0, tau_y=5.0),
        brdf.create("li_torrance", k_dd=0.9, sigma=0.23, tau=9.9, d_omega_i=0.01),
        materials.get("aluminized_ground_glass"),
    ]


unit = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def directions(draw):
    v = np.array([draw(unit), draw(unit), draw(st.floats(1e-9, 1.0))])
    return v / np.linalg.norm(v)


@given(directions(), directions())
def test_reciprocity_without_forward_scattering(a, b):
    for m in _reciprocal_models():
        x, y = m(a, b), m(b, a)
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-300)


def test_forward_scattering_is_not_reciprocal_as_printed():
    m = brdf.create("li_torrance", k_dd=0.0, k_uds=0.0, k_fs=1.0, sigma=0.7, tau=8.2)
    wi, wo = to_vector(np.radians(70), 0.0), to_vector(np.radians(30), np.pi)
    assert float(m(wi, wo)) != pytest.approx(float(m(wo, wi)), rel=1e-3)
    # forward lobe: peak at grazing forward reflection, nothing backwards (module docstring)
    th = np.radians(np.linspace(1, 89, 89))
    fwd = m(to_vector(np.radians(60), 0.0), to_vector(th, np.pi))
    back = m(to_vector(np.radians(60), 0.0), to_vector(th, 0.0))
    assert np.argmax(fwd) >= 70 and np.all(back == 0.0)


ADVERSARIAL = np.array(
    [
        [0.0, 0.0, 1.0],
        [np.cos(1e-9), 0.0, np.sin(1e-9)],
        [0.0, 1.0, 0.0],
        [0.6, 0.0, 0.8],
        [-0.6, 0.0, 0.8],
        [0.6, 0.0, -0.8],
        [0.0, 0.0, -1.0],
    ]
)


@pytest.mark.parametrize("name", PRESETS + [p + "_he_torrance" for p in PRESETS])
def test_presets_nonnegative_finite_and_zero_below_horizon(name):
    m = materials.get(name)
    wi = np.concatenate([_dirs(300, 7), ADVERSARIAL])
    wo = np.concatenate([_dirs(300, 8), ADVERSARIAL[::-1]])
    v = m(wi[:, None], wo[None, :])
    assert v.shape == (len(wi), len(wo), 31)
    assert np.isfinite(v).all() and (v >= 0).all()
    below = (wi[:, None, 2] <= 0) | (wo[None, :, 2] <= 0)
    assert np.all(v[below] == 0.0)
    _, rho = m.delta(wi)
    assert rho.shape == (len(wi), 31) and np.all(rho >= 0) and np.all(rho[wi[:, 2] <= 0] == 0)


def test_shapes_grey_and_spectral():
    grey = brdf.create("li_torrance")
    assert grey.wavelengths_nm is None and grey.n_bands is None
    assert grey(_dirs(4, 1), _dirs(4, 2)).shape == (4,)
    assert grey(_dirs(4, 1)[:, None], _dirs(5, 2)[None]).shape == (4, 5)
    assert grey([0, 0, 1.0], [0, 0, 1.0]).shape == ()
    spec = brdf.create("li_torrance", k_dd=np.linspace(0.2, 0.6, 31))
    np.testing.assert_array_equal(spec.wavelengths_nm, DEFAULT_WAVELENGTHS_NM)
    assert spec(_dirs(4, 1), _dirs(4, 2)).shape == (4, 31)
    three = brdf.create("li_torrance", k_dd=[0.5, 0.4, 0.3], wavelength_nm=[650, 550, 450])
    assert three(_dirs(4, 1), _dirs(4, 2)).shape == (4, 3)
    np.testing.assert_array_equal(three.wavelengths_nm, [650, 550, 450])
    # per-band values equal grey models band by band
    wi, wo = _dirs(50, 3), _dirs(50, 4)
    v = spec(wi, wo)
    for j in (0, 17, 30):
        g = brdf.create("li_torrance", k_dd=float(spec.params["k_dd"][j]))
        np.testing.assert_allclose(v[:, j], g(wi, wo), rtol=1e-13)


def test_anisotropic_reduces_to_isotropic_and_rotates():
    iso = brdf.create("li_torrance", k_fs=0.5, tau=3.0)
    same = brdf.create("li_torrance", k_fs=0.5, tau=1.0, tau_x=3.0, tau_y=3.0)
    wi, wo = _dirs(500, 11), _dirs(500, 12)
    np.testing.assert_allclose(iso(wi, wo), same(wi, wo), rtol=1e-14)
    a = brdf.create("li_torrance", k_fs=0.5, tau_x=2.5, tau_y=5.0)
    b = brdf.create("li_torrance", k_fs=0.5, tau_x=5.0, tau_y=2.5)
    assert a.is_anisotropic
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    np.testing.assert_allclose(a(wi, wo), b(wi @ rot.T, wo @ rot.T), rtol=1e-12)
    assert not np.allclose(a(wi, wo), iso(wi, wo))


def test_mirror_part_is_davies_and_redder_at_75_degrees():
    """§5.2.1: the specular peak of sample #45 appears at 75° and is larger in R than in B."""
    m = materials.get("aluminized_non_glare_glass")
    wi = to_vector(np.radians(75.0), 0.0)
    d, rho = m.delta(wi)
    np.testing.assert_allclose(d, to_vector(np.radians(75.0), np.pi), atol=1e-15)
    lam = m.wavelengths_nm * 1e-3
    ci = np.cos(np.radians(75.0))
    f = 0.91 + 0.09 * (1 - ci) ** 5
    np.testing.assert_allclose(rho, f * np.exp(-((4 * np.pi * 0.23 * ci / lam) ** 2)), rtol=1e-13)
    assert rho[-1] > 2 * rho[0]  # 700 nm vs 400 nm
    assert m.delta(to_vector(np.radians(30.0), 0.0))[1].max() < 1e-3
    # eq. 16's top hat carries the same reflectance
    box = brdf.create("li_torrance", **{**m.params, "d_omega_i": 0.0005})
    assert np.all(box.delta(wi)[1] == 0.0)
    alpha = np.arccos(1 - 0.0005 / (2 * np.pi))
    r = np.sqrt((np.arange(400) + 0.5) / 400) * alpha  # equal-area rings inside the cone
    phi = np.arange(400) * 2.399963229728653
    offs = np.stack([np.sin(r) * np.cos(phi), np.sin(r) * np.sin(phi), np.cos(r)], -1)
    c, s = np.cos(np.radians(75.0)), np.sin(np.radians(75.0))
    rot = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    wo = offs @ rot.T  # cone around the mirror direction (-sin75, 0, cos75)
    box_only = box(wi, wo) - m(wi, wo)
    integral = np.mean(box_only * wo[:, 2:3], axis=0) * 0.0005
    np.testing.assert_allclose(integral, rho, rtol=0.01)


def test_albedo_includes_mirror_part():
    m = materials.get("aluminized_non_glare_glass")
    wi = to_vector(np.radians(75.0), 0.0)
    a = m.albedo(wi, rtol=1e-5)
    cont = brdf.create("li_torrance", **{**m.params, "specular": False}).albedo(wi, rtol=1e-5)
    np.testing.assert_allclose(a - cont, m.delta(wi)[1], rtol=1e-9, atol=1e-12)
    # eq. 16 neglects S and lets k_dd scale both terms: at 75 deg its albedo exceeds 1 in the
    # red (measured 1.227 at 700 nm, 0.958 at 400 nm) -- a property of the constructed model
    assert a[0] < 1.0 < a[-1]
    box = brdf.create("li_torrance", **{**m.params, "d_omega_i": 0.0005})
    np.testing.assert_allclose(box.albedo(wi, rtol=1e-5), a, rtol=1e-12)


def test_presets_follow_tables_1_to_3():
    for name in PRESETS:
        rec = materials.info(name)
        assert rec["source"].startswith("Li and Torrance 2005")
        assert materials.info(name + "_he_torrance")["model"] == "li_torrance"
    band = {450: 5, 550: 15, 650: 25}
    gg = materials.get("aluminized_ground_glass").params
    assert (gg["sigma"], gg["tau"]) == (0.86, 4.99)
    assert [gg["k_udf"][band[w]] for w in (650, 550, 450)] == [0.33, 0.34, 0.32]
    assert [gg["k_dd"][band[w]] for w in (650, 550, 450)] == [0.45, 0.44, 0.44]
    gr = materials.get("garnet_red_paint").params
    assert (gr["sigma"], gr["tau"], gr["n_ior"]) == (0.7, 8.2, 1.7)
    assert [gr["k_uds"][band[w]] for w in (650, 550, 450)] == [0.10, 0.0, 0.0]
    assert [gr["k_fs"][band[w]] for w in (650, 550, 450)] == [1.1, 1.0, 1.2]
    grh = materials.get("garnet_red_paint_he_torrance").params
    assert (grh["sigma"], grh["tau"]) == (0.64, 8.2) and grh["k_fs"] == 0.0
    lp = materials.get("laser_paper").params
    assert (lp["sigma"], lp["tau"], lp["n_ior"]) == (0.39, 5.4, 1.5)
    assert [lp["k_fs"][band[w]] for w in (650, 550, 450)] == [1.9, 2.0, 1.7]
    ng = materials.get("aluminized_non_glare_glass")
    assert (ng.params["sigma"], ng.params["tau"], ng.params["k_dd"]) == (0.23, 9.9, 1.0)
    assert materials.get("aluminized_non_glare_glass_he_torrance").params["tau"] == 10.4
    # garnet red: the uniform diffuse exists only in R (table 2 discussion)
    m = materials.get("garnet_red_paint")
    no_uds = brdf.create("li_torrance", **{**m.params, "k_uds": 0.0})
    wi, wo = to_vector(0.3, 0.0), to_vector(0.3, 2.0)
    extra = m(wi, wo) - no_uds(wi, wo)
    assert extra[25] > 0.01 and extra[5] == 0.0 and extra[15] == 0.0


def test_bad_input():
    with pytest.raises(ValueError, match="k_dd"):
        brdf.create("li_torrance", k_dd=-0.1)
    with pytest.raises(ValueError, match="different lengths"):
        brdf.create("li_torrance", k_dd=np.ones(31) * 0.5, k_fs=np.ones(3))
    with pytest.raises(ValueError, match="wavelength_nm"):
        brdf.create("li_torrance", k_dd=[0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="shadowing"):
        brdf.create("li_torrance", shadowing="yes")
    with pytest.raises(ValueError, match="sigma"):
        brdf.create("li_torrance", sigma=0.0)
    with pytest.raises(ValueError, match="theta"):
        smith_shadowing(2.0, 0.5, 2.5)
    with pytest.raises(ValueError, match="wi"):
        brdf.create("li_torrance")([0, 0, np.nan], [0, 0, 1.0])


@pytest.mark.parametrize(
    "params",
    [
        {},
        dict(k_fs=1.0, k_udf=0.1),
        dict(k_fs=0.5, tau_x=2.0, tau_y=4.0),
        dict(k_dd=0.9, sigma=0.23, tau=9.9, d_omega_i=0.01),
        dict(shadowing=False, effective_roughness=False, k_dd=np.linspace(0.2, 0.8, 31)),
        dict(shortcut=False, f0=0.9, k_uds=0.0),
    ],
)
def test_numba_kernel_equals_numpy_reference(params):
    m = brdf.create("li_torrance", **params)
    wi = np.concatenate([_dirs(3000, 21), ADVERSARIAL, ADVERSARIAL])
    wo = np.concatenate([_dirs(3000, 22), ADVERSARIAL, ADVERSARIAL[::-1]])
    wo[::5] = wi[::5] * [-1, -1, 1]  # exact mirror pairs (inside the top hat)
    fast = m(wi, wo)
    slow_model = brdf.create("li_torrance", **params)
    slow_model.use_kernel = False
    slow = slow_model(wi, wo)
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-300)


def test_sigma_and_tau_enter_only_as_a_ratio_outside_the_mirror_part():
    """Eq. 6, 8, 10 and 13 depend on σ/τ only; only g (eq. 4) sees σ/λ (report for fitting)."""
    p = materials.get("garnet_red_paint").params
    a = brdf.create("li_torrance", **p)
    b = brdf.create("li_torrance", **{**p, "sigma": 2 * p["sigma"], "tau": 2 * p["tau"]})
    wi, wo = _dirs(2000, 31), _dirs(2000, 32)
    np.testing.assert_allclose(a(wi, wo), b(wi, wo), rtol=1e-12, atol=1e-300)
    ng = materials.get("aluminized_non_glare_glass").params
    c = brdf.create("li_torrance", **ng)
    d = brdf.create("li_torrance", **{**ng, "sigma": 2 * ng["sigma"], "tau": 2 * ng["tau"]})
    w = to_vector(np.radians(75.0), 0.0)
    assert c.delta(w)[1][15] > 10 * d.delta(w)[1][15]
