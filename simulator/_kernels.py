"""numba kernels of the LBL capture hot path (imported lazily by :mod:`gonio.simulator.lbl`).

The per-capture work is split so that the only transcendental call per pixel, Ward's
``exp``, runs in numpy's SIMD ``exp`` (faster than a scalar libm call from numba):

1. :func:`ward_exponent` — per candidate pixel: rotate the cached dome-frame direction into
   the sample frame, test the beam footprint, write ``-exponent`` (eq. 5a or 5b);
2. ``numpy.exp`` in place;
3. :func:`compose_u16` / :func:`compose_float` — one pass over the image: background + dark
   electrons, plus ``resp · lit · (kdc + ksc · g · isq)`` at the candidate pixels, then the
   ADC (``compose_u16``, noise off) or the float electrons (``compose_float``), followed
   with noise on by :func:`noise_float` in place and :func:`digitise_linear` (three tight
   passes run faster than one fused loop: the generator's state stays in registers).

Candidate pixel indices ``idx`` are sorted; a pixel may appear several times in a row (one
entry per sub-pixel ray when the capture supersamples, each with its share of ``resp``).

Noise (:func:`shot_read_noise`): shot noise is Poisson in electrons and read noise Gaussian.
Below ``threshold`` electrons the Poisson count is drawn exactly (inversion with one uniform
for λ < 10, numba's PTRS ``Generator.poisson`` above) plus a normal read-noise draw; at or
above it shot and read noise are drawn together from ONE standard normal ``z`` through the
Cornish-Fisher (skew-corrected) transform ``e = λ + s z + c (z² - 1)`` whose mean and variance
equal those of Poisson(λ) + N(0, σ²) and whose third central moment is λ - 4c³ (Poisson's
is λ): ``s² + 2c² = λ + σ²``, ``c = λ / 6(λ + σ²)``. See :mod:`gonio.simulator.sensor` for the
threshold and the measured distance between the two distributions.

All kernels release the GIL (``nogil``), so a capture overlaps with other threads (the
campaign's image writer). Each has a plain-numpy twin in :mod:`gonio.simulator.lbl`
(``kernel=False``), and the tests check that both give the same image (the noise draw's
reference is numpy's exact Poisson, ``Sensor.add_noise(exact=True)``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "compose_float",
    "compose_u16",
    "digitise_linear",
    "exact_shot_read",
    "noise_float",
    "plan_masks",
    "plan_scene",
    "shot_read_noise",
    "ward_cone",
    "ward_exponent",
]


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def compose_float(bg, dark, tk, t, idx, resp, lit, g, isq, kdc, ksc, out):  # pragma: no cover
    """``out = bg·tk + dark·t`` plus the candidate signal (float electrons)."""
    n = idx.size
    j = 0
    for i in range(out.size):
        e = bg[i] * tk + dark[i] * t
        while j < n and idx[j] == i:
            if lit[j]:
                e += resp[j] * (kdc + ksc * g[j] * isq[j])
            j += 1
        out[i] = e


@njit(cache=True, nogil=True)
def _adc(e, full_well, inv_gain, black, max_dn):  # pragma: no cover - compiled
    if e > full_well:
        e = full_well
    d = np.rint(e * inv_gain + black)
    if d < 0.0:
        d = 0.0
    elif d > max_dn:
        d = max_dn
    return np.uint16(d)


@njit(cache=True, nogil=True)
def compose_u16(
    bg, dark, tk, t, idx, resp, lit, g, isq, kdc, ksc, full_well, inv_gain, black, max_dn, out
):  # pragma: no cover - compiled
    """:func:`compose_float` fused with the linear ADC (no float image is written)."""
    n = idx.size
    j = 0
    for i in range(out.size):
        e = bg[i] * tk + dark[i] * t
        while j < n and idx[j] == i:
            if lit[j]:
                e += resp[j] * (kdc + ksc * g[j] * isq[j])
            j += 1
        out[i] = _adc(e, full_well, inv_gain, black, max_dn)


@njit(cache=True, nogil=True)
def exact_shot_read(lam, rng, sigma):  # pragma: no cover - compiled
    """Exact Poisson(λ) count (λ >= 0) plus N(0, σ²) read noise."""
    if lam <= 0.0:
        k = 0.0
    elif lam < 10.0:  # inversion of the Poisson CDF with one uniform
        u = rng.random()
        p = math.exp(-lam)
        f = p
        m = 0
        while u > f and m < 200:
            m += 1
            p *= lam / m
            f += p
        k = float(m) if m < 200 else float(rng.poisson(lam))  # (2^-53-rare rounding guard)
    else:
        k = float(rng.poisson(lam))
    if sigma > 0.0:
        k += sigma * rng.standard_normal()
    return k


@njit(cache=True, nogil=True)
def shot_read_noise(lam, rng, threshold, sigma):  # pragma: no cover - compiled
    """One noisy electron count: Poisson(λ) shot noise plus N(0, σ²) read noise (λ >= 0).

    Exact below ``threshold`` (:func:`exact_shot_read`); at or above it the skew-corrected
    normal (module docstring) with ``c = λ / 6V`` (``V = λ + σ²``), ``s = sqrt(V - 2c²)``:
    mean λ and variance V exactly, third central moment ``λ - 4c³`` (``c <= 1/6``).
    """
    if lam < threshold:
        return exact_shot_read(lam, rng, sigma)
    v = lam + sigma * sigma
    c = lam / (6.0 * v)
    s = math.sqrt(v - 2.0 * c * c)
    z = rng.standard_normal()
    return lam + s * z + c * (z * z - 1.0)


@njit(cache=True, nogil=True)
def noise_float(lam, rng, threshold, sigma, out):  # pragma: no cover - compiled
    """``out[i]`` = :func:`shot_read_noise` of ``max(lam[i], 0)``."""
    s2 = sigma * sigma
    for i in range(lam.size):
        v = lam[i]
        if v < 0.0:
            v = 0.0
        if v < threshold:
            out[i] = exact_shot_read(v, rng, sigma)
        else:  # (shot_read_noise, inlined by hand: numba keeps the generator in registers)
            w = v + s2
            c = v / (6.0 * w)
            z = rng.standard_normal()
            out[i] = v + math.sqrt(w - 2.0 * c * c) * z + c * (z * z - 1.0)


@njit(cache=True, nogil=True)
def digitise_linear(e, full_well, inv_gain, black, max_dn, out):  # pragma: no cover - compiled
    """Linear ADC: clip at full well, scale, add black level, round half to even, clip."""
    for i in range(e.size):
        out[i] = _adc(e[i], full_well, inv_gain, black, max_dn)


@njit(cache=True, nogil=True)
def _plan_pixel(a, dk, s, inv_n2, sat_e, min_e):  # pragma: no cover - compiled
    """(usable-stop bits, number of leading stops at which the total is <= ``sat_e``)."""
    bits = 0
    lead = 0
    ok = True
    for q in range(inv_n2.size):
        r = inv_n2[q]
        tot = a * r + dk
        if tot <= sat_e:
            if ok:
                lead += 1
            if s * r >= min_e:
                bits |= 1 << q
        else:
            ok = False
    return bits, lead


@njit(cache=True, nogil=True)
def plan_scene(
    bg, dark, t, idx, resp, lit, g, isq, kdc, ksc, inv_n2, sat_e, min_e, masks, lead
):  # pragma: no cover - compiled
    """Bracket planning in one pass over the candidate pixels (a run of ``idx`` each).

    Per pixel: total electrons at f/1 ``e1`` as :func:`compose_float` forms it (exposure
    ``t``), background alone ``b1 = bg·t + dark·t``, signal ``sig = e1 - b1``; pixels with
    ``sig > 0`` (lit) get ``masks[m]``: bit i set when usable at stop i (``inv_n2[i]`` =
    1/N², darkest first): total ``(e1 - dark·t)/N² + dark·t <= sat_e`` and ``sig/N² >=
    min_e``. ``lead[0]`` becomes the smallest number of leading stops at which a lit pixel's
    total stays <= ``sat_e`` (so stops ``0 .. lead[0]-1`` saturate no lit pixel). Returns
    the number of lit pixels.
    """
    n = idx.size
    m = 0
    j = 0
    lmin = inv_n2.size
    while j < n:
        i = idx[j]
        dk = dark[i] * t
        b = bg[i] * t
        e = b + dk
        while j < n and idx[j] == i:
            if lit[j]:
                e += resp[j] * (kdc + ksc * g[j] * isq[j])
            j += 1
        s = e - (b + dk)
        if s > 0.0:
            bits, ld = _plan_pixel(e - dk, dk, s, inv_n2, sat_e, min_e)
            masks[m] = bits
            if ld < lmin:
                lmin = ld
            m += 1
    lead[0] = lmin
    return m


@njit(cache=True, nogil=True)
def plan_masks(a, d, sig, inv_n2, sat_e, min_e, masks, lead):  # pragma: no cover
    """:func:`plan_scene` on precomputed lit pixels (``a = e1 - dark·t``, ``d = dark·t``)."""
    lmin = inv_n2.size
    for p in range(a.size):
        bits, ld = _plan_pixel(a[p], d[p], sig[p], inv_n2, sat_e, min_e)
        masks[p] = bits
        if ld < lmin:
            lmin = ld
    lead[0] = lmin
