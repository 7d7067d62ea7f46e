"""Ward 1992 (Ward 1992): eq. 5a values, the numba kernel, eq. 7 sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from gonio import brdf
from gonio.brdf import ward as ward_mod
from gonio.brdf.base import hemisphere_integral

BRASS = dict(rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)


def _rand_dirs(n: int, seed: int, upper: float = 0.8) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    flip = rng.random(n) < upper
    v[:, 2] = np.where(flip, np.abs(v[:, 2]), v[:, 2])
    return v


def test_eq5a_against_trigonometric_form() -> None:
    """eq. 5a written with δ = angle(h, n) and φ = azimuth(h) (arccos/atan2) agrees."""
    m = brdf.create("ward", **BRASS)
    wi, wo = _rand_dirs(500, 1, 1.0), _rand_dirs(500, 2, 1.0)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    d = np.arccos(h[:, 2])
    phi = np.arctan2(h[:, 1], h[:, 0])
    expo = -(np.tan(d) ** 2) * (np.cos(phi) ** 2 / 0.05**2 + np.sin(phi) ** 2 / 0.16**2)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    ref = 0.1 / np.pi + 0.33 / np.sqrt(wi[:, 2] * wo[:, 2]) * np.exp(expo) / (
        4 * np.pi * 0.05 * 0.16
    )
    np.testing.assert_allclose(m(wi, wo)[ok], ref[ok], rtol=1e-10)


@pytest.mark.parametrize("name", ["ward", "ward_approx", "ward_neumann"])
def test_numba_and_numpy_agree(name: str) -> None:
    if ward_mod.kernel(name) is None:
        pytest.skip("numba not available")
    m = brdf.create(name, **BRASS)
    wi, wo = _rand_dirs(20000, 3), _rand_dirs(20000, 4)
    fast = m(wi, wo)
    ref = m._eval_numpy(wi, wo)
    np.testing.assert_allclose(fast, ref, rtol=1e-13, atol=0.0)
    # one direction against many, (…, 3) shapes, evaluate_unchecked
    np.testing.assert_allclose(m(wi, wo[0]), m._eval_numpy(wi, wo[0]), rtol=1e-13)
    np.testing.assert_allclose(m(wi[0], wo), m._eval_numpy(wi[0], wo), rtol=1e-13)
    a = wi.reshape(100, 200, 3)
    b = wo.reshape(100, 200, 3)
    np.testing.assert_allclose(m(a, b), ref.reshape(100, 200), rtol=1e-13)
    np.testing.assert_allclose(m.evaluate_unchecked(wi, wo), ref, rtol=1e-13)


def test_fast_path_validation() -> None:
    m = brdf.create("ward")
    wi = _rand_dirs(10, 5)
    bad = wi.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="wi"):
        m(bad, wi)
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="wo"):
        m(wi, bad)
    with pytest.raises(ValueError, match="shape"):
        m(wi[:, :2], wi)
    with pytest.raises(ValueError, match="broadcast"):
        m(wi, wi[:7])


def test_numpy_fallback_env(monkeypatch) -> None:
    monkeypatch.setenv("GONIO_NO_NUMBA", "1")
    monkeypatch.setattr(ward_mod, "_KERNELS", {})
    assert ward_mod.kernel("ward") is None
    m = brdf.create("ward", **BRASS)
    wi, wo = _rand_dirs(50, 6), _rand_dirs(50, 7)
    np.testing.assert_array_equal(m(wi, wo), m._eval_numpy(wi, wo))


def test_half_vector_pdf_normalised() -> None:
    for ax, ay in [(0.05, 0.16), (0.3, 0.3), (0.8, 0.1)]:
        val = hemisphere_integral(
            lambda h, ax=ax, ay=ay: (
                ward_mod.half_vector_pdf(h, ax, ay) / np.maximum(h[..., 2], 1e-300)
            ),
            256,
            512,
        )
        assert val == pytest.approx(1.0, rel=1e-6)


@pytest.mark.parametrize(("ax", "ay"), [(0.05, 0.16), (0.3, 0.3), (0.6, 0.15)])
def test_eq7_half_vector_chi_square(ax: float, ay: float) -> None:
    """Half vectors from eq. 7a/7b against half_vector_pdf, binned in (tan²δ, φ)."""
    n = 100_000
    rng = np.random.default_rng(11)
    u = rng.random((2, n))
    h = ward_mod.sample_half_vector(ax, ay, 1.0 - u[0], u[1])
    np.testing.assert_allclose(np.linalg.norm(h, axis=-1), 1.0, rtol=1e-12)
    # in (s = 1 − exp(−tan²δ/a²), φ) with a = max(ax, ay) the density is smooth
    a2 = max(ax, ay) ** 2
    t2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / h[:, 2] ** 2
    s = 1.0 - np.exp(-t2 / a2)
    phi = np.mod(np.arctan2(h[:, 1], h[:, 0]), 2 * np.pi)
    nb_s, nb_p = 20, 36
    obs, _, _ = np.histogram2d(s, phi, bins=[nb_s, nb_p], range=[[0, 1], [0, 2 * np.pi]])
    x, w = np.polynomial.legendre.leggauss(16)
    uu = 0.5 * (x + 1)
    sc = ((np.arange(nb_s)[:, None] + uu) / nb_s).ravel()
    pc = ((np.arange(nb_p)[:, None] + uu) * 2 * np.pi / nb_p).ravel()
    tan2 = -a2 * np.log1p(-sc)
    # dω = sinδ dδ dφ, and ds/dδ = exp(−tan²/a²)·2 tanδ sec²δ/a²
    cd = 1 / np.sqrt(1 + tan2)
    sd = np.sqrt(tan2) * cd
    hh = np.stack(
        np.broadcast_arrays(sd[:, None] * np.cos(pc), sd[:, None] * np.sin(pc), cd[:, None]), -1
    )
    dd_ds = a2 / (np.exp(-tan2 / a2) * 2 * np.sqrt(tan2) / cd**2)
    dens = ward_mod.half_vector_pdf(hh, ax, ay) * (sd * dd_ds)[:, None]
    dens = dens.reshape(nb_s, 16, nb_p, 16)
    exp = np.einsum("iajb,a,b->ij", dens, 0.5 * w / nb_s, 0.5 * w * 2 * np.pi / nb_p) * n
    assert exp.sum() == pytest.approx(n, rel=1e-4)
    e, o = exp.ravel(), obs.ravel()
    small = e < 5
    if small.any():
        e = np.append(e[~small], e[small].sum())
        o = np.append(o[~small], o[small].sum())
    stat = np.sum((o - e) ** 2 / e)
    assert chi2.sf(stat, len(e) - 1) > 1e-3


def test_eq7b_keeps_quadrant() -> None:
    u2 = (np.arange(1000) + 0.5) / 1000
    h = ward_mod.sample_half_vector(0.05, 0.16, np.full_like(u2, 0.5), u2)
    phi = np.mod(np.arctan2(h[:, 1], h[:, 0]), 2 * np.pi)
    assert np.all(np.floor(phi / (np.pi / 2)) == np.floor(u2 * 4))


def test_sample_pdf_matches_and_isotropic_albedo() -> None:
    m = brdf.create("ward", **BRASS)
    wo = np.array([0.3, 0.2, math.sqrt(1 - 0.13)])
    wi, pdf = m.sample(np.tile(wo, (1000, 1)), 3)
    up = wi[:, 2] > 0
    np.testing.assert_allclose(pdf[up], m.pdf(wo, wi[up]), rtol=1e-12)
    assert np.all(pdf[~up] == 0)
    # Monte Carlo albedo with the eq. 7 sampler agrees with the quadrature albedo
    wi, pdf = m.sample(np.tile(wo, (200_000, 1)), 4)
    f = m(wi, wo) * np.maximum(wi[:, 2], 0)
    est = np.where(pdf > 0, f / np.where(pdf > 0, pdf, 1), 0).mean()
    assert est == pytest.approx(float(m.albedo(wo)), rel=5e-3)


def test_ward_albedo_quadrature_vs_brute_force() -> None:
    m = brdf.create("ward", **BRASS)
    for t in (0.0, 0.8, 1.3):
        w = np.array([math.sin(t) * math.cos(0.4), math.sin(t) * math.sin(0.4), math.cos(t)])
        bf = hemisphere_integral(lambda wo, w=w: m._eval_numpy(w, wo), 256, 512)
        assert float(m.albedo(w, rtol=1e-9)) == pytest.approx(bf, rel=1e-5)


def test_bad_params() -> None:
    with pytest.raises(ValueError, match="alpha_y"):
        brdf.create("ward", alpha_y=-0.1)
    with pytest.raises(ValueError, match="rho_s"):
        brdf.create("ward", rho_s=float("nan"))


def test_interpreted_block_takes_the_numpy_path_and_keeps_the_kernels():
    from gonio.brdf._jit import interpreted, is_interpreted
    from gonio.brdf.ward import kernel

    m = brdf.create("ward", rho_d=0.1, rho_s=0.3, alpha_x=0.05, alpha_y=0.16)
    rng = np.random.default_rng(3)
    wi = rng.normal(size=(500, 3))
    wo = rng.normal(size=(500, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    fast = m(wi, wo)
    with interpreted():
        assert is_interpreted() and kernel("pre") is None
        slow = m(wi, wo)
    assert not is_interpreted()
    np.testing.assert_allclose(slow, m._eval_numpy(wi, wo), rtol=0, atol=0)
    np.testing.assert_allclose(slow, fast, rtol=1e-12)
    if kernel("pre") is not None:  # (numba installed: the kernel is back after the block)
        assert m._fast(wi, wo) is not None


def test_one_kernel_signature_serves_every_layout() -> None:
    # read-only, strided, Fortran-ordered, broadcast and many-dimensional directions all go
    # through the kernel's one compiled signature (each layout compiled its own before,
    # 0.23-0.26 s on an empty cache), with the values of plain C-ordered arrays
    pre = ward_mod.kernel("pre")
    if pre is None:
        pytest.skip("numba not available")
    m = brdf.create("ward", **BRASS)
    wi, wo = _rand_dirs(60, 8), _rand_dirs(60, 9)
    ref = m(wi, wo)
    ro = wi.copy()
    ro.flags.writeable = False
    both = np.concatenate([wi, wo], axis=1)
    np.testing.assert_array_equal(m(ro, wo), ref)
    np.testing.assert_array_equal(m(both[:, :3], both[:, 3:]), ref)
    np.testing.assert_array_equal(m(np.asfortranarray(wi), wo), ref)
    np.testing.assert_array_equal(m(wi[0], wo), m(np.repeat(wi[:1], 60, axis=0), wo))
    np.testing.assert_array_equal(m(wi.reshape(6, 10, 3), wo.reshape(6, 10, 3)).ravel(), ref)
    assert len(pre.signatures) == 1 and len(ward_mod.kernel("post").signatures) == 1
