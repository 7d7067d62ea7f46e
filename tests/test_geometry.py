import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio import geometry as g


def test_spherical_roundtrip_and_pole():
    th = np.array([0.0, 0.3, np.pi / 2, 1.2])
    ph = np.array([0.0, -2.0, 1.0, np.pi])
    v = g.to_vector(th, ph)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, rtol=0, atol=1e-15)
    t2, p2 = g.to_spherical(v)
    np.testing.assert_allclose(t2, th, atol=1e-15)
    np.testing.assert_allclose(p2[1:], ph[1:], atol=1e-15)
    assert p2[0] == 0.0  # exactly normal: phi defined as 0
    assert g.to_spherical([-1.0, 0.0, 0.0])[1] == np.pi  # phi in (-pi, pi]


def test_half_vector_degenerate_and_reflect():
    wi = np.array([0.6, 0.0, 0.8])
    np.testing.assert_array_equal(g.half_vector(wi, -wi), [0, 0, 1])
    np.testing.assert_allclose(g.reflect(wi), [-0.6, 0.0, 0.8])
    graze = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(g.reflect(graze), [-1.0, 0.0, 0.0])
    np.testing.assert_allclose(g.half_vector(graze, g.reflect(graze)), [0, 0, 1])


@given(
    st.floats(0, np.pi / 2),
    st.floats(-np.pi, np.pi),
    st.floats(0, np.pi / 2),
    st.floats(-np.pi, np.pi),
)
def test_difference_half_roundtrip(ti, pi, to, po):
    wi, wo = g.to_vector(ti, pi), g.to_vector(to, po)
    if np.linalg.norm(wi + wo) < 1e-6:
        return
    wi2, wo2 = g.from_difference_half_angles(*g.difference_half_angles(wi, wo))
    np.testing.assert_allclose(wi2, wi, atol=1e-9)
    np.testing.assert_allclose(wo2, wo, atol=1e-9)


def test_difference_half_angles_opposite():
    # the half vector is undefined; it is taken as the normal, so theta_d = theta_i
    th, _, td, _ = g.difference_half_angles([0.6, 0, 0.8], [-0.6, 0, -0.8])
    assert th == 0.0 and td == pytest.approx(np.arccos(0.8), abs=1e-15)


def test_local_frame_orthonormal_and_parallel_tangent():
    n = g.normalize(np.array([[0.2, -0.3, 0.9], [0, 0, -1.0], [1.0, 0, 0]]))
    for t in (None, n, np.array([1.0, 0, 0])):
        f = g.local_frame(n, t)
        eye = np.einsum("...ij,...kj->...ik", f, f)
        np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-12)
        np.testing.assert_allclose(f[..., 2, :], n, atol=1e-15)
        np.testing.assert_allclose(np.linalg.det(f), 1.0, atol=1e-12)  # right-handed
    local = g.to_local(n, g.local_frame(n))
    np.testing.assert_allclose(local, [[0, 0, 1]] * 3, atol=1e-12)


def test_shirley_chiu_area_preserving_and_li_torrance_grid():
    grid = g.uniform_hemisphere_grid(21)
    assert grid.shape == (441, 3)
    assert np.all(grid[:, 2] > 0)
    # uniform in solid angle: mean cos theta over the hemisphere is 1/2 (midpoint error ~1/n^2)
    assert np.mean(g.uniform_hemisphere_grid(200)[:, 2]) == pytest.approx(0.5, abs=1e-4)
    # cosine-weighted: mean cos theta is 2/3; midpoint error falls as n^-1.5 (sqrt at the rim)
    errs = [np.mean(g.cosine_hemisphere_grid(n)[:, 2]) - 2 / 3 for n in (128, 512)]
    assert abs(errs[1]) < 1e-4
    assert np.log2(errs[0] / errs[1]) / 2 == pytest.approx(1.5, abs=0.1)
    x, y = g.shirley_chiu_square_to_disk(0.5, 0.5)
    assert (x, y) == (0.0, 0.0)
    with pytest.raises(ValueError, match="n must be a positive integer"):
        g.uniform_hemisphere_grid(0)


def test_samplers_reproducible_and_pdf():
    w1, p1 = g.sample_cosine_hemisphere(1000, rng=3)
    w2, _ = g.sample_cosine_hemisphere(1000, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(w1, w2)
    np.testing.assert_allclose(p1, w1[:, 2] / np.pi)
    wu, pu = g.sample_uniform_hemisphere(20000, rng=1)
    assert np.mean(wu[:, 2]) == pytest.approx(0.5, abs=0.01)
    assert np.all(pu == 1 / (2 * np.pi))
