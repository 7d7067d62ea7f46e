"""Compiled inverse of the Kannala-Brandt radial map (used by :mod:`gonio.simulator.lenses`).

:func:`kb_inverse` runs the safeguarded Newton iteration of
:meth:`FisheyeLens._g_inv <gonio.simulator.lenses.FisheyeLens>` element by element in
compiled code, with the same operations in the same order and the same global stopping rule
(every element's last step within ``1e-15`` relative, at most 60 iterations), so its result
is the same bit for bit as the numpy loop's (a test checks it): the numpy form evaluates
~15 whole-array expressions per iteration over every pixel of the grid (1.0 s for a
640 x 480 grid on the shared 2-core test machine), this one a few milliseconds. No
``fastmath``: LLVM then neither reorders nor fuses the multiply-adds, which keeps the
arithmetic IEEE-identical to numpy's.

Kept apart from :mod:`gonio.simulator._kernels` (the capture's kernels), because the
laboratory's reduction uses the lens model too and must not load the simulator's capture
kernels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["KB_INVERSE_SIGNATURE", "kb_inverse"]

#: The argument types with which a campaign calls :func:`kb_inverse` (see
#: :data:`gonio.simulator._kernels.CAMPAIGN_SIGNATURES`).
KB_INVERSE_SIGNATURE = "(f8[::1], f8, f8, f8, f8, f8, f8[::1])"


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _g(t, k1, k2, k3, k4):  # pragma: no cover - compiled
    t2 = t * t
    return t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _dg(t, k1, k2, k3, k4):  # pragma: no cover - compiled
    t2 = t * t
    return 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))


@njit(cache=True, nogil=True, error_model="numpy")
def kb_inverse(r, k1, k2, k3, k4, hi_t, out):  # pragma: no cover - compiled
    """θ with ``g(θ) = r`` for every element of the flat array ``r`` into ``out``."""
    n = r.size
    lo = np.empty(n)  # the brackets, filled below (np.zeros and np.full: 0.3 s more to compile)
    hi = np.empty(n)
    t = out
    for i in range(n):  # np.clip(r, 0, hi_t)
        x = r[i]
        t[i] = hi_t if x > hi_t else (0.0 if x < 0.0 else x)
        lo[i] = 0.0
        hi[i] = hi_t
    for _ in range(60):
        done = True
        for i in range(n):
            ti = t[i]
            f = _g(ti, k1, k2, k3, k4) - r[i]
            if f < 0.0:
                lo[i] = ti
            if f > 0.0:
                hi[i] = ti
            d = _dg(ti, k1, k2, k3, k4)
            step = f / d if d > 0.0 else 0.0
            tn = ti - step
            if (tn <= lo[i]) or (tn >= hi[i]) or (d <= 0.0):
                tn = 0.5 * (lo[i] + hi[i])
            if not (abs(tn - ti) <= 1e-15 * max(1.0, abs(ti))):
                done = False
            t[i] = tn
        if done:
            break
    return out
