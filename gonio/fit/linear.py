"""Variable projection for models that are linear in some of their parameters.

Many reflectance models are sums ``f = Σ_j k_j B_j(θ)`` of basis terms with non-negative
scale factors ``k_j`` (Li and Torrance's ``k_dd``, ``k_udf``, ``k_uds``, ``k_fs`` per band,
Li and Torrance 2005, eq. 2, 9, 11-13; Ward's ρ_d, ρ_s). For fixed non-linear parameters
``θ`` the weighted least-squares problem in ``k`` is linear and is solved exactly (with the
bounds of ``k``); the outer optimiser then only searches ``θ`` ("variable projection",
Golub & Pereyra 1973). The minimiser is the same as that of the joint problem.

This module holds the numerical pieces, free of any model code; :func:`gonio.fit.fit` uses
them when called with ``linear=[...]``.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.

Li and Torrance 2005, §5 (one shared σ, τ, per-band coefficients k), eq. 2-14.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["blocks", "solve_bounded"]


def blocks(A: NDArray[np.float64]) -> list[tuple[NDArray[np.intp], NDArray[np.intp]]]:
    """Independent sub-problems of the design matrix ``A`` (rows × columns).

    Columns that share no row with a non-zero entry in both are decoupled (per-band
    coefficients touch only their band's rows). Returns ``[(rows, cols), ...]`` covering
    every column once; ``rows`` are the rows with a non-zero entry in ``cols`` (possibly
    empty for a column the data do not see).
    """
    nz = A != 0
    if A.shape[1] == 0:
        return []
    from scipy.sparse.csgraph import connected_components  # scipy loads on first use

    inc = nz.astype(np.float64)
    adj = (inc.T @ inc) > 0
    n, labels = connected_components(adj, directed=False)
    out = []
    for c in range(n):
        cols = np.flatnonzero(labels == c)
        rows = np.flatnonzero(nz[:, cols].any(axis=1))
        out.append((rows, cols))
    return out


def solve_bounded(
    A: NDArray[np.float64],
    b: NDArray[np.float64],
    lo: NDArray[np.float64],
    hi: NDArray[np.float64],
    parts: list[tuple[NDArray[np.intp], NDArray[np.intp]]] | None = None,
) -> NDArray[np.float64]:
    """``argmin ‖A x − b‖`` subject to ``lo ≤ x ≤ hi``, block by block.

    Each independent block (:func:`blocks`) is solved by ordinary least squares; when the
    solution leaves the bounds, by bounded-variable least squares
    (:func:`scipy.optimize.lsq_linear`, ``method="bvls"``). A column without data gets the
    value inside the bounds closest to 0.
    """
    x = np.clip(np.zeros(A.shape[1]), lo, hi)
    for rows, cols in parts if parts is not None else blocks(A):
        if rows.size == 0:
            continue
        a = A[np.ix_(rows, cols)]
        bb = b[rows]
        sol, *_ = np.linalg.lstsq(a, bb, rcond=None)
        if np.any(sol < lo[cols]) or np.any(sol > hi[cols]):
            from scipy.optimize import lsq_linear  # only when a bound is hit

            sol = lsq_linear(a, bb, bounds=(lo[cols], hi[cols]), method="bvls", tol=1e-14).x
        x[cols] = sol
    return x
