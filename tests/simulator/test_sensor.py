"""The CCD sensor model."""

from __future__ import annotations

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
