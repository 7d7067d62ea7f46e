"""Property tests over every registered model constructible with its defaults.

Random directions (hypothesis) and adversarial ones (exactly normal, 90° − 1e-9, wi = wo,
wi = mirror of wo, exactly on and below the horizon, wi = −wo): values are finite, ≥ 0 and 0
below the horizon; reciprocal to 1e-12 relative where ``spec(name).reciprocal``; shapes are
``(...)`` for grey and ``(..., n_bands)`` for spectral models; float32 input is accepted.
Models with required parameters and ``tabulated`` are skipped.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio import brdf


def _constructible() -> list[str]:
    out = []
    for name in brdf.names():
        if name == "tabulated":
            continue
        sp = brdf.spec(name)
        if any(p.default is None and not p.optional for p in sp.params.values()):
            continue
        out.append(name)
    return out


MODELS = _constructible()
_CACHE: dict[str, brdf.BRDF] = {}


def _model(name: str) -> brdf.BRDF:
    if name not in _CACHE:
        _CACHE[name] = brdf.create(name)
    return _CACHE[name]


def _vec(theta: float, phi: float) -> np.ndarray:
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _adversarial_pairs() -> tuple[np.ndarray, np.ndarray]:
    g = 0.5 * np.pi - 1e-9
    base = [
        _vec(0.0, 0.0),
        _vec(g, 0.0),
        _vec(g, 2.0),
        _vec(0.7, 0.4),
        _vec(1.2, -2.5),
        _vec(1e-9, 1.0),
        _vec(0.5 * np.pi, 0.3),  # exactly on the horizon
        _vec(2.0, 0.1),  # below
        _vec(np.pi, 0.0),  # straight down
    ]
    wi, wo = [], []
    for a in base:
        for b in base:
            wi.append(a)
            wo.append(b)
        wi += [a, a, a]
        wo += [a, a * [-1.0, -1.0, 1.0], -a]  # wi = wo, mirror, opposite
    return np.array(wi), np.array(wo)


def _check(model: brdf.BRDF, name: str, wi: np.ndarray, wo: np.ndarray) -> None:
    f = np.asarray(model(wi, wo))
    bands = model.n_bands
    assert f.shape == wi.shape[:-1] + ((bands,) if bands else ())
    assert np.all(np.isfinite(f)), f"{name}: non-finite values"
    assert np.all(f >= 0.0), f"{name}: negative values"
    below = (wi[..., 2] <= 0.0) | (wo[..., 2] <= 0.0)
    if bands:
        below = below[..., None] & np.ones(bands, bool)
    # strictly below the horizon: exactly zero (on it, z = 0, the limit is allowed)
    strict = (wi[..., 2] < 0.0) | (wo[..., 2] < 0.0)
    if bands:
        strict = strict[..., None] & np.ones(bands, bool)
    assert np.all(f[strict] == 0.0), f"{name}: non-zero below the horizon"
    if brdf.spec(name).reciprocal:
        r = np.asarray(model(wo, wi))
        np.testing.assert_allclose(f, r, rtol=1e-12, atol=0.0, err_msg=f"{name}: not reciprocal")


@pytest.mark.parametrize("name", MODELS)
def test_adversarial_directions(name: str) -> None:
    wi, wo = _adversarial_pairs()
    _check(_model(name), name, wi, wo)


_angles = st.tuples(
    st.floats(0.0, np.pi, allow_nan=False), st.floats(-np.pi, np.pi, allow_nan=False)
)


@pytest.mark.parametrize("name", MODELS)
@settings(max_examples=40, deadline=None)
@given(pairs=st.lists(st.tuples(_angles, _angles), min_size=1, max_size=6))
def test_random_directions(name: str, pairs) -> None:
    wi = np.array([_vec(*a) for a, _ in pairs])
    wo = np.array([_vec(*b) for _, b in pairs])
    _check(_model(name), name, wi, wo)


@pytest.mark.parametrize("name", MODELS)
def test_shapes_broadcast_and_float32(name: str) -> None:
    model = _model(name)
    rng = np.random.default_rng(3)
    v = rng.normal(size=(4, 5, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    wo = _vec(0.4, 0.2)
    bands = model.n_bands
    tail = (bands,) if bands else ()
    f = model(v, wo)
    assert f.shape == (4, 5) + tail
    assert model(v[0, 0], wo).shape == tail
    np.testing.assert_allclose(model(v, np.broadcast_to(wo, v.shape)), f, rtol=1e-13)
    # float32 input accepted (converted to float64)
    f32 = model(v.astype(np.float32), wo.astype(np.float32))
    assert f32.dtype == np.float64 and f32.shape == f.shape
    exact = model(v.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(f32, exact, rtol=1e-12)


@pytest.mark.parametrize("name", MODELS)
def test_nan_input_raises(name: str) -> None:
    model = _model(name)
    wi = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]])
    with pytest.raises(ValueError, match="wi"):
        model(wi, [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="wo"):
        model([0.0, 0.0, 1.0], wi)


# Spectral variants of this module's own models (defaults are grey).
_SPECTRAL = [
    ("metal_neumann", dict(kappa_re=[0.2, 0.5, 1.1], kappa_im=[3.5, 2.6, 2.6])),
    ("plastic_neumann", dict(a_d=[0.6, 0.3, 0.1], a_s=0.3, kappa=1.5)),
]


@pytest.mark.parametrize(("name", "params"), _SPECTRAL)
def test_spectral_variants(name: str, params: dict) -> None:
    model = brdf.create(name, **params)
    assert model.n_bands == 3
    wi, wo = _adversarial_pairs()
    _check(model, name, wi, wo)
