"""The compiled noise generator (xoshiro256++ + ziggurat) and the run-based compose kernels."""

import math

import numpy as np
import pytest
from gonio.simulator import LBLInstrument, Sensor, Source
from scipy import stats

from gonio import brdf, materials

K = pytest.importorskip("gonio.simulator._kernels")

TH = math.radians(30)


def _normals(seed, n):
    z = np.empty(n)
    K.standard_normals(K.seed_state(np.random.default_rng(seed)), z)
    return z


def test_ziggurat_tables_match_numpys():
    # numba ports numpy's tables; ours are built from the recurrence (within 1e-12)
    c = pytest.importorskip("numba.np.random._constants")
    k, w, f = K._ziggurat()
    assert np.allclose(w, c.wi_double, rtol=1e-12, atol=0)
    assert np.allclose(f, c.fi_double, rtol=1e-12, atol=0)
    assert np.allclose(k.astype(float), c.ki_double.astype(float), rtol=1e-12, atol=0)


def test_normals_moments_tail_and_shape():
    n = 4_000_000
    z = _normals(11, n)
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * math.sqrt(2.0 / n)
    assert abs((z**3).mean()) < 5 * math.sqrt(15.0 / n)
    assert abs((z**4).mean() - 3.0) < 5 * math.sqrt(96.0 / n)
    # the base layer's tail (|z| > R) and the wedges are drawn in the right proportion
    r = K._ZIG_R
    p = 2 * stats.norm.sf(r)
    assert abs((np.abs(z) > r).sum() - p * n) < 5 * math.sqrt(p * n)
    h, edges = np.histogram(z, bins=400, range=(-5.0, 5.0))
    expect = np.diff(stats.norm.cdf(edges)) * n
    chi2 = float(((h - expect) ** 2 / expect).sum())
    assert stats.chi2.sf(chi2, len(h) - 1) > 1e-4
    assert stats.kstest(z[:1_000_000], "norm").pvalue > 1e-4


def test_normals_uncorrelated_between_neighbours_and_seeds():
    n = 2_000_000
    z = _normals(5, n)
    lim = 5 / math.sqrt(n)
    for lag in (1, 2, 3, 640, K.BLOCK - 1, K.BLOCK):  # neighbouring pixels, rows, blocks
        assert abs(np.corrcoef(z[lag:], z[:-lag])[0, 1]) < lim
    assert abs(np.corrcoef(z[1:] ** 2, z[:-1] ** 2)[0, 1]) < lim  # no variance clustering
    y = _normals(6, n)
    assert abs(np.corrcoef(z, y)[0, 1]) < lim
    # two draws from one Generator (successive captures) are independent too
    rng = np.random.default_rng(5)
    a, b = np.empty(n), np.empty(n)
    K.standard_normals(K.seed_state(rng), a)
    K.standard_normals(K.seed_state(rng), b)
    assert abs(np.corrcoef(a, b)[0, 1]) < lim


def test_generator_reproducible_and_state_advances():
    st = K.seed_state(np.random.default_rng(3))
    st0 = st.copy()
    a, b = np.empty(1000), np.empty(1000)
    K.standard_normals(st, a)
    assert not np.array_equal(st, st0)
    K.standard_normals(st0, b)
    assert np.array_equal(a, b)
    K.standard_normals(st, b)
    assert not np.array_equal(a, b)


@pytest.mark.parametrize("lam", [3.0, 15.0, 25.0])
def test_exact_poisson_draws(lam):
    # read noise 0: every pixel is an exact Poisson count (inversion below 10, PTRS above)
    n = 400_000
    x = Sensor(read_noise=0.0).add_noise(np.full(n, lam), np.random.default_rng(int(lam)))
    assert np.array_equal(x, np.rint(x))
    k = np.arange(int(lam + 8 * math.sqrt(lam) + 10))
    h = np.bincount(x.astype(int), minlength=k.size)[: k.size]
    expect = stats.poisson.pmf(k, lam) * n
    keep = expect > 5
    chi2 = float(((h[keep] - expect[keep]) ** 2 / expect[keep]).sum())
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-4


def test_noise_u16_is_noise_float_then_adc():
    s = Sensor(read_noise=3.0)  # exact draws below 30 e-, skew-corrected normal above
    lam = np.random.default_rng(0).uniform(-10.0, 45000.0, 50_001)
    lam[::7] = np.random.default_rng(1).uniform(0.0, 40.0, lam[::7].size)
    e = np.empty_like(lam)
    K.noise_float(lam, K.seed_state(np.random.default_rng(9)), s.normal_threshold, 3.0, e)
    img = np.empty(lam.size, dtype=np.uint16)
    K.noise_u16(
        lam, K.seed_state(np.random.default_rng(9)), s.normal_threshold, 3.0, s.full_well,
        1.0 / s.gain, s.black_level, float(s.max_dn), img,
    )  # fmt: skip
    assert np.array_equal(img, s.digitise(e))


def test_capture_noise_independent_of_thread_count():
    numba = pytest.importorskip("numba")
    inst = LBLInstrument(width=160, height=120)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = inst.capture("rolled_brass", TH, rng=4)[0]
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        b = inst.capture("rolled_brass", TH, rng=4)[0]
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(a, b)


def test_run_kernels_equal_the_per_entry_kernels_bit_for_bit():
    # the noise-off image (and the float electrons) of the run-based compose equal those of
    # the per-entry kernels, for foot-printed and full beams, Ward, Ward approx, Lambert
    insts = (
        LBLInstrument(width=160, height=120),
        LBLInstrument(
            "hemisphere", 0.15, 0.02, width=160, height=120, sample_radius=0.012,
            source=Source(spot_radius=0.002),
        ),
    )  # fmt: skip
    models = (
        materials.get("rolled_brass"),
        brdf.create("ward_approx", rho_d=0.1, rho_s=0.3, alpha_x=0.05, alpha_y=0.2),
        brdf.create("lambert", rho=0.5),
    )
    for inst in insts:
        sen = inst.sensor
        adc = sen.linear_adc
        for model in models:
            sc = inst._scene("brdf", model, TH, 0.7, 0.01, None, None)
            assert sc.runs is not None
            for fn in (1.4, 4.0, 16.0):
                tk = sc.exposure / fn**2
                kd, ks = sc.k0 * tk * sc.kd0, sc.k0 * tk * sc.ks0
                args = (sc.rc, sc.lit, sc.g, sc.isq, kd, ks)
                n = sc.bg.size
                a, b = np.empty(n, np.uint16), np.empty(n, np.uint16)
                K.compose_u16(sc.bg, sc.dark, tk, sc.exposure, sc.idx, *args, *adc, a)
                K.compose_u16_runs(sc.bg, sc.dark, tk, sc.exposure, *sc.runs, *args, *adc, b)
                assert np.array_equal(a, b)
                fa, fb = np.empty(n), np.empty(n)
                K.compose_float(sc.bg, sc.dark, tk, sc.exposure, sc.idx, *args, fa)
                K.compose_float_runs(sc.bg, sc.dark, tk, sc.exposure, *sc.runs, *args, fb)
                assert np.array_equal(fa.view(np.int64), fb.view(np.int64))
