"""Kinematics and plans of the simulated Cornell three-axis gonioreflectometer."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.simulator.cornell_kinematics import Kinematics, forward, inverse
from gonio.simulator.cornell_plans import (
    Timing,
    estimate_run_time,
    hemispherical_plan,
    incidence_plane_plan,
    order_plan,
    read_plan_csv,
)

from gonio.geometry import (
    sample_uniform_hemisphere,
    to_spherical,
    to_vector,
    uniform_hemisphere_grid,
)


def _rz(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def test_forward_specular_pose():
    wi, wo = forward(np.radians([40.0, 20.0, 0.0]))
    np.testing.assert_allclose(wi, to_vector(np.radians(20), 0.0), atol=1e-15)
    np.testing.assert_allclose(wo, to_vector(np.radians(20), np.pi), atol=1e-15)
    # the phase angle between wi and wo is the arm angle whatever the sample does
    ang = np.radians([[33.0, -50.0, 20.0], [-120.0, 10.0, -60.0]])
    wi, wo = forward(ang)
    np.testing.assert_allclose(np.sum(wi * wo, -1), np.cos(ang[:, 0]), atol=1e-14)


@pytest.mark.parametrize(
    "kin",
    [Kinematics(), Kinematics(axis2=(0.0, 1.0, 0.0), axis3=(0.0, 0.0, 1.0))],
    ids=["turntable_tilt", "tilt_turntable"],
)
def test_inverse_round_trip_directions(kin):
    wi = sample_uniform_hemisphere(3000, 1)[0]
    wo = sample_uniform_hemisphere(3000, 2)[0]
    r = inverse(wi, wo, kin)
    ok = r.reachable
    np.testing.assert_array_equal(ok, kin.reachable_directions(wi, wo))
    assert ok.mean() > 0.75
    # reached = Rz(psi) requested: same θi, θo, φo − φi (max error measured: ~2e-14)
    err = np.abs(_rz(wi, r.psi) - r.wi)[ok].max()
    err_o = np.abs(_rz(wo, r.psi) - r.wo)[ok].max()
    assert err < 1e-12 and err_o < 1e-12
    fi, fo = forward(r.angles, kin)
    np.testing.assert_allclose(fi, r.wi, atol=1e-15)
    np.testing.assert_allclose(fo, r.wo, atol=1e-15)


def test_inverse_round_trip_motor_angles():
    kin = Kinematics()
    g = np.random.default_rng(5)
    n = 2000
    ang = np.stack(
        [
            g.uniform(np.radians(7.5), np.radians(170), n) * g.choice([-1, 1], n),
            g.uniform(-np.pi, np.pi, n),
            g.uniform(-1.5, 1.5, n),
        ],
        -1,
    )
    wi, wo = forward(ang, kin)
    r = inverse(wi, wo, kin, current=ang)
    ok = r.reachable
    assert ok.sum() > 200
    # from the current pose the same solution is the quickest: exact motor round trip
    assert np.abs(r.angles - ang)[ok].max() < 1e-12
    assert np.abs(r.psi[ok]).max() < 1e-12


def test_reachability_limits():
    kin = Kinematics()
    r = inverse(
        np.array([to_vector(np.radians(86), 0.0), to_vector(np.radians(30), 0.0)] * 2),
        np.array(
            [
                to_vector(np.radians(30), np.pi),
                to_vector(np.radians(86), np.pi),
                to_vector(np.radians(27), 0.0),  # 3 deg from retro-reflection
                to_vector(np.radians(84), np.pi),
            ]
        ),
        kin,
    )
    assert r.reachable.tolist() == [False, False, False, True]
    tight = Kinematics(limits=((-np.pi, np.pi), (-0.1, 0.1), (-np.pi / 2, np.pi / 2)))
    r2 = inverse(to_vector(np.radians(60), 0.0), to_vector(np.radians(20), np.pi), tight)
    assert not r2.reachable  # needs the turntable at ~±20 deg
    with pytest.raises(ValueError, match="zero_x"):
        Kinematics(zero_x=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="angles"):
        forward(np.zeros(2))


def test_incidence_plane_plan_density():
    p = incidence_plane_plan()
    for g, ti in enumerate((15, 30, 45, 60, 75)):
        rows = (p.group == g) & p.reachable
        assert 40 <= rows.sum() <= 70
        th, ph = to_spherical(p.wo[rows])
        signed = np.degrees(np.where(np.cos(ph) < 0, -th, th))
        near = np.abs(signed + ti) <= 10.5
        assert near.sum() >= 15 and (~near).sum() <= 40  # 1 deg steps near specular, 5 elsewhere
        np.testing.assert_allclose(to_spherical(p.wi[rows])[0], np.radians(ti))


def test_hemispherical_plan():
    p = hemispherical_plan()
    assert len(p) == 8 * 441
    th, _ = to_spherical(p.wo)
    assert np.degrees(th).max() <= 85.0 + 1e-9
    np.testing.assert_array_equal(p.wo[:441], uniform_hemisphere_grid(21))
    # equal-area cells: cos θ uniform over [0, 1], the outer cells at 84.6 deg
    assert abs(p.wo[:441, 2].mean() - 0.5) < 0.01
    assert np.degrees(th).max() == pytest.approx(np.degrees(np.arccos(1 - (20 / 21) ** 2)))
    # only the retro-reflection cone is lost (3-4 rows per θi)
    lost = np.bincount(p.group[~p.reachable], minlength=8)
    assert lost.max() <= 4 and lost.sum() == len(p) - p.reachable.sum()
    cap = hemispherical_plan((40,), cap_deg=60.0)
    assert np.degrees(np.arccos(cap.wo[:, 2])).max() < 60.0


def test_ordering_and_run_time():
    p = hemispherical_plan((30, 60), n=9)
    o = order_plan(p)
    t_raw = estimate_run_time(p)
    t_ord = estimate_run_time(o)
    assert t_ord["move_s"] < 0.8 * t_raw["move_s"]
    assert sorted(map(tuple, o.angles.round(12))) == sorted(
        map(tuple, p.measurable().angles.round(12))
    )
    assert t_ord["n_measurements"] == p.reachable.sum()
    assert t_ord["total_s"] == pytest.approx(
        t_ord["move_s"] + t_ord["integration_s"] + t_ord["overhead_s"]
    )
    # a slower stage makes the run longer
    slow = Timing(speeds=tuple(np.radians([1.0, 2.0, 2.0])))
    assert estimate_run_time(o, slow)["move_s"] > 3 * t_ord["move_s"]
    with pytest.raises(ValueError, match="integration_s"):
        estimate_run_time(o, integration_s=[1.0])


def test_user_plan_from_csv(tmp_path):
    f = tmp_path / "plan.csv"
    f.write_text("# my plan\ntheta_i,phi_i,theta_o,phi_o\n30,0,30,180\n30,0,50,90\n60,0,10,180\n")
    p = read_plan_csv(f)
    assert len(p) == 3 and p.reachable.all() and p.group.tolist() == [0, 0, 1]
    _, wo = forward(p.angles)
    np.testing.assert_allclose(np.degrees(to_spherical(wo)[0]), [30, 50, 10], atol=1e-9)
    bad = tmp_path / "bad.csv"
    bad.write_text("theta_i,phi_i,theta_o\n1,2,3\n")
    with pytest.raises(ValueError, match="missing column"):
        read_plan_csv(bad)
    with pytest.raises(ValueError, match="does not exist"):
        read_plan_csv(tmp_path / "nope.csv")
    bad.write_text("theta_i,phi_i,theta_o,phi_o\n95,0,3,0\n")
    with pytest.raises(ValueError, match="theta_i and theta_o"):
        read_plan_csv(bad)
