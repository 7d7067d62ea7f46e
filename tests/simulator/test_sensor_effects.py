"""Sensor effects (EMVA 1288 terms): each off at zero and bit-identical to the sensor before
them, each with the physics its docstring states, bad values refused."""

from __future__ import annotations

import hashlib
import math
import warnings

import numpy as np
import pytest
from gonio.simulator import STANDARD, LBLInstrument, Sensor, reproduce
from gonio.simulator.sensor import REALISTIC, REALISTIC_SOURCES, EMVA1288Warning

from gonio import materials

TH = math.radians(30)


def _h(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


@pytest.fixture(scope="module")
def inst():
    return LBLInstrument("ellipsoid", width=160, height=120)


# ---------------------------------------------------------------------------- zero = off
#: sha256 prefixes of images made by the code before the sensor effects existed (the main
#: branch, same seeds); scenes without Ward's exp, whose SIMD rounding could depend on the CPU
MAIN_HASHES = {
    "std_noise": "7799e07ee838e606",
    "std_clean": "cac1900a59a475ed",
    "bg_noise": "7402ccfdebc00194",
    "std_binned": "d1f7c269f4753de7",
    "bracket": "421176c4f3113702",
    "bands": "904dd16511c24811",
    "gamma_noise": "e61998ba87a886b9",
    "maps": "0868ce7d842212eb",
    "digitise_noise": "28dd972d2a27d166",
}


@pytest.mark.parametrize("array_shape", [None, (120, 160)])
def test_ideal_sensor_is_bit_identical_to_the_code_before_the_effects(array_shape):
    # Sensor() (every effect off), and a physical array of the image's own shape, give the
    # images the code made before the effects existed
    sen = Sensor(array_shape=array_shape)
    inst = LBLInstrument("ellipsoid", width=160, height=120, sensor=sen)
    gam = LBLInstrument("ellipsoid", width=160, height=120,
                        sensor=Sensor(response_gamma=0.45, adc_bits=8))  # fmt: skip
    got = {
        "std_noise": _h(inst.capture(STANDARD, TH, rng=5)[0]),
        "std_clean": _h(inst.capture(STANDARD, TH, noise=False)[0]),
        "bg_noise": _h(inst.capture(None, TH, 0.3, rng=6)[0]),
        "std_binned": _h(inst.capture(STANDARD, TH, rng=7, binning=True)[0]),
        "bracket": _h(np.concatenate([f.ravel() for f, _ in inst.bracket(STANDARD, TH, rng=8)])),
        "bands": _h(
            np.concatenate([f.ravel() for f, _ in inst.capture_bands(STANDARD, TH, rng=9)])
        ),
        "gamma_noise": _h(gam.capture(STANDARD, TH, rng=11)[0]),
        "maps": _h(np.stack(Sensor().maps(480, 640))),
        "digitise_noise": _h(
            sen.digitise(sen.add_noise(np.linspace(0, 50000, 9999), np.random.default_rng(12)))
        ),
    }
    assert got == MAIN_HASHES
    assert "array_shape" not in Sensor().to_dict() and "charge_clip" not in Sensor().to_dict()


@pytest.mark.parametrize("noise", [False, True])
@pytest.mark.parametrize("binning", [None, (54, 40)])
def test_effects_path_at_zero_equals_the_fused_path(inst, noise, binning):
    # the readout of a sensor with effects (Sensor.readout, then the ADC without a second
    # clip), run for the ideal sensor, gives the fused kernels' image bit for bit, Ward
    # scene and saturated pixels included
    sc = inst._scene("brdf", materials.get("rolled_brass"), TH, 0.0, 0.01, None, None)
    for f_number in (8.0, 2.0):
        a, _ = inst._shoot(sc, f_number, noise, np.random.default_rng(3), binning)
        e = inst._compose(sc, f_number)
        b, _ = inst._finish_effects(e, sc.dark * sc.exposure, noise,
                                    np.random.default_rng(3), binning)  # fmt: skip
        assert np.array_equal(a, b)
    assert (a == inst.sensor.saturation_dn).any()  # the f/2 frame saturates


# ---------------------------------------------------------------------------- saturation
def test_charge_clip_puts_read_noise_on_saturated_pixels_then_the_adc_ceiling():
    # today's order: a saturated pixel reads exactly the white level; with the charge
    # clipped before the read noise it reads black + full_well/gain with the read noise's
    # spread (8 e- / 10 e-/DN = 0.8 DN, plus 1/12 DN^2 rounding), below the ADC's ceiling
    lam = np.full((200, 500), 80_000.0)
    old = Sensor().frames(lam / 0.5, 0.01, 1, 1)[0].astype(float)
    assert old.std() == 0.0 and old[0, 0] == Sensor().saturation_dn
    s = Sensor(charge_clip=True)
    new = s.frames(lam / 0.5, 0.01, 1, 1)[0].astype(float)
    assert new.mean() == pytest.approx(64 + 4000, abs=0.01)
    assert new.var() == pytest.approx(0.8**2 + 1 / 12, rel=0.03)
    # below saturation the two orders give the same distribution
    mid = np.full((200, 500), 20_000.0)
    a = Sensor().frames(mid, 0.01, 1, 2)[0].astype(float)
    b = s.frames(mid, 0.01, 1, 2)[0].astype(float)
    assert a.mean() == pytest.approx(b.mean(), abs=0.05)
    assert a.var() == pytest.approx(b.var(), rel=0.02)
    # a full well beyond the ADC's range: the ADC's own ceiling clips (no noise there)
    big = Sensor(charge_clip=True, full_well=50_000.0)
    top = big.frames(lam / 0.5, 0.01, 1, 3)[0]
    assert (top == big.max_dn).all()
    # the exact (numpy) draw agrees with the compiled one
    ex = s.frames(lam / 0.5, 0.01, 1, 4, exact=True)[0].astype(float)
    assert ex.mean() == pytest.approx(64 + 4000, abs=0.01)
    assert ex.var() == pytest.approx(0.8**2 + 1 / 12, rel=0.03)


def _bloom_reference(e, fw, frac):
    """Slow, direct charge bookkeeping: every pixel's spill walks its column pixel by pixel."""
    e = e.astype(float).copy()
    h, w = e.shape
    half = np.where(e > fw, 0.5 * frac * (e - fw), 0.0)
    e = np.minimum(e, fw)
    for direction in (1, -1):
        for c in range(w):
            carry = 0.0
            rows = range(h) if direction == 1 else range(h - 1, -1, -1)
            for r in rows:
                take = min(carry, fw - e[r, c])
                e[r, c] += take
                carry -= take
                carry += half[r, c]
    return e


def test_blooming_spills_along_the_column_and_conserves_charge():
    fw = 1000.0
    rng = np.random.default_rng(1)
    e = rng.uniform(0.0, 900.0, (40, 7))
    e[10, 3] = 30_000.0  # 30x overexposed
    e[30, 5] = 5_000.0
    s = Sensor(full_well=fw, blooming=1.0)
    out = s.spread(e)
    assert np.allclose(out, _bloom_reference(e, fw, 1.0))
    # only the overexposed columns change, nothing exceeds the full well, and with frac = 1
    # the charge is conserved except what left the column's ends
    changed = np.flatnonzero((out != e).any(axis=0))
    assert list(changed) == [3, 5]
    assert out.max() <= fw
    assert out[:, 5].sum() == pytest.approx(e[:, 5].sum())
    # column 3: the upward half (14 500 e-) overfills the 10 pixels above and leaves the
    # array; the downward half fits into the 29 pixels below
    assert out[:, 3].sum() < e[:, 3].sum() and (out[:11, 3] == fw).all()
    assert out[11:, 3].sum() == pytest.approx(e[11:, 3].sum() + 14_500.0)
    # a drain rated 1000x: 1e-3 of the excess spills, so 30x overexposure fills no neighbour
    part = Sensor(full_well=fw, blooming=1e-3).spread(e)
    assert np.allclose(part, _bloom_reference(e, fw, 1e-3))
    assert part[9, 3] == pytest.approx(e[9, 3] + min(0.5e-3 * 29_000.0, fw - e[9, 3]))
    # off: the very same array comes back
    assert Sensor(full_well=fw).spread(e) is not None
    assert np.array_equal(Sensor(full_well=fw).spread(e), e)


def test_smear_adds_the_columns_mean_photo_charge():
    photo = np.zeros((100, 8))
    photo[40:50, 2] = 10_000.0  # a bright band of 1/10 of the height in column 2
    dark = np.full((100, 8), 7.0)
    s = Sensor(smear=1e-4)
    out = s.spread(photo + dark, dark)
    expect = photo + dark
    expect[:, 2] += 1e-4 * 10_000.0 / 10.0
    assert np.allclose(out, expect)
    # on a window of a taller physical array the column mean is over the array's height
    tall = Sensor(smear=1e-4, array_shape=(200, 8))
    assert np.allclose(tall.spread(photo + dark, dark)[:, 2] - expect[:, 2] + 0.1, 0.05)


# ---------------------------------------------------------------------------- fixed patterns
def test_patterns_belong_to_the_physical_array():
    s = Sensor(array_shape=(48, 64), offset_dsnu=3.0, row_dsnu=2.0, column_dsnu=1.0,
               hot_pixels=0.05, hot_pixel_dark=500.0)  # fmt: skip
    full_p, full_d = s.maps(48, 64)
    p, d = s.maps(20, 30)
    win = (slice(14, 34), slice(17, 47))
    assert np.array_equal(p, full_p[win]) and np.array_equal(d, full_d[win])
    assert np.array_equal(s.offset_map(20, 30), s.offset_map(48, 64)[win])
    assert np.array_equal(s.dark_map(20, 30), s.dark_map(48, 64)[win])
    # the array's own shape has today's PRNU/DSNU draw; the offsets are separate streams
    assert np.array_equal(full_p, Sensor().maps(48, 64)[0])
    assert np.array_equal(full_d, Sensor().maps(48, 64)[1])
    assert np.array_equal(Sensor(array_shape=(48, 64), offset_dsnu=3.0).offset_map(48, 64),
                          Sensor(offset_dsnu=3.0).offset_map(48, 64))  # fmt: skip
    # a larger image does not fit
    with pytest.raises(ValueError, match="array_shape"):
        s.maps(50, 64)
    # an instrument whose lens is a window of the array reads that window
    inst = LBLInstrument(width=160, height=120, sensor=Sensor(array_shape=(240, 320)))
    big = Sensor().maps(240, 320)[0]
    k = inst.sensor.qe * (math.pi / 4.0) * inst.sensor.pixel_pitch**2
    assert np.array_equal(inst._response()[0].reshape(120, 160), big[60:180, 80:240] * k)
    with pytest.raises(ValueError, match="does not fit"):
        LBLInstrument(width=640, height=480, sensor=Sensor(array_shape=(240, 320))).capture(
            STANDARD, TH
        )


def test_offset_and_hot_pixel_statistics():
    s = Sensor(array_shape=(400, 500), offset_dsnu=3.0, row_dsnu=2.0, column_dsnu=1.5,
               hot_pixels=0.01, hot_pixel_dark=400.0)  # fmt: skip
    off = s.offset_map(400, 500)
    assert off.mean(axis=1).std() == pytest.approx(2.0, rel=0.1)
    assert off.mean(axis=0).std() == pytest.approx(1.5, rel=0.1)
    resid = off - off.mean(axis=1, keepdims=True) - off.mean(axis=0, keepdims=True)
    assert resid.std() == pytest.approx(3.0, rel=0.02)
    hot = s.dark_map(400, 500) - Sensor().maps(400, 500)[1] * s.dark_current
    assert (hot > 0).mean() == pytest.approx(0.01, rel=0.1)
    assert hot[hot > 0].mean() == pytest.approx(400.0, rel=0.1)
    # the dark frame shows them: mean DN = black + (dark + hot) t / gain + offsets / gain
    t = 2.0
    dark = s.frames(0.0, t, 4, 5).astype(float).mean(axis=0)
    expect = s.black_level + (s.dark_map(400, 500) * t + off) / s.gain
    assert np.abs(dark - expect).mean() < 0.5


def test_frames_are_independent_reproducible_and_follow_the_model():
    s = Sensor(array_shape=(100, 100))
    f = s.frames(5000.0, 0.01, 3, 7)
    assert f.shape == (3, 100, 100) and f.dtype == np.uint16
    assert np.array_equal(f, s.frames(5000.0, 0.01, 3, 7))
    assert not np.array_equal(f[0], f[1])
    d = (f[0].astype(float) - f[1]).ravel()  # fixed pattern cancels in a difference
    var = (s.qe * 5000.0 + s.read_noise**2) / s.gain**2 + 1.0 / 12.0
    assert d.var() / 2 == pytest.approx(var, rel=0.05)
    with pytest.raises(ValueError, match="photons"):
        s.frames(-1.0, 0.01)
    with pytest.raises(ValueError, match="photons"):
        s.frames(np.full((4, 4), np.nan), 0.01)
    with pytest.raises(ValueError, match="exposure"):
        s.frames(1.0, 0.0)
    with pytest.raises(ValueError, match="n must"):
        s.frames(1.0, 0.01, 0)
    with pytest.raises(ValueError, match="more than the"):
        Sensor(array_shape=(1000, 2000)).frames(1.0, 0.01, 1000)
    with pytest.raises(ValueError, match="array_shape"):
        Sensor().frames(1.0, 0.01)


# ---------------------------------------------------------------------------- calibration captures
def test_dark_and_flat_field_captures(inst):
    t = 2.0
    dark, meta = inst.capture_dark(exposure=t, rng=3)
    assert meta["calibration"] == "dark" and meta["shutter"] == "closed"
    assert meta["photons_per_pixel"] == 0.0 and meta["exposure_s"] == t
    s = inst.sensor
    expect = s.black_level + s.dark_map(120, 160) * t / s.gain
    assert np.abs(dark.astype(float) - expect).mean() < 0.1 + 0.8
    assert abs(dark.astype(float).mean() - expect.mean()) < 0.01
    flat, fm = inst.capture_flat(20_000.0, exposure=0.01, rng=4)
    assert fm["calibration"] == "flat_field" and fm["photons_per_pixel"] == 20_000.0
    prnu = s.maps(120, 160)[0]
    want = s.black_level + (s.qe * 20_000.0 * prnu + s.dark_map(120, 160) * 0.01) / s.gain
    assert abs(flat.mean() - want.mean()) < 0.05
    for img, m in ((dark, meta), (flat, fm)):
        assert np.array_equal(reproduce(m)[0], img)
    small, sm = inst.capture_flat(20_000.0, rng=4, binning=True)
    assert small.shape == (80, 108) and sm["binning"] == [108, 80]
    with pytest.raises(ValueError, match="photons_per_pixel"):
        inst.capture_flat(-5.0)


def test_realistic_instrument_captures_and_reproduces():
    inst = LBLInstrument(width=160, height=120, sensor=Sensor.realistic())
    img, meta = inst.capture("rolled_brass", TH, f_number=2.0, rng=2)
    assert meta["sensor"]["charge_clip"] is True and meta["sensor"]["smear"] == 1e-4
    assert np.array_equal(reproduce(meta)[0], img)
    assert Sensor.from_dict(inst.sensor.to_dict()) == inst.sensor
    ideal = LBLInstrument(width=160, height=120).capture("rolled_brass", TH, f_number=2.0,
                                                          rng=2)[0]  # fmt: skip
    assert not np.array_equal(img, ideal)
    # saturated pixels carry noise now: more than one value near the white level
    sat = img[img >= inst.sensor.saturation_dn - 3]
    assert sat.size > 10 and np.unique(sat).size > 1
    assert set(REALISTIC) <= set(REALISTIC_SOURCES)
    assert Sensor.realistic(smear=0.0).smear == 0.0


# ---------------------------------------------------------------------------- EMVA figures
def test_emva1288_figures_and_warnings():
    s = Sensor()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = s.emva1288(0.01)
    assert fig["system_gain_dn_per_e"] == 0.1 and fig["quantum_efficiency"] == 0.5
    assert fig["dark_noise_e"] == pytest.approx(math.sqrt(64 + 0.2))
    assert fig["saturation_capacity_e"] == pytest.approx(40_000 - 0.2)
    assert fig["snr_max"] == pytest.approx(math.sqrt(40_000 - 0.2))
    mu_min = (math.sqrt(64.2 + 100 / 12) + 0.5) / 0.5
    assert fig["absolute_sensitivity_threshold_p"] == pytest.approx(mu_min)
    assert fig["dynamic_range"] == pytest.approx((40_000 - 0.2) / 0.5 / mu_min)
    assert fig["prnu_percent"] == pytest.approx(0.5)
    assert fig["dsnu_e"] == pytest.approx(0.1 * 20 * 0.01)
    with pytest.warns(EMVA1288Warning, match="response_gamma"):
        Sensor(response_gamma=0.45).emva1288()
    with pytest.warns(EMVA1288Warning, match="clips the dark"):
        Sensor(black_level=1.0).emva1288()
    with pytest.warns(EMVA1288Warning, match="below 0.5 DN"):
        Sensor(gain=40.0).emva1288()
    assert Sensor(black_level=1.0).emva1288_problems()


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"full_well": 0.0}, r"full_well must be a finite number in \(0.0, inf\], got 0.0"),
        ({"full_well": -5.0}, r"full_well .* got -5.0"),
        ({"dark_current": -1.0}, r"dark_current must be a finite number in \[0.0, inf\]"),
        ({"blooming": 1.5}, r"blooming must be a finite number in \[0.0, 1.0\], got 1.5"),
        ({"smear": 1.0}, r"smear must be a finite number in \[0.0, 1.0\), got 1.0"),
        ({"offset_dsnu": -1.0}, r"offset_dsnu .* got -1.0"),
        ({"row_dsnu": float("nan")}, r"row_dsnu"),
        ({"column_dsnu": "x"}, r"column_dsnu must be a number"),
        ({"hot_pixels": 2.0}, r"hot_pixels .*\[0.0, 1.0\], got 2.0"),
        ({"hot_pixel_dark": -3.0}, r"hot_pixel_dark"),
        ({"array_shape": (0, 5)}, r"array_shape must be \(rows, cols\).*got \(0, 5\)"),
        ({"array_shape": (100000, 100000)}, r"array_shape"),
        ({"array_shape": 5}, r"array_shape"),
        ({"charge_clip": "yes"}, r"charge_clip must be True or False"),
        ({"pattern_seed": -1}, r"pattern_seed must be a non-negative integer, got -1"),
    ],
)
def test_bad_sensor_effects(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Sensor(**kwargs)


# ---------------------------------------------------------------------------- issue 15, item 10
def test_reassigned_sensor_or_background_is_used_not_the_cached_old_one():
    # reassigning a part after a capture used to be ignored (cached QE, PRNU, dark map and
    # background mixed with the new gain): the next image must be a fresh instrument's
    from gonio.simulator import Background

    inst = LBLInstrument(width=160, height=120)
    inst.capture(STANDARD, TH, rng=1)
    inst.capture(None, TH, rng=1)
    new = Sensor(qe=0.8, gain=5.0, prnu=0.02, dark_current=200.0, pattern_seed=9)
    inst.sensor = new
    fresh = LBLInstrument(width=160, height=120, sensor=new)
    a, meta = inst.capture(STANDARD, TH, rng=2)
    assert np.array_equal(a, fresh.capture(STANDARD, TH, rng=2)[0])
    assert np.array_equal(a, reproduce(meta)[0])
    bg = Background(ambient=inst.background.ambient * 7.0)
    inst.background = bg
    fresh = LBLInstrument(width=160, height=120, sensor=new, background=bg)
    b, meta = inst.capture(None, TH, rng=3)
    assert np.array_equal(b, fresh.capture(None, TH, rng=3)[0])
    assert np.array_equal(b, reproduce(meta)[0])
    with pytest.raises(ValueError, match="sensor must be a Sensor"):
        inst.sensor = "a sensor"


def test_charge_clip_near_the_full_well_matches_the_exact_clipped_poisson():
    # pixels whose mean sits at the full well: the DN's mean and variance are those of
    # min(Poisson(lam), FW) + N(0, sigma^2), computed exactly from the Poisson pmf
    from scipy import stats

    fw, sigma, n = 40_000.0, 8.0, 400_000
    for lam in (39_700.0, 40_000.0, 40_300.0):
        k = np.arange(int(lam - 12 * math.sqrt(lam)), int(lam + 12 * math.sqrt(lam)))
        pmf = stats.poisson.pmf(k, lam)
        c = np.minimum(k, fw)
        mean = float((pmf * c).sum())
        var = float((pmf * c * c).sum()) - mean**2 + sigma**2
        s = Sensor(charge_clip=True, read_noise=sigma, gain=1.0, adc_bits=16, black_level=100.0,
                   full_well=fw, dark_current=0.0, prnu=0.0)  # fmt: skip
        e = s.readout(np.full((400, 1000), lam), np.random.default_rng(int(lam)))
        assert abs(e.mean() - mean) < 5 * math.sqrt(var / n), lam
        assert abs(e.var() - var) < 5 * var * math.sqrt(2.0 / n) * 1.5, lam
        # the fused u16 pass is the float readout and the ADC, bit for bit
        lamimg = np.full((400, 1000), lam)
        a = s.readout_dn(lamimg, np.random.default_rng(7))
        b = s.adc(s.readout(lamimg, np.random.default_rng(7)))
        assert np.array_equal(a, b)
    r = Sensor.realistic(array_shape=(120, 160))
    img = np.random.default_rng(0).uniform(0, 60_000, (120, 160))
    for noise in (False, True):
        a = r.readout_dn(img, np.random.default_rng(8), noise=noise)
        b = r.adc(r.readout(img, np.random.default_rng(8), noise=noise))
        assert np.array_equal(a, b)
