"""The PTFE diffuse standard and the deviation of the real one from its certificate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator.standard import (
    PTFE_TARGETS,
    _lobe_norms,
    certificate_deviation,
    make_certificate,
    ptfe_factor,
    true_standard,
)
from scipy import integrate


def _dir(theta, phi=0.0):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                     math.cos(theta)])  # fmt: skip


@pytest.mark.parametrize(("theta_deg", "value"), PTFE_TARGETS)
def test_reflectance_factor_meets_the_stated_values(theta_deg, value):
    """1.04 at normal incidence and viewing; 1.07, 1.10, 1.22 in the forward direction."""
    th = math.radians(theta_deg)
    assert float(ptfe_factor(_dir(th), _dir(th, math.pi))) == pytest.approx(value, abs=1e-4)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 80.0])
def test_directional_hemispherical_reflectance_is_rho_at_every_incidence(theta_deg):
    """Independent check by scipy's adaptive quadrature: (1/π) ∫ R cos θo dω = 1."""
    wi = _dir(math.radians(theta_deg))

    def f(t, p):
        return float(ptfe_factor(wi, _dir(t, p))) * math.cos(t) * math.sin(t) / math.pi

    val, _ = integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, math.pi / 2, epsabs=1e-7)
    assert val == pytest.approx(1.0, abs=2e-4)


def test_lobe_normalisation_against_quadrature_and_closed_ends():
    """N(θi) with the azimuth integrated in closed form, against scipy's adaptive quadrature
    of the clipped lobe over the hemisphere (an independent form), and the exact values
    N(0) = 2/5 (∫ cos⁴θ dω / π) and N(π/2) = 4/(15π)."""
    th = np.radians([0.0, 10.0, 45.0, 60.0, 75.0, 89.0, 90.0])
    got = _lobe_norms(th)
    assert got[0] == pytest.approx(0.4, rel=1e-12)
    assert got[-1] == pytest.approx(4.0 / (15.0 * math.pi), rel=1e-9)
    for t, n in zip(th[1:-1], got[1:-1]):
        wi = _dir(t)
        mirror = wi * np.array([-1.0, -1.0, 1.0])

        def f(to, po, mirror=mirror):
            c = max(float(_dir(to, po) @ mirror), 0.0)
            return c**3 * math.cos(to) * math.sin(to) / math.pi

        val, _ = integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, math.pi / 2, epsabs=1e-10)
        assert n == pytest.approx(val, rel=1e-7)


def test_forward_scattering_grows_and_backward_falls_towards_grazing():
    fwd = [float(ptfe_factor(_dir(math.radians(t)), _dir(math.radians(t), math.pi)))
           for t in (0, 30, 45, 60, 75, 85)]  # fmt: skip
    assert fwd == sorted(fwd)
    back = float(ptfe_factor(_dir(math.radians(60)), _dir(math.radians(80))))
    assert back < 0.95
    assert float(ptfe_factor(_dir(0.5), _dir(0.7), 0.0)) == 1.0  # scale 0: Lambertian


def test_real_standard_deviates_from_its_certificate_by_about_u():
    rng = np.random.default_rng(0)
    wo = np.stack([_dir(t, p) for t in np.radians(np.arange(2.5, 85, 5))
                   for p in np.radians(np.arange(0, 360, 15))])  # fmt: skip
    rms = [math.sqrt(np.mean(certificate_deviation(_dir(0.6), wo, 0.01, rng) ** 2))
           for _ in range(300)]  # fmt: skip
    assert np.sqrt(np.mean(np.square(rms))) == pytest.approx(0.01, rel=0.25)
    f = true_standard(0.99, 1.0, 0.01, np.random.default_rng(4))
    g = true_standard(0.99, 1.0, 0.01, np.random.default_rng(4))
    assert np.array_equal(f(_dir(0.6), wo), g(_dir(0.6), wo))
    plain = true_standard(0.99, 1.0, 0.0, None)
    ratio = f(_dir(0.6), wo) / plain(_dir(0.6), wo)
    assert 0.0 < np.abs(ratio - 1).max() < 0.1


def test_certificate_of_the_model_interpolates_it():
    c = make_certificate(0.99, 1.0, 0.005)
    assert c.expanded_uncertainty == pytest.approx(0.01) and c.coverage_factor == 2.0
    for t in (0.3, 0.8, 1.2):
        wi, wo = _dir(t), _dir(t + 0.05, math.pi - 0.3)
        assert c.brdf(wi, wo) == pytest.approx(0.99 / math.pi * ptfe_factor(wi, wo), rel=4e-3)
