"""Mitsuba 3 measured BSDF files: gonio's files checked by Mitsuba's own ``measured`` plugin."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from gonio import brdf, materials
from gonio.geometry import sample_uniform_hemisphere, to_vector
from gonio.io import mitsuba as gm
from gonio.samples import BRDFSamples

mi = pytest.importorskip("mitsuba")


def _mi_eval(path, wi, wo, variant="scalar_rgb", wavelengths=None):
    """Mitsuba's own eval (f_r cos θo) of a measured file, one pair at a time."""
    mi.set_variant(variant)
    b = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    if wavelengths is not None:
        si.wavelengths = mi.Spectrum(*wavelengths)
    out = np.empty((len(wi), 4 if wavelengths is not None else 3))
    for k in range(len(wi)):
        si.wi = mi.Vector3f(*wi[k])
        v = b.eval(ctx, si, mi.Vector3f(*wo[k]))
        out[k] = [v[j] for j in range(out.shape[1])]
    return out


def _pairs(n, seed):
    rng = np.random.default_rng(seed)
    return sample_uniform_hemisphere(n, rng)[0], sample_uniform_hemisphere(n, rng)[0]


def _peaks(n, seed):
    """Mirror pairs: wo the mirror image of wi, θi up to 75 deg."""
    rng = np.random.default_rng(seed)
    wi = to_vector(np.radians(rng.uniform(0, 75, n)), rng.uniform(-np.pi, np.pi, n))
    return wi, wi * [-1.0, -1.0, 1.0]


def _rel(a, b):
    return np.abs(a - b) / np.abs(b)


@pytest.fixture(scope="module")
def brass_file(tmp_path_factory):
    m = materials.get("rolled_brass")
    path = gm.write_bsdf(tmp_path_factory.mktemp("mi") / "brass.bsdf", gm.model_table(m, 48, 12, 5))
    return m, path


def test_tensor_layout_matches_mitsubas_own_reader_and_writer(tmp_path):
    from mitsuba import tensor_io

    a = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    p = gm.write_tensor(tmp_path / "t.bsdf", {"a": a, "s": "hello", "j": np.ones(1, np.uint8)})
    got = tensor_io.read(str(p))
    np.testing.assert_array_equal(got["a"], a)
    assert bytes(got["s"]) == b"hello" and got["j"].tolist() == [1]
    # and Mitsuba's writer read by gonio: the same bytes
    tensor_io.write(str(tmp_path / "m.bsdf"), a=a, s="hello", j=np.ones(1, np.uint8))
    assert (tmp_path / "m.bsdf").read_bytes() == p.read_bytes()
    back = gm.read_tensor(tmp_path / "m.bsdf")
    np.testing.assert_array_equal(back["a"], a)


def test_mitsuba_loads_an_anisotropic_fit_and_agrees_with_the_model(brass_file):
    m, path = brass_file
    wi, wo = _pairs(600, 1)
    v = _mi_eval(path, wi, wo)
    truth = m(wi, wo) * wo[:, 2]
    # grey: three equal channels
    np.testing.assert_allclose(v[:, 1], v[:, 0], rtol=1e-6)
    # gonio's reader is Mitsuba's eval (float32 tables: 1e-4)
    mine = gm.read_bsdf(path).eval_cos(wi, wo)
    np.testing.assert_allclose(mine, v, rtol=2e-4, atol=1e-6 * truth.max())
    rel = _rel(v[:, 0], truth)
    deg_o = np.degrees(np.arccos(wo[:, 2]))
    assert np.median(rel) < 0.02, np.median(rel)
    assert np.percentile(rel[deg_o < 80], 90) < 0.1
    # at the specular peaks the half vector is the normal: a node of the grid
    pi, po = _peaks(200, 2)
    vp = _mi_eval(path, pi, po)[:, 0]
    tp = m(pi, po) * po[:, 2]
    assert np.max(_rel(vp, tp)) < 0.02, np.max(_rel(vp, tp))
    assert gm.read_bsdf(path).reduction == 4  # Ward's mirror symmetry found


def test_isotropic_rgb_file_of_a_spectral_model(tmp_path):
    from gonio.colour import spectrum_to_linear_srgb

    m = materials.get("garnet_red_paint")
    path = gm.write_bsdf(tmp_path / "g.bsdf", gm.model_table(m, channels="rgb"))
    wi, wo = _pairs(300, 3)
    v = _mi_eval(path, wi, wo)
    truth = spectrum_to_linear_srgb(m(wi, wo), m.wavelengths_nm) * wo[:, 2:3]
    # where the lobe is (the paint has no diffuse floor: far from it f_r is 0)
    lit = np.abs(truth[:, 0]) > 0.01 * np.abs(truth[:, 0]).max()
    assert lit.sum() > 50
    assert np.median(_rel(v[lit], truth[lit])) < 0.03
    t = gm.read_bsdf(path)
    assert t.kind == "rgb" and t.isotropic


def test_spectral_file_in_mitsubas_spectral_variant(tmp_path):
    m = materials.get("garnet_red_paint")
    path = gm.write_bsdf(tmp_path / "s.bsdf", gm.model_table(m))
    wi, wo = _pairs(200, 4)
    bands = [400.0, 500.0, 600.0, 700.0]
    v = _mi_eval(path, wi, wo, "scalar_spectral", bands)
    idx = [list(m.wavelengths_nm).index(b) for b in bands]
    truth = m(wi, wo)[:, idx] * wo[:, 2:3]
    lit = truth[:, 3] > 0.01 * truth[:, 3].max()
    assert lit.sum() > 30
    assert np.median(_rel(v[lit], truth[lit])) < 0.03
    # the reader's bands are the file's
    back = brdf.create("measured", filename=path)
    np.testing.assert_array_equal(back.wavelengths_nm, m.wavelengths_nm)
    np.testing.assert_allclose(back(wi, wo)[:, idx] * wo[:, 2:3], v, rtol=2e-4, atol=1e-7)
    with pytest.raises(RuntimeError, match="spectral"):
        mi.set_variant("scalar_rgb")
        mi.load_dict({"type": "measured", "filename": str(path)})


def test_reader_follows_mitsuba_on_a_warped_vndf_with_the_jacobian(tmp_path):
    """The RGL database's form: a non-uniform VNDF and the Jacobian flag on."""
    rng = np.random.default_rng(5)
    npi, nti, n = 3, 4, 9
    f = {
        "description": "random warp",
        "jacobian": np.ones(1, np.uint8),
        "phi_i": np.linspace(-np.pi, np.pi, npi).astype(np.float32),
        "theta_i": np.linspace(0, 1.4, nti).astype(np.float32),
        "ndf": rng.uniform(0.5, 2, (n, n)).astype(np.float32),
        "sigma": rng.uniform(0.5, 2, (n, n)).astype(np.float32),
        "vndf": rng.uniform(0.2, 3, (npi, nti, n, n)).astype(np.float32),
        "luminance": rng.uniform(0.2, 3, (npi, nti, n, n)).astype(np.float32),
        "rgb": rng.uniform(0.1, 1, (npi, nti, 3, n, n)).astype(np.float32),
    }
    path = gm.write_tensor(tmp_path / "w.bsdf", f)
    wi, wo = _pairs(400, 6)
    v = _mi_eval(path, wi, wo)
    mine = gm.read_bsdf(path).eval_cos(wi, wo)
    np.testing.assert_allclose(mine, v, rtol=1e-4, atol=1e-6)


def test_measured_samples_exported_against_the_truth(tmp_path):
    m = brdf.create("ward", rho_d=0.2, rho_s=0.1, alpha_x=0.2, alpha_y=0.2)
    tis = np.radians([0.0, 20.0, 40.0, 60.0])
    wo = to_vector(
        *np.meshgrid(np.radians(np.linspace(0.5, 85, 40)), np.radians(np.arange(0, 181, 5)))
    )
    wo = wo.reshape(-1, 3)
    wi = np.concatenate([np.broadcast_to(to_vector(t, 0.0), wo.shape) for t in tis])
    wos = np.tile(wo, (len(tis), 1))
    s = BRDFSamples.from_directions(wi, wos, m(wi, wos))
    fields = gm.samples_table(s, 32)
    meta = gm.coverage_summary(fields)
    assert meta["isotropic"] and 0.8 < meta["coverage"] <= 1.0
    path = gm.write_bsdf(tmp_path / "s.bsdf", fields)
    qi, qo = _pairs(400, 7)
    keep = (np.arccos(qi[:, 2]) < np.radians(60)) & (np.arccos(qo[:, 2]) < np.radians(80))
    qi, qo = qi[keep], qo[keep]
    v = _mi_eval(path, qi, qo)[:, 0]
    assert np.median(_rel(v, m(qi, qo) * qo[:, 2])) < 0.03


def test_round_trip_gonio_file_gonio(tmp_path):
    m = brdf.create("oren_nayar", rho=0.6, sigma=0.3)
    path = gm.write_bsdf(tmp_path / "on.bsdf", gm.model_table(m))
    back = brdf.create("measured", filename=path)
    assert back.n_bands is None  # grey stays grey
    wi, wo = _pairs(2000, 8)
    rel = _rel(back(wi, wo), m(wi, wo))
    assert np.median(rel) < 0.01
    assert gm.read_bsdf(path).meta["model"] == "oren_nayar"


def test_bad_input_is_refused_with_a_clear_error(tmp_path):
    m = brdf.create("lambert", rho=0.5)
    with pytest.raises(ValueError, match=r"\.bsdf suffix"):
        gm.write_bsdf(tmp_path / "x.bin", gm.model_table(m, 8, 4))
    with pytest.raises(ValueError, match="resolution"):
        gm.model_table(m, 1)
    with pytest.raises(ValueError, match="spectral"):
        gm.model_table(m, 8, 4, channels="spectral")
    with pytest.raises(ValueError, match="does not exist"):
        gm.read_bsdf(tmp_path / "none.bsdf")
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(b"not a tensor file at all")
    with pytest.raises(ValueError, match="header"):
        gm.read_bsdf(bad)
    good = gm.write_bsdf(tmp_path / "good.bsdf", gm.model_table(m, 8, 4))
    data = good.read_bytes()
    (tmp_path / "cut.bsdf").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="past the end"):
        gm.read_bsdf(tmp_path / "cut.bsdf")
    f = gm.read_tensor(good)
    del f["vndf"]
    gm.write_tensor(tmp_path / "novndf.bsdf", f)
    with pytest.raises(ValueError, match="missing field"):
        gm.read_bsdf(tmp_path / "novndf.bsdf")
    f = dict(gm.read_tensor(good))
    f["theta_i"] = f["theta_i"].astype(np.float64)
    gm.write_tensor(tmp_path / "f64.bsdf", f)
    with pytest.raises(ValueError, match="theta_i"):
        gm.read_bsdf(tmp_path / "f64.bsdf")
    # a model that fails leaves no file behind
    nan = brdf.CallableBRDF(
        lambda wi, wo: np.full(np.broadcast_shapes(wi.shape, wo.shape)[:-1], np.nan)
    )
    with pytest.raises(ValueError, match="non-finite"):
        gm.write_bsdf(tmp_path / "nan.bsdf", gm.model_table(nan, 8, 4))
    assert not (tmp_path / "nan.bsdf").exists()
    assert struct.unpack("<I", data[14:18])[0] == len(gm.read_tensor(good))


def test_incidence_plane_samples_are_isotropic_and_cover_only_the_plane(tmp_path):
    """A Cornell incidence-plane plan: θi on both sides of the normal, all in one plane."""
    m = brdf.create("lambert", rho=0.5)
    rows = [(0.0, 0.0)] + [(t, p) for t in np.radians([15.0, 45.0]) for p in (0.0, np.pi)]
    wi, wo = [], []
    for t, p in rows:
        to = np.radians(np.linspace(0, 80, 17))
        wo.append(to_vector(to, np.where(to > 0, np.pi - p, 0.0)))
        wi.append(np.broadcast_to(to_vector(t, p), wo[-1].shape))
    wi, wo = np.concatenate(wi), np.concatenate(wo)
    fields = gm.samples_table(BRDFSamples.from_directions(wi, wo, m(wi, wo)), 16)
    meta = gm.coverage_summary(fields)
    # covered: only the nodes on the plane (the rows φm - φi = ±π and the normal's column)
    assert meta["isotropic"] and meta["isotropic_assumed"] and meta["coverage"] < 0.2
    t = gm.read_bsdf(gm.write_bsdf(tmp_path / "plane.bsdf", fields))
    # in the plane the nearest samples are exact for a Lambertian surface
    qi, qo = to_vector(np.radians(15.0), 0.0), to_vector(np.radians(30.0), np.pi)
    assert float(t(qi, qo)) == pytest.approx(0.5 / np.pi, rel=0.02)


def test_spectral_samples_as_rgb_and_as_31_bands(tmp_path):
    from gonio.colour import spectrum_to_linear_srgb

    m = materials.get("garnet_red_paint")
    wo = to_vector(
        *np.meshgrid(np.radians(np.linspace(0.5, 80, 30)), np.radians(np.linspace(0, 180, 25)))
    )
    wo = wo.reshape(-1, 3)
    wi = np.broadcast_to(to_vector(np.radians(30.0), 0.0), wo.shape)
    wl = m.wavelengths_nm
    f = m(wi, wo)  # (n, 31)
    s = BRDFSamples.from_directions(
        np.repeat(wi, len(wl), 0),
        np.repeat(wo, len(wl), 0),
        f.ravel(),
        wavelength_nm=np.tile(wl, len(wo)),
    )
    spec = gm.read_bsdf(gm.write_bsdf(tmp_path / "s.bsdf", gm.samples_table(s, 32)))
    rgb = gm.read_bsdf(gm.write_bsdf(tmp_path / "r.bsdf", gm.samples_table(s, 32, channels="rgb")))
    assert spec.kind == "spectral" and spec.shape[2] == 31 and rgb.kind == "rgb"
    # at the measured directions both give back the samples (the grid's interpolation aside)
    q = slice(None, None, 7)
    a, b = spec.eval_cos(wi[q], wo[q]), rgb.eval_cos(wi[q], wo[q])
    t = f[q] * wo[q, 2:3]
    lit = t[:, 15] > 0.05 * t[:, 15].max()
    assert np.median(_rel(a[lit], t[lit])) < 0.02
    # the RGB file is the spectral one through the (linear) colour map, node for node
    np.testing.assert_allclose(b, spectrum_to_linear_srgb(a, wl), rtol=1e-4, atol=1e-6 * b.max())
