"""Side-car consistency rules of the reduction (issue 15 item 2): every case a wrong value
with exit 0 before, now a ValueError naming the file and the field."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from gonio.calibration import Capture, load_capture, reduce_capture
from gonio.calibration.consistency import check_captures, check_frame
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gonio.io.images import write_image

sim = pytest.importorskip("gonio.simulator")


@pytest.fixture(scope="module")
def shots():
    inst = sim.LBLInstrument(mirror="ellipsoid", radius=0.15, half_separation=0.01,
                             lens="equidistant", width=96, height=72)  # fmt: skip
    out = {}
    views = [("m40", "rolled_brass", 40), ("s40", "standard", 40), ("b40", None, 40),
             ("s20", "standard", 20), ("b20", None, 20)]  # fmt: skip
    for key, sample, deg in views:
        out[key] = inst.capture(sample, math.radians(deg), 0.0, exposure=0.01, f_number=4.0,
                                rng=np.random.default_rng(deg))  # fmt: skip
    return out


def _files(tmp_path, shots, **override):
    """Write the m/s/b triple as files (``override``: key -> (image, meta)); load captures."""
    caps = []
    for role, key in (("m", "m40"), ("s", "s40"), ("b", "b40")):
        img, meta = override.get(role, shots[key])
        suffix = ".png" if img.dtype == np.uint8 else ".tif"
        p = tmp_path / f"{role}{suffix}"
        write_image(p, img, meta)
        caps.append(load_capture(p))
    return caps


def _edit(shot, img=None, **fields):
    img0, meta = shot
    meta = copy.deepcopy(meta)
    for k, v in fields.items():
        if v is None:
            meta.pop(k, None)
            meta.get("sensor", {}).pop(k, None)
        elif k in meta.get("sensor", {}):
            meta["sensor"][k] = v
        else:
            meta[k] = v
    img = img0 if img is None else img
    meta["dtype"] = img.dtype.name
    meta["shape"] = list(img.shape)
    return img, meta


def test_consistent_triple_reduces(tmp_path, shots):
    r = reduce_capture(*_files(tmp_path, shots))
    assert r.stats["n_after"] > 0 and np.isfinite(r.samples.value).all()


def test_standard_and_background_at_another_incidence(tmp_path, shots):
    m, _, _ = _files(tmp_path, shots)
    s20 = load_capture(write_image(tmp_path / "s20.tif", *shots["s20"]))
    b20 = load_capture(write_image(tmp_path / "b20.tif", *shots["b20"]))
    with pytest.raises(ValueError, match=r"s20\.tif: side-car field 'theta_i' = 20 deg differs"):
        reduce_capture(m, s20, b20)


def test_8bit_image_with_a_12bit_side_car(tmp_path, shots):
    img = shots["m40"][0]
    bad = _edit(shots["m40"], img=(img >> 4).astype(np.uint8))
    bad[1].pop("dtype")
    with pytest.raises(ValueError, match=r"m\.png: the side-car's ADC range \(max_dn 4095\)"):
        reduce_capture(*_files(tmp_path, shots, m=bad))


def test_8bit_standard_with_a_12bit_measurement(tmp_path, shots):
    img, _ = shots["s40"]
    s8 = _edit(shots["s40"], img=(img >> 4).astype(np.uint8), adc_bits=8, max_dn=255,
               saturation_dn=254.0, black_level_dn=4.0)  # fmt: skip
    with pytest.raises(ValueError, match=r"s\.png: max_dn 255 differs from .*m\.tif's 4095"):
        reduce_capture(*_files(tmp_path, shots, s=s8))


def test_values_beyond_the_adc_range(tmp_path, shots):
    img, _ = shots["m40"]
    big = _edit(shots["m40"], img=(img.astype(np.uint32) * 16).clip(0, 65535).astype(np.uint16))
    with pytest.raises(ValueError, match=r"m\.tif: \d+ pixel\(s\) up to \d+ DN exceed .*max_dn"):
        reduce_capture(*_files(tmp_path, shots, m=big))


def test_side_car_without_f_number(tmp_path, shots):
    with pytest.raises(ValueError, match=r"m\.tif: side-car field 'f_number' .* is missing"):
        reduce_capture(*_files(tmp_path, shots, m=_edit(shots["m40"], f_number=None)))


def test_all_zero_image(tmp_path, shots):
    zero = _edit(shots["m40"], img=np.zeros_like(shots["m40"][0]))
    with pytest.raises(ValueError, match=r"m\.tif: every pixel is 0 DN, not above .*black"):
        reduce_capture(*_files(tmp_path, shots, m=zero))


def test_measured_frame_as_its_own_standard(tmp_path, shots):
    same = _edit(shots["m40"], sample=None)  # even without the side-car's role label
    with pytest.raises(ValueError, match=r"s\.tif: the standard frame is pixel-for-pixel"):
        reduce_capture(*_files(tmp_path, shots, s=same))
    with pytest.raises(ValueError, match=r"s\.tif: side-car field 'sample' = 'brdf'"):
        reduce_capture(*_files(tmp_path, shots, s=shots["m40"]))


def test_rho_standard_not_a_number(shots):
    caps = [Capture.single(*shots[k]) for k in ("m40", "s40", "b40")]
    with pytest.raises(ValueError, match=r"rho_standard must be a number in \(0, 1\], got 'abc'"):
        reduce_capture(*caps, rho_standard="abc")


# -------------------------------------------------------------- property test: side-cars
_FIELDS = ["exposure_s", "f_number", "theta_i", "adc_bits", "max_dn", "black_level_dn",
           "gain_e_per_dn", "read_noise_e", "sample"]  # fmt: skip
_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**40), 2**40), st.text(max_size=5),
    st.floats(allow_nan=True, allow_infinity=True), st.lists(st.integers(), max_size=2),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)  # fmt: skip


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(edits=st.dictionaries(st.sampled_from(_FIELDS), _VALUES, max_size=4),
       role=st.sampled_from(["m40", "s40", "b40"]))  # fmt: skip
def test_mutated_side_cars_give_a_result_or_a_value_error(shots, edits, role):
    caps = {}
    for name, key in (("measured", "m40"), ("standard", "s40"), ("background", "b40")):
        img, meta = shots[key]
        if key == role:
            img, meta = _edit(shots[key], **edits)
        caps[name] = Capture.single(img, meta)
    try:
        check_captures(caps)
        r = reduce_capture(caps["measured"], caps["standard"], caps["background"])
    except ValueError:
        return
    assert np.isfinite(r.samples.value).all() and np.isfinite(r.samples.sigma).all()


@settings(max_examples=100, deadline=None)
@given(text=st.text(max_size=60))
def test_random_side_car_text_gives_a_value_error(tmp_path_factory, text):
    from gonio.io.images import read_image

    d = tmp_path_factory.mktemp("sc")
    p = d / "x.tif"
    write_image(p, np.full((4, 4), 100, np.uint16), {"theta_i": 0.1})
    (d / "x.tif.json").write_text(text, encoding="utf-8")
    try:
        img, meta = read_image(p, require_metadata=True)
    except ValueError:
        return
    try:
        check_frame(img, meta, str(p))
    except ValueError:
        pass
