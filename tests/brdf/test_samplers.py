"""Chi-square goodness-of-fit of every BRDF sampler against its own pdf (Mitsuba style).

The sphere of incident directions is binned in (cos θ, φ); the expected count of each bin is
``N ∫_bin pdf dω`` (Gauss-Legendre points per bin, refined until converged); directions the
sampler rejects (below the horizon, pdf 0) form one more cell with expected count ``N (1 − ∫ pdf)``.
Cells with an expected count below 5 are pooled; the statistic is compared with the χ²
distribution (scipy.stats.chi2). Every pdf must integrate to ≤ 1 over the hemisphere.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from gonio import brdf, materials

N_SAMPLES = 100_000
N_THETA, N_PHI = 24, 48
P_MIN = 1e-3


def _dir(theta_deg: float, phi: float = 0.3) -> np.ndarray:
    t = np.radians(theta_deg)
    return np.array([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])


def _bin_integrals(pdf_fn) -> np.ndarray:
    """∫ pdf dω per (cos θ, φ) bin, Gauss-Legendre refined until converged.

    Converged: the change on doubling is below 5 % of each bin's Poisson standard deviation.

    Narrow lobes at grazing incidence are very thin in φ (the out-of-plane width of a
    reflected lobe shrinks as cos θ_o), so the per-bin rule is doubled from 8 × 8 points.
    """
    prev = None
    for n_gl in (8, 16, 32, 64):
        cur = _bin_integrals_n(pdf_fn, n_gl)
        noise = np.sqrt(cur * N_SAMPLES + 1.0)  # Poisson standard deviation of a count
        if prev is not None and np.all(np.abs(cur - prev) * N_SAMPLES < 0.05 * noise):
            return cur
        prev = cur
    raise AssertionError("bin integrals of the pdf did not converge")


def _bin_integrals_n(pdf_fn, N_GL: int) -> np.ndarray:
    x, w = np.polynomial.legendre.leggauss(N_GL)
    u = 0.5 * (x + 1.0)
    dc, dp = 1.0 / N_THETA, 2.0 * np.pi / N_PHI
    c = (np.arange(N_THETA)[:, None] + u[None, :]).ravel() * dc  # (T*G,)
    p = (np.arange(N_PHI)[:, None] + u[None, :]).ravel() * dp  # (P*G,)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    wi = np.stack(
        np.broadcast_arrays(
            s[:, None] * np.cos(p)[None, :], s[:, None] * np.sin(p)[None, :], c[:, None]
        ),
        axis=-1,
    )
    vals = pdf_fn(wi)  # (T*G, P*G)
    wt = 0.5 * w * dc
    wp = 0.5 * w * dp
    vals = vals.reshape(N_THETA, N_GL, N_PHI, N_GL)
    return np.einsum("iajb,a,b->ij", vals, wt, wp)


def chi_square(model: brdf.BRDF, wo: np.ndarray, seed: int = 7) -> tuple[float, float, float]:
    """Return ``(p_value, ∫ pdf dω, rejected fraction)`` for sampling ``wi`` given ``wo``."""
    wos = np.broadcast_to(wo, (N_SAMPLES, 3)).copy()
    wi, pdf = model.sample(wos, seed)
    assert wi.shape == (N_SAMPLES, 3) and pdf.shape == (N_SAMPLES,)
    assert np.all(np.isfinite(wi)) and np.all(np.isfinite(pdf)) and np.all(pdf >= 0)
    up = wi[:, 2] > 0.0
    # accepted samples have a positive pdf equal to model.pdf; rejected ones pdf 0
    assert np.all(pdf[~up] == 0.0)
    np.testing.assert_allclose(pdf[up], model.pdf(wo, wi[up]), rtol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(wi[up], axis=-1), 1.0, rtol=1e-12)
    ct = wi[up, 2]
    ph = np.mod(np.arctan2(wi[up, 1], wi[up, 0]), 2.0 * np.pi)
    obs, _, _ = np.histogram2d(
        ct, ph, bins=[N_THETA, N_PHI], range=[[0.0, 1.0], [0.0, 2.0 * np.pi]]
    )
    integ = _bin_integrals(lambda w: model.pdf(wo, w))
    total = float(integ.sum())
    exp = np.append(integ.ravel() * N_SAMPLES, max(N_SAMPLES * (1.0 - total), 0.0))
    obs = np.append(obs.ravel(), np.count_nonzero(~up))
    small = exp < 5.0
    e = np.append(exp[~small], exp[small].sum())
    o = np.append(obs[~small], obs[small].sum())
    keep = e > 0.0
    assert np.all(o[~keep] == 0), "samples fell where the pdf is zero"
    e, o = e[keep], o[keep]
    stat = float(np.sum((o - e) ** 2 / e))
    p = float(chi2.sf(stat, len(e) - 1))
    return p, total, float(np.count_nonzero(~up)) / N_SAMPLES


def _default_samplers() -> list[str]:
    out = []
    for name in brdf.names():
        sp = brdf.spec(name)
        if name == "tabulated" or not sp.has_sampler:
            continue
        if any(p.default is None and not p.optional for p in sp.params.values()):
            continue
        out.append(name)
    return out


@pytest.mark.parametrize("theta", [0.0, 35.0, 75.0])
@pytest.mark.parametrize("name", _default_samplers())
def test_default_sampler_chi_square(name: str, theta: float) -> None:
    model = brdf.create(name)
    p, total, rejected = chi_square(model, _dir(theta))
    assert total <= 1.0 + 1e-3
    # ∫ pdf ≈ 1 − rejected fraction (binomial standard error of the fraction)
    assert abs((1.0 - total) - rejected) < 5.0 * np.sqrt(0.25 / N_SAMPLES) + 1e-3
    assert p > P_MIN, f"{name} at {theta}°: chi-square p = {p:.3g}"


_EXTRA = [
    ("ward", dict(rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)),  # rolled brass
    ("ward", dict(rho_d=0.0, rho_s=1.0, alpha_x=0.3, alpha_y=0.08)),
    ("ward_neumann", dict(rho_d=0.2, rho_s=0.5, alpha_x=0.2, alpha_y=0.1)),
    ("ward_gmd", dict(rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)),  # rolled brass
    ("phong", dict(n=3.0, rho_d=0.4)),
    ("phong_neumann", dict(n=200.0, p=0.5)),
    ("phong_retro", dict(n=5.0, rho_d=0.2)),
    ("metal_neumann", dict(n=80.0, kappa_re=0.2, kappa_im=3.0)),
    ("plastic_neumann", dict(n=9.0, a_d=0.5, a_s=0.09)),
    (
        "lafortune",
        dict(
            lobes=[
                (0.86, 0.86, 0.77, 18.6),
                (-0.41, -0.41, 0.018, 2.58),
                (-1.03, -1.03, 0.70, 63.8),
            ],
            rho_d=0.13,
        ),
    ),
    ("lafortune", dict(lobes=[(-1.0, -0.8, 0.95, 30.0, 1.0), (0.0, 0.0, 1.0, 2.0)], rho_d=0.0)),
]


@pytest.mark.parametrize("theta", [10.0, 60.0, 85.0])
@pytest.mark.parametrize(
    ("name", "params"), _EXTRA, ids=[f"{n}-{i}" for i, (n, _) in enumerate(_EXTRA)]
)
def test_sampler_chi_square_non_default(name: str, params: dict, theta: float) -> None:
    model = brdf.create(name, **params)
    p, total, rejected = chi_square(model, _dir(theta, phi=1.1))
    assert total <= 1.0 + 1e-3
    assert abs((1.0 - total) - rejected) < 5.0 * np.sqrt(0.25 / N_SAMPLES) + 1e-3
    assert p > P_MIN, f"{name}{params} at {theta}°: chi-square p = {p:.3g}"


def test_chi_square_detects_a_wrong_pdf() -> None:
    """The test has power: a pdf off by a smooth factor fails it."""

    class Wrong(brdf.get_class("phong")):
        name = "phong_wrong_pdf_for_test"

        def _pdf(self, wo, wi):
            return super()._pdf(wo, wi) * (0.9 + 0.2 * wi[..., 2])

    p, _, _ = chi_square(Wrong(n=10.0), _dir(30.0))
    assert p < 1e-6


def test_preset_sampler_blue_paint() -> None:
    model = materials.get("blue_paint_lafortune")
    p, total, _ = chi_square(model, _dir(65.0, 0.0))
    assert p > P_MIN and total <= 1.0 + 1e-3
