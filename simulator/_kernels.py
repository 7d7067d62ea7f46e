"""numba kernels of the LBL capture hot path (imported lazily by the LBL parts
:mod:`gonio.simulator.lbl_scene` and :mod:`gonio.simulator.lbl_frame`).

The per-capture work is split so that the only transcendental call per pixel, Ward's
``exp``, runs in numpy's SIMD ``exp`` (faster than a scalar libm call from numba, and the
noise-free image is defined by it):

1. :func:`ward_exponent` — per candidate pixel: rotate the cached dome-frame direction into
   the sample frame, test the beam footprint, write ``-exponent`` (eq. 5a or 5b);
2. ``numpy.exp`` in place;
3. :func:`compose_u16_runs` (noise off): one pass over the image: background + dark
   electrons, plus ``resp · lit · (kdc + ksc · g · isq)`` at the candidate pixels, then the
   ADC (no float image is written); noise on: the same into float electrons
   (:func:`compose_float_runs`), then shot + read noise and the ADC in one pass
   (:func:`noise_u16`). (Composing inside the noise pass, block by block, measured slower:
   5.1-5.9 ms against 3.7-4.1 ms for the two passes on a 1024 x 1024 frame.)

The candidate pixels ``idx`` are sorted and, with one ray per pixel, unique; they come in
runs of consecutive pixels (one or two per image row), so the compose kernels walk the
image run by run (``rpix``: first pixel of each run, ``rj``: its first candidate entry):
background-only stretches and candidate stretches are straight loops the compiler turns
into SIMD code. With supersampling a pixel appears once per sub-pixel ray (each with its
share of ``resp``) and :func:`compose_u16` / :func:`compose_float` handle the repeats.
Every kernel uses numpy's error model (``error_model="numpy"``): without it numba checks
each float division for zero, which keeps LLVM from vectorising the loop; the arithmetic,
and so the image, is the same bit for bit.

Noise: shot noise is Poisson in electrons and read noise Gaussian. Below ``threshold``
electrons the Poisson count is drawn exactly (:func:`exact_shot_read`: inversion with one
uniform for λ < 10, Hörmann's PTRS above) plus a normal read-noise draw; at or above it shot
and read noise are drawn together from ONE standard normal ``z`` through the Cornish-Fisher
(skew-corrected) transform ``e = λ + s z + c (z² - 1)`` whose mean and variance equal those
of Poisson(λ) + N(0, σ²) and whose third central moment is λ - 4c³ (Poisson's is λ):
``s² + 2c² = λ + σ²``, ``c = λ / 6(λ + σ²)``. See :mod:`gonio.simulator.sensor` for the
threshold and the measured distance between the two distributions.

Random numbers come from a xoshiro256++ generator (Blackman & Vigna 2018) compiled into the
kernels, its 256-bit state held in registers, seeded by :func:`seed_state` with four 64-bit
words drawn from the caller's ``numpy.random.Generator`` (so a capture is reproducible from
its seed, and successive draws from one Generator differ). Standard normals use the
256-layer ziggurat of Marsaglia & Tsang (2000) in numpy's form (52-bit mantissa, layer
index and sign from the low 9 bits of the same word; tables built by :func:`_ziggurat`).
The noise kernels draw the normals of a block of :data:`BLOCK` pixels first and then
transform the block in a loop without branches (SIMD): drawing and transforming per pixel
in one loop is about twice as slow (1.24 against 0.66 ms for 640 x 480 pixels). The draws
are sequential in one thread, so the image does not depend on the number of threads.

All kernels release the GIL (``nogil``), so a capture overlaps with other threads (the
campaign's image writer). Each has a plain-numpy twin in the LBL parts
(:mod:`gonio.simulator.lbl_scene`, :mod:`gonio.simulator.lbl_frame`; ``kernel=False``),
and the tests check that both give the same image (the noise draw's reference is numpy's
exact Poisson, ``Sensor.add_noise(exact=True)``).

References
----------
G. Marsaglia, W. W. Tsang, "The ziggurat method for generating random variables", J. Stat.
Softw. 5(8), 2000. D. Blackman, S. Vigna, "Scrambled linear pseudorandom number
generators", 2018 (xoshiro256++). W. Hörmann, "The transformed rejection method for
generating Poisson random variables", Insurance Math. Econom. 12, 1993 (PTRS).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "BLOCK",
    "CAMPAIGN_SIGNATURES",
    "adc_charge",
    "argument_types",
    "bloom_columns",
    "compose_float",
    "compose_float_runs",
    "compose_u16",
    "compose_u16_runs",
    "digitise_linear",
    "exact_shot_read",
    "noise_float",
    "noise_u16",
    "plan_masks",
    "plan_scene",
    "readout_float",
    "readout_u16",
    "seed_state",
    "standard_normals",
    "ward_cone",
    "ward_exponent",
]


#: The argument types (numba's notation: ``f8[::1]`` a C-ordered float64 vector) with which an
#: LBL campaign calls the kernels it loads: what
#: :meth:`gonio.campaign.executor.CampaignExecutor.compile_ahead` compiles on an empty cache
#: (a call with other types compiles its own specialisation on first use, as before).
CAMPAIGN_SIGNATURES: dict[str, str] = {
    "ward_exponent": "(f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], b1, f8, f8, f8, f8, f8, f8, "
    "f8, f8, f8, f8, b1, f8[::1], u1[::1])",
    "plan_scene": "(f8[::1], f8[::1], f8, i8[::1], f8[::1], u1[::1], f8[::1], f8[::1], f8, f8, "
    "f8[::1], f8, f8, i8[::1], i8[::1])",
    "compose_float_runs": "(f8[::1], f8[::1], f8, f8, i8[::1], i8[::1], f8[::1], u1[::1], "
    "f8[::1], f8[::1], f8, f8, f8[::1])",
    "noise_u16": "(f8[::1], u8[::1], f8, f8, f8, f8, f8, f8, u2[::1])",
    "noise_float": "(f8[::1], u8[::1], f8, f8, f8[::1])",
    "digitise_linear": "(f8[::1], f8, f8, f8, f8, u2[::1])",
}


def argument_types(signature: str) -> tuple:
    """A signature of :data:`CAMPAIGN_SIGNATURES` as the tuple of numba types a call's
    arguments have: what a kernel's ``compile`` must be given, since numba's cache keys an
    entry by the signature as given (an entry compiled from the string is not found by a
    call, which compiles it again)."""
    from numba.core.sigutils import normalize_signature

    return normalize_signature(signature)[0]


@njit(cache=True, nogil=True, error_model="numpy")
def ward_exponent(
    wx, wy, wz, qx, qy, foot, ix, iy, iz, c, s, bx, by, r2, iax2, iay2, approx, ex, lit
):  # pragma: no cover - compiled
    """``ex[j] = -exponent`` of Ward's specular lobe; ``lit[j]`` = inside the beam footprint.

    One straight loop per (``foot``, ``approx``) case, so each vectorises; without
    ``foot`` the sample points are not read.
    """
    if foot:
        if approx:
            _ward_loop(wx, wy, wz, qx, qy, True, ix, iy, iz, c, s, bx, by, r2, iax2, iay2,
                       True, ex, lit)  # fmt: skip
        else:
            _ward_loop(wx, wy, wz, qx, qy, True, ix, iy, iz, c, s, bx, by, r2, iax2, iay2,
                       False, ex, lit)  # fmt: skip
    elif approx:
        _ward_loop(wx, wy, wz, qx, qy, False, ix, iy, iz, c, s, bx, by, r2, iax2, iay2,
                   True, ex, lit)  # fmt: skip
    else:
        _ward_loop(wx, wy, wz, qx, qy, False, ix, iy, iz, c, s, bx, by, r2, iax2, iay2,
                   False, ex, lit)  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ward_loop(
    wx, wy, wz, qx, qy, foot, ix, iy, iz, c, s, bx, by, r2, iax2, iay2, approx, ex, lit
):  # pragma: no cover - compiled
    for j in range(wx.size):
        w = wz[j]
        ok = w > 0.0
        if foot:  # (a constant in each inlined copy)
            x = qx[j]
            y = qy[j]
            p = x * bx + y * by
            ok = ok & (x * x + y * y - p * p <= r2)
        ox = c * wx[j] + s * wy[j]
        oy = -s * wx[j] + c * wy[j]
        hx = ix + ox
        hy = iy + oy
        hz = iz + w
        num = hx * hx * iax2 + hy * hy * iay2
        if approx:
            n2 = hx * hx + hy * hy + hz * hz
            e = 2.0 * num / (n2 * (1.0 + hz / math.sqrt(n2)))
        else:
            e = num / (hz * hz)
        ex[j] = -e
        lit[j] = np.uint8(ok)


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
def _adc(e, full_well, inv_gain, black, max_dn):  # pragma: no cover - compiled
    """Linear ADC of one pixel (selects, no branches: the loops calling it vectorise)."""
    e = e if e < full_well else full_well
    d = np.rint(e * inv_gain + black)
    d = d if d > 0.0 else 0.0
    d = d if d < max_dn else max_dn
    return np.uint16(d)


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _store(e, adc):  # pragma: no cover - compiled
    """``e`` as is (``adc`` None: float electrons) or through the linear ADC (``adc`` =
    ``(full_well, inv_gain, black, max_dn)``); numba compiles one branch per type."""
    if adc is None:
        return e
    return _adc(e, adc[0], adc[1], adc[2], adc[3])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bg_run(bg, dark, tk, t, adc, out):  # pragma: no cover - compiled
    for i in range(out.size):
        out[i] = _store(bg[i] * tk + dark[i] * t, adc)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lit_run(bg, dark, tk, t, resp, lit, g, isq, kdc, ksc, adc, out):  # pragma: no cover
    for i in range(out.size):
        e = bg[i] * tk + dark[i] * t
        s = e + resp[i] * (kdc + ksc * g[i] * isq[i])
        out[i] = _store(s if lit[i] else e, adc)


@njit(cache=True, nogil=True, error_model="numpy")
def _compose_runs(
    bg, dark, tk, t, rpix, rj, resp, lit, g, isq, kdc, ksc, adc, out
):  # pragma: no cover - compiled
    """The image walked run by run (module docstring): background-only stretches, then
    each run of candidate pixels; values stored by :func:`_store`."""
    nr = rpix.size
    nc = resp.size
    p = 0
    for r in range(nr):
        a = rpix[r]
        j0 = rj[r]
        m = (rj[r + 1] if r + 1 < nr else nc) - j0
        _bg_run(bg[p:a], dark[p:a], tk, t, adc, out[p:a])
        _lit_run(
            bg[a : a + m], dark[a : a + m], tk, t, resp[j0 : j0 + m], lit[j0 : j0 + m],
            g[j0 : j0 + m], isq[j0 : j0 + m], kdc, ksc, adc, out[a : a + m],
        )  # fmt: skip
        p = a + m
    _bg_run(bg[p:], dark[p:], tk, t, adc, out[p:])


@njit(cache=True, nogil=True, error_model="numpy")
def compose_u16_runs(
    bg, dark, tk, t, rpix, rj, resp, lit, g, isq, kdc, ksc, full_well, inv_gain, black, max_dn, out
):  # pragma: no cover - compiled
    """:func:`compose_u16` for unique candidates given as runs (module docstring): the same
    arithmetic per pixel, so the same image bit for bit."""
    adc = (float(full_well), float(inv_gain), float(black), float(max_dn))
    _compose_runs(bg, dark, tk, t, rpix, rj, resp, lit, g, isq, kdc, ksc, adc, out)


@njit(cache=True, nogil=True, error_model="numpy")
def compose_float_runs(
    bg, dark, tk, t, rpix, rj, resp, lit, g, isq, kdc, ksc, out
):  # pragma: no cover - compiled
    """:func:`compose_float` for unique candidates given as runs (same arithmetic)."""
    _compose_runs(bg, dark, tk, t, rpix, rj, resp, lit, g, isq, kdc, ksc, None, out)


# ---------------------------------------------------------------------------- random numbers
#: pixels whose normals are drawn before the block is transformed (module docstring)
BLOCK = 1024
_U = np.uint64
_D53 = 1.0 / 9007199254740992.0  # 2^-53
_ZIG_R = 3.6541528853610088  # start of the tail of numpy's 256-layer normal ziggurat
_ZIG_INV_R = 1.0 / _ZIG_R


def _ziggurat(r: float = _ZIG_R, n: int = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tables ``(k, w, f)`` of the ``n``-layer normal ziggurat with tail start ``r``
    (Marsaglia & Tsang 2000, 52-bit form as in numpy): layer ``i`` has right edge
    ``x_i = w[i]·2^52``, density ``f[i] = exp(-x_i²/2)``; a 52-bit ``u`` in layer ``i`` is
    accepted at once when ``u < k[i]``. Every layer (the base with its tail) has area
    ``v = r f(r) + ∫_r^∞ f``."""
    m1 = 2.0**52
    v = r * math.exp(-0.5 * r * r) + math.sqrt(math.pi / 2) * math.erfc(r / math.sqrt(2.0))
    k = np.zeros(n, dtype=np.uint64)
    w = np.zeros(n)
    f = np.zeros(n)
    dn = tn = r
    q = v / math.exp(-0.5 * dn * dn)
    k[0] = int(dn / q * m1)
    w[0] = q / m1
    w[n - 1] = dn / m1
    f[0] = 1.0
    f[n - 1] = math.exp(-0.5 * dn * dn)
    for i in range(n - 2, 0, -1):
        dn = math.sqrt(-2.0 * math.log(v / dn + math.exp(-0.5 * dn * dn)))
        k[i + 1] = int(dn / tn * m1)
        tn = dn
        f[i] = math.exp(-0.5 * dn * dn)
        w[i] = dn / m1
    return k, w, f


_ZIG_K, _ZIG_W, _ZIG_F = _ziggurat()


def seed_state(rng: np.random.Generator) -> np.ndarray:
    """A xoshiro256++ state (4 uint64) drawn from ``rng`` (never all zero)."""
    st = rng.integers(0, 2**64, size=4, dtype=np.uint64)
    if not st.any():  # (probability 2^-256; the all-zero state is a fixed point)
        st[0] = 1
    return st


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rotl(x, k):  # pragma: no cover - compiled
    return (x << _U(k)) | (x >> _U(64 - k))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _next(s0, s1, s2, s3):  # pragma: no cover - compiled
    """One xoshiro256++ output and the next state."""
    r = _rotl(s0 + s3, 23) + s0
    t = s1 << _U(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    return r, s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _uniform(s0, s1, s2, s3):  # pragma: no cover - compiled
    """Uniform in [0, 1) with 53 random bits."""
    r, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
    return float(r >> _U(11)) * _D53, s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_slow(r, s0, s1, s2, s3):  # pragma: no cover - compiled
    """The rest of a ziggurat draw whose first word ``r`` was not accepted at once: the
    wedge test (or the tail beyond R for the base layer), else a new draw."""
    idx = r & _U(0xFF)
    x = float(np.int64((r >> _U(9)) & _U(0x000FFFFFFFFFFFFF))) * _ZIG_W[idx]
    if (r >> _U(8)) & _U(1):
        x = -x
    while True:
        if idx == 0:
            while True:  # Marsaglia's tail method
                u, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
                xx = -_ZIG_INV_R * math.log1p(-u)
                u, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
                yy = -math.log1p(-u)
                if yy + yy > xx * xx:
                    return (-(_ZIG_R + xx) if x < 0.0 else _ZIG_R + xx), s0, s1, s2, s3
        u, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
        if (_ZIG_F[idx - 1] - _ZIG_F[idx]) * u + _ZIG_F[idx] < math.exp(-0.5 * x * x):
            return x, s0, s1, s2, s3
        r, s0, s1, s2, s3 = _next(s0, s1, s2, s3)  # start again
        idx = r & _U(0xFF)
        rabs = (r >> _U(9)) & _U(0x000FFFFFFFFFFFFF)
        x = float(np.int64(rabs)) * _ZIG_W[idx]
        if (r >> _U(8)) & _U(1):
            x = -x
        if rabs < _ZIG_K[idx]:
            return x, s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _normal(s0, s1, s2, s3):  # pragma: no cover - compiled
    """One standard normal (ziggurat; about 99 % of draws take one word and no branch)."""
    r, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
    idx = r & _U(0xFF)
    rabs = (r >> _U(9)) & _U(0x000FFFFFFFFFFFFF)
    if rabs < _ZIG_K[idx]:
        x = float(np.int64(rabs)) * _ZIG_W[idx]
        return (-x if (r >> _U(8)) & _U(1) else x), s0, s1, s2, s3
    return _normal_slow(r, s0, s1, s2, s3)


@njit(cache=True, nogil=True, error_model="numpy")
def standard_normals(state, out):  # pragma: no cover - compiled
    """``out[:]`` = standard normals from the xoshiro256++ ``state`` (advanced in place)."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    for i in range(out.size):
        out[i], s0, s1, s2, s3 = _normal(s0, s1, s2, s3)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def _poisson_ptrs(lam, s0, s1, s2, s3):  # pragma: no cover - compiled
    """Poisson(λ), λ >= 10, by Hörmann's transformed rejection (PTRS), as numpy draws it."""
    slam = math.sqrt(lam)
    loglam = math.log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        u, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
        v, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
        u -= 0.5
        us = 0.5 - abs(u)
        k = np.floor((2.0 * a / us + b) * u + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return k, s0, s1, s2, s3
        if k < 0.0 or (us < 0.013 and v > us):
            continue
        if math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b) <= (
            -lam + k * loglam - math.lgamma(k + 1.0)
        ):
            return k, s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def exact_shot_read(lam, sigma, s0, s1, s2, s3):  # pragma: no cover - compiled
    """Exact Poisson(λ) count (λ >= 0) plus N(0, σ²) read noise; returns it and the state."""
    if lam <= 0.0:
        k = 0.0
    elif lam < 10.0:  # inversion of the Poisson CDF with one uniform
        u, s0, s1, s2, s3 = _uniform(s0, s1, s2, s3)
        p = math.exp(-lam)
        f = p
        m = 0
        while u > f and m < 200:
            m += 1
            p *= lam / m
            f += p
        k = float(m)
        if m == 200:  # (2^-53-rare rounding guard)
            k, s0, s1, s2, s3 = _poisson_ptrs(max(lam, 10.0), s0, s1, s2, s3)
    else:
        k, s0, s1, s2, s3 = _poisson_ptrs(lam, s0, s1, s2, s3)
    if sigma > 0.0:
        z, s0, s1, s2, s3 = _normal(s0, s1, s2, s3)
        k += sigma * z
    return k, s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cf(v, s2, z):  # pragma: no cover - compiled
    """Skew-corrected normal of mean ``v`` >= 0 (module docstring), read variance ``s2``."""
    w = v + s2
    c = v / (6.0 * w)
    return v + math.sqrt(w - 2.0 * c * c) * z + c * (z * z - 1.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _noise_block(lam, z, threshold, sigma, out, s0, s1, s2, s3):  # pragma: no cover
    """Noisy electrons of one block: normals into ``z``, then the transform (SIMD), then
    the exact draws of the pixels below ``threshold`` (only when ``threshold`` > 0)."""
    m = lam.size
    for k in range(m):
        z[k], s0, s1, s2, s3 = _normal(s0, s1, s2, s3)
    sg2 = sigma * sigma
    for k in range(m):
        v = lam[k]
        out[k] = _cf(v if v > 0.0 else 0.0, sg2, z[k])
    if threshold > 0.0:
        for k in range(m):
            v = lam[k]
            if v < threshold:
                out[k], s0, s1, s2, s3 = exact_shot_read(max(v, 0.0), sigma, s0, s1, s2, s3)
    return s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def noise_float(lam, state, threshold, sigma, out):  # pragma: no cover - compiled
    """``out[i]`` = noisy electrons of mean ``max(lam[i], 0)`` (module docstring); ``state``
    is a xoshiro256++ state (:func:`seed_state`), advanced in place. ``out`` may be ``lam``."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    n = lam.size
    z = np.empty(BLOCK)
    for b0 in range(0, n, BLOCK):
        b1 = min(b0 + BLOCK, n)
        s0, s1, s2, s3 = _noise_block(lam[b0:b1], z, threshold, sigma, out[b0:b1], s0, s1, s2, s3)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def noise_u16(
    lam, state, threshold, sigma, full_well, inv_gain, black, max_dn, out
):  # pragma: no cover - compiled
    """:func:`noise_float` followed by the linear ADC (no float image is written)."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    n = lam.size
    z = np.empty(BLOCK)
    e = np.empty(BLOCK)
    for b0 in range(0, n, BLOCK):
        b1 = min(b0 + BLOCK, n)
        eb = e[: b1 - b0]
        s0, s1, s2, s3 = _noise_block(lam[b0:b1], z, threshold, sigma, eb, s0, s1, s2, s3)
        o = out[b0:b1]
        for k in range(eb.size):
            o[k] = _adc(eb[k], full_well, inv_gain, black, max_dn)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _readout_block(
    lb, z, threshold, sigma, clip, full_well, lo, o, s0, s1, s2, s3
):  # pragma: no cover
    """Noisy, clipped electrons of one block (:func:`readout_float`) into ``o``."""
    s0, s1, s2, s3 = _noise_block(lb, z, threshold, sigma, o, s0, s1, s2, s3)
    if clip:
        for k in range(lb.size):
            v = lb[k]
            if v >= lo:
                if v >= threshold:
                    zz, s0, s1, s2, s3 = _normal(s0, s1, s2, s3)
                    q = _cf(max(v, 0.0), 0.0, zz)
                else:
                    q, s0, s1, s2, s3 = exact_shot_read(max(v, 0.0), 0.0, s0, s1, s2, s3)
                q = q if q < full_well else full_well
                if sigma > 0.0:
                    zz, s0, s1, s2, s3 = _normal(s0, s1, s2, s3)
                    q += sigma * zz
                o[k] = q
    else:
        for k in range(o.size):
            e = o[k]
            o[k] = e if e < full_well else full_well
    return s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def readout_float(lam, state, threshold, sigma, clip, full_well, out):  # pragma: no cover
    """Noisy electrons at the ADC's input: :func:`noise_float` followed by the full-well
    clip; with ``clip`` the clip acts on the charge, BEFORE the read noise.

    With ``clip``, a pixel whose mean is below ``full_well - 8·sqrt(full_well) - 1`` passes
    the full well with probability < 1e-15, so its joint shot + read draw stands; the others
    draw the shot noise alone (the skew-corrected normal with no read variance from
    ``threshold`` on, else the exact count), clip it at ``full_well`` and add ``sigma·z``.
    """
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    n = lam.size
    z = np.empty(BLOCK)
    lo = full_well - 8.0 * math.sqrt(full_well) - 1.0
    for b0 in range(0, n, BLOCK):
        b1 = min(b0 + BLOCK, n)
        s0, s1, s2, s3 = _readout_block(
            lam[b0:b1], z, threshold, sigma, clip, full_well, lo, out[b0:b1], s0, s1, s2, s3
        )
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def readout_u16(
    lam, state, threshold, sigma, clip, full_well, off, inv_gain, black, max_dn, out
):  # pragma: no cover - compiled
    """:func:`readout_float`, plus the offsets ``off`` (electrons per pixel; an empty array:
    none), then the linear ADC with no further clip, in one pass (the same random numbers,
    so the same image as :func:`readout_float` and the ADC apart)."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    n = lam.size
    z = np.empty(BLOCK)
    e = np.empty(BLOCK)
    lo = full_well - 8.0 * math.sqrt(full_well) - 1.0
    has_off = off.size > 0
    for b0 in range(0, n, BLOCK):
        b1 = min(b0 + BLOCK, n)
        eb = e[: b1 - b0]
        s0, s1, s2, s3 = _readout_block(
            lam[b0:b1], z, threshold, sigma, clip, full_well, lo, eb, s0, s1, s2, s3
        )
        o = out[b0:b1]
        if has_off:
            ob = off[b0:b1]
            for k in range(eb.size):
                o[k] = _adc(eb[k] + ob[k], math.inf, inv_gain, black, max_dn)
        else:
            for k in range(eb.size):
                o[k] = _adc(eb[k], math.inf, inv_gain, black, max_dn)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@njit(cache=True, nogil=True, error_model="numpy")
def adc_charge(lam, full_well, off, inv_gain, black, max_dn, out):  # pragma: no cover
    """Noise-free readout: ``min(max(lam, 0), full_well)`` plus the offsets ``off`` (empty:
    none), then the linear ADC with no further clip."""
    if off.size > 0:
        for i in range(lam.size):
            v = lam[i]
            v = v if v > 0.0 else 0.0
            v = v if v < full_well else full_well
            out[i] = _adc(v + off[i], math.inf, inv_gain, black, max_dn)
    else:
        for i in range(lam.size):
            v = lam[i]
            v = v if v > 0.0 else 0.0
            v = v if v < full_well else full_well
            out[i] = _adc(v, math.inf, inv_gain, black, max_dn)


@njit(cache=True, nogil=True, error_model="numpy")
def bloom_columns(e, full_well, frac):  # pragma: no cover - compiled
    """Blooming on an expected-charge image ``e`` (rows, cols), in place: a fraction ``frac``
    of each pixel's charge above ``full_well`` spills along its column, half towards each
    end, filling every pixel it meets to ``full_well`` before moving on; what reaches the
    end of the column leaves the array, the rest (``1 - frac``) goes to the overflow drain.
    Rows are walked in order with one carry per column (sequential memory access)."""
    h, w = e.shape
    over = False
    for r in range(h):
        for c in range(w):
            over |= e[r, c] > full_well
    if not over:
        return
    half = np.empty((h, w))
    for r in range(h):
        for c in range(w):
            x = e[r, c] - full_well
            if x > 0.0:
                half[r, c] = 0.5 * frac * x
                e[r, c] = full_well
            else:
                half[r, c] = 0.0
    carry = np.zeros(w)
    for step in range(2):  # down the columns, then up
        for c in range(w):
            carry[c] = 0.0
        for rr in range(h):
            r = rr if step == 0 else h - 1 - rr
            for c in range(w):
                cr = carry[c]
                if cr > 0.0:
                    room = full_well - e[r, c]
                    if room > 0.0:
                        take = cr if cr < room else room
                        e[r, c] += take
                        carry[c] = cr - take
                carry[c] += half[r, c]


@njit(cache=True, nogil=True, error_model="numpy")
def digitise_linear(e, full_well, inv_gain, black, max_dn, out):  # pragma: no cover - compiled
    """Linear ADC: clip at full well, scale, add black level, round half to even, clip."""
    for i in range(e.size):
        out[i] = _adc(e[i], full_well, inv_gain, black, max_dn)


@njit(cache=True, nogil=True, error_model="numpy")
def _plan_pixel(a, dk, s, inv_n2, sat_e, min_e):  # pragma: no cover - compiled
    """(usable-stop bits, number of leading stops at which the total is <= ``sat_e``).

    ``inv_n2`` ascends (darkest stop first) and ``a >= 0``, ``s > 0``, so the total
    ``a·r + dk`` (rounding is monotone) stays <= ``sat_e`` for a prefix of the stops, ``hi``
    of them, and the signal ``s·r`` reaches ``min_e`` from stop ``lo`` on: the usable stops
    are ``lo .. hi-1`` and the leading count is ``hi``. Two branch-free counts instead of a
    branchy loop (the same bits as testing every stop; tests/simulator/test_kernels_plan.py).
    """
    hi = 0
    lo = 0
    for q in range(inv_n2.size):
        r = inv_n2[q]
        hi += a * r + dk <= sat_e
        lo += s * r < min_e
    bits = ((1 << hi) - 1) ^ ((1 << lo) - 1) if hi > lo else 0
    return bits, hi


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
def plan_masks(a, d, sig, inv_n2, sat_e, min_e, masks, lead):  # pragma: no cover
    """:func:`plan_scene` on precomputed lit pixels (``a = e1 - dark·t``, ``d = dark·t``)."""
    lmin = inv_n2.size
    for p in range(a.size):
        bits, ld = _plan_pixel(a[p], d[p], sig[p], inv_n2, sat_e, min_e)
        masks[p] = bits
        if ld < lmin:
            lmin = ld
    lead[0] = lmin
