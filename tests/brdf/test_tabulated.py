"""The ``tabulated`` model (MERL grid) against its source models."""

import numpy as np
import pytest

from gonio import brdf
from gonio.geometry import difference_half_angles, from_difference_half_angles
from gonio.io.merl import WAVELENGTHS_NM, tabulate, write_merl

WARD = {"rho_d": 0.1, "rho_s": 0.2, "alpha_x": 0.15, "alpha_y": 0.15}


@pytest.fixture(scope="module")
def ward_table():
    return tabulate("ward", **WARD)


def _dirs(n, rng):
    w = rng.normal(size=(n, 3))
    w[:, 2] = np.abs(w[:, 2]) + 0.02
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def _cell_bounds(wi, wo):
    """Edges of the MERL cell each pair falls in, in (θh, θd, φd folded to [0, π))."""
    th, _, td, pd = difference_half_angles(wi, wo)
    pd = np.where(pd < 0, pd + np.pi, pd)
    ih = np.floor(90 * np.sqrt(th / (np.pi / 2)))
    idd = np.floor(td / (np.pi / 2) * 90)
    ip = np.floor(pd / np.pi * 180) % 180
    h = ((ih / 90) ** 2 * np.pi / 2, ((ih + 1) / 90) ** 2 * np.pi / 2)
    d = (idd / 90 * np.pi / 2, (idd + 1) / 90 * np.pi / 2)
    p = (ip / 180 * np.pi, (ip + 1) / 180 * np.pi)
    return h, d, p, (ih, idd, ip)


def test_tabulated_ward_agrees_to_grid_resolution(ward_table):
    """tabulated(tabulate(ward)) equals ward at the cell centre, and lies within the range
    ward takes over the cell's corners (ward is monotonic inside each MERL cell: its extrema
    in θh, θd, φd are at cell edges), so the error is bounded by the grid resolution."""
    m = brdf.create("tabulated", data=ward_table)
    w = brdf.create("ward", **WARD)
    rng = np.random.default_rng(7)
    wi, wo = _dirs(4000, rng), _dirs(4000, rng)
    v = m(wi, wo)
    truth = w(wi, wo)
    h, d, p, (ih, idd, ip) = _cell_bounds(wi, wo)
    # (a) the value is the model at the cell centre
    ci, co = from_difference_half_angles(
        ((ih + 0.5) / 90) ** 2 * np.pi / 2,
        0.0,
        (idd + 0.5) / 90 * np.pi / 2,
        (ip + 0.5) / 180 * np.pi,
    )
    centre = w(ci, co)
    inside = (ci[:, 2] > 0) & (co[:, 2] > 0)
    np.testing.assert_allclose(v[inside], centre[inside], rtol=1e-12)
    # (b) within the corner range of the cell (cells whose corners are all above the horizon)
    lo = np.full(len(v), np.inf)
    hi = np.full(len(v), -np.inf)
    ok = inside.copy()
    for a in h:
        for b in d:
            for c in p:
                xi, xo = from_difference_half_angles(a, 0.0, b, c)
                ok &= (xi[:, 2] > 0) & (xo[:, 2] > 0)
                f = w(xi, xo)
                lo, hi = np.minimum(lo, f), np.maximum(hi, f)
    assert ok.sum() > 3000
    tol = 1e-12 * hi
    assert np.all(v[ok] >= lo[ok] - tol[ok]) and np.all(v[ok] <= hi[ok] + tol[ok])
    assert np.all(truth[ok] >= lo[ok] - tol[ok]) and np.all(truth[ok] <= hi[ok] + tol[ok])
    rel = np.abs(v[ok] / truth[ok] - 1)
    assert np.median(rel) < 1e-3


def test_tabulated_oren_nayar_agrees_with_source():
    src = brdf.create("oren_nayar", rho=0.8, sigma=0.5)
    m = brdf.create("tabulated", data=tabulate(src))
    rng = np.random.default_rng(2)
    wi, wo = _dirs(3000, rng), _dirs(3000, rng)
    keep = (wi[:, 2] > 0.2) & (wo[:, 2] > 0.2)
    rel = np.abs(m(wi, wo)[keep] / src(wi, wo)[keep] - 1)
    # measured: median 0.27 %, 99th percentile 1.6 %, max 3.7 % (cells straddling the
    # θr = θi kink of eq. 27); a regression bound at the grid's resolution
    assert np.median(rel) < 4e-3 and np.quantile(rel, 0.99) < 0.02 and np.max(rel) < 0.05


def test_merl_file_is_spectral_with_documented_bands(tmp_path, ward_table):
    p = write_merl(
        tmp_path / "w.binary", np.stack([ward_table, 0.5 * ward_table, 0.25 * ward_table])
    )
    m = brdf.create("tabulated", data=str(p))
    np.testing.assert_array_equal(m.wavelengths_nm, WAVELENGTHS_NM)
    assert m.n_bands == 3
    wi, wo = np.array([0.3, 0.0, 0.954]), np.array([-0.2, 0.1, 0.975])
    wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
    v = m(wi, wo)
    assert v.shape == (3,)
    np.testing.assert_allclose(v / v[0], [1, 0.5, 0.25], rtol=1e-14)
    v2 = m(np.stack([wi, wi]), np.stack([wo, wo]))
    assert v2.shape == (2, 3)
    g = brdf.create("tabulated", data=ward_table)
    assert g.n_bands is None and g(wi, wo).shape == ()


def test_reciprocal_isotropic_below_horizon_and_missing(ward_table):
    t = ward_table.copy()
    t[0] = -1.0  # MERL's "unmeasured" marker in the first theta_h row
    m = brdf.create("tabulated", data=t)
    assert m.n_missing == 90 * 180
    n = np.array([0.0, 0.0, 1.0])
    assert m(n, n) == 0.0  # theta_h = 0 -> row 0, missing -> 0
    rng = np.random.default_rng(5)
    wi, wo = _dirs(2000, rng), _dirs(2000, rng)
    np.testing.assert_array_equal(m(wi, wo), m(wo, wi))
    rot = np.array([[np.cos(1.1), -np.sin(1.1), 0], [np.sin(1.1), np.cos(1.1), 0], [0, 0, 1]])
    same = np.abs(m(wi, wo) - m(wi @ rot.T, wo @ rot.T)) <= 1e-12 * m(wi, wo)
    assert same.mean() > 0.97  # isotropic up to cell-boundary rounding
    assert m([0.6, 0, -0.8], [0, 0, 1.0]) == 0.0
    assert m([0, 0, 1.0], [1.0, 0, 0.0]) == 0.0


def test_bad_input():
    with pytest.raises(ValueError, match="missing required parameter 'data'"):
        brdf.create("tabulated")
    with pytest.raises(ValueError, match="shape"):
        brdf.create("tabulated", data=np.zeros((90, 90)))
    with pytest.raises(ValueError, match="non-finite"):
        brdf.create("tabulated", data=np.full((90, 90, 180), np.nan))
    with pytest.raises(ValueError, match="wavelengths_nm"):
        brdf.create("tabulated", data=np.zeros((2, 90, 90, 180)))
    with pytest.raises(ValueError, match="wavelengths_nm"):
        brdf.create("tabulated", data=np.zeros((3, 90, 90, 180)), wavelengths_nm=[1, 2])
    with pytest.raises(ValueError, match="wavelengths_nm given for a grey"):
        brdf.create("tabulated", data=np.zeros((90, 90, 180)), wavelengths_nm=[500])
    with pytest.raises(ValueError, match="cannot read MERL file"):
        brdf.create("tabulated", data="/nonexistent/x.binary")
