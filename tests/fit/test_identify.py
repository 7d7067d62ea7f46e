"""Tests of gonio.fit.identify: which parameters a set of geometries separates."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import fit
from gonio.campaign.determined import hemisphere_geometries
from gonio.fit.identify import distinct_geometries, free_parameters, unseparated
from gonio.samples import BRDFSamples


def test_a_hemisphere_separates_ward_and_one_geometry_does_not():
    wi, wo = hemisphere_geometries((10.0, 40.0, 70.0))
    assert unseparated("ward", wi, wo) == []
    # the same geometry fifty times is one geometry: four parameters, one row of information
    rep_i, rep_o = np.repeat(wi[:1], 50, axis=0), np.repeat(wo[:1], 50, axis=0)
    assert distinct_geometries(rep_i, rep_o) == 1
    assert unseparated("ward", rep_i, rep_o) == ["rho_d", "rho_s", "alpha_x", "alpha_y"]


def test_a_sum_of_two_lambert_terms_is_never_separated():
    wi, wo = hemisphere_geometries(range(0, 81, 10), (0.0, 90.0))
    assert unseparated("lambert+lambert", wi, wo) == ["lambert.rho", "lambert#2.rho"]


def test_unseparated_agrees_with_the_fit_on_noise_free_data():
    """What the pre-capture check says is what the fit finds: the same parameters come out
    with infinite standard errors when the model's own values are fitted."""
    wi, wo = hemisphere_geometries((30.0,))  # incidence in the x-z plane only
    model = fit.parse_model("lafortune")
    names = unseparated(model, wi, wo)
    assert names == ["lobes[0].c_y"]  # wi_y = 0: c_y multiplies nothing
    y = fit.predict(model, BRDFSamples.from_directions(wi, wo, np.ones(len(wi))))
    res = fit.fit(BRDFSamples.from_directions(wi, wo, y, 0.01 * y + 1e-4), model, guess=False)
    assert [k for k in res.free if not np.isfinite(res.stderr[k])] == names


def test_free_parameters_follow_the_fit_defaults():
    assert free_parameters("ward") == ["rho_d", "rho_s", "alpha_x", "alpha_y"]
    assert free_parameters("ward", fixed=["rho_d"]) == ["rho_s", "alpha_x", "alpha_y"]
    assert "r_m" not in free_parameters("lafortune")  # held by default (DEFAULT_FIXED)


def test_a_model_that_is_zero_everywhere_is_a_clear_error():
    wi, wo = hemisphere_geometries((30.0,))
    with pytest.raises(ValueError, match="zero or not finite"):
        unseparated(fit.parse_model("lambert", rho=0.0), wi, wo)
