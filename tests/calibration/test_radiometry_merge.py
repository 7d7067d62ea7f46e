"""Eq. 2 radiometry, error propagation and exposure merging (Ward 1992, eq. 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.calibration.merge import merge_linear
from gonio.calibration.radiometry import SensorModel, eq2, linearize

META = {
    "exposure_s": 0.1,
    "f_number": 2.0,
    "sensor": {
        "gain_e_per_dn": 4.0,
        "read_noise_e": 6.0,
        "black_level_dn": 64.0,
        "saturation_dn": 4000.0,
    },
}


def _frames(e_signal, meta, rng, n):
    """n raw frames (DN) of a flat electron signal with shot, read and quantisation noise."""
    s = SensorModel.from_metadata(meta)
    e = rng.poisson(e_signal, size=n) + s.read_noise * rng.standard_normal(n)
    return np.clip(np.rint(s.black_level + np.minimum(e, 15000) / s.gain), 0, 4095)


def test_eq2_value_and_sigma_match_monte_carlo():
    rng = np.random.default_rng(1)
    n = 40000
    m = _frames(3000.0, META, rng, n).reshape(200, 200)
    st = _frames(8000.0, META, rng, n).reshape(200, 200)
    bg = _frames(400.0, META, rng, n).reshape(200, 200)
    r = eq2(linearize(m, META), linearize(st, META), linearize(bg, META), 0.99)
    assert r.mask.all()
    truth = (3000 - 400) / (8000 - 400) * 0.99 / math.pi
    assert abs(r.value.mean() / truth - 1) < 2e-3
    # propagated sigma (incl. the shared-background covariance) equals the scatter
    assert r.sigma.mean() == pytest.approx(r.value.std(), rel=0.03)


def test_eq2_debias_removes_the_ratio_bias():
    """A dim standard (σ_d/d ≈ 8 %): n/d is high by about (σ_d/d)² (E[1/d] > 1/E[d]), 16
    standard errors of the mean over 40 000 pixels; ``debias`` removes it (eq. 2,
    Ward 1992)."""
    rng = np.random.default_rng(2)
    n = 40000
    m = _frames(3000.0, META, rng, n).reshape(200, 200)
    st = _frames(300.0, META, rng, n).reshape(200, 200)
    bg = _frames(50.0, META, rng, n).reshape(200, 200)
    truth = (3000 - 50) / (300 - 50) * 0.99 / math.pi
    for variance in ("own", "neighbours"):
        args = (linearize(m, META), linearize(st, META), linearize(bg, META), 0.99)
        raw = eq2(*args, variance=variance)
        fixed = eq2(*args, variance=variance, debias=True)
        assert raw.mask.all() and fixed.mask.all()
        np.testing.assert_array_equal(fixed.sigma, raw.sigma)
        se = raw.value.std() / math.sqrt(n)
        assert (raw.value.mean() - truth) / se > 8.0  # the bias, in standard errors
        assert abs(fixed.value.mean() - truth) / se < 4.0


def test_eq2_masks_standard_at_background():
    img = np.full((4, 4), 500.0)
    meas = linearize(img, META)
    r = eq2(meas, linearize(img, META), linearize(img, META), 0.9)
    assert not r.mask.any() and np.isfinite(r.value).all() and (r.value == 0).all()


def test_eq2_rejects_bad_rho():
    m = linearize(np.full((2, 2), 100.0), META)
    with pytest.raises(ValueError, match="rho_standard"):
        eq2(m, m, m, 1.5)


def test_sensor_metadata_missing_gain():
    with pytest.raises(ValueError, match="gain"):
        SensorModel.from_metadata({"exposure_s": 1.0})


def test_merge_linear_unbiased_and_noise_optimal():
    rng = np.random.default_rng(2)
    n = 20000
    flux = 1.5e4  # e- per unit exposure scale t/N^2
    metas, imgs = [], []
    for t in (0.02, 0.1, 0.5):
        mt = dict(META, exposure_s=t)
        metas.append(mt)
        imgs.append(_frames(flux * t / 4.0, mt, rng, n).reshape(100, 200))
    m = merge_linear(imgs, metas)
    truth = flux / 4.0  # DN per unit t/N^2: flux / gain
    assert m.valid.all()
    assert abs(m.value.mean() / truth - 1) < 2e-3
    assert m.sigma.mean() == pytest.approx(m.value.std(), rel=0.05)
    # a saturated frame (≥ saturation_dn) adds nothing and changes nothing
    m2 = merge_linear([*imgs, np.full((100, 200), 4000.0)], [*metas, dict(META, exposure_s=5.0)])
    assert np.array_equal(m2.value, m.value)
