"""Tests of gonio.campaign.resolution: the instrument's angular resolution against a lobe."""

from __future__ import annotations

import math

import pytest

from gonio import brdf, materials
from gonio.campaign.resolution import (
    Resolution,
    angular_resolution,
    lobe_hwhm,
    resolution_warnings,
)
from gonio.fit import parse_model

MIRROR = {"type": "ellipsoid", "radius": 0.15, "half_separation": 0.01}


@pytest.mark.parametrize("n", [500.0, 5000.0])
def test_lobe_half_width_of_a_blinn_lobe_is_the_analytic_one(n):
    """At normal incidence the half vector turns by half the reflected direction: the
    (h.n)^n lobe is at half its peak where cos^n(d/2) = 1/2."""
    m = brdf.create("blinn_phong", n=n, c_n=1.0, rho_d=0.0)
    exact = 2.0 * math.acos(0.5 ** (1.0 / n))
    assert lobe_hwhm(m, 0.0) == pytest.approx(exact, rel=1e-3)


def test_a_diffuse_material_has_no_narrow_lobe():
    assert lobe_hwhm(brdf.create("lambert")) == math.inf
    assert lobe_hwhm(materials.get("wall_plaster")) > math.radians(10.0)  # Oren-Nayar


def test_the_digitiser_widens_the_pixel_by_its_binning():
    full = angular_resolution(MIRROR, 150.0, 640, None, math.radians(0.25))
    binned = angular_resolution(MIRROR, 150.0, 640, (108, 80), math.radians(0.25))
    assert binned.footprint == pytest.approx(full.footprint * 640 / 108)
    assert binned.hwhm > full.hwhm
    # the dome maps camera angles to reflection angles with a magnification of order 1
    assert 0.2 < full.footprint * 150.0 < 5.0


def test_a_lobe_narrower_than_the_resolution_gives_a_bound_at_the_resolution():
    truth = materials.get("neumann_fig12_silver_mirror")
    coarse = Resolution(math.radians(4.0), math.radians(0.5), math.radians(0.25))
    (w,) = resolution_warnings(truth, parse_model("metal_neumann"), coarse)
    assert w.startswith("n >= ") and "narrower than the instrument resolves" in w
    bound = float(w.split()[2].rstrip(":"))
    at_bound = type(truth)(**{**truth.params, "n": bound})
    assert lobe_hwhm(at_bound, math.radians(30.0)) == pytest.approx(coarse.hwhm, rel=0.03)
    fine = Resolution(math.radians(0.3), 0.0, math.radians(0.25))
    assert resolution_warnings(truth, parse_model("metal_neumann"), fine) == []
