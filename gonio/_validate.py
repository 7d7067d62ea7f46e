"""Input validation shared by the whole package.

Every public function that takes user arrays or parameters funnels them through here so that
bad input raises :class:`ValueError` naming the argument, the value and what was expected
(``docs/architecture.md``, Conventions).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


def as_directions(w: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return ``w`` as a float64 array of shape ``(..., 3)`` with only finite entries.

    Raises
    ------
    ValueError
        If the last axis is not of length 3, or any entry is NaN or infinite.
    """
    try:
        a = np.asarray(w, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be an array of directions of shape (..., 3): {exc}"
        ) from None
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got shape {a.shape}")
    if not np.isfinite(a).all():
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN or inf)")
    return a


def as_finite_array(x: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return ``x`` as float64, raising ``ValueError`` if any entry is not finite."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains non-finite value(s) (NaN or inf)")
    return a


def check_scalar(
    value: Any,
    name: str,
    lower: float = -math.inf,
    upper: float = math.inf,
    *,
    lower_open: bool = False,
    upper_open: bool = False,
) -> float:
    """Return ``value`` as a finite float inside its bounds, else raise ``ValueError``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    lo_bad = v <= lower if lower_open else v < lower
    hi_bad = v >= upper if upper_open else v > upper
    if lo_bad or hi_bad:
        lb = "(" if lower_open else "["
        ub = ")" if upper_open else "]"
        raise ValueError(f"{name} = {v!r} is outside its allowed range {lb}{lower}, {upper}{ub}")
    return v


def check_choice(value: Any, name: str, choices) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` listing them."""
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; expected one of {sorted(map(str, choices))}")
    return value
