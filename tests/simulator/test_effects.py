"""The LBL instrument's imperfections: the effect framework and the instrument's use of it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator import LBLInstrument
from gonio.simulator.effects import (
    EFFECTS,
    PRESET_OPTIONS,
    PRESETS,
    Distribution,
    EffectSpec,
    check_magnitudes,
    is_ideal,
    realise,
)
from gonio.simulator.lbl_effects import (
    fstop_area_factor,
    lamp_factor,
    psf_sigma_px,
    slope_field,
    tilt_rotation,
    true_f_number,
)

from gonio import materials

TH = math.radians(30)


@pytest.fixture(scope="module")
def small():
    return LBLInstrument(width=160, height=120)


# ---------------------------------------------------------------------------- the framework
def test_every_effect_is_documented_with_a_source_and_a_unit():
    assert len(EFFECTS) >= 18
    for name, spec in EFFECTS.items():
        assert isinstance(spec, EffectSpec) and spec.name == name
        assert spec.unit and len(spec.doc) > 60 and len(spec.reference) > 30
        lo, hi = spec.valid
        assert lo <= 0.0 < hi  # zero (off) is always a valid magnitude
        assert spec.contains(0.0)


def test_presets_state_every_effect_as_a_distribution():
    assert set(PRESETS) == {"ideal", "ward1992", "modern"} == set(PRESET_OPTIONS)
    for preset, dists in PRESETS.items():
        assert set(dists) == set(EFFECTS)
        for name, d in dists.items():
            assert isinstance(d, Distribution) and d.spread >= 0.0
            assert EFFECTS[name].contains(d.typical), (preset, name)
    assert all(d.typical == 0.0 and d.spread == 0.0 for d in PRESETS["ideal"].values())
    assert PRESET_OPTIONS["ward1992"]["binning"] == (108, 80)
    # Ward's acrylic dome and video camera are worse than a modern build
    for name in ("dome_slope_error", "veiling_glare", "reillumination", "fstop_error"):
        assert PRESETS["ward1992"][name].typical > PRESETS["modern"][name].typical


def test_realise_is_deterministic_per_seed_and_differs_between_instruments():
    a, b, c = realise("modern", 7), realise("modern", 7), realise("modern", 8)
    assert a == b and a != c
    assert set(a) == set(EFFECTS)
    assert realise("ideal", 3) == dict.fromkeys(EFFECTS, 0.0)
    assert is_ideal(realise("ideal", 3)) and is_ideal(None) and not is_ideal(a)
    # fixed effects (spread 0) are the same in every instrument
    assert a["fstop_series"] == c["fstop_series"] == 1.0


def test_realised_magnitudes_spread_as_the_preset_says_and_stay_valid():
    draws = np.array([realise("ward1992", s)["dome_slope_error"] for s in range(400)])
    d = PRESETS["ward1992"]["dome_slope_error"]
    assert abs(draws.mean() - d.typical) < 4 * d.spread / math.sqrt(400)
    assert abs(draws.std() / d.spread - 1.0) < 0.15
    for s in range(50):
        check_magnitudes(realise("ward1992", s))  # clipped into the valid ranges


def test_distribution_draw_is_clipped_to_its_range():
    d = Distribution(0.0, 1.0, (0.0, 0.5))
    rng = np.random.default_rng(0)
    v = np.array([d.draw(rng) for _ in range(200)])
    assert v.min() == 0.0 and v.max() == 0.5
    assert Distribution(0.2).draw(rng) == 0.2
    with pytest.raises(ValueError, match="spread"):
        Distribution(0.1, -1.0)


def test_realise_accepts_a_mapping_of_distributions():
    m = realise({"veiling_glare": Distribution(0.02)}, 0)
    assert m["veiling_glare"] == 0.02 and m["dome_slope_error"] == 0.0
    with pytest.raises(ValueError, match="unknown"):
        realise({"glare": Distribution(0.02)}, 0)
    with pytest.raises(ValueError, match="preset 'lab'"):
        realise("lab", 0)


@pytest.mark.parametrize(
    ("name", "value", "text"),
    [
        ("veiling_glare", 1.0, r"veiling_glare = 1.0 is outside its valid range \[0, 1\)"),
        ("dome_slope_error", -0.001, r"dome_slope_error = -0.001 .*\[0, 0.02\]"),
        ("pixel_fill", 1.5, r"pixel_fill = 1.5 .*\[0, 1\]"),
        ("lamp_drift", math.nan, r"lamp_drift = nan"),
        ("sample_height", 0.01, r"sample_height = 0.01 .*\[-0.003, 0.003\]"),
    ],
)
def test_a_magnitude_outside_its_physical_range_is_refused(name, value, text):
    with pytest.raises(ValueError, match=text):
        check_magnitudes({name: value})
    with pytest.raises(ValueError, match=text):
        LBLInstrument(width=32, height=24, effects={name: value})


def test_unknown_effects_and_bad_seeds_are_refused():
    with pytest.raises(ValueError, match="effect 'blur' is unknown"):
        LBLInstrument(width=32, height=24, effects={"blur": 0.1})
    with pytest.raises(ValueError, match="instrument_seed"):
        LBLInstrument(width=32, height=24, instrument_seed=-1)
    with pytest.raises(ValueError, match="must be a number"):
        check_magnitudes({"veiling_glare": "much"})


# ---------------------------------------------------------------------------- ideal = today's
def test_all_zero_effects_give_bit_identical_images_and_skip_the_work(small):
    zero = LBLInstrument(width=160, height=120, effects=realise("ideal", 4), instrument_seed=4)
    assert zero._fx == {} and not zero._frame_fx and not zero._scene_fx
    for sample in ("rolled_brass", "standard", None, "white_ceramic_tile"):
        for noise in (False, True):
            a = small.bracket(sample, TH, 0.3, rng=9, noise=noise)
            b = zero.bracket(sample, TH, 0.3, rng=9, noise=noise)
            assert len(a) == len(b)
            for (ia, ma), (ib, mb) in zip(a, b):
                assert np.array_equal(ia, ib) and ma == mb
    ia, _ = small.capture("rolled_brass", TH, binning=(54, 40), rng=2)
    ib, _ = zero.capture("rolled_brass", TH, binning=(54, 40), rng=2)
    assert np.array_equal(ia, ib)
    assert "_true_geometry" not in zero.__dict__
    assert zero._standard_model().name == "lambert"


def test_every_effect_changes_the_images_it_should(small):
    """Each effect at the modern preset's typical magnitude (x 5 where that is too small to
    move a noise-free DN) changes the sample's or the standard's image; but defocus, which
    this short fisheye's depth of field makes negligible (next test)."""
    base = {
        s: small.capture(s, TH, 0.0, noise=False, f_number=11.0)[0]
        for s in ("rolled_brass", "standard")
    }
    for name in EFFECTS:
        if name == "focus_error":
            continue
        v = PRESETS["modern"][name].typical
        if v == 0.0:  # signed, typically zero: take one spread
            v = PRESETS["modern"][name].spread
        v = EFFECTS[name].clip(v * (1.0 if name in ("fstop_series", "pixel_fill") else 5.0))
        inst = LBLInstrument(width=160, height=120, effects={name: v}, instrument_seed=1)
        inst.clock_s = 1200.0  # 20 min into the campaign (lamp warm-up and drift)
        changed = [
            not np.array_equal(inst.capture(s, TH, 0.0, noise=False, f_number=11.0)[0], img)
            for s, img in base.items()
        ]
        assert any(changed), name


# ---------------------------------------------------------------------------- the effects
def test_true_f_numbers_of_the_engraved_series():
    assert true_f_number(11.0, 1.0) == pytest.approx(2**3.5)
    assert true_f_number(5.6, 1.0) == pytest.approx(2**2.5)
    assert true_f_number(22.0, 1.0) == pytest.approx(2**4.5)
    assert true_f_number(8.0, 1.0) == 8.0 and true_f_number(11.0, 0.0) == 11.0
    assert true_f_number(9.5, 1.0) == 9.5  # not an engraved value: taken as exact
    assert fstop_area_factor(4.0, 0.0, 3) == 1.0
    assert fstop_area_factor(4.0, 0.02, 3) == fstop_area_factor(4.0, 0.02, 3) != 1.0


def test_marked_f11_images_like_an_ideal_lens_at_11_31(small):
    """The engraved series alone: a capture at the marked f/11 is the ideal instrument's
    capture at 2^3.5 = 11.314, bit for bit (the side-car still says 11)."""
    real = LBLInstrument(width=160, height=120, effects={"fstop_series": 1.0})
    a, meta = real.capture("rolled_brass", TH, noise=False, f_number=11.0)
    b, _ = small.capture("rolled_brass", TH, noise=False, f_number=2**3.5)
    assert meta["f_number"] == 11.0
    assert np.array_equal(a, b)


def test_lamp_warms_up_and_drifts():
    assert lamp_factor(0.0, 0.02, 0.0) == pytest.approx(0.98)
    assert lamp_factor(6000.0, 0.02, 0.0) == pytest.approx(1.0, abs=1e-5)
    assert lamp_factor(3600.0, 0.0, 0.01) == pytest.approx(1.01)
    inst = LBLInstrument(width=160, height=120, effects={"lamp_warmup": 0.1})
    e0 = inst.capture("standard", TH, noise=False, clock_s=0.0)[0].astype(float)
    e1 = inst.capture("standard", TH, noise=False, clock_s=1e5)[0].astype(float)
    bg = inst.capture(None, TH, noise=False)[0].astype(float)
    lit = e1 - bg > 500
    ratio = (e0 - bg)[lit].sum() / (e1 - bg)[lit].sum()
    assert ratio == pytest.approx(0.9, abs=2e-3)


def test_psf_sigma_adds_its_terms_in_quadrature():
    assert psf_sigma_px(8.0, {}, 9e-6, 150.0, 0.075) == 0.0
    assert psf_sigma_px(8.0, {"pixel_fill": 1.0}, 9e-6, 150.0, 0.075) == pytest.approx(
        math.sqrt(1 / 12)
    )
    d = psf_sigma_px(8.0, {"diffraction_wavelength": 550.0}, 9e-6, 150.0, 0.075)
    assert d == pytest.approx(0.42 * 550e-9 * 8.0 / 9e-6)
    both = psf_sigma_px(
        8.0, {"diffraction_wavelength": 550.0, "pixel_fill": 1.0}, 9e-6, 150.0, 0.075
    )
    assert both == pytest.approx(math.hypot(d, math.sqrt(1 / 12)))


def test_defocus_of_the_short_fisheye_is_far_below_a_pixel(small):
    """Focused at R/2 = 75 mm, a 1.35 mm fisheye (150 px/rad at 9 um) has a hyperfocal
    distance f^2 / (N c) of ~50 mm at f/4: the modern preset's focus error blurs < 0.05
    pixel even at f/2, a 50 % error < 0.2 pixel."""
    fpx = small.lens.fx * 4.0  # the 640 x 480 default lens
    typical = PRESETS["modern"]["focus_error"].typical
    assert 0.0 < psf_sigma_px(2.0, {"focus_error": typical}, 9e-6, fpx, 0.075) < 0.05
    assert psf_sigma_px(2.0, {"focus_error": 0.5}, 9e-6, fpx, 0.075) < 0.2


def test_dome_slope_map_grows_towards_the_rim_and_is_the_instruments_own():
    r = 0.15
    t = np.linspace(0.0, 2 * math.pi, 4000, endpoint=False)
    rim = np.stack([r * np.cos(t), r * np.sin(t), np.zeros_like(t)], -1)
    mid = rim * 0.5
    mid[:, 2] = r * math.sqrt(0.75)
    rms = [math.sqrt(np.mean(np.square(slope_field(p, 4e-3, r, 5)[0]))) for p in (rim, mid)]
    assert rms[0] == pytest.approx(4e-3, rel=0.5)  # one realisation of 12 modes
    assert rms[1] == pytest.approx(rms[0] * 0.25, rel=0.6)  # (rho/R)^2
    a = slope_field(rim, 4e-3, r, 5)[0]
    assert np.array_equal(a, slope_field(rim, 4e-3, r, 5)[0])
    assert not np.array_equal(a, slope_field(rim, 4e-3, r, 6)[0])


def test_tilt_rotation_maps_the_tilted_normal_to_z():
    t = tilt_rotation(0.01, 0.7)
    n = np.array([math.sin(0.01) * math.cos(0.7), math.sin(0.01) * math.sin(0.7), math.cos(0.01)])
    assert t @ n == pytest.approx([0.0, 0.0, 1.0], abs=1e-15)
    assert t @ t.T == pytest.approx(np.eye(3), abs=1e-15)


def test_dome_figure_error_moves_the_specular_peak(small):
    """A 4 mrad rim slope error deviates reflected directions by up to ~2 x 4 mrad: the
    pixels of a narrow lobe shift, the standard's smooth image hardly changes."""
    bad = LBLInstrument(width=160, height=120, effects={"dome_slope_error": 4e-3})
    g0, g1 = small._geometry(1), bad._scene_geometry("brdf", 1)
    common, i0, i1 = np.intersect1d(g0.idx, g1.idx, return_indices=True)
    assert common.size > 0.8 * g0.idx.size  # (grazing rays: the sample point moves ~1/cos)
    w0 = np.stack([g0.wx[i0], g0.wy[i0], g0.wz[i0]], -1)
    w1 = np.stack([g1.wx[i1], g1.wy[i1], g1.wz[i1]], -1)
    ang = np.arccos(np.clip(np.sum(w0 * w1, -1), -1, 1))
    assert 1e-4 < np.median(ang) and ang.max() < 8 * 4e-3


def test_occlusion_removes_grazing_pixels_only(small):
    occ = LBLInstrument(
        width=160, height=120, effects={"lens_body_height": 0.003, "holder_rim_height": 0.0005}
    )
    g0, g1 = small._geometry(1), occ._scene_geometry("standard", 1)
    assert 0 < g1.idx.size < g0.idx.size
    lost = np.setdiff1d(g0.idx, g1.idx)
    pos = np.searchsorted(g0.idx, lost)
    assert np.degrees(np.arccos(g0.wz[pos])).min() > 60.0  # only grazing directions


@pytest.mark.parametrize("height", [3e-4, -5e-4, 0.0])
def test_the_rim_test_of_a_raised_sample_reads_only_the_points_near_the_rim(height):
    # the bound on the moved radii (|h| tan θi) must select exactly the points a test of
    # every point selects, on both sides of the rim and at every incidence
    from gonio.simulator.lbl import _near_rim

    inst = LBLInstrument(
        width=160, height=120, effects={"sample_height": height, "sample_tilt": 0.002}
    )
    g = inst._scene_geometry("brdf", 1)
    rs = inst.sample_radius
    for th in np.radians([0.0, 20.0, 55.0, 80.0]):
        wi_local, wi_dome, psi = inst._frames(th, 0.4)
        posed, _ = inst._posed(g, th, wi_local, wi_dome, psi)
        r = np.hypot(posed.qx, posed.qy)
        for r_min in (0.0, 0.6 * rs, 0.95 * rs, float(np.median(r)), float(r.max())):
            got = _near_rim(posed, r_min)
            assert np.array_equal(got, np.flatnonzero(r > r_min)), (th, r_min)


def test_standard_of_the_real_instrument_is_ptfe_and_its_certificate_says_so():
    inst = LBLInstrument(
        width=160, height=120,
        effects={"standard_non_lambertian": 1.0, "standard_certificate_u": 0.005},
    )  # fmt: skip
    cert = inst.certificate()
    assert cert.expanded_uncertainty == pytest.approx(0.01)
    assert cert.rho == inst.rho_standard
    wi = np.array([math.sin(TH), 0.0, math.cos(TH)])
    wo = np.array([-math.sin(TH), 0.0, math.cos(TH)])
    true = inst._standard_model()(wi, wo)
    assert true == pytest.approx(cert.brdf(wi, wo), rel=0.05)  # within a few u
    ideal = LBLInstrument(width=32, height=24).certificate()
    assert ideal.expanded_uncertainty == 0.0 and np.all(ideal.factor == 1.0)


def test_reillumination_adds_light_in_proportion_to_the_albedos(small):
    r = 0.01
    inst = LBLInstrument(width=160, height=120, effects={"reillumination": r})
    m = materials.get("rolled_brass")
    e0 = small.electrons(m, TH)
    e1 = inst.electrons(m, TH)
    g = small.geometry
    extra = (e1 - e0).ravel()[g.idx]
    assert (extra > 0).all()
    # independent: r rho_dh(wi) E cos(theta_i) (spot / disk area) rho_dh(wo) / pi
    alb_i = float(m.albedo(np.array([math.sin(TH), 0.0, math.cos(TH)])))
    j = int(np.argmax(g.wz))  # the pixel nearest the normal
    alb_o = float(m.albedo(np.array([g.wx[j], g.wy[j], g.wz[j]])))
    k = small.source.irradiance * small.mirror.transmittance * small.mirror.reflectance
    area = min(math.pi * small.source.spot_radius**2 / math.cos(TH), math.pi * 0.008**2)
    e_re = r * alb_i * math.cos(TH) * area / (math.pi * 0.008**2)
    want = small._response()[1][j] * k * e_re * alb_o / math.pi * 0.01 / 4.0**2
    assert extra[j] == pytest.approx(want, rel=0.02)
