"""numba kernels of the LBL capture hot path (imported lazily by :mod:`gonio.simulator.lbl`).

The per-capture work is split so that the only transcendental call per pixel, Ward's
``exp``, runs in numpy's SIMD ``exp`` (faster than a scalar libm call from numba):

1. :func:`ward_exponent` — per candidate pixel: rotate the cached dome-frame direction into
   the sample frame, test the beam footprint, write ``-exponent`` (eq. 5a or 5b);
2. ``numpy.exp`` in place;
3. :func:`compose_u16` / :func:`compose_float` — one pass over the image: background + dark
   electrons, plus ``resp · lit · (kdc + ksc · g · isq)`` at the candidate pixels, then the
   ADC (``compose_u16``) or the float electrons (for noise, delta parts or binning).

Each has a plain-numpy twin in :mod:`gonio.simulator.lbl` (``kernel=False``), and the tests
check that both give the same image.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["compose_float", "compose_u16", "digitise_linear", "ward_cone", "ward_exponent"]


@njit(cache=True)
def ward_exponent(
    wx, wy, wz, qx, qy, foot, ix, iy, iz, c, s, bx, by, r2, iax2, iay2, approx, ex, lit
):  # pragma: no cover - compiled
    """``ex[j] = -exponent`` of Ward's specular lobe; ``lit[j]`` = inside the beam footprint."""
    for j in range(wx.size):
        ok = True
        if foot:
            x = qx[j]
            y = qy[j]
            p = x * bx + y * by
            ok = x * x + y * y - p * p <= r2
        ox = c * wx[j] + s * wy[j]
        oy = -s * wx[j] + c * wy[j]
        hx = ix + ox
        hy = iy + oy
        hz = iz + wz[j]
        num = hx * hx * iax2 + hy * hy * iay2
        if approx:
            n2 = hx * hx + hy * hy + hz * hz
            e = 2.0 * num / (n2 * (1.0 + hz / math.sqrt(n2)))
        else:
            e = num / (hz * hz)
        ex[j] = -e
        lit[j] = 1 if ok and wz[j] > 0.0 else 0


@njit(cache=True)
def ward_cone(
    wx, wy, wz, qx, qy, wis, wsrc, c, s, bx, by, r2, kd, ks, iax2, iay2, approx, acc, lit
):  # pragma: no cover - compiled
    """Ward averaged over several source directions: ``acc[j] = Σ w f_r(wi_m, wo) cos θ_m``."""
    m = wis.shape[0]
    for j in range(wx.size):
        x = qx[j]
        y = qy[j]
        p = x * bx + y * by
        lit[j] = 1 if (x * x + y * y - p * p <= r2 and wz[j] > 0.0) else 0
        ox = c * wx[j] + s * wy[j]
        oy = -s * wx[j] + c * wy[j]
        oz = wz[j]
        a = 0.0
        for q in range(m):
            ix = wis[q, 0]
            iy = wis[q, 1]
            iz = wis[q, 2]
            if iz <= 0.0 or oz <= 0.0:
                continue
            hx = ix + ox
            hy = iy + oy
            hz = iz + oz
            num = hx * hx * iax2 + hy * hy * iay2
            if approx:
                n2 = hx * hx + hy * hy + hz * hz
                e = 2.0 * num / (n2 * (1.0 + hz / math.sqrt(n2)))
            else:
                e = num / (hz * hz)
            f = kd
            if ks != 0.0:
                f += ks * math.exp(-e) / math.sqrt(iz * oz)
            a += wsrc[q] * f * iz
        acc[j] = a


@njit(cache=True)
def compose_float(bg, dark, tk, t, idx, resp, lit, g, isq, kdc, ksc, out):  # pragma: no cover
    """``out = bg·tk + dark·t`` plus the candidate signal (float electrons)."""
    n = idx.size
    j = 0
    for i in range(out.size):
        e = bg[i] * tk + dark[i] * t
        if j < n and idx[j] == i:
            if lit[j]:
                e += resp[j] * (kdc + ksc * g[j] * isq[j])
            j += 1
        out[i] = e


@njit(cache=True)
def compose_u16(
    bg, dark, tk, t, idx, resp, lit, g, isq, kdc, ksc, full_well, inv_gain, black, max_dn, out
):  # pragma: no cover - compiled
    """:func:`compose_float` fused with the linear ADC (no float image is written)."""
    n = idx.size
    j = 0
    for i in range(out.size):
        e = bg[i] * tk + dark[i] * t
        if j < n and idx[j] == i:
            if lit[j]:
                e += resp[j] * (kdc + ksc * g[j] * isq[j])
            j += 1
        if e > full_well:
            e = full_well
        d = np.rint(e * inv_gain + black)
        if d < 0.0:
            d = 0.0
        elif d > max_dn:
            d = max_dn
        out[i] = np.uint16(d)


@njit(cache=True)
def digitise_linear(e, full_well, inv_gain, black, max_dn, out):  # pragma: no cover - compiled
    """Linear ADC: clip at full well, scale, add black level, round half to even, clip."""
    for i in range(e.size):
        v = e[i]
        if v > full_well:
            v = full_well
        d = np.rint(v * inv_gain + black)
        if d < 0.0:
            d = 0.0
        elif d > max_dn:
            d = max_dn
        out[i] = np.uint16(d)
