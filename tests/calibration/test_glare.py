"""Veiling glare from a known-dark region (calibration/glare.py) and the reduction's hooks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.calibration import Capture
from gonio.calibration.glare import dark_region, glare_offset, veil, veil_shape

SENSOR = {"gain_e_per_dn": 10.0, "read_noise_e": 8.0, "black_level_dn": 64.0,
          "saturation_dn": 4064.0}  # fmt: skip


def _cap(signal_dn, rng, f_number=4.0):
    raw = 64.0 + signal_dn + rng.normal(0.0, 0.8, signal_dn.shape)
    meta = {"exposure_s": 0.01, "f_number": f_number, "sensor": SENSOR}
    return Capture.single(np.clip(np.rint(raw), 0, 4095).astype(np.uint16), meta)


def test_the_veil_is_measured_where_no_sample_light_arrives():
    rng = np.random.default_rng(0)
    h, w = 60, 80
    v, u = np.mgrid[:h, :w]
    r = np.hypot(u - 40, v - 30) / 30.0
    field = r <= 1.0
    resp = np.where(field, 1.0 - 0.3 * r**2, 0.0)  # relative illumination
    occluded = field & (u < 22)  # the lens body's shadow, dark in every image
    amb = 200.0 * resp
    light = np.where(field & ~occluded, 1.0, 0.0)
    std_sig = amb + 2000.0 * resp * light + 40.0 * resp  # 40 DN of veil at the centre
    meas_sig = amb + 900.0 * resp * light + 15.0 * resp
    std, bg, meas = _cap(std_sig, rng), _cap(amb, rng), _cap(meas_sig, rng)
    dark = dark_region(std, bg, field, margin=2)
    assert dark is not None and set(dark) <= set(np.flatnonzero(occluded.ravel()))
    assert dark.size > 0.9 * (occluded & (u < 20)).sum()
    scale = 0.01 / 4.0**2
    g_s, g_m = glare_offset(std, bg, dark), glare_offset(meas, bg, dark)
    mean_resp_dark = resp.ravel()[dark].mean()
    assert g_s.value * scale == pytest.approx(40.0 * mean_resp_dark, rel=0.03)
    assert g_m.value * scale == pytest.approx(15.0 * mean_resp_dark, rel=0.06)
    shape = veil_shape(bg, field, r.ravel() * math.pi / 2)
    vm = veil(g_m, shape, dark).reshape(h, w) * scale
    centre = vm[30, 40]
    assert centre == pytest.approx(15.0, rel=0.08)  # the veil's full height at the centre


def test_the_blurred_edge_of_the_occluder_is_left_out():
    """A bright lobe beside the occluder lights its first pixels (the point-spread
    function): with every dark pixel the veil reads high, beyond the margin it is right."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(3)
    h, w = 120, 160
    v, u = np.mgrid[:h, :w]
    field = np.hypot(u - 80, v - 60) <= 58
    occluded = field & (u < 60)
    lit = np.where(field & ~occluded, 1.0, 0.0)
    lobe = 60000.0 * np.exp(-0.5 * (((u - 64) / 3.0) ** 2 + ((v - 60) / 6.0) ** 2)) * lit
    std_sig = 2000.0 * lit + 20.0 * field
    meas_sig = gaussian_filter(200.0 * lit + lobe, 1.5) * field + 10.0 * field
    std, bg, meas = _cap(std_sig, rng), _cap(np.zeros((h, w)), rng), _cap(meas_sig, rng)
    scale = 0.01 / 4.0**2
    near = glare_offset(meas, bg, dark_region(std, bg, field, margin=0)).value * scale
    far = glare_offset(meas, bg, dark_region(std, bg, field)).value * scale
    assert near > 10.5  # the lobe's blurred edge
    assert far == pytest.approx(10.0, abs=0.15)


def test_no_dark_region_and_bad_fraction():
    rng = np.random.default_rng(1)
    field = np.ones((20, 20), bool)
    std, bg = _cap(np.full((20, 20), 1000.0), rng), _cap(np.full((20, 20), 50.0), rng)
    assert dark_region(std, bg, field) is None
    with pytest.raises(ValueError, match="fraction"):
        dark_region(std, bg, field, fraction=1.5)
    with pytest.raises(ValueError, match="margin"):
        dark_region(std, bg, field, margin=-1)


def test_certificate_factor_multiplies_eq2():
    sim = pytest.importorskip("gonio.simulator")
    from gonio.calibration import reduce_selected

    class Flat:  # a certificate stating R = 1.1 everywhere up to 80 deg
        rho = 0.99
        theta_o_deg = (0.0, 80.0)

        def check_covers(self, theta_i, theta_o=None):
            if np.degrees(np.max(theta_i)) > 80.0:
                raise ValueError("theta_i not covered")

        def factor_at(self, ti, to, dphi):
            return np.full(np.shape(to), 1.1)

    inst = sim.LBLInstrument(width=320, height=240)
    ti = math.radians(30.0)
    std = Capture(inst.bracket("standard", ti, 0.0, noise=False))
    bg = Capture(inst.bracket(None, ti, 0.0, noise=False))
    meas = Capture(inst.bracket("rolled_brass", ti, 0.0, noise=False))
    plain = reduce_selected(meas, std, bg, rng=1).samples
    cert = reduce_selected(meas, std, bg, rng=1, certificate=Flat()).samples
    top = plain.theta_o <= math.radians(80.0)  # the same selection (same seed), covered
    assert np.allclose(cert.value, 1.1 * plain.value[top])
    assert np.allclose(cert.sigma, 1.1 * plain.sigma[top])
    steep = [Capture(inst.bracket(x, math.radians(85.0), 0.0, noise=False))
             for x in ("rolled_brass", "standard", None)]  # fmt: skip
    with pytest.raises(ValueError, match="covered"):
        reduce_selected(*steep, rng=1, certificate=Flat())


def test_the_veil_shape_from_the_standard_ignores_the_beams_glow():
    """Near normal incidence the beam's glow on the dome fills the background's central
    rings; the shape read from the standard's light (over its certified factor) does not
    see it, the background's does."""
    rng = np.random.default_rng(4)
    h, w = 120, 160
    v, u = np.mgrid[:h, :w]
    r = np.hypot(u - 80, v - 60) / 58.0
    field = r <= 1.0
    resp = np.where(field, 1.0 - 0.2 * r**2, 0.0)
    glow = 60.0 * np.exp(-0.5 * (r / 0.15) ** 2) * field
    factor = 1.0 + 0.1 * r**2  # the standard's certified reflectance factor
    bg = _cap(3.0 * resp + glow, rng)
    std = _cap(3.0 * resp + glow + 2500.0 * resp * factor, rng)
    th = (r * math.pi / 2).ravel()
    want = np.where(field, resp, 0.0).ravel()
    want = want / want[field.ravel()].mean()
    centre = field.ravel() & (r.ravel() < 0.2)
    from_bg = veil_shape(bg, field, th)
    from_std = veil_shape(bg, field, th, standard=std, factor=factor.ravel())
    assert from_bg[centre].mean() > 2.0 * want[centre].mean()
    assert np.allclose(from_std[field.ravel()], want[field.ravel()], rtol=0.02)


def test_a_captures_signal_at_chosen_pixels_is_its_whole_signal_there():
    # glare_offset reads a sample capture's veil at the dark pixels only: the same values
    from gonio.calibration.glare import _longest_signal

    rng = np.random.default_rng(3)
    sig = rng.uniform(0.0, 5000.0, (30, 40))  # some pixels saturate
    frames = [(img, {**meta, "exposure_s": t})
              for t in (0.004, 0.01) for img, meta in _cap(sig * t / 0.01, rng).frames]  # fmt: skip
    at = rng.choice(sig.size, 300, replace=False)
    part = _longest_signal(Capture(frames), at)
    whole = _longest_signal(Capture(frames))
    assert np.array_equal(part[0], whole[0][at]) and np.array_equal(part[1], whole[1][at])
    assert not whole[1].all()  # (saturated pixels are marked)
    assert np.array_equal(_longest_signal(Capture(frames), at)[0], part[0])


def test_a_digitised_images_dark_region_limits_are_the_cameras_in_its_pixels():
    """Ward's 108 x 80 digitiser (Ward 1992 §3) averages about 6 x 6 camera pixels: the
    camera's six-pixel margin is one digitised pixel (plus the box straddling the edge) and
    the camera's 200-pixel minimum is six (floored at MIN_BINNED_PIXELS)."""
    from gonio.calibration.glare import (
        DARK_MARGIN_PX,
        MIN_BINNED_PIXELS,
        MIN_DARK_PIXELS,
        binned_limits,
    )

    assert binned_limits(640, 480, 640, 480) == (DARK_MARGIN_PX, MIN_DARK_PIXELS)
    assert binned_limits(640, 480, 108, 80) == (2, MIN_BINNED_PIXELS)
    assert binned_limits(640, 480, 320, 240) == (4, 50)
    with pytest.raises(ValueError, match="min_pixels must be a positive integer"):
        dark_region(None, None, np.ones((2, 2), bool), min_pixels=0)
