"""Tests of gonio.campaign.reference: the model's best approximation of the truth."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import brdf, fit
from gonio.campaign.determined import hemisphere_geometries
from gonio.campaign.reference import inadequacy, model_reference
from gonio.samples import BRDFSamples


def _samples(model, rel_noise=0.0, seed=0):
    wi, wo = hemisphere_geometries((10.0, 40.0, 70.0))
    y = np.asarray(model(wi, wo), float)
    rng = np.random.default_rng(seed)
    sig = 0.01 * y + 1e-4
    return BRDFSamples.from_directions(wi, wo, y * (1 + rel_noise * rng.normal(size=y.shape)), sig)


def test_the_reference_of_the_truths_own_family_is_the_truth():
    truth = brdf.create("ward", rho_d=0.2, rho_s=0.1, alpha_x=0.1, alpha_y=0.2)
    s = _samples(truth, rel_noise=0.01)
    res = fit.fit(s, "ward")
    ref = model_reference(truth, res, s)
    for k, v in truth.params.items():
        assert ref["params"][k] == pytest.approx(v, rel=1e-5)
    assert ref["inadequacy"]["reference"]["worst_relative"] < 1e-5


def test_the_reference_is_the_noise_free_fit_on_the_same_directions_and_weights():
    """An independent form: the same fit written out by hand on the noise-free values."""
    truth = brdf.create("oren_nayar", rho=0.6, sigma=0.4)
    s = _samples(truth, rel_noise=0.02)
    res = fit.fit(s, "lambert")
    ref = model_reference(truth, res, s)
    y = truth(s.wi, s.wo)
    w = 1.0 / s.sigma**2  # Lambert: f = rho/pi, weighted least squares in closed form
    rho = np.pi * np.sum(w * y) / np.sum(w)
    assert ref["params"]["rho"] == pytest.approx(rho, rel=1e-6)
    ina = inadequacy(res.model, truth, s)
    assert ina["worst_relative"] >= ina["rms_relative"] > 0.01
