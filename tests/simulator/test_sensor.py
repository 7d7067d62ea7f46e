"""The CCD sensor model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator import Sensor


def test_linear_adc_and_inverse():
    s = Sensor(gain=10.0, black_level=64.0, full_well=40000.0, adc_bits=12)
    e = np.array([0.0, 1000.0, 12345.0, 39990.0, 1e6])
    dn = s.digitise(e)
    assert dn.dtype == np.uint16
    assert list(dn) == [64, 164, 1298, 4063, 4064]
    assert s.saturation_dn == 4064.0 and s.max_dn == 4095
    assert np.allclose(s.linearise(dn[:3]), [0.0, 1000.0, 12340.0])


def test_adc_clips_at_max_dn():
    s = Sensor(gain=1.0, full_well=1e6, adc_bits=8, black_level=10.0)
    assert s.digitise(np.array([1e5]))[0] == 255
    assert s.saturation_dn == 255


def test_response_curve_round_trip():
    s = Sensor(response_gamma=0.45)
    e = np.linspace(0.0, s.full_well, 50)
    x = s.linearise(s.digitise(e))
    # quantisation of a gamma curve: error grows where the curve is flat (bright end)
    assert np.abs(x - e).max() < 0.02 * s.full_well
    assert not s.linear and Sensor().linear


def test_fixed_patterns_reproducible():
    a = Sensor(pattern_seed=3).maps(20, 30)
    b = Sensor(pattern_seed=3).maps(20, 30)
    c = Sensor(pattern_seed=4).maps(20, 30)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    prnu, dsnu = Sensor(prnu=0.01, dsnu=0.2).maps(200, 200)
    assert prnu.std() == pytest.approx(0.01, rel=0.05)
    assert dsnu.std() == pytest.approx(0.2, rel=0.05)


def test_noise_statistics():
    s = Sensor(read_noise=5.0)
    e = np.full(200_000, 900.0)
    n = s.add_noise(e, np.random.default_rng(1))
    assert n.mean() == pytest.approx(900.0, abs=0.2)
    assert n.var() == pytest.approx(900.0 + 25.0, rel=0.02)
    assert np.array_equal(n, s.add_noise(e, np.random.default_rng(1)))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"qe": 0.0}, "qe"),
        ({"qe": 1.5}, "qe"),
        ({"gain": -1.0}, "gain"),
        ({"adc_bits": 20}, "adc_bits"),
        ({"black_level": 5000.0}, "black_level"),
        ({"read_noise": float("nan")}, "read_noise"),
        ({"response_gamma": 0.0}, "response_gamma"),
    ],
)
def test_bad_sensor(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Sensor(**kwargs)


def test_dict_round_trip():
    s = Sensor(qe=0.4, adc_bits=10, response_gamma=0.5, pixel_pitch=7e-6)
    assert Sensor.from_dict(s.to_dict()) == s


def _moments(x):
    m = x.mean()
    d = x - m
    v = (d * d).mean()
    return m, v, (d**3).mean() / v**1.5


@pytest.mark.parametrize("read_noise", [8.0, 3.0, 0.5])
@pytest.mark.parametrize("lam", [0.2, 4.0, 20.0, 100.0, 3000.0])
def test_fast_noise_moments_match_poisson_plus_read_noise(lam, read_noise):
    # mean, variance and skewness of the compiled draw (exact Poisson, or the skew-corrected
    # normal where Sensor.normal_threshold allows it) against Poisson(lam) + N(0, sigma^2)
    s = Sensor(read_noise=read_noise)
    n = 400_000
    e = s.add_noise(np.full(n, lam), np.random.default_rng(int(lam * 10) + 7))
    m, v, g = _moments(e)
    var = lam + read_noise**2
    skew = lam / var**1.5
    assert abs(m - lam) < 5 * math.sqrt(var / n)
    assert abs(v - var) < 5 * var * math.sqrt(2.0 / n) * 1.5
    assert abs(g - skew) < 5 * math.sqrt(6.0 / n) + 0.1 * skew


def test_noise_threshold_rule_and_zero_read_noise_is_exact_poisson():
    assert Sensor(read_noise=8.0).normal_threshold == 0.0
    assert Sensor(read_noise=6.0).normal_threshold == 0.0
    assert Sensor(read_noise=4.0).normal_threshold == 30.0
    assert Sensor(read_noise=1.9).normal_threshold == math.inf
    s = Sensor(read_noise=0.0)
    e = s.add_noise(np.full(200_000, 50.0), np.random.default_rng(3))
    assert np.array_equal(e, np.round(e)) and e.min() >= 0
    assert e.mean() == pytest.approx(50.0, abs=5 * math.sqrt(50 / 2e5))
    assert e.var() == pytest.approx(50.0, rel=0.02)


def test_flat_field_dn_statistics_fast_and_exact():
    # digitised flat fields: mean DN = black + lam/gain, variance = (lam + sigma^2)/gain^2 +
    # 1/12 (rounding), for the fast and the exact draw alike; both reproducible from the seed
    s = Sensor()
    n = 300_000
    for lam in (500.0, 5000.0, 30000.0):
        flat = np.full(n, lam)
        for exact in (False, True):
            a = s.digitise(s.add_noise(flat, np.random.default_rng(9), exact=exact))
            b = s.digitise(s.add_noise(flat, np.random.default_rng(9), exact=exact))
            assert np.array_equal(a, b)
            dn = a.astype(float)
            var = (lam + s.read_noise**2) / s.gain**2 + 1.0 / 12.0
            assert abs(dn.mean() - (s.black_level + lam / s.gain)) < 5 * math.sqrt(var / n)
            assert abs(dn.var() - var) < 5 * var * math.sqrt(2.0 / n)
    # different seeds differ; negative expectations are treated as zero
    x = s.add_noise(np.full(1000, 100.0), np.random.default_rng(1))
    y = s.add_noise(np.full(1000, 100.0), np.random.default_rng(2))
    assert not np.array_equal(x, y)
    z = s.add_noise(np.full(100_000, -5.0), np.random.default_rng(1))
    assert abs(z.mean()) < 5 * s.read_noise / math.sqrt(1e5)
