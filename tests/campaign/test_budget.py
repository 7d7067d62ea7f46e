"""The GUM budget's linearised propagation against brute-force re-fits (campaign/budget.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio import fit
from gonio.campaign import Plan, run
from gonio.campaign.budget import Perturbation, Sensitivity, budget_table, build_budget


@pytest.fixture(scope="module")
def brass():
    plan = Plan(theta_i_deg=(10.0, 25.0, 40.0, 55.0, 70.0), plots=False, seed=3)
    return run(plan, workers=1)


def _refit(res, samples, dy):
    s2 = samples.subset(np.arange(len(samples)))
    s2.value = samples.value + dy
    r2 = fit.fit(s2, res.model, residual=res.residual, guess=False)
    return np.array([r2.params[k] - res.params[k] for k in res.free])


@pytest.mark.parametrize(
    "shape",
    ["scale", "grazing_incidence", "additive", "grazing_view"],
)
def test_linear_shift_matches_a_refit(brass, shape):
    s, res = brass.samples, brass.fit
    y = s.value
    dy = {
        "scale": 0.01 * y,
        "grazing_incidence": 0.02 * y * np.sin(s.theta_i) ** 2,
        "additive": np.full_like(y, 1e-3),
        "grazing_view": 0.02 * y * (1.0 - np.cos(s.theta_o)),
    }[shape]
    lin = Sensitivity(res, s).shift(dy)
    brute = _refit(res, s, dy)
    p = np.array([abs(res.params[k]) for k in res.free])
    # the first-order shift is the re-fit's to 2 % of the shift (or 1e-5 of the value)
    assert np.all(np.abs(lin - brute) <= 0.02 * np.abs(brute) + 1e-5 * p), (lin, brute)


def test_combination_systematic_and_random(brass):
    s, res = brass.samples, brass.fit
    sens = Sensitivity(res, s)
    y = s.value
    groups = np.unique(np.stack([s.theta_i, s.phi_i], 1), axis=0, return_inverse=True)[1]
    groups = groups.ravel()
    sys_p = Perturbation("scale", 0.01, "1", y, note="a 1 % scale error")
    rnd_p = Perturbation("capture", 0.01, "1", y, kind="random", groups=groups)
    b = build_budget(res, s, [sys_p, rnd_p], sensitivity=sens)
    # a pure scale error moves the two reflectances by 1 % and the widths not at all
    t = b.terms[0]
    assert t.contribution["rho_d"] == pytest.approx(0.01 * res.params["rho_d"], rel=1e-3)
    assert t.contribution["alpha_x"] < 1e-4 * res.params["alpha_x"]
    # independent per-capture errors average down: less than the shared one for rho_d
    assert 0 < b.terms[1].contribution["rho_d"] < t.contribution["rho_d"]
    for n in res.free:
        rss = math.sqrt(b.statistical[n] ** 2 + sum(x.contribution[n] ** 2 for x in b.terms))
        assert b.combined[n] <= rss * (1 + 1e-9)  # correlations can only help... or equal
        assert b.expanded[n] == pytest.approx(2.0 * b.combined[n])
    d = b.to_dict()
    assert set(d["terms"]) == {"scale", "capture"}
    text = budget_table(d)
    assert "expanded U (k=2)" in text and "scale" in text


def test_bad_perturbations(brass):
    s = brass.samples
    with pytest.raises(ValueError, match="kind"):
        Perturbation("x", 0.1, "1", s.value, kind="other")
    with pytest.raises(ValueError, match="u of"):
        Perturbation("x", -1.0, "1", s.value)
    with pytest.raises(ValueError, match="groups"):
        Perturbation("x", 0.1, "1", s.value, kind="random")
    with pytest.raises(ValueError, match="shape"):
        build_budget(brass.fit, s, [Perturbation("x", 0.1, "1", s.value[:5])])
    with pytest.raises(ValueError, match="coverage"):
        build_budget(brass.fit, s, [], k=0.0)


def test_a_direction_field_moves_alpha_as_a_refit(brass):
    """A field that scales every dome direction's polar angle by 1 + ε: the direction
    term (cell means interpolated, differenced at a small step) gives alpha's shift as a
    re-fit of the samples seen through the scaled directions does."""
    from types import SimpleNamespace

    from gonio.campaign.budget_terms import _cell_means, direction_terms
    from gonio.geometry import to_spherical, to_vector

    rng = np.random.default_rng(0)
    w0 = to_vector(np.arccos(rng.uniform(0.05, 1.0, 400_000)), rng.uniform(0, 2 * np.pi, 400_000))

    def scaled(w, eps):  # polar angle times 1 + eps, per unit: theta along e_theta
        t, p = to_spherical(w)
        return to_vector(t * (1.0 + eps), p)

    field = ("polar_scale", 1e-3, "1", _cell_means(w0, w0 + (scaled(w0, 1e-4) - w0) / 1e-4), True)
    cal = SimpleNamespace(_direction_fields=[field])
    s, res = brass.samples, brass.fit
    (term,) = direction_terms(s, res.model, cal)
    lin = 1e-3 * Sensitivity(res, s).shift(term.dy)
    c, si = np.cos(-s.phi_i), np.sin(-s.phi_i)
    w = s.wo
    wd = np.stack([c * w[:, 0] - si * w[:, 1], si * w[:, 0] + c * w[:, 1], w[:, 2]], 1)
    w1 = scaled(wd, 1e-3)
    back = np.stack([c * w1[:, 0] + si * w1[:, 1], -si * w1[:, 0] + c * w1[:, 1], w1[:, 2]], 1)
    brute = _refit(res, s, res.model(s.wi, back) - res.model(s.wi, s.wo))
    for k in ("alpha_x", "alpha_y"):
        j = res.free.index(k)
        assert abs(brute[j]) > 1e-4 * res.params[k]  # a 0.1 % angle scale moves alpha
        assert lin[j] == pytest.approx(brute[j], rel=0.15), (k, lin[j], brute[j])


def _campaign_like_samples(n=20_000, seed=0):
    """Samples in captures: a few incidences, several rotations each (θi ties across φi)."""
    from gonio.samples import BRDFSamples

    rng = np.random.default_rng(seed)
    ti = np.radians(rng.choice([10.0, 25.0, 40.0], n))
    pi = np.radians(rng.choice([-90.0, 0.0, 45.0, 180.0], n))
    to = np.arccos(rng.uniform(0.05, 1.0, n))
    return BRDFSamples(ti, pi, to, rng.uniform(-np.pi, np.pi, n), rng.uniform(0.1, 1.0, n),
                       np.full(n, 0.01))  # fmt: skip


def test_capture_groups_number_captures_as_unique_rows():
    """The captures numbered from the columns' ranks are np.unique(axis=0)'s numbering of
    the rounded (θi, φi) rows (the independent, slow computation)."""
    from gonio.campaign.budget_terms import budget_view, capture_groups

    s = _campaign_like_samples()
    key = np.round(np.stack([s.theta_i, s.phi_i], 1), 9)
    want = np.unique(key, axis=0, return_inverse=True)[1].ravel()
    cap, inc = capture_groups(s)
    assert cap.max() == 11 and np.array_equal(cap, want)
    assert np.array_equal(inc, np.unique(np.round(s.theta_i, 9), return_inverse=True)[1])
    v = budget_view(s)
    assert all(np.array_equal(a, b) for a, b in zip(capture_groups(v), (cap, inc)))


def test_budget_view_shares_the_columns_and_computes_directions_once():
    from gonio.campaign.budget_terms import budget_view

    s = _campaign_like_samples(2000)
    v = budget_view(s)
    assert v.value is s.value and budget_view(v) is v and len(v) == len(s)
    assert np.array_equal(v.wi, s.wi) and np.array_equal(v.wo, s.wo)
    assert v.wi is v.wi and not v.wo.flags.writeable


def test_direction_terms_are_each_fields_corners_times_the_gradient():
    """Each field's δy, from one sparse matrix of every sample's corner weights times its
    gradient's coefficients, equals the independent slow form: the field's four corners
    gathered and weighted at the sample's dome direction, turned back into the sample frame,
    and f differenced along that change (central, a 1e-5 rad step): to 1e-4 of the largest."""
    from types import SimpleNamespace

    from gonio import brdf
    from gonio.campaign.budget_terms import GRID, _bilinear, _unit, direction_terms

    rng = np.random.default_rng(1)
    s = _campaign_like_samples(5000)
    model = brdf.create("ward", rho_d=0.1, rho_s=0.3, alpha_x=0.2, alpha_y=0.3)
    fields = [(f"f[{k}]", 1.0, "rad", rng.normal(size=(GRID * GRID, 3)), k == 0)
              for k in range(3)]  # fmt: skip
    terms = direction_terms(s, model, SimpleNamespace(_direction_fields=fields))
    c, si = np.cos(-s.phi_i), np.sin(-s.phi_i)
    w = s.wo
    wd = np.stack([c * w[:, 0] - si * w[:, 1], si * w[:, 0] + c * w[:, 1], w[:, 2]], 1)
    corners, weights = _bilinear(wd)
    h = 1e-5
    for t, (_, _, _, cells, _) in zip(terms, fields, strict=True):
        d = np.einsum("nk,nkc->nc", weights, cells[corners])  # the field at each sample
        d_s = np.stack([c * d[:, 0] + si * d[:, 1], -si * d[:, 0] + c * d[:, 1], d[:, 2]], 1)
        want = (model(s.wi, _unit(w + h * d_s)) - model(s.wi, _unit(w - h * d_s))) / (2 * h)
        np.testing.assert_allclose(t.dy, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_digitiser_term_is_the_blur_of_its_box():
    """Ward's 108 x 80 images of a 640 x 480 camera: the box's variance beyond one pixel,
    (b^2 - 1)/12 px^2 per axis, through the lens's pixels per radian; none at full size."""
    from types import SimpleNamespace

    from gonio import brdf
    from gonio.campaign import budget_terms as bt
    from gonio.campaign.determined import hemisphere_geometries
    from gonio.samples import BRDFSamples

    wi, wo = hemisphere_geometries((30.0,))
    model = brdf.create("ward", rho_d=0.1, rho_s=0.3, alpha_x=0.05, alpha_y=0.1)
    s = BRDFSamples.from_directions(wi, wo, model(wi, wo))
    lens = SimpleNamespace(width=640, height=480, fx=150.0)
    assert bt.digitiser_term(s, model, lens, [(480, 640)]) == []
    (t,) = bt.digitiser_term(s, model, lens, [(80, 108)] * 3)
    bx, by = 640 / 108, 480 / 80
    sigma = math.sqrt(((bx**2 + by**2) / 2 - 1) / 12) / 150.0
    (ref,) = bt.blur_term(s, model, sigma)
    assert t.name == "digitiser" and not t.corrected
    assert t.u == pytest.approx(sigma**2) and np.array_equal(t.dy, ref.dy)
    assert bt.digitiser_term(s, model, lens, [(80, 108), (480, 640)]) == []  # mixed: unknown


def test_realisations_of_one_row_are_reported_as_their_root_sum_of_squares():
    """Perturbations that share a row (a Monte Carlo term's realisations) make one line of
    the budget, u and contributions their root sum of squares; the combined uncertainty is
    that of the realisations one by one."""
    from gonio.campaign.budget import Perturbation, build_budget
    from gonio.fit import fit

    s = _campaign_like_samples(3000)

    r = fit(s, "ward")
    rng = np.random.default_rng(3)
    dys = [rng.normal(size=len(s)) * s.value * 1e-3 for _ in range(3)]
    apart = [Perturbation(f"fig[{k}]", 0.5, "rad", dy) for k, dy in enumerate(dys)]
    rows = [Perturbation(f"fig[{k}]", 0.5, "rad", dy, row="fig") for k, dy in enumerate(dys)]
    a, b = build_budget(r, s, apart), build_budget(r, s, rows)
    assert [t.name for t in b.terms] == ["fig"]
    assert b.terms[0].u == pytest.approx(0.5 * np.sqrt(3))
    for n in a.combined:
        assert b.combined[n] == a.combined[n]
        rss = np.sqrt(sum(t.contribution[n] ** 2 for t in a.terms))
        assert b.terms[0].contribution[n] == pytest.approx(rss, rel=1e-12)
