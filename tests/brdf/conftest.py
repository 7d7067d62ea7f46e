"""Fixtures shared by the BRDF model tests."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def sphere_pairs():
    """``make(n, seed)``: ``n`` direction pairs ``(wi, wo)`` uniform over the whole sphere
    (normalised normal draws of ``default_rng(seed)``, ``wi`` first), so directions below the
    horizon are among them."""

    def make(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        wi = rng.normal(size=(n, 3))
        wo = rng.normal(size=(n, 3))
        wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        return wi, wo

    return make
