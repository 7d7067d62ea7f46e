"""Which parameters a set of geometries can determine, before anything is measured.

A least-squares fit determines a free parameter only if the model's Jacobian over the
samples' geometries has full column rank (the Gauss-Newton normal matrix ``JᵀJ`` is then
invertible; Björck 1996, §9.1). The rank depends on the geometries alone and on the
parameters' values, not on the measured values or their noise, so it can be checked on a
plan's directions at the model's start values — noise-free "data" from the model itself —
before any capture. :func:`unseparated` does that with the fit's own machinery (the same
parameter layout, the same fixed parameters, the same difference Jacobian and the same
rank test as :func:`gonio.fit.fit`), so what it says is what the fit would find.

References
----------
.. [Bjorck1996] Å. Björck, *Numerical Methods for Least Squares Problems*, SIAM, 1996,
   §9.1 (the Gauss-Newton method; a rank-deficient Jacobian leaves a null space of
   undetermined parameter combinations).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gonio.samples import BRDFSamples

__all__ = ["distinct_geometries", "free_parameters", "unseparated"]


def distinct_geometries(wi: ArrayLike, wo: ArrayLike, decimals: int = 9) -> int:
    """How many different direction pairs ``(wi, wo)`` there are (unit vectors compared to
    ``decimals`` decimals): repeats of one geometry add no information on the parameters."""
    key = np.round(np.concatenate([np.asarray(wi, float), np.asarray(wo, float)], axis=1),
                   decimals)  # fmt: skip
    return int(np.unique(key, axis=0).shape[0]) if key.size else 0


def unseparated(
    model: Any,
    wi: ArrayLike,
    wo: ArrayLike,
    *,
    wavelength_nm: ArrayLike | None = None,
    fixed: Iterable[str] | Mapping[str, Any] | None = None,
    jitter: float = 0.0,
) -> list[str]:
    """The free parameters of ``model`` that the geometries ``(wi, wo)`` cannot separate.

    Parameters
    ----------
    model : str or BRDF
        The model to fit as :func:`gonio.fit.fit` takes it; its values are used as they
        are (the start values of the planned fit).
    wi, wo : array_like, shape (n, 3)
        The plan's incident and outgoing directions (sample frame).
    wavelength_nm : array_like, optional
        The bands of a spectral measurement: each geometry is then one row per band.
    fixed : names or mapping, optional
        Parameters the fit holds (as :func:`gonio.fit.fit`'s ``fixed``).
    jitter : float
        Check at the model's values each scaled by a random factor within ``1 ± jitter``
        (seeded; clipped to the bounds) instead of at the values themselves: a start that
        sits on a symmetry (three equal Lafortune lobes) is degenerate there only.

    Returns
    -------
    list of str
        The flat names of the free parameters in the null space of the Jacobian (empty when
        the geometries determine every free parameter). With fewer distinct geometry rows
        than free parameters every free parameter is returned.
    """
    from gonio.fit.core import _covariance, _jacobian, _Problem, parse_model, predict

    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    key = np.round(np.concatenate([wi, wo], axis=1), 9)
    _u, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    wi, wo = wi[first], wo[first]
    wl = None
    if wavelength_nm is not None:
        bands = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))
        n = len(wi)
        wi, wo = np.repeat(wi, len(bands), axis=0), np.repeat(wo, len(bands), axis=0)
        wl = np.tile(bands, n)
    template = parse_model(model)
    if jitter:
        template = _jittered(template, jitter)
    ones = np.ones(len(wi))
    probe = BRDFSamples.from_directions(wi, wo, ones, np.full(len(wi), np.nan), wavelength_nm=wl)
    value = np.asarray(predict(template, probe), dtype=np.float64).reshape(-1)
    top = float(np.max(np.abs(value))) if value.size else 0.0
    if not (math.isfinite(top) and top > 0):
        raise ValueError(f"{template.name} is zero or not finite on every geometry")
    # 1 % of each value, at least 1e-3 of the largest: relative weights, none infinite
    scale = np.maximum(np.abs(value), 1e-3 * top)
    samples = BRDFSamples.from_directions(wi, wo, value, 0.01 * scale, wavelength_nm=wl)
    try:
        p = _Problem(samples, template, "absolute", fixed=fixed, free=None, init=None,
                     per_band=None, guess=False)  # fmt: skip
    except ValueError as exc:
        if "usable rows" not in str(exc):
            raise
        p = _Problem(_tiled(samples), template, "absolute", fixed=fixed, free=None, init=None,
                     per_band=None, guess=False)  # fmt: skip
        return [p.names[i] for i in p.free_idx]
    r0 = p.fun_checked(p.x0)
    J = _jacobian(p.fun_checked, p.x0, p.lb, p.ub, r0)
    _cov, rank_ok, free_inf = _covariance(J)
    if rank_ok:
        return []
    return [p.names[i] for j, i in enumerate(p.free_idx) if free_inf[j]]


def free_parameters(
    model: Any, fixed: Iterable[str] | Mapping[str, Any] | None = None
) -> list[str]:
    """The flat names of the parameters :func:`gonio.fit.fit` would fit of ``model``
    (its defaults held, ``fixed`` held)."""
    from gonio.fit.core import _Problem

    wi = np.tile([[0.0, 0.0, 1.0]], (1000, 1))
    table = BRDFSamples.from_directions(wi, wi, np.ones(1000))
    p = _Problem(table, model, "absolute", fixed=fixed, free=None, init=None, per_band=None,
                 guess=False)  # fmt: skip
    return [p.names[i] for i in p.free_idx]


def _tiled(samples: BRDFSamples, times: int = 1000) -> BRDFSamples:
    """``samples`` repeated (only to learn a problem's free parameters when there are fewer
    rows than parameters)."""
    idx = np.tile(np.arange(len(samples)), times)
    return samples.subset(idx)


def _jittered(model: Any, jitter: float, seed: int = 12345) -> Any:
    """``model`` with each flat parameter scaled by ``1 + jitter·u``, ``u`` uniform in
    [-1, 1] (a fixed seed), clipped to its bounds."""
    from gonio.fit.core import _model_entries, _rebuild

    rng = np.random.default_rng(seed)
    flat = {}
    for name, v, lo, hi in _model_entries(model):
        flat[name] = float(np.clip(v * (1.0 + jitter * rng.uniform(-1.0, 1.0)), lo, hi))
    return _rebuild(model, flat)
