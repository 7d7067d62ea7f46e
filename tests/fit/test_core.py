"""Tests of gonio.fit: round trips, coverage of the reported errors, options and bad input."""

from __future__ import annotations

import json
import math
from typing import ClassVar

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio import brdf, fit
from gonio.brdf.base import BRDF, Param
from gonio.samples import BRDFSamples


def _geometry(n_ti=11, n_o=150, rotations=(0.0, np.pi / 2), seed=0):
    """Incidence angles 0-80 deg, outgoing directions cosine-distributed over the hemisphere."""
    rng = np.random.default_rng(seed)
    rows = []
    for phi_i in rotations:
        for ti in np.radians(np.linspace(0, 80, n_ti)):
            to = np.arccos(np.sqrt(rng.uniform(0.02, 1.0, n_o)))
            po = rng.uniform(0, 2 * np.pi, n_o)
            rows.append(np.stack([np.full(n_o, ti), np.full(n_o, phi_i), to, po], axis=1))
    a = np.concatenate(rows)
    n = len(a)
    return BRDFSamples(a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.zeros(n), np.full(n, np.nan))


def _samples(model, noise=0.0, seed=0, sigma_known=True, **kw):
    """Samples of ``model`` with Gaussian noise of sigma = noise * f + 1e-3 (seeded)."""
    s = _geometry(**kw)
    f = np.asarray(model(s.wi, s.wo))
    if noise > 0:
        sig = noise * f + 1e-3
        rng = np.random.default_rng(1000 + seed)
        s.value = f + sig * rng.normal(size=f.shape)
        if sigma_known:
            s.sigma = sig
    else:
        s.value = f
    return s


BRASS = dict(rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)


# ------------------------------------------------------------------ noise-free round trips
@pytest.mark.parametrize(
    "params",
    [
        BRASS,
        dict(rho_d=0.67, rho_s=0.07, alpha_x=0.092, alpha_y=0.092),
        dict(rho_d=0.33, rho_s=0.025, alpha_x=0.04, alpha_y=0.11),
    ],
)
def test_ward_noise_free_recovers_parameters(params):
    true = brdf.create("ward", **params)
    r = fit.fit(_samples(true), "ward")
    assert r.converged and r.identifiable
    for k, v in params.items():
        assert abs(r.params[k] - v) <= 1e-6 * v, (k, r.params[k], v)
    assert r.rms < 1e-8


@pytest.mark.parametrize("residual", ["absolute", "relative", "log", "li_torrance"])
def test_every_residual_recovers_noise_free_parameters(residual):
    true = brdf.create("ward", **BRASS)
    r = fit.fit(_samples(true, n_ti=6, n_o=100), "ward", residual=residual)
    assert r.converged
    for k, v in BRASS.items():
        assert r.params[k] == pytest.approx(v, rel=1e-6)


def test_li_torrance_residual_is_cosine_weighted_l2():
    """Sum of squared residuals equals eq. 15's cos(theta_i)-weighted squared differences."""
    true = brdf.create("ward", **BRASS)
    s = _samples(true, n_ti=5, n_o=40)
    off = brdf.create("ward", rho_d=0.12, rho_s=0.3, alpha_x=0.06, alpha_y=0.15)
    s.value = np.asarray(off(s.wi, s.wo))
    res = fit.core._Residual("li_torrance", fit.core._prepare(s))
    f = np.asarray(true(s.wi, s.wo))
    eq15 = np.sum(np.cos(s.theta_i) * (f - s.value) ** 2)
    assert np.sum(res(f) ** 2) == pytest.approx(eq15, rel=1e-12)


# ------------------------------------------------------------------ noisy: honest error bars
def test_noisy_fit_parameters_within_reported_uncertainty_coverage():
    """Over 40 seeds the pulls (fit - truth)/stderr are standard normal.

    Pooled over 4 parameters x 40 seeds (160 pulls): the 1-sigma coverage must lie in
    [0.56, 0.80] (68.3 % +- 3.3 binomial sd) and the 2-sigma coverage in [0.89, 0.995].
    """
    true = brdf.create("ward", **BRASS)
    pulls = []
    chi2 = []
    for seed in range(40):
        s = _samples(true, noise=0.05, seed=seed, n_ti=6, n_o=80)
        r = fit.fit(s, "ward")
        assert r.converged
        pulls += [(r.params[k] - v) / r.stderr[k] for k, v in BRASS.items()]
        chi2.append(r.chi2_dof)
    pulls = np.abs(np.array(pulls))
    c1 = np.mean(pulls < 1)
    c2 = np.mean(pulls < 2)
    assert 0.56 <= c1 <= 0.80, c1
    assert 0.89 <= c2 <= 0.995, c2
    assert np.all(pulls < 5)
    assert abs(np.mean(chi2) - 1.0) < 0.05


def test_unknown_sigma_scales_covariance_by_reduced_chi2():
    true = brdf.create("ward", **BRASS)
    known = _samples(true, noise=0.05, seed=3, n_ti=6, n_o=80)
    unknown = BRDFSamples(
        known.theta_i,
        known.phi_i,
        known.theta_o,
        known.phi_o,
        known.value,
        np.full(len(known), np.nan),
    )
    r = fit.fit(unknown, "ward")
    assert not r.absolute_sigma
    # unweighted residuals: reported errors follow from the scatter about the fit
    J = fit.core._jacobian(
        lambda x: fit.predict(brdf.create("ward", **dict(zip(BRASS, x))), unknown) - unknown.value,
        np.array([r.params[k] for k in BRASS]),
        np.zeros(4),
        np.ones(4),
        fit.predict(r.model, unknown) - unknown.value,
    )
    cov = np.linalg.inv(J.T @ J) * r.chi2_dof
    for j, k in enumerate(BRASS):
        assert r.stderr[k] == pytest.approx(math.sqrt(cov[j, j]), rel=1e-3)
    assert r.chi2_dof == pytest.approx(r.rms**2 * r.n_samples / r.dof, rel=1e-9)


# ------------------------------------------------------------------ options
def test_fixed_parameters_hold_their_values():
    true = brdf.create("ward", **BRASS)
    s = _samples(true, n_ti=6, n_o=80)
    r = fit.fit(s, "ward", fixed={"rho_d": 0.1, "alpha_y": 0.16})
    assert r.params["rho_d"] == 0.1 and r.params["alpha_y"] == 0.16
    assert r.stderr["rho_d"] == 0.0 and set(r.fixed) == {"rho_d", "alpha_y"}
    assert r.free == ["rho_s", "alpha_x"]
    assert r.params["alpha_x"] == pytest.approx(0.05, rel=1e-6)


def test_sum_lambert_plus_ward_with_fixed_ward_diffuse():
    true = brdf.create("lambert", rho=0.2) + brdf.create(
        "ward", rho_d=0.0, rho_s=0.1, alpha_x=0.1, alpha_y=0.1
    )
    s = _samples(true, n_ti=6, n_o=80)
    r = fit.fit(s, "lambert + ward", fixed={"ward.rho_d": 0.0})
    assert r.model_name == "lambert + ward"
    assert r.converged
    assert r.params["lambert.rho"] == pytest.approx(0.2, rel=1e-6)
    assert r.params["ward.rho_s"] == pytest.approx(0.1, rel=1e-6)
    assert r.params["ward.alpha_x"] == pytest.approx(0.1, rel=1e-6)


def test_degenerate_sum_is_reported_unidentifiable():
    """lambert + ward with both diffuse terms free: only their sum is constrained."""
    true = brdf.create("lambert", rho=0.2) + brdf.create(
        "ward", rho_d=0.1, rho_s=0.1, alpha_x=0.1, alpha_y=0.1
    )
    s = _samples(true, n_ti=4, n_o=60)
    r = fit.fit(s, "lambert + ward")
    assert not r.identifiable
    assert math.isinf(r.stderr["lambert.rho"]) and math.isinf(r.stderr["ward.rho_d"])
    assert r.params["lambert.rho"] + r.params["ward.rho_d"] == pytest.approx(0.3, rel=1e-5)
    d = r.to_dict()
    assert d["stderr"]["lambert.rho"] is None
    json.dumps(d, allow_nan=False)


def test_spectral_data_grey_model_per_band_reflectances_shared_widths():
    wl = np.array([450.0, 550.0, 650.0])
    rho_d = [0.1, 0.3, 0.5]
    rho_s = [0.2, 0.1, 0.05]
    tables = []
    for k, w in enumerate(wl):
        m = brdf.create("ward", rho_d=rho_d[k], rho_s=rho_s[k], alpha_x=0.07, alpha_y=0.12)
        s = _samples(m, n_ti=5, n_o=60)
        s.wavelength_nm = np.full(len(s), w)
        tables.append(s)
    s = BRDFSamples.concatenate(tables)
    r = fit.fit(s, "ward")  # default per_band: the reflectances
    assert r.wavelengths_nm == wl.tolist()
    assert len(r.models) == 3
    for k in range(3):
        assert r.params[f"rho_d[{k}]"] == pytest.approx(rho_d[k], rel=1e-6)
        assert r.params[f"rho_s[{k}]"] == pytest.approx(rho_s[k], rel=1e-6)
    assert r.params["alpha_x"] == pytest.approx(0.07, rel=1e-6)
    assert "alpha_x[0]" not in r.params
    # fixing a base name fixes every band
    r2 = fit.fit(s, "ward", fixed={"rho_d": 0.3})
    assert all(r2.params[f"rho_d[{k}]"] == 0.3 for k in range(3))


class _SpectralToy(BRDF):
    """A spectral test model: per-band diffuse k_d plus a shared Gaussian lobe width."""

    name: ClassVar[str] = "spectral_toy"
    PARAMS = (
        Param("k_d", [0.1, 0.2], 0.0, 1.0, spectral=True),
        Param("k_s", [0.3, 0.3], 0.0, 10.0, spectral=True),
        Param("width", 0.2, 0.01, 1.0),
        Param("wavelengths", [500.0, 600.0], kind="object"),
    )

    @property
    def wavelengths_nm(self):
        return np.asarray(self._params["wavelengths"], float)

    def _eval(self, wi, wo):
        h = wi + wo
        t2 = (h[..., 0] ** 2 + h[..., 1] ** 2) / np.maximum(h[..., 2], 1e-9) ** 2
        lobe = np.exp(-t2 / self._params["width"] ** 2)
        up = ((wi[..., 2] > 0) & (wo[..., 2] > 0))[..., None]
        v = self._params["k_d"] / np.pi + self._params["k_s"] * lobe[..., None]
        return np.where(up, v, 0.0)


def test_spectral_model_shares_scalars_and_fits_per_band_arrays():
    true = _SpectralToy(k_d=[0.15, 0.4], k_s=[0.8, 0.5], width=0.15, wavelengths=[500.0, 600.0])
    tables = []
    for k, w in enumerate([500.0, 600.0]):
        s = _geometry(n_ti=5, n_o=60)
        s.value = np.asarray(true(s.wi, s.wo))[:, k]
        s.wavelength_nm = np.full(len(s), w)
        tables.append(s)
    s = BRDFSamples.concatenate(tables)
    start = _SpectralToy(wavelengths=[500.0, 600.0])
    r = fit.fit(s, start)
    assert set(r.params) == {"k_d[0]", "k_d[1]", "k_s[0]", "k_s[1]", "width"}
    assert r.params["width"] == pytest.approx(0.15, rel=1e-6)
    assert r.params["k_d[1]"] == pytest.approx(0.4, rel=1e-6)
    assert r.params["k_s[0]"] == pytest.approx(0.8, rel=1e-6)
    assert np.allclose(r.model.params["k_s"], [0.8, 0.5], rtol=1e-6)
    # a band the model does not have
    s2 = BRDFSamples.concatenate([tables[0]])
    s2.wavelength_nm = np.full(len(s2), 700.0)
    with pytest.raises(ValueError, match="700"):
        fit.fit(s2, start)


def test_multistart_escapes_a_bad_start():
    true = brdf.create("ward", **BRASS)
    s = _samples(true, n_ti=6, n_o=80)
    bad_start = dict(guess=False, init={"alpha_x": 0.9, "alpha_y": 0.0002, "rho_s": 1.0})
    one = fit.fit(s, "ward", **bad_start, n_starts=0, max_nfev=30)
    many = fit.fit(s, "ward", **bad_start, n_starts=6, rng=1)
    assert many.n_starts == 7
    assert many.chi2 <= one.chi2
    assert many.params["alpha_y"] == pytest.approx(0.16, rel=1e-5)


def test_initial_guess_is_close_for_ward():
    true = brdf.create("ward", **BRASS)
    g = fit.initial_guess(_samples(true, n_ti=6, n_o=200), "ward")
    assert g.params["alpha_x"] == pytest.approx(0.05, rel=0.2)
    assert g.params["alpha_y"] == pytest.approx(0.16, rel=0.2)
    assert g.params["rho_s"] == pytest.approx(0.33, rel=0.3)


def test_result_to_dict_is_json_and_summary_prints():
    true = brdf.create("ward", **BRASS)
    r = fit.fit(_samples(true, noise=0.05, n_ti=4, n_o=50), "ward")
    d = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert d["model"] == "ward" and d["converged"] is True
    assert set(d["params"]) == set(BRASS)
    assert "alpha_x" in r.summary()


# ------------------------------------------------------------------ bad input
def test_bad_inputs_raise_value_error_naming_the_problem():
    true = brdf.create("ward", **BRASS)
    s = _samples(true, n_ti=3, n_o=20)
    with pytest.raises(ValueError, match="unknown BRDF model 'nope'"):
        fit.fit(s, "nope")
    with pytest.raises(ValueError, match="residual"):
        fit.fit(s, "ward", residual="L1")
    with pytest.raises(ValueError, match="unknown parameter 'alpha'"):
        fit.fit(s, "ward", fixed=["alpha"])
    with pytest.raises(ValueError, match="BRDFSamples"):
        fit.fit(s.to_array(), "ward")
    with pytest.raises(ValueError, match="every parameter is fixed"):
        fit.fit(s, "ward", fixed=list(BRASS))
    with pytest.raises(ValueError, match="free parameters"):
        fit.fit(s.subset(np.arange(3)), "ward")
    with pytest.raises(ValueError, match="n_starts"):
        fit.fit(s, "ward", n_starts=-1)
    with pytest.raises(ValueError, match="empty term"):
        fit.fit(s, "lambert + ")
    with pytest.raises(ValueError, match="must be finite"):
        fit.fit(s, "ward", init={"rho_d": float("nan")})
    zero = s.subset(np.arange(len(s)))
    zero.sigma = np.zeros(len(s))
    with pytest.raises(ValueError, match="zero standard error"):
        fit.fit(zero, "ward")
    neg = s.subset(np.arange(len(s)))
    neg.value = -np.abs(neg.value)
    with pytest.raises(ValueError, match="positive"):
        fit.fit(neg, "ward", residual="log")
    with pytest.raises(ValueError, match="per_band"):
        fit.fit(s, "ward", per_band=["rho_d"])


def test_model_returning_nan_is_an_error_not_a_nan_fit():
    class _Bad(BRDF):
        name: ClassVar[str] = "bad_toy"
        PARAMS = (Param("a", 0.5, 0.0, 1.0),)

        def _eval(self, wi, wo):
            return np.full(wi.shape[:-1], np.nan) * self._params["a"]

    s = _samples(brdf.create("ward", **BRASS), n_ti=3, n_o=20)
    with pytest.raises(ValueError, match="non-finite"):
        fit.fit(s, _Bad())


def test_log_residual_excludes_nonpositive_samples():
    true = brdf.create("ward", **BRASS)
    s = _samples(true, n_ti=4, n_o=50)
    s.value[:5] = 0.0
    r = fit.fit(s, "ward", residual="log")
    assert r.n_excluded == 5
    assert r.params["alpha_x"] == pytest.approx(0.05, rel=1e-6)


def test_multistart_on_a_large_table_screens_a_subset_and_polishes_on_all(monkeypatch):
    monkeypatch.setattr(fit.core, "SCREEN_ROWS", 500)
    true = brdf.create("ward", **BRASS)
    s = _samples(true, noise=0.05, seed=2, n_ti=6, n_o=100)
    one = fit.fit(s, "ward")
    many = fit.fit(s, "ward", n_starts=3, rng=4)
    assert len(s) > 500 and many.n_starts == 4
    for k in BRASS:
        assert many.params[k] == pytest.approx(one.params[k], rel=1e-6)
    assert many.n_samples == len(s)


def test_lafortune_lobes_are_flattened_and_recovered():
    """Two generalized lobes + diffuse (Lafortune eq. 8), anisotropic C_x != C_y."""
    true = brdf.create(
        "lafortune", lobes=[(-0.9, -0.7, 0.8, 20.0), (0.5, 0.5, 0.4, 3.0)], rho_d=0.2
    )
    s = _samples(true, n_ti=6, n_o=120)
    template = brdf.create("lafortune", lobes=[(-1.0, -1.0, 1.0, 10.0)] * 2)
    r = fit.fit(s, template, rng=3)
    assert r.converged
    assert "lobes[1].c_z" in r.params and "r_m" in r.fixed  # the mirror term is held
    assert r.rms < 1e-6 * float(np.max(s.value))
    got = sorted(r.model.params["lobes"], key=lambda lb: lb[3])
    want = sorted(true.params["lobes"], key=lambda lb: lb[3])
    for g, w in zip(got, want):
        assert np.allclose(g[:4], w[:4], rtol=1e-4)
    assert r.params["rho_d"] == pytest.approx(0.2, rel=1e-4)


def test_li_torrance_per_band_ks_with_one_shared_roughness():
    """Li-Torrance §5: one sigma, tau for all bands, per-band k's (eq. 15 residual).

    Off the specular direction the model depends on sigma and tau only through the slope
    sigma/tau (its eq. 10 simplification), so the fit recovers the slope and the k's and
    reports sigma, tau individually as unidentifiable (infinite standard errors).
    """
    wl = np.array([450.0, 550.0, 650.0])
    true = brdf.create("li_torrance", k_dd=[0.3, 0.4, 0.5], k_uds=[0.1, 0.2, 0.05],
                       sigma=0.3, tau=3.0, wavelength_nm=wl)  # fmt: skip
    g = _geometry(n_ti=5, n_o=150)
    v = np.asarray(true(g.wi, g.wo))
    tables = []
    for k, w in enumerate(wl):
        t = g.subset(np.arange(len(g)))
        t.value = v[:, k]
        t.wavelength_nm = np.full(len(t), w)
        tables.append(t)
    s = BRDFSamples.concatenate(tables)
    start = brdf.create("li_torrance", wavelength_nm=wl, k_dd=[0.5] * 3, k_uds=[0.3] * 3)
    r = fit.fit(s, start, fixed={"k_udf": 0.0, "k_fs": 0.0}, residual="li_torrance")
    assert r.converged
    assert sorted(r.free) == sorted(
        [f"k_dd[{k}]" for k in range(3)] + [f"k_uds[{k}]" for k in range(3)] + ["sigma", "tau"]
    )  # wavelength_nm and n_ior are held by default
    for k in range(3):
        assert r.params[f"k_dd[{k}]"] == pytest.approx(true.params["k_dd"][k], rel=1e-6)
        assert r.params[f"k_uds[{k}]"] == pytest.approx(true.params["k_uds"][k], rel=1e-6)
    assert r.params["sigma"] / r.params["tau"] == pytest.approx(0.1, rel=1e-6)
    assert not r.identifiable and math.isinf(r.stderr["sigma"]) and math.isinf(r.stderr["tau"])


# ------------------------------------------------------------------ variable projection
def _li_torrance_bands(noise=0.02, seed=3):
    wl = np.array([450.0, 550.0, 650.0])
    true = brdf.create("li_torrance", k_dd=[0.3, 0.4, 0.5], k_uds=[0.1, 0.2, 0.0],
                       k_fs=[0.5, 1.0, 1.5], sigma=0.3, tau=3.0, wavelength_nm=wl)  # fmt: skip
    g = _geometry(n_ti=5, n_o=120)
    v = np.asarray(true(g.wi, g.wo))
    rng = np.random.default_rng(seed)
    tables = []
    for k, w in enumerate(wl):
        t = g.subset(np.arange(len(g)))
        sig = noise * v[:, k] + 1e-3
        t.value = v[:, k] + sig * rng.normal(size=len(t))
        t.sigma = sig
        t.wavelength_nm = np.full(len(t), w)
        tables.append(t)
    start = brdf.create("li_torrance", wavelength_nm=wl, k_dd=[0.5] * 3, k_uds=[0.3] * 3,
                        k_fs=[0.5] * 3, sigma=0.3, tau=2.4)  # fmt: skip
    return BRDFSamples.concatenate(tables), start


def _assert_same_fit(a, b, rtol=1e-6):
    assert a.free == b.free and a.converged and b.converged
    assert b.chi2 == pytest.approx(a.chi2, rel=1e-9)
    for k in a.free:
        va, vb = a.params[k], b.params[k]
        assert vb == pytest.approx(va, rel=rtol, abs=1e-10), k
        assert b.stderr[k] == pytest.approx(a.stderr[k], rel=1e-5, abs=1e-12), k


def test_linear_parameters_by_variable_projection_give_the_joint_fit():
    """Li-Torrance is linear in its k's (Li and Torrance 2005, eq. 2-14): solving them
    exactly per trial tau (linear=) reaches the joint least-squares minimum, with the same
    standard errors, also where a k sits on its bound (k_uds of the last band is 0)."""
    s, start = _li_torrance_bands()
    kw = dict(fixed={"k_udf": 0.0, "sigma": 0.3}, guess=False)
    joint = fit.fit(s, start, **kw)
    fast = fit.fit(s, start, linear=["k_dd", "k_uds", "k_fs"], **kw)
    _assert_same_fit(joint, fast)
    assert fast.params["k_uds[2]"] < 1e-3
    assert abs(fast.params["tau"] / 3.0 - 1) < 5 * fast.stderr["tau"] / 3.0
    # the cosine-weighted residual (eq. 15) is linear in the model too
    joint = fit.fit(s, start, residual="li_torrance", **kw)
    fast = fit.fit(s, start, residual="li_torrance", linear=["k_dd", "k_uds", "k_fs"], **kw)
    _assert_same_fit(joint, fast)


def test_linear_grey_per_band_and_scalar_reflectances():
    """Ward is linear in rho_d and rho_s: per-band copies (grey model, spectral data) and
    plain scalars give the joint fit's parameters and errors."""
    true = brdf.create("ward", rho_d=0.2, rho_s=0.1, alpha_x=0.12, alpha_y=0.12)
    s = _samples(true, noise=0.03, n_ti=5, n_o=60, rotations=(0.0,))
    _assert_same_fit(fit.fit(s, "ward"), fit.fit(s, "ward", linear=["rho_d", "rho_s"]))
    tables = []
    for k, w in enumerate((450.0, 550.0, 650.0)):
        t = s.subset(np.arange(len(s)))
        t.value = s.value * (1.0 + 0.2 * k)
        t.sigma = s.sigma * (1.0 + 0.2 * k)
        t.wavelength_nm = np.full(len(t), w)
        tables.append(t)
    sp = BRDFSamples.concatenate(tables)
    joint = fit.fit(sp, "ward", per_band=["rho_d", "rho_s"])
    fast = fit.fit(sp, "ward", per_band=["rho_d", "rho_s"], linear=["rho_d", "rho_s"])
    _assert_same_fit(joint, fast)
    assert len(fast.free) == 3 * 2 + 2


def test_linear_rejects_parameters_that_are_not_linear():
    true = brdf.create("ward", rho_d=0.2, rho_s=0.1, alpha_x=0.12, alpha_y=0.12)
    s = _samples(true, noise=0.03, n_ti=3, n_o=40, rotations=(0.0,))
    with pytest.raises(ValueError, match="linear"):
        fit.fit(s, "ward", linear=["alpha_x"])
    with pytest.raises(ValueError, match="log"):
        fit.fit(s, "ward", residual="log", linear=["rho_d"])
    with pytest.raises(ValueError, match="string"):
        fit.fit(s, "ward", linear="rho_d")
    with pytest.raises(ValueError, match="no_such"):
        fit.fit(s, "ward", linear=["no_such"])


def test_lafortune_random_starts_cycle_retro_lobes():
    """Start k: exponents one per log stratum of [1, 200], sorted; retro lobes cycle through
    none, each single lobe, then each pair (so every single-retro layout is tried)."""
    from gonio.fit.core import _start_lafortune

    params = {"lobes": [(-1.0, -1.0, 1.0, 10.0, 0.0)] * 3, "rho_d": 0.1}
    rng = np.random.default_rng(0)
    seen = []
    for k in range(8):
        st = _start_lafortune(params, rng, k)
        lobes = st["lobes"]
        ns = [lb[3] for lb in lobes]
        assert ns == sorted(ns) and 1.0 <= ns[0] and ns[-1] <= 200.0
        edges = np.exp(np.linspace(0.0, np.log(200.0), 4))
        assert all(edges[i] <= ns[i] <= edges[i + 1] for i in range(3))
        seen.append(tuple(i for i, lb in enumerate(lobes) if lb[0] > 0))  # C_x > 0: retro
        assert all(lb[0] == lb[1] and lb[2] > 0 for lb in lobes)
        assert 0.0 <= st["rho_d"] <= 0.5
    assert seen == [(), (0,), (1,), (2,), (0, 1), (0, 2), (1, 2), (0, 1, 2)]


def test_jacobian_ignores_a_jump_inside_the_step():
    """A row with a jump (threshold) inside the difference step: the robust Jacobian keeps the
    smooth derivative there, so an exactly degenerate pair stays rank-deficient."""
    from gonio.fit.core import _covariance, _jacobian

    rng = np.random.default_rng(0)
    n = 200
    u = rng.uniform(0.5, 2.0, n)
    x = np.array([0.5, 6.0])  # (sigma, tau): the model depends on sigma/tau only
    h_tau = 1e-6 * 1e-2 * 1e4  # the step _jacobian takes for tau with bounds [1e-4, 1e4]
    thresh = np.full(n, 99.0)
    thresh[7] = x[0] / (x[1] + 0.5 * h_tau)  # row 7 jumps inside the larger tau step only

    def fun(p):
        k = p[0] / p[1]
        return u * k + 0.01 * (k > thresh)  # jump of 0.01 where the ratio passes a threshold

    lb, ub = np.array([1e-4, 1e-4]), np.array([1e2, 1e4])
    r0 = fun(x)
    J = _jacobian(fun, x, lb, ub, r0)
    exact = np.stack([u / x[1], -u * x[0] / x[1] ** 2], axis=1)
    np.testing.assert_allclose(J, exact, rtol=1e-6)
    _, ok, inf = _covariance(J)
    assert not ok and inf.all()


def test_a_fit_stuck_far_from_the_data_says_so():
    """Started at the lower corner of Ward's bounds without the data guess, the optimizer
    stops at a misfit its σ cannot explain: converged (the optimizer's word) but noted."""
    from gonio import brdf
    from gonio.fit import fit
    from gonio.fit.core import CHI2_NOTE
    from gonio.geometry import to_vector
    from gonio.samples import BRDFSamples

    rng = np.random.default_rng(0)
    n = 2000
    wi = to_vector(rng.uniform(0.0, 1.4, n), rng.uniform(-np.pi, np.pi, n))
    wo = to_vector(np.arccos(rng.uniform(0.05, 1.0, n)), rng.uniform(-np.pi, np.pi, n))
    truth = brdf.create("ward", rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)
    f = truth(wi, wo)
    s = BRDFSamples.from_directions(wi, wo, f * (1 + 0.01 * rng.standard_normal(n)), 0.01 * f)
    good = fit(s, "ward")
    assert good.chi2_dof < 2 and "note:" not in good.message
    spec = brdf.spec("ward").params
    low = {k: p.lower + 1e-6 * (p.upper - p.lower) for k, p in spec.items() if p.kind == "float"}
    bad = fit(s, "ward", init=low, guess=False)
    assert bad.chi2_dof > CHI2_NOTE and "local minimum" in bad.message
    assert np.isfinite(list(bad.params.values())).all()


# ------------------------------------------------------------------ issue 15 item 11
def test_unidentifiable_fit_says_so_in_its_message():
    true = brdf.create("lambert", rho=0.2) + brdf.create(
        "ward", rho_d=0.1, rho_s=0.1, alpha_x=0.1, alpha_y=0.1
    )
    r = fit.fit(_samples(true, n_ti=4, n_o=60), "lambert + ward")
    assert "note: not identifiable" in r.message and "lambert.rho" in r.message


def test_init_outside_the_bounds_is_refused_not_clipped():
    s = _samples(brdf.create("ward", **BRASS), n_ti=4, n_o=60)
    with pytest.raises(ValueError, match=r"init alpha_x = 5.0 is outside its bounds \[0.0001, 1"):
        fit.fit(s, "ward", init={"alpha_x": 5.0})


def test_number_of_starts_is_bounded():
    s = _samples(brdf.create("ward", **BRASS), n_ti=4, n_o=60)
    with pytest.raises(ValueError, match=r"n_starts must be in \[0, 10000\], got 100000000"):
        fit.fit(s, "ward", n_starts=100_000_000)


@settings(max_examples=300, deadline=None)
@given(
    rows=st.lists(
        st.lists(st.sampled_from([0.0, -0.0, 1.0, 2.5, math.nan, math.inf]), min_size=3,
                 max_size=3),
        max_size=40,
    )
)  # fmt: skip
def test_repeated_rows_counts_what_numpy_unique_counts(rows):
    # the hashed count against the record sort it replaces: -0.0 is 0.0, NaN as numpy says
    from gonio.fit.core import repeated_rows

    key = np.array(rows, dtype=np.float64).reshape(len(rows), 3)
    want = len(rows) - np.unique(key, axis=0).shape[0] if rows else 0
    assert repeated_rows(key) == want


def test_repeated_rows_are_noted():
    s = _samples(brdf.create("ward", **BRASS), noise=0.02, n_ti=4, n_o=60)
    once = fit.fit(s, "ward")
    twice = fit.fit(BRDFSamples.concatenate([s, s]), "ward")
    assert "repeat" not in once.message
    assert f"note: {len(s)} of {2 * len(s)} rows repeat other rows exactly" in twice.message
    assert twice.stderr["rho_s"] == pytest.approx(once.stderr["rho_s"] / math.sqrt(2), rel=0.02)


def test_warnings_are_the_notes_of_the_message():
    """FitResult.warnings: one sentence per note the message carries (the message and
    fit.json unchanged)."""
    from gonio.campaign.determined import hemisphere_geometries

    wi, wo = hemisphere_geometries((20.0, 50.0))
    y = np.full(len(wi), 0.2)
    res = fit.fit(BRDFSamples.from_directions(wi, wo, y, np.full(len(wi), 1e-3)),
                  "lambert+lambert")  # fmt: skip
    assert len(res.warnings) == 1 and res.warnings[0].startswith("not identifiable")
    assert res.message.endswith("; note: " + res.warnings[0])
    assert "warnings" not in res.to_dict()
