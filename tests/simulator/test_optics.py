"""Dome mirrors, exact tracing and Ward's eq. 3 (Ward 1992)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gonio.simulator import (
    Mirror,
    eq3_error,
    eq3_reflection_angles,
    make_lens,
    traced_reflection_angles,
)


def _grid(n=60):
    tc, pc = np.meshgrid(
        np.linspace(0.0, math.pi / 2 * 0.999, n), np.linspace(-math.pi, math.pi, n)
    )
    return tc, pc


def _eq3_printed(tc, pc, R, D):
    """Eq. 3 typed in literally (acos and atan2), as an independent check."""
    rc = D * np.sin(pc) * np.sin(tc) + np.sqrt(
        D**2 * np.sin(pc) ** 2 * np.sin(tc) ** 2 + R**2 - D**2
    )
    den = np.sqrt(
        rc**2 * np.cos(pc) ** 2 * np.sin(tc) ** 2
        + (rc * np.sin(pc) * np.sin(tc) - 2 * D) ** 2
        + rc**2 * np.cos(tc) ** 2
    )
    theta = np.arccos(rc * np.cos(tc) / den)
    phi = np.arctan2(rc * np.sin(pc) * np.sin(tc) - 2 * D, rc * np.cos(pc) * np.sin(tc))
    return theta, phi


def test_eq3_matches_printed_formula():
    tc, pc = _grid()
    t, p = eq3_reflection_angles(tc, pc, 0.15, 0.01)
    t0, p0 = _eq3_printed(tc, pc, 0.15, 0.01)
    assert np.abs(t - t0).max() < 1e-7  # acos loses digits near 0; atan2 form used in the code
    dp = np.angle(np.exp(1j * (p - p0)))
    assert np.abs(dp).max() < 1e-12


def test_eq3_range_and_broadcast():
    t, p = eq3_reflection_angles(np.array([[0.3], [0.6]]), np.array([0.0, 1.0, -2.0]), 1.0, 0.1)
    assert t.shape == p.shape == (2, 3)
    tc, pc = _grid(40)
    t, p = eq3_reflection_angles(tc, pc, 1.0, 0.05)
    assert np.all((t >= 0) & (t <= math.pi / 2 + 1e-12))
    assert np.all((p > -math.pi) & (p <= math.pi))
    # phi exactly -pi (atan2(-0.0, negative)) is mapped to +pi
    _, p = eq3_reflection_angles(math.pi / 2, math.pi, 1.0, 0.0)
    assert float(p) == pytest.approx(math.pi)
    assert float(p) > 0


def test_eq3_d_zero_is_identity():
    tc, pc = _grid(30)
    t, p = eq3_reflection_angles(tc, pc, 1.0, 0.0)
    assert np.allclose(t, tc, atol=1e-14)
    inner = tc > 1e-9
    assert np.allclose(np.cos(p[inner] - pc[inner]), 1.0, atol=1e-12)


@pytest.mark.parametrize("dr", [0.01, 0.05, 0.2, 0.5])
def test_ellipsoid_eq3_is_exact(dr):
    tc, pc = _grid(80)
    t, p = eq3_reflection_angles(tc, pc, 1.0, dr, mirror="ellipsoid")
    tt, pt, off = traced_reflection_angles(tc, pc, 1.0, dr, mirror="ellipsoid")
    a = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    b = np.stack([np.sin(tt) * np.cos(pt), np.sin(tt) * np.sin(pt), np.cos(tt)], -1)
    err = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
    assert err.max() <= 1e-9
    assert off.max() < 1e-12  # every ray reflects through the sample centre (focal property)
    assert eq3_error("ellipsoid", dr)["max"] <= 1e-9


def test_hemisphere_eq3_error_grows_as_d_over_r_squared():
    errs = {dr: eq3_error("hemisphere", dr)["max"] for dr in (0.01, 0.02, 0.05, 0.1)}
    for dr, e in errs.items():
        assert e == pytest.approx(dr**2, rel=0.05)
    assert eq3_error("hemisphere", 0.1)["p95"] < errs[0.1]


def test_printed_eq3_on_ellipsoid_is_not_exact():
    """Eq. 3 with the sphere r_c (R = semi-major axis) is only approximate for the ellipsoid."""
    e = eq3_error("ellipsoid", 0.1, form="printed")
    assert 1e-5 < e["max"] < 1e-2


@pytest.mark.parametrize("kind", ["hemisphere", "ellipsoid"])
def test_trace_obeys_law_of_reflection(kind):
    m = Mirror(kind, 0.2, 0.03)
    tc, pc = _grid(25)
    u = np.stack([np.sin(tc) * np.cos(pc), np.sin(tc) * np.sin(pc), np.cos(tc)], -1)
    tr = m.trace(u)
    ok = tr["valid"]
    p, n, wo = tr["point"][ok], m.normal(tr["point"][ok]), tr["wo"][ok]
    ax, ay, az = m.semi_axes
    assert np.allclose((p[:, 0] / ax) ** 2 + (p[:, 1] / ay) ** 2 + (p[:, 2] / az) ** 2, 1.0)
    incoming = u[ok]
    outgoing = -wo
    # angle of incidence = angle of reflection, coplanar with the normal
    assert np.allclose(-(incoming * n).sum(-1), (outgoing * n).sum(-1), atol=1e-12)
    assert np.allclose(np.einsum("ij,ij->i", np.cross(incoming, outgoing), n), 0.0, atol=1e-12)
    # wo points from Q to P
    d = p - tr["sample_point"][ok]
    assert np.allclose(d / np.linalg.norm(d, axis=-1, keepdims=True), wo, atol=1e-9)


def test_eq3_error_over_a_lens():
    lens = make_lens("equisolid", 200, 150)
    e = eq3_error("hemisphere", 0.05, lens=lens)
    assert e["n_pixels"] > 10000
    assert e["max"] == pytest.approx(0.0025, rel=0.05)


@pytest.mark.parametrize(
    "args, match",
    [
        ((0.3, 0.0, 1.0, 1.0), "half_separation D"),
        ((0.3, 0.0, 1.0, 2.0), "must be smaller than radius"),
        ((0.3, 0.0, -1.0, 0.1), "radius must be"),
        ((0.3, 0.0, 1.0, -0.1), "half_separation must be"),
        ((2.0, 0.0, 1.0, 0.1), "theta_c must be in"),
        ((np.nan, 0.0, 1.0, 0.1), "finite"),
    ],
)
def test_eq3_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        eq3_reflection_angles(*args)


def test_mirror_bad_input():
    with pytest.raises(ValueError, match="mirror 'cone' is unknown"):
        Mirror("cone")
    with pytest.raises(ValueError, match="must be smaller than radius"):
        Mirror("hemisphere", 0.1, 0.1)
    with pytest.raises(ValueError, match="exceeds 1"):
        Mirror("hemisphere", 0.1, 0.01, 0.7, 0.7)
    m = Mirror("hemisphere", 0.1, 0.01)
    assert Mirror.from_dict(m.to_dict()) == m
