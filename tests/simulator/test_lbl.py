"""The simulated LBL imaging gonioreflectometer (Ward 1992, §3)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from gonio.simulator import (
    STANDARD,
    LBLInstrument,
    Source,
    capture,
    eq3_reflection_angles,
    reproduce,
)
from gonio.simulator.lbl import _GEOMETRY_CACHE

from gonio import brdf, materials
from gonio.brdf.base import BRDF

TH = math.radians(30)


@pytest.fixture(scope="module")
def inst():
    return LBLInstrument("ellipsoid", width=160, height=120)


@pytest.fixture(scope="module")
def hemi():
    return LBLInstrument("hemisphere", 0.15, 0.02, width=160, height=120, sample_radius=0.012)


def _lit(inst, th=TH, ph=0.0):
    e_std = inst.electrons(STANDARD, th, ph)
    e_bg = inst.electrons(None, th, ph)
    return e_std > e_bg


def test_capture_types_and_metadata(inst):
    img, meta = inst.capture("rolled_brass", TH, 0.2, rng=5)
    assert img.dtype == np.uint16 and img.shape == (120, 160)
    json.dumps(meta, allow_nan=False)  # the side-car must be plain JSON
    assert meta["brdf"] == {
        "name": "ward",
        "params": materials.get("rolled_brass").params,
        "material": "rolled_brass",
    }
    for key in ("mirror", "lens", "sensor", "source", "background", "exposure_s", "f_number"):
        assert key in meta
    assert meta["theta_i"] == TH and meta["phi_i"] == 0.2 and meta["seed"] == 5
    assert meta["sample"] == "brdf" and meta["shape"] == [120, 160]
    assert int(img.max()) <= meta["sensor"]["max_dn"]


def test_reproducible_with_seed_and_deterministic_without_noise(inst):
    a, _ = inst.capture("rolled_brass", TH, rng=11)
    b, meta = inst.capture("rolled_brass", TH, rng=11)
    c, _ = inst.capture("rolled_brass", TH, rng=12)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    again, _ = reproduce(meta)
    assert np.array_equal(again, a)
    n1, m1 = inst.capture("rolled_brass", TH, noise=False)
    n2, _ = inst.capture("rolled_brass", TH, noise=False)
    assert np.array_equal(n1, n2) and m1["seed"] is None and not m1["noise"]
    _, m_none = inst.capture("rolled_brass", TH, rng=None)
    assert isinstance(m_none["seed"], int)  # a drawn seed is recorded


def test_lambertian_equal_to_standard_gives_standard_image(inst):
    lam = brdf.create("lambert", rho=inst.rho_standard)
    a, _ = inst.capture(lam, TH, noise=False)
    b, _ = inst.capture(STANDARD, TH, noise=False)
    assert np.array_equal(a, b)
    lit = _lit(inst).ravel()
    # with noise: the difference of two independent captures is zero-mean noise
    x, _ = inst.capture(lam, TH, rng=1)
    y, _ = inst.capture(STANDARD, TH, rng=2)
    d = x.astype(float).ravel()[lit] - y.astype(float).ravel()[lit]
    assert abs(d.mean()) < 4.0 * d.std() / math.sqrt(d.size)
    # and a Lambertian of half the reflectance gives half the signal
    half = inst.electrons(brdf.create("lambert", rho=inst.rho_standard / 2), TH, 0.0)
    bg = inst.electrons(None, TH, 0.0)
    full = inst.electrons(STANDARD, TH, 0.0)
    assert np.allclose((half - bg)[lit.reshape(bg.shape)], 0.5 * (full - bg)[lit.reshape(bg.shape)])


def _eq2_on_lit_pixels(inst, v, vs, vb):
    """Eq. 2 on the pixels the standard lights (``vs > vb``): the mask, the BRDF it gives, and
    each lit pixel's camera-ray polar and azimuth angles (the inputs of eq. 3)."""
    lit = vs > vb
    rho = (v - vb)[lit] / (vs - vb)[lit] * inst.rho_standard / math.pi
    d = inst.lens.unproject(inst.lens.pixel_grid()[lit])
    tc = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    pc = np.arctan2(d[:, 1], d[:, 0])
    return lit, rho, tc, pc


def test_eq2_recovers_the_brdf_through_eq3(inst):
    """(V - V_bg)/(V_std - V_bg) rho_std/pi = f_r at the angles eq. 3 assigns (ellipsoid)."""
    model = materials.get("rolled_brass")
    ph = math.radians(25)
    kw = dict(f_number=22.0)
    v = inst.electrons(model, TH, ph, **kw)
    vs = inst.electrons(STANDARD, TH, ph, **kw)
    vb = inst.electrons(None, TH, ph, **kw)
    lit, rho, tc, pc = _eq2_on_lit_pixels(inst, v, vs, vb)
    R, D = inst.mirror.radius, inst.mirror.half_separation
    tr, pr = eq3_reflection_angles(tc, pc, R, D, mirror="ellipsoid")
    pl = pr - (inst.source.arm_azimuth - ph)  # dome azimuth -> sample frame
    wo = np.stack([np.sin(tr) * np.cos(pl), np.sin(tr) * np.sin(pl), np.cos(tr)], -1)
    wi = np.array([math.sin(TH) * math.cos(ph), math.sin(TH) * math.sin(ph), math.cos(TH)])
    assert np.allclose(rho, model(wi, wo), rtol=1e-10)
    assert lit.sum() > 0.7 * math.pi / 4 * 120**2 * 0.98**2


def test_linear_in_exposure(inst):
    sen = inst.sensor
    a, _ = inst.capture("rolled_aluminum", TH, exposure=0.002, f_number=8, noise=False)
    b, _ = inst.capture("rolled_aluminum", TH, exposure=0.004, f_number=8, noise=False)
    c, _ = inst.capture(
        "rolled_aluminum", TH, exposure=0.004, f_number=8 / math.sqrt(2), noise=False
    )
    a = a.astype(float) - sen.black_level
    b = b.astype(float) - sen.black_level
    c = c.astype(float) - sen.black_level
    ok = b < 0.9 * (sen.saturation_dn - sen.black_level)
    assert ok.sum() > 1000 and (a > 100).sum() > 100
    assert np.abs(b - 2 * a)[ok].max() <= 1.0  # rounding of a, doubled, plus rounding of b
    # one stop wider aperture = doubled exposure (dark current is not scaled by aperture)
    ec = inst.electrons("rolled_aluminum", TH, exposure=0.004, f_number=8 / math.sqrt(2))
    eb = inst.electrons("rolled_aluminum", TH, exposure=0.004, f_number=8)
    eb2 = inst.electrons("rolled_aluminum", TH, exposure=0.008, f_number=8)
    assert np.all(ec <= eb2 + 1e-6) and np.all(ec >= eb - 1e-9)
    assert np.abs(c - b).max() > 10


def test_saturation(inst):
    img, meta = inst.capture("rolled_brass", TH, exposure=1.0, f_number=2, noise=False)
    assert img.max() == int(meta["sensor"]["saturation_dn"])


class _Mirror(BRDF):
    """A perfect mirror: nothing but a delta component of reflectance 0.8."""

    name = "test_mirror"

    def _eval(self, wi, wo):
        return np.zeros(np.broadcast_shapes(wi.shape, wo.shape)[:-1])

    def delta(self, wi):
        wi = np.asarray(wi, dtype=float)
        return wi * np.array([-1.0, -1.0, 1.0]), np.full(wi.shape[:-1], 0.8)


def test_specular_sample_lights_exactly_the_mirror_pixels():
    gam = math.radians(3.0)
    inst = LBLInstrument("ellipsoid", width=160, height=120, source=Source(divergence=gam))
    ph = math.radians(40)
    m = _Mirror()
    assert m.has_delta
    sig = inst.electrons(m, TH, ph) - inst.electrons(None, TH, ph)
    lit = np.flatnonzero(sig.ravel() > 1e-9)
    g = inst.geometry
    wi_dome = np.array([math.sin(TH), 0.0, math.cos(TH)])  # arm azimuth 0
    mirror_dir = wi_dome * [-1, -1, 1]
    wo = np.stack([g.wx, g.wy, g.wz], -1)
    ang = np.arccos(np.clip(wo @ mirror_dir, -1, 1))
    pos = {p: a for p, a in zip(g.idx, ang)}
    assert lit.size > 10
    # every lit pixel's footprint reaches into the cone, every pixel well inside is lit
    assert max(pos[p] for p in lit) <= gam + g.pixel_angle
    inside = {p for p, a in pos.items() if a < gam - g.pixel_angle}
    assert inside and inside <= set(lit.tolist())
    # fully covered pixels carry the mirror's radiance rho E T / Omega_s
    k = inst.source.irradiance * inst.mirror.transmittance * inst.mirror.reflectance * 0.01 / 16
    resp, _ = inst._response()
    expect = k * resp * 0.8 / inst.source.solid_angle
    p = next(iter(inside))
    assert sig.ravel()[p] == pytest.approx(expect[p], rel=1e-12)
    # the same image through capture()
    img, _ = inst.capture(m, TH, ph, noise=False)
    bg, _ = inst.capture(None, TH, ph, noise=False)
    assert set(np.flatnonzero(img.ravel() > bg.ravel() + 1).tolist()) <= set(lit.tolist())


def test_unlit_pixels_read_background(hemi):
    """Pixels whose ray misses the sample or the beam footprint read only the background."""
    small = LBLInstrument(
        "hemisphere", 0.15, 0.02, width=160, height=120, sample_radius=0.012,
        source=Source(spot_radius=0.0005),
    )  # fmt: skip
    e = small.electrons("rolled_brass", TH)
    bg = small.electrons(None, TH)
    lit = e > bg
    g = small.geometry
    assert 0 < lit.sum() < g.idx.size  # the spot is smaller than what the camera sees
    assert np.array_equal(e[~lit], bg[~lit])
    q2 = g.qx**2 + g.qy**2
    assert lit.ravel()[g.idx[q2 < 1e-8]].all()
    # background is present with and without a sample, and brighter near the beam crossing
    assert bg.min() >= 0 and bg.max() > 2 * np.median(bg[bg > 0])


def test_kernel_and_generic_paths_agree(inst, hemi):
    for ins in (inst, hemi):
        for name in ("rolled_brass", "ward_approx", "lambert"):
            a = ins.electrons(name, TH, 0.4)
            b = ins.electrons(name, TH, 0.4, kernel=False)
            c = ins.electrons(name, TH, 0.4, kernel=False, visible_only=False)
            assert np.allclose(a, b, rtol=1e-12, atol=0)
            assert np.array_equal(b, c)


def test_any_brdf_can_be_imaged(inst):
    ward = materials.get("rolled_brass")
    via_callable = inst.electrons(lambda wi, wo: ward(wi, wo), TH, 0.3)
    via_model = inst.electrons(ward, TH, 0.3)
    assert np.allclose(via_callable, via_model, rtol=1e-12)
    for s in ("oren_nayar", brdf.create("lafortune")):
        img, meta = inst.capture(s, TH, noise=False)
        assert meta["brdf"]["name"] in brdf.names()
        assert img.max() > inst.capture(None, TH, noise=False)[0].max()


def test_binning_to_ward_resolution(inst):
    img, meta = inst.capture("rolled_brass", TH, binning=True, noise=False)
    assert img.shape == (80, 108) and meta["lens"]["width"] == 108
    full, _ = inst.capture("rolled_brass", TH, noise=False)
    assert abs(img.astype(float).mean() - full.astype(float).mean()) < 1.0
    again, _ = reproduce(meta)
    assert np.array_equal(again, img)


def test_bracketing():
    inst = LBLInstrument("ellipsoid", width=160, height=120)
    # a two-level BRDF: a bright cap and a dim floor 2000x lower with no values in between,
    # so the stops between the two ranges add no pixel and are skipped

    def two_level(wi, wo):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        return np.where(h[..., 2] > math.cos(0.1), 20.0, 0.01)

    plan = inst.plan_bracket(two_level, TH, f_stops=(32, 22, 16, 11, 8, 5.6, 4, 2.8, 2, 1.4))
    assert len(plan["f_numbers"]) >= 2 and plan["skipped"]
    assert plan["covered_fraction"] == 1.0 and not plan["peak_saturated"]
    shots = inst.bracket(two_level, TH, noise=False)
    first = shots[0][0]
    assert first.max() < inst.sensor.saturation_dn  # the peak is not saturated
    assert [m["f_number"] for _, m in shots] == plan["f_numbers"]
    assert inst.plan_bracket("lambert", TH)["f_numbers"] == [2.0]


def test_grey_bands_evaluated_once(inst):
    once = inst.capture_bands("rolled_brass", TH, noise=False)
    each = inst.capture_bands("rolled_brass", TH, noise=False, evaluate_once=False)
    assert len(once) == 3
    for (a, _), (b, _) in zip(once, each):
        assert np.array_equal(a, b)
    assert [m["filter_nm"] for _, m in once] == [450.0, 550.0, 650.0]


def test_camera_render_hook(inst):
    render = inst.camera_render("rolled_brass", noise=False)
    img, meta = render({"source": 30.0, "sample": -40.0}, 0.01, 4.0)
    assert meta["phi_i"] == pytest.approx(math.radians(40))
    ref, _ = inst.capture("rolled_brass", TH, math.radians(40), noise=False)
    assert np.array_equal(img, ref)


def test_geometry_is_cached():
    a = LBLInstrument("hemisphere", 0.1, 0.01, width=64, height=48, sample_radius=0.005)
    b = LBLInstrument("hemisphere", 0.1, 0.01, width=64, height=48, sample_radius=0.005)
    assert a.geometry is b.geometry
    assert any(v is a.geometry for v in _GEOMETRY_CACHE.values())


def test_module_level_capture():
    img, meta = capture(STANDARD, TH, noise=False)
    assert img.shape == (480, 640) and meta["sample"] == "standard"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"theta_i": math.pi / 2}, "theta_i must be in"),
        ({"theta_i": 2.0}, "theta_i must be in"),
        ({"theta_i": -0.1}, "theta_i must be in"),
        ({"exposure": -0.01}, "exposure must be a finite positive"),
        ({"exposure": 0.0}, "exposure"),
        ({"f_number": 0.0}, "f_number"),
        ({"rng": -3}, "rng must be"),
        ({"sample": "unobtainium"}, "neither a material preset"),
        ({"sample": 42}, "sample must be"),
        ({"binning": (0, 3)}, "binning"),
    ],
)
def test_bad_capture_input(inst, kwargs, match):
    args = {"sample": "rolled_brass", "theta_i": TH}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        inst.capture(args.pop("sample"), args.pop("theta_i"), **args)


def test_bad_instrument_input():
    with pytest.raises(ValueError, match="half_separation D"):
        LBLInstrument("hemisphere", 0.1, 0.1)
    with pytest.raises(ValueError, match="lens 'pinhole' is unknown"):
        LBLInstrument(lens="pinhole")
    with pytest.raises(ValueError, match="mirror 'flat' is unknown"):
        LBLInstrument("flat")
    with pytest.raises(ValueError, match="sample_radius"):
        LBLInstrument(half_separation=0.01, sample_radius=0.03)
    with pytest.raises(ValueError, match="rho_standard"):
        LBLInstrument(rho_standard=1.2)


def test_tabulated_grey_and_spectral(inst):
    from gonio.io.merl import tabulate

    grey = brdf.create("tabulated", data=tabulate("lambert", rho=0.5))
    img, meta = inst.capture(grey, TH, noise=False)
    assert meta["brdf"]["params"]["data"]["ndarray_shape"] == [90, 90, 180]
    json.dumps(meta)
    lam, _ = inst.capture(brdf.create("lambert", rho=0.5), TH, noise=False)
    # MERL's nearest-cell lookup reads 0 within a few tenths of a degree of grazing
    g = inst.geometry
    keep = np.zeros(img.size, bool)
    keep[g.idx[g.wz > math.cos(math.radians(85))]] = True
    keep = keep.reshape(img.shape)
    assert np.abs(img.astype(int) - lam)[keep].max() <= 1
    with pytest.raises(ValueError, match="pass it as sample"):
        reproduce(meta)
    assert np.array_equal(reproduce(meta, grey)[0], img)
    # three bands scaled 1 : 2 : 3 -> per-filter signals in that ratio
    t = tabulate("lambert", rho=0.2)
    spec = brdf.create(
        "tabulated", data=np.stack([t, 2 * t, 3 * t]), wavelengths_nm=[450, 550, 650]
    )
    e = [inst.electrons(spec, TH, band=b) for b in range(3)]
    bg = inst.electrons(None, TH)
    lit = e[0] > bg
    assert np.allclose((e[1] - bg)[lit], 2 * (e[0] - bg)[lit])
    assert np.allclose((e[2] - bg)[lit], 3 * (e[0] - bg)[lit])
    shots = inst.capture_bands(spec, TH, 0.0, (452.0, 550.0, 648.0), noise=False)
    assert [m["band"] for _, m in shots] == [0, 1, 2]
    with pytest.raises(ValueError, match="within 5 nm"):
        inst.capture_bands(spec, TH, 0.0, (500.0,))


def test_camera_render_negative_arm_angle(inst):
    render = inst.camera_render("rolled_brass", noise=False)
    img, meta = render({"source": -30.0, "sample": 0.0}, 0.01, 4.0)
    assert meta["theta_i"] == pytest.approx(TH)
    assert meta["phi_i"] == pytest.approx(math.pi)
    assert np.array_equal(img, inst.capture("rolled_brass", TH, math.pi, noise=False)[0])
    with pytest.raises(ValueError, match="theta_i"):
        render({"source": 95.0, "sample": 0.0}, 0.01, 4.0)


def test_eq2_hemisphere_with_exact_trace_and_eq3_error(hemi):
    """Hemisphere: eq. 2 gives f_r at the exactly traced angles; eq. 3's angles are off by
    at most (D/R)² rad."""
    from gonio.simulator import traced_reflection_angles

    model = materials.get("lightly_brushed_aluminum")
    ph = math.radians(-50)
    v, vs, vb = (hemi.electrons(s, TH, ph, f_number=22.0) for s in (model, STANDARD, None))
    _, rho, tc, pc = _eq2_on_lit_pixels(hemi, v, vs, vb)
    R, D = hemi.mirror.radius, hemi.mirror.half_separation
    tr, pr, _ = traced_reflection_angles(tc, pc, R, D, "hemisphere")
    te, pe = eq3_reflection_angles(tc, pc, R, D)

    def vec(t, p):
        p = p - (hemi.source.arm_azimuth - ph)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

    wi = np.array([math.sin(TH) * math.cos(ph), math.sin(TH) * math.sin(ph), math.cos(TH)])
    assert np.allclose(rho, model(wi, vec(tr, pr)), rtol=1e-10)
    err = np.arccos(np.clip(np.sum(vec(tr, pr) * vec(te, pe), -1), -1, 1))
    assert err.max() <= (D / R) ** 2 * 1.01
    assert not np.allclose(rho, model(wi, vec(te, pe)), rtol=1e-6)


def test_video_response_curve():
    from gonio.simulator import Sensor

    inst = LBLInstrument(width=80, height=60, sensor=Sensor(response_gamma=0.45, adc_bits=8))
    img, meta = inst.capture("rolled_brass", TH, noise=False)
    e = inst.electrons("rolled_brass", TH)
    assert np.array_equal(img, inst.sensor.digitise(e))
    assert meta["sensor"]["response_gamma"] == 0.45 and img.max() <= 255
    lin = LBLInstrument(width=80, height=60, sensor=Sensor(adc_bits=8))
    a = lin.capture("rolled_brass", TH, noise=False)[0].astype(float) - 64
    b = img.astype(float) - 64
    mid = (a > 5) & (a < 150)
    assert np.all(b[mid] >= a[mid])  # gamma < 1 lifts the mid-tones


# --------------------------------------------------------------------------- fast bracket / noise
def _two_level(wi, wo):
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return np.where(h[..., 2] > math.cos(0.1), 20.0, 0.01)


@pytest.mark.parametrize(
    "sample, phi",
    [("rolled_brass", 0.0), ("rolled_brass", math.pi / 2), (STANDARD, 0.0), (None, 0.0),
     (_two_level, 0.3), ("mirror", 0.4)],
)  # fmt: skip
def test_bracket_noise_off_equals_separate_captures(sample, phi):
    # the bracket renders the scene once and composes every stop from it; each frame must be
    # the capture at that f-number bit for bit (also binned, and with a mirror component)
    inst = LBLInstrument("ellipsoid", width=160, height=120, source=Source(divergence=0.05))
    smp = _Mirror() if sample == "mirror" else sample
    for binning in (None, (40, 30)):
        shots = inst.bracket(smp, TH, phi, noise=False, binning=binning)
        plan = inst.plan_bracket(smp, TH, phi)
        assert [m["f_number"] for _, m in shots] == plan["f_numbers"]
        for i, (img, meta) in enumerate(shots):
            ref, rmeta = inst.capture(smp, TH, phi, f_number=meta["f_number"], noise=False,
                                      binning=binning)  # fmt: skip
            assert np.array_equal(img, ref)
            assert meta["bracket"] == {"index": i, **plan}
            assert {k: v for k, v in meta.items() if k != "bracket"} == rmeta


def test_bracket_noise_is_seeded_per_stop(inst):
    a = inst.bracket("rolled_brass", TH, rng=5)
    b = inst.bracket("rolled_brass", TH, rng=5)
    c = inst.bracket("rolled_brass", TH, rng=6)
    assert all(np.array_equal(x[0], y[0]) for x, y in zip(a, b))
    assert not np.array_equal(a[0][0], c[0][0])
    assert all(m["seed"] == 5 for _, m in a)


def _standardised_residuals(inst, img, e):
    """(DN - model mean) / model sd: shot + read noise + rounding (1/12 DN²), at pixels far
    from saturation whose noise is at least 1 DN (where rounding adds a uniform 1/12)."""
    sen = inst.sensor
    lam = e.ravel()
    dn = img.ravel().astype(float)
    var_e = lam + sen.read_noise**2
    mean = sen.black_level + lam / sen.gain
    ok = (var_e >= sen.gain**2) & (mean + 6 * np.sqrt(var_e) / sen.gain < sen.saturation_dn)
    var = var_e[ok] / sen.gain**2 + 1.0 / 12.0
    return (dn[ok] - mean[ok]) / np.sqrt(var)


@pytest.mark.parametrize(
    "read_noise, gain, full_well",
    [(8.0, 10.0, 40000.0), (3.0, 1.0, 4000.0), (1.0, 0.5, 2000.0)],
)
def test_capture_noise_matches_the_sensor_model(read_noise, gain, full_well):
    # fused compose + noise + ADC in the three draw regimes (read noise 8 e-: skew-corrected
    # normal at every mean; 3 e-: exact Poisson below 30 e-; 1 e-: exact everywhere): the DN
    # of every pixel has the model's mean and variance; reproducible from the seed
    from gonio.simulator import Sensor

    sen = Sensor(read_noise=read_noise, gain=gain, full_well=full_well)
    assert sen.normal_threshold == {8.0: 0.0, 3.0: 30.0, 1.0: math.inf}[read_noise]
    inst = LBLInstrument("ellipsoid", width=160, height=120, sensor=sen)
    zs = []
    for f_number, smp in ((2.8, STANDARD), (8.0, "rolled_brass"), (2.0, None), (16.0, None)):
        t = 0.01 * full_well / 40000.0  # similar fill of the full well
        img, meta = inst.capture(smp, TH, exposure=t, f_number=f_number, rng=11)
        assert np.array_equal(img, reproduce(meta)[0])
        e = inst.electrons(smp, TH, exposure=t, f_number=f_number)
        zs.append(_standardised_residuals(inst, img, e))
    z = np.concatenate(zs)
    assert z.size > 20000
    se = 1.0 / math.sqrt(z.size)
    assert abs(z.mean()) < 5 * se
    assert abs(z.var() - 1.0) < 5 * math.sqrt(2.0) * se


def test_skip_stops_switch_keeps_every_stop_and_the_same_coverage():
    inst = LBLInstrument("ellipsoid", width=160, height=120)
    stops = (32, 22, 16, 11, 8, 5.6, 4, 2.8, 2, 1.4)
    on = inst.plan_bracket(_two_level, TH, f_stops=stops)
    off = inst.plan_bracket(_two_level, TH, f_stops=stops, skip_stops=False)
    assert on["skipped"] and not off["skipped"]
    assert set(on["f_numbers"]) < set(off["f_numbers"])
    assert off["f_numbers"] == sorted(off["f_numbers"], reverse=True)
    assert off["f_numbers"][0] == on["f_numbers"][0]
    assert off["covered_fraction"] == on["covered_fraction"] == 1.0
    frames = inst.bracket(_two_level, TH, f_stops=stops, noise=False, skip_stops=False)
    assert [m["f_number"] for _, m in frames] == off["f_numbers"]
    with pytest.raises(ValueError, match="unexpected"):
        inst.bracket(_two_level, TH, noise=False, bogus=1)


def test_skip_noise_draws_switch_gives_the_same_image(inst):
    a, _ = inst.capture("rolled_brass", TH, noise=False)
    b, _ = inst.capture("rolled_brass", TH, noise=False, skip_noise_draws=False)
    assert np.array_equal(a, b)


def test_rays_per_pixel_supersampling():
    inst = LBLInstrument("ellipsoid", width=80, height=60)
    one = inst.electrons("rolled_brass", TH)
    assert np.array_equal(inst.electrons("rolled_brass", TH, rays_per_pixel=1), one)
    # a smooth (Lambertian) sample: the pixel average equals the centre value to first order,
    # and the supersampled image converges as the sub-pixel grid is refined
    sharp = brdf.create("ward", rho_d=0.02, rho_s=0.3, alpha_x=0.02, alpha_y=0.02)
    bg = inst.electrons(None, TH)
    imgs = {n: inst.electrons(sharp, TH, rays_per_pixel=n) - bg for n in (1, 4, 16, 64)}
    ref = imgs[64]
    lit = ref > 1e-3 * ref.max()
    err = {n: float(np.abs(imgs[n] - ref)[lit].sum() / ref[lit].sum()) for n in (1, 4, 16)}
    assert err[1] > err[4] > err[16] and err[16] < 0.3 * err[1]
    # total signal is conserved to within the sample-edge pixels
    assert imgs[16].sum() == pytest.approx(imgs[1].sum(), rel=0.02)
    # the kernel and generic paths agree with sub-pixel rays too (repeated pixel indices)
    lamb = inst.electrons("lambert", TH, rays_per_pixel=4)
    lamb_np = inst.electrons("lambert", TH, rays_per_pixel=4, kernel=False)
    assert np.allclose(lamb, lamb_np, rtol=1e-12, atol=0)
    img, meta = inst.capture(sharp, TH, noise=False, rays_per_pixel=4)
    assert meta["rays_per_pixel"] == 4
    assert "rays_per_pixel" not in inst.capture(sharp, TH, noise=False)[1]
    assert np.array_equal(reproduce(meta, sample=sharp)[0], img)
    br = inst.bracket(sharp, TH, noise=False, rays_per_pixel=4)
    ref_img, _ = inst.capture(sharp, TH, noise=False, rays_per_pixel=4,
                              f_number=br[0][1]["f_number"])  # fmt: skip
    assert np.array_equal(br[0][0], ref_img)
    for bad in (2, 0, 100, 2.5, "4"):
        with pytest.raises(ValueError, match="rays_per_pixel"):
            inst.capture(sharp, TH, rays_per_pixel=bad)


@pytest.mark.parametrize("preset", ["ideal", "modern"])
def test_capture_series_equals_separate_captures(preset):
    # one scene rendered for every frame of the series; each frame (noise on, seeded, with
    # the realistic instrument's effects) must be the separate capture bit for bit
    from gonio.simulator.effects import realise

    inst = LBLInstrument("ellipsoid", width=160, height=120, effects=realise(preset, 3),
                         instrument_seed=3)  # fmt: skip
    settings = [{"exposure": 0.004 * (n / 2.0) ** 2, "f_number": n, "rng": 11 + i}
                for i, n in enumerate((2.0, 5.6, 16.0, 2.0))]  # fmt: skip
    for sample in (STANDARD, "rolled_brass", None):
        got = inst.capture_series(sample, TH, 0.2, settings=settings)
        assert len(got) == len(settings)
        for (img, meta), s in zip(got, settings):
            ref, rmeta = inst.capture(sample, TH, 0.2, **s)
            assert np.array_equal(img, ref)
            assert meta == rmeta
    with pytest.raises(ValueError, match="unknown keys"):
        inst.capture_series(STANDARD, TH, settings=[{"exposure": 0.01, "gain": 2}])
