"""End-to-end reduction on simulated LBL captures (reduced form of benchmarks/bench_reduce.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.calibration import Capture, reduce_capture, reduce_selected

from gonio import materials

sim = pytest.importorskip("gonio.simulator")


def _triple(inst, name, ti, noise, seed):
    kw = {"noise": noise, "rng": np.random.default_rng(seed)}
    meas = Capture(inst.bracket(name, ti, 0.0, min_signal_dn=400, **kw))
    std = Capture(inst.bracket("standard", ti, 0.0, **kw))
    bg = Capture(
        [inst.capture(None, ti, 0.0, exposure=m["exposure_s"], f_number=m["f_number"], **kw)
         for _, m in std.frames]
    )  # fmt: skip
    return meas, std, bg


@pytest.mark.parametrize(("mirror", "method"), [("ellipsoid", "eq3"), ("hemisphere", "exact")])
def test_noise_off_accuracy(mirror, method):
    inst = sim.LBLInstrument(mirror=mirror, radius=0.15, half_separation=0.0075,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    r = reduce_capture(*_triple(inst, "rolled_brass", np.radians(30), False, 0), method=method)
    s = r.samples
    rel = np.abs(s.value / materials.get("rolled_brass")(s.wi, s.wo) - 1)
    assert np.median(rel) <= 0.005 and np.percentile(rel, 95) <= 0.02
    assert r.stats["n_after"] < r.stats["n_before"]


def test_noise_on_normalised_residuals():
    inst = sim.LBLInstrument(mirror="ellipsoid", radius=0.15, half_separation=0.01,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    r = reduce_capture(*_triple(inst, "glossy_grey_paper", np.radians(50), True, 7))
    s = r.samples
    z = (s.value - materials.get("glossy_grey_paper")(s.wi, s.wo)) / s.sigma
    assert 0.8 <= z.std() <= 1.25


def test_rejects_non_capture():
    with pytest.raises(ValueError, match="Capture"):
        reduce_capture(None, None, None)


def _noisy_brass():
    inst = sim.LBLInstrument(mirror="ellipsoid", radius=0.15, half_separation=0.01,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    return _triple(inst, "rolled_brass", np.radians(35), True, 11)


def test_selected_pixels_match_the_full_reduction_and_are_unbiased():
    triple = _noisy_brass()
    sel = reduce_selected(*triple, base_level=4, peak_level=7, rng=3)
    full = reduce_capture(*triple, thinning=False)  # every pixel, independent computation
    at = {tuple(uv): k for k, uv in enumerate(full.pixels["uv"])}
    k = np.array([at[tuple(uv)] for uv in sel.pixels["uv"]])
    # the same eq. 2 values; where frames of a bracket overlap, the merge weights come from
    # slightly different neighbour estimates, which moves a value by a small fraction of σ
    dv = np.abs(sel.pixels["value"] - full.pixels["value"][k]) / full.pixels["sigma"][k]
    assert dv.max() <= 0.1 and np.median(dv) <= 1e-9
    np.testing.assert_array_equal(sel.pixels["wo"], full.pixels["wo"][k])
    # one pixel per cell: far fewer than all, denser in the peak
    st = sel.stats
    assert 300 < st["n_after"] < full.stats["n_after"] / 10
    assert st["n_merged"] < 0.2 * st["n_geometry_valid"]
    s = sel.samples
    z = (s.value - materials.get("rolled_brass")(s.wi, s.wo)) / s.sigma
    assert abs(z.mean()) < 4 / np.sqrt(len(z)) and 0.85 <= z.std() <= 1.2
    # reproducible from the seed, another seed picks other pixels
    again = reduce_selected(*triple, base_level=4, peak_level=7, rng=3)
    np.testing.assert_array_equal(again.samples.value, s.value)
    other = reduce_selected(*triple, base_level=4, peak_level=7, rng=4)
    assert not np.array_equal(other.pixels["uv"], sel.pixels["uv"])


def test_reduce_selected_debias_is_a_small_downward_correction():
    """``debias`` removes eq. 2's ratio bias ``(r var(d) - var(V_b))/d²`` (positive where the
    sample is brighter than the background): the same pixels, values lower by a small
    fraction of σ, σ unchanged."""
    triple = _noisy_brass()
    a = reduce_selected(*triple, base_level=4, peak_level=7, rng=3)
    b = reduce_selected(*triple, base_level=4, peak_level=7, rng=3, debias=True)
    np.testing.assert_array_equal(a.pixels["uv"], b.pixels["uv"])
    np.testing.assert_array_equal(a.pixels["sigma"], b.pixels["sigma"])
    dz = (a.pixels["value"] - b.pixels["value"]) / a.pixels["sigma"]
    assert np.median(dz) > 0 and dz.max() < 0.1


def test_neighbour_sigma_removes_the_weighting_bias():
    """A 1/σ² weighted mean of the reduced values of a flat (Lambertian) field: σ from the
    pixel's own reading pulls it low by about the relative variance; neighbour σ does not."""
    inst = sim.LBLInstrument(mirror="ellipsoid", radius=0.15, half_separation=0.01,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    from gonio import brdf

    flat = brdf.create("lambert", rho=0.05)
    kw = {"noise": True, "rng": np.random.default_rng(5)}
    meas = Capture([inst.capture(flat, 0.5, 0.0, exposure=0.002, **kw)])
    std = Capture([inst.capture("standard", 0.5, 0.0, exposure=0.002, **kw)])
    bg = Capture([inst.capture(None, 0.5, 0.0, exposure=0.002, **kw)])
    out = {}
    for mode in ("own", "neighbours"):
        r = reduce_capture(meas, std, bg, thinning=False, variance=mode)
        w = 1.0 / r.pixels["sigma"] ** 2
        est = (w * r.pixels["value"]).sum() / w.sum()
        se = w.sum() ** -0.5
        out[mode] = (est - 0.05 / np.pi) / se
    assert out["own"] < -5.0  # the bias, in standard errors
    assert abs(out["neighbours"]) < 4.0


def test_reduce_selected_rejects_bad_levels():
    triple = _noisy_brass()
    with pytest.raises(ValueError, match="peak_level"):
        reduce_selected(*triple, base_level=6, peak_level=5)
    with pytest.raises(ValueError, match="peak_fraction"):
        reduce_selected(*triple, peak_fraction=1.5)


def test_binary_lens_file_names_the_file(tmp_path):
    from gonio.calibration.reduce import load_lens

    p = tmp_path / "lens.bin"
    p.write_bytes(bytes(range(256)))
    with pytest.raises(ValueError, match=r"lens calibration '.*lens\.bin': not valid JSON"):
        load_lens(str(p))


def test_pixel_geometry_and_grid_field_angle_share_one_inverse_of_the_lens():
    from gonio.calibration.angles import MirrorGeometry
    from gonio.calibration.reduce import _lens_grid, grid_field_angle, pixel_geometry
    from gonio.simulator.lenses import FisheyeLens

    lens = FisheyeLens("kannala_brandt", 150.0, 150.5, 320.1, 239.2, 640, 480,
                       k=(0.004, -0.004, 0.002, -0.0005))  # fmt: skip
    geom = MirrorGeometry.from_metadata({"type": "hemisphere", "radius": 0.15,
                                         "half_separation": 0.01})  # fmt: skip
    _lens_grid.cache_clear()
    theta = grid_field_angle(lens)
    assert np.array_equal(theta, lens.field_angle(lens.pixel_grid()))
    assert not theta.flags.writeable
    wo, valid = pixel_geometry(lens, geom)
    info = _lens_grid.cache_info()
    assert (info.misses, info.hits) == (1, 1)  # the rays came from the field angles' inverse
    assert wo.shape == (480, 640, 3) and valid.any()
