"""MERL binary read/write/index/tabulate (gonio.io.merl)."""

import numpy as np
import pytest

from gonio import brdf
from gonio.geometry import from_difference_half_angles
from gonio.io.merl import SCALES, SHAPE, cell_centres, merl_index, read_merl, tabulate, write_merl


@pytest.fixture(scope="module")
def table():
    rng = np.random.default_rng(3)
    return rng.random((3, *SHAPE)) * 2.0


def test_round_trip_scaled_and_raw(tmp_path, table):
    p = write_merl(tmp_path / "a.binary", table)
    raw = p.read_bytes()
    assert len(raw) == 12 + 3 * 90 * 90 * 180 * 8
    assert np.frombuffer(raw[:12], "<i4").tolist() == [90, 90, 180]
    back = read_merl(p)
    np.testing.assert_allclose(back, table, rtol=4e-16, atol=0)
    stored = read_merl(p, raw=True)
    np.testing.assert_allclose(stored * SCALES[:, None, None, None], back, rtol=0, atol=0)
    p2 = write_merl(tmp_path / "b.binary", stored, raw=True)
    assert p2.read_bytes() == raw  # raw round trip is bit exact


def test_grey_table_written_to_three_channels(tmp_path, table):
    p = write_merl(tmp_path / "g.binary", table[1])
    back = read_merl(p)
    for c in range(3):
        np.testing.assert_allclose(back[c], table[1], rtol=4e-16)


def test_malformed_files_raise(tmp_path, table):
    good = write_merl(tmp_path / "ok.binary", table).read_bytes()
    cases = {
        "truncated": good[:-8],
        "header only": good[:12],
        "too short": good[:5],
        "long": good + b"\0" * 8,
        "dims": np.asarray([90, 90, 360], "<i4").tobytes() + good[12:],
    }
    msgs = {
        "truncated": "truncated",
        "header only": "truncated",
        "too short": "too short",
        "long": "longer",
        "dims": r"header dimensions \(90, 90, 360\)",
    }
    for k, data in cases.items():
        p = tmp_path / f"{k.replace(' ', '_')}.binary"
        p.write_bytes(data)
        with pytest.raises(ValueError, match=msgs[k]):
            read_merl(p)
    nan = bytearray(good)
    nan[12:20] = np.array([np.nan]).tobytes()
    (tmp_path / "nan.binary").write_bytes(bytes(nan))
    with pytest.raises(ValueError, match="non-finite"):
        read_merl(tmp_path / "nan.binary")
    with pytest.raises(ValueError, match="cannot read"):
        read_merl(tmp_path / "missing.binary")


def test_write_rejects_bad_arrays_and_leaves_no_file(tmp_path):
    with pytest.raises(ValueError, match="shape"):
        write_merl(tmp_path / "x.binary", np.zeros((90, 90, 90)))
    with pytest.raises(ValueError, match="3 channels"):
        write_merl(tmp_path / "x.binary", np.zeros((2, *SHAPE)))
    bad = np.zeros(SHAPE)
    bad[1, 2, 3] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        write_merl(tmp_path / "x.binary", bad)
    assert list(tmp_path.iterdir()) == []


def test_index_of_cell_centres_is_the_cell():
    th, td, pd = cell_centres()
    sel = (slice(None, None, 7), slice(None, None, 5), slice(None, None, 11))
    th, td, pd = th[sel], td[sel], pd[sel]
    wi, wo = from_difference_half_angles(th, 0.3, td, pd)
    valid, idx = merl_index(wi, wo)
    i, j, k = np.meshgrid(
        *(np.arange(90)[::7], np.arange(90)[::5], np.arange(180)[::11]), indexing="ij"
    )
    want = (i * 90 + j) * 180 + k
    ok = valid & (wi[..., 2] > 0) & (wo[..., 2] > 0)
    assert ok.sum() > 0.4 * ok.size
    np.testing.assert_array_equal(idx[ok], want[ok])


def test_index_follows_merl_sqrt_theta_half_and_fold():
    # theta_h just below the first cell boundary ((1/90)^2 * pi/2) and just above
    b = (1 / 90) ** 2 * np.pi / 2
    for th, want in ((0.999 * b, 0), (1.001 * b, 1), (np.radians(45), int(90 * np.sqrt(0.5)))):
        wi, wo = from_difference_half_angles(th, 0.0, 0.2, 0.5)
        assert merl_index(wi, wo)[1] // (90 * 180) == want
    # phi_d and phi_d + pi are the same cell (reciprocity fold); in-plane pairs stay reciprocal
    wi, wo = from_difference_half_angles(0.3, 0.0, 0.4, 0.7)
    wi2, wo2 = from_difference_half_angles(0.3, 0.0, 0.4, 0.7 + np.pi)
    assert merl_index(wi, wo)[1] == merl_index(wi2, wo2)[1]
    a = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    c = np.array([-np.sin(0.2), 0.0, np.cos(0.2)])
    assert merl_index(a, c)[1] == merl_index(c, a)[1]
    valid, idx = merl_index([0.6, 0, -0.8], [0, 0, 1.0])
    assert not valid and idx == 0


def test_tabulate_shapes():
    t = tabulate("lambert", rho=0.4)
    assert t.shape == SHAPE
    up = t > 0
    np.testing.assert_allclose(t[up], 0.4 / np.pi, rtol=1e-15)
    assert 0.3 < up.mean() < 1.0  # cell centres with a direction below the horizon give 0
    tab = brdf.create("tabulated", data=np.stack([t, 2 * t, 3 * t]))
    assert tab.n_bands == 3


def test_merl_angles_equal_geometry_difference_half_angles():
    from gonio.geometry import difference_half_angles
    from gonio.io.merl import merl_angles

    rng = np.random.default_rng(4)
    w = rng.normal(size=(2, 5000, 3))
    w[..., 2] = np.abs(w[..., 2])
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    th, td, pd = merl_angles(w[0], w[1])
    th2, _, td2, pd2 = difference_half_angles(w[0], w[1])
    np.testing.assert_allclose(th, th2, atol=1e-12)
    np.testing.assert_allclose(td, td2, atol=1e-12)
    dp = np.abs((pd - np.mod(pd2, np.pi) + np.pi / 2) % np.pi - np.pi / 2)
    assert np.all(dp < 1e-9)
    # swap symmetry is bit-exact
    s = merl_angles(w[1], w[0])
    for a, b in zip((th, td, pd), s):
        np.testing.assert_array_equal(a, b)
