"""The calibration certificate of a diffuse standard (data a reduction reads)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gonio.io.certificate import Certificate, relative_angles


def _cert(**kw):
    args = dict(
        rho=0.99, theta_i_deg=(0.0, 40.0, 80.0), theta_o_deg=(0.0, 40.0, 80.0),
        dphi_deg=(0.0, 180.0), factor=np.ones((3, 3, 2)), expanded_uncertainty=0.01,
    )  # fmt: skip
    args.update(kw)
    return Certificate(**args)


def test_json_round_trip():
    f = np.arange(18, dtype=float).reshape(3, 3, 2) * 0.01 + 0.9
    c = _cert(factor=f)
    d = json.loads(json.dumps(c.to_dict()))
    c2 = Certificate.from_dict(d)
    assert np.array_equal(c2.factor, c.factor) and c2.rho == c.rho
    assert c2.standard_uncertainty == pytest.approx(0.005)


def test_factor_table_is_a_read_only_copy_and_the_fingerprint_its_json():
    f = np.full((3, 3, 2), 1.02)
    c = _cert(factor=f)
    f[0, 0, 0] = 5.0  # the caller's array stays theirs and writable
    assert c.factor[0, 0, 0] == 1.02 and f.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        c.factor[0, 0, 0] = 5.0
    assert c.fingerprint == json.dumps(c.to_dict(), sort_keys=True)
    assert _cert(factor=np.full((3, 3, 2), 1.03)).fingerprint != c.fingerprint


def test_interpolation_is_trilinear_and_keeps_the_query_shape():
    f = np.zeros((3, 3, 2))
    f[:] = np.array([1.0, 2.0, 3.0])[:, None, None]  # linear in theta_i
    c = _cert(factor=f)
    v = c.factor_at(np.radians([20.0, 60.0]), np.radians([10.0, 10.0]), math.pi)
    assert v.shape == (2,) and v == pytest.approx([1.5, 2.5])
    assert np.shape(c.factor_at(0.1, 0.1, 0.0)) == ()


def test_angles_outside_the_certificate_are_refused():
    c = _cert(theta_i_deg=(0.0, 30.0, 60.0))
    with pytest.raises(ValueError, match=r"theta_i 70\.\.70 deg is not covered .*\[0, 60\]"):
        c.factor_at(math.radians(70.0), 0.2, 0.0)
    with pytest.raises(ValueError, match="theta_o"):
        c.check_covers(0.1, math.radians(85.0))


def test_bad_certificates_are_refused():
    with pytest.raises(ValueError, match="rho"):
        _cert(rho=1.2)
    with pytest.raises(ValueError, match="increasing"):
        _cert(theta_i_deg=(0.0, 0.0, 80.0))
    with pytest.raises(ValueError, match="shape"):
        _cert(factor=np.ones((2, 3, 2)))
    with pytest.raises(ValueError, match="expanded_uncertainty"):
        _cert(expanded_uncertainty=-0.1)
    with pytest.raises(ValueError, match="missing"):
        Certificate.from_dict({"rho": 0.9})


def test_relative_angles_forward_is_pi():
    wi = np.array([math.sin(0.5), 0.0, math.cos(0.5)])
    wo = np.array([-math.sin(0.5), 0.0, math.cos(0.5)])
    ti, to, dphi = relative_angles(wi, wo)
    assert (float(ti), float(to), float(dphi)) == pytest.approx((0.5, 0.5, math.pi))
