"""Dome geometry from front-surface-mirror spot captures (calibration/mirror.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.calibration.angles import MirrorGeometry
from gonio.calibration.mirror import MirrorCalibration, fit_mirror, spot_centroid

from gonio.brdf.lambert import Lambert
from gonio.geometry import to_vector

sim = pytest.importorskip("gonio.simulator")


class _FrontMirror(Lambert):
    """A front-surface mirror: no diffuse part, a mirror part of reflectance 0.9."""

    name = "test_front_mirror"

    def delta(self, wi):
        wi = np.asarray(wi, dtype=np.float64)
        return wi * np.array([-1.0, -1.0, 1.0]), np.full(wi.shape[:-1], 0.9)


def test_spot_centroid_of_a_gaussian():
    v, u = np.mgrid[:60, :80]
    img = 100.0 + 1000.0 * np.exp(-((u - 31.3) ** 2 + (v - 22.7) ** 2) / (2 * 1.5**2))
    cu, cv, peak = spot_centroid(img, 100.0)
    assert (cu, cv) == (pytest.approx(31.3, abs=0.02), pytest.approx(22.7, abs=0.02))
    assert peak == pytest.approx(1000.0 * math.exp(-(0.3**2 + 0.3**2) / 4.5))  # pixel (31, 23)
    with pytest.raises(ValueError, match="spot"):
        spot_centroid(np.zeros((5, 5)))


@pytest.mark.parametrize("true_d", [0.01, 0.011])
def test_fit_recovers_d_over_r_from_spots(true_d):
    inst = sim.LBLInstrument(half_separation=true_d)
    m = _FrontMirror(rho=0.0)
    uv, dirs = [], []
    for th in np.radians(np.arange(6.0, 80.0, 8.0)):
        img, meta = inst.capture(m, th, 0.0, exposure=2e-5, f_number=32.0, noise=False)
        u, v, _ = spot_centroid(img, meta["sensor"]["black_level_dn"])
        uv.append((u, v))
        dirs.append(to_vector(th, math.pi))  # the mirror direction, arm at azimuth 0
    cal = fit_mirror(uv, dirs, inst.lens, MirrorGeometry("ellipsoid", 0.15, 0.0095))
    assert cal.geometry.half_separation == pytest.approx(true_d, rel=5e-3)
    assert abs(cal.geometry.d_over_r - true_d / 0.15) < 4 * cal.stderr["d_over_r"] + 1e-4
    assert cal.rms_deg < 0.03
    back = MirrorCalibration.from_dict(cal.to_dict())
    assert back.geometry == cal.geometry
    with pytest.raises(ValueError, match="mirror parameter"):
        fit_mirror(uv, dirs, inst.lens, cal.geometry, free=("radius",))
