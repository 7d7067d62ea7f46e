"""Lafortune et al. 1997 (Lafortune et al. 1997): generalized cosine lobes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio import brdf, materials
from gonio.brdf.base import hemisphere_integral
from gonio.brdf.lafortune import classic_lobe

BLUE = [(0.86, 0.86, 0.77, 18.6), (-0.41, -0.41, 0.018, 2.58), (-1.03, -1.03, 0.70, 63.8)]


def _wi(theta: float, phi: float = 0.0) -> np.ndarray:
    return np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )


def test_blue_paint_preset_is_table_1() -> None:
    rec = materials.info("blue_paint_lafortune")
    assert rec["model"] == "lafortune"
    assert [tuple(lb) for lb in rec["params"]["lobes"]] == BLUE  # Cx = Cy column
    assert rec["params"]["rho_d"] == 0.13
    m = materials.get("blue_paint_lafortune")
    assert m.params["lobes"][0][0] > 0  # lobe I retro-reflective (positive Cx)
    assert all(lb[0] < 0 for lb in m.params["lobes"][1:])  # II, III forward


def test_eq8_values() -> None:
    m = brdf.create("lafortune", lobes=BLUE, rho_d=0.13)
    u, v = _wi(0.8, 0.3), _wi(0.5, 2.0)
    expect = 0.13 / math.pi
    for cx, cy, cz, n in BLUE:
        b = cx * u[0] * v[0] + cy * u[1] * v[1] + cz * u[2] * v[2]
        expect += b**n if b > 0 else 0.0
    assert float(m(u, v)) == pytest.approx(expect, rel=1e-13)
    # retro direction at 65°: lobe I = (0.86 sin² + 0.77 cos²)^18.6
    w = _wi(math.radians(65.0))
    lobe1 = brdf.create("lafortune", lobes=BLUE[:1])
    s2 = math.sin(math.radians(65.0)) ** 2
    assert float(lobe1(w, w)) == pytest.approx((0.86 * s2 + 0.77 * (1 - s2)) ** 18.6, rel=1e-13)


def test_negative_base_contributes_zero_and_n0() -> None:
    m = brdf.create("lafortune", lobes=[(1.0, 1.0, -1.0, 0.0)])
    assert float(m(_wi(0.3), _wi(0.3))) == 0.0  # base < 0
    assert float(m(_wi(1.2), _wi(1.2))) == pytest.approx(1.0)  # base > 0, n = 0: 1


def test_classic_lobe_equals_phong(sphere_pairs) -> None:
    wi, wo = sphere_pairs(100, seed=2)
    laf = brdf.create("lafortune", lobes=[classic_lobe(25.0)])
    np.testing.assert_allclose(
        laf(wi, wo), brdf.create("phong", n=25.0)(wi, wo), rtol=1e-12, atol=1e-300
    )
    # Neumann eq. 16 with p = 1 equals phong_neumann
    lp = brdf.create("lafortune", lobes=[(*classic_lobe(25.0), 1.0)])
    np.testing.assert_allclose(
        lp(wi, wo), brdf.create("phong_neumann", n=25.0)(wi, wo), rtol=1e-12, atol=1e-300
    )


def test_eq6_minnaert_lobe_albedo() -> None:
    """Eq. 6: ρ_d C_d [u_z v_z]^n with C_d = (n+2)/(2π): albedo ρ_d at normal incidence and
    ρ_d cos^n θ in general (the lobe factorises)."""
    n = 0.5
    c = ((n + 2) / (2 * math.pi)) ** (1 / n)
    m = brdf.create("lafortune", lobes=[(0.0, 0.0, c, n)])
    th = np.radians([0.0, 40.0, 80.0])
    w = np.stack([np.sin(th), 0 * th, np.cos(th)], -1)
    np.testing.assert_allclose(m.albedo(w), np.cos(th) ** n, rtol=1e-10)


@pytest.mark.parametrize("theta", [0.0, 0.6, 1.2, 1.5])
def test_albedo_vs_brute_force(theta: float) -> None:
    m = brdf.create("lafortune", lobes=BLUE, rho_d=0.13)
    w = _wi(theta, 0.4)
    bf = hemisphere_integral(lambda wo: m._eval(w, wo), 256, 512)
    assert float(m.albedo(w)) == pytest.approx(bf, rel=1e-6)


def test_albedo_with_fractional_p_by_quadrature() -> None:
    m = brdf.create(
        "lafortune", lobes=[(0.9, 0.7, 0.8, 12.0, 0.5), (-1.0, -1.0, 0.9, 30.0)], rho_d=0.05
    )
    assert not m.spec().analytic_albedo or m._albedo(np.array([0, 0, 1.0]), 1e-6) is None
    w = _wi(1.0, 0.2)
    bf = hemisphere_integral(lambda wo: m._eval(w, wo), 512, 1024)
    assert float(m.albedo(w, rtol=1e-9)) == pytest.approx(bf, rel=1e-5)


def test_eq7_mirror_term() -> None:
    """Classical lobe with C_s = (n+1)/(2π): δ reflectance R_m (ρ_s − ρ_s(u))."""
    n, rho_s, r_m = 20.0, 0.6, 0.4
    c = (rho_s * (n + 1) / (2 * math.pi)) ** (1 / n)
    m = brdf.create("lafortune", lobes=[(-c, -c, c, n)], r_m=r_m)
    d, r = m.delta(_wi(0.0))
    np.testing.assert_allclose(d, [0, 0, 1.0], atol=1e-15)
    # at normal incidence ρ_s(u) = ρ_s (n+1)/(n+2)
    assert float(r) == pytest.approx(r_m * rho_s / (n + 2), rel=1e-10)
    th = 1.3
    d, r = m.delta(_wi(th, 0.5))
    np.testing.assert_allclose(d, _wi(th, 0.5) * [-1, -1, 1])
    a = float(m.albedo(_wi(th, 0.5)))
    assert float(r) == pytest.approx(r_m * (rho_s - a), rel=1e-10)
    assert float(m.delta(_wi(2.0))[1]) == 0.0  # below the horizon
    assert float(brdf.create("lafortune").delta(_wi(0.3))[1]) == 0.0  # r_m = 0
    assert brdf.spec("lafortune").has_delta


@pytest.mark.parametrize(
    ("lobes", "match"),
    [
        ("abc", "lobes"),
        (5, "lobes"),
        ([(1.0, 2.0, 3.0)], "4 or 5"),
        ([(1.0, 2.0, 3.0, 4.0, 0.5, 6.0)], "4 or 5"),
        ([(1.0, 2.0, float("nan"), 4.0)], "non-finite"),
        ([(1.0, 2.0, 3.0, -1.0)], "exponent n"),
        ([(1.0, 2.0, 3.0, 4.0, 1.5)], "p ="),
        ([("a", 2.0, 3.0, 4.0)], "numbers"),
        ([[[1.0, 2.0], [3.0, 4.0]]], "4 or 5"),
    ],
)
def test_malformed_lobes(lobes, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        brdf.create("lafortune", lobes=lobes)


def test_bad_scalars() -> None:
    with pytest.raises(ValueError, match="rho_d"):
        brdf.create("lafortune", rho_d=1.5)
    with pytest.raises(ValueError, match="r_m"):
        brdf.create("lafortune", r_m=float("nan"))
