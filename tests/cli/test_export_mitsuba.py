"""``gonio export mitsuba``: fits and samples to Mitsuba 3 measured BSDF files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio import brdf
from gonio.cli import main
from gonio.geometry import sample_uniform_hemisphere, to_vector
from gonio.io import mitsuba as gm
from gonio.io.samples_table import write_samples
from gonio.samples import BRDFSamples


def test_export_fit_anisotropic(tmp_path, capsys):
    fit = tmp_path / "fit.json"
    params = {"rho_d": 0.1, "rho_s": 0.33, "alpha_x": 0.05, "alpha_y": 0.16}
    fit.write_text(json.dumps({"model": "ward", "params": params}))
    out, rep = tmp_path / "brass.bsdf", tmp_path / "r.json"
    argv = ["export", "mitsuba", "--fit", str(fit), str(out), "--grid", "24", "--theta-i", "6"]
    assert main([*argv, "--phi-i", "3", "--json", str(rep)]) == 0
    assert "grey measured BSDF" in capsys.readouterr().out
    report = json.loads(rep.read_text())
    assert report["shape"] == [3, 6, 3, 24, 24] and report["symmetry_reduction"] == 4
    t = gm.read_bsdf(out)
    m = brdf.create("ward", **params)
    wi = to_vector(np.radians(30.0), 0.4)
    wo = wi * [-1, -1, 1]  # the peak: a node of the grid
    np.testing.assert_allclose(t(wi, wo), m(wi, wo), rtol=1e-3)
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    b = mi.load_dict({"type": "measured", "filename": str(out)})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*wi)
    v = b.eval(mi.BSDFContext(), si, mi.Vector3f(*wo))[0]
    assert v == pytest.approx(float(m(wi, wo)) * wo[2], rel=1e-3)


def test_export_samples_reports_coverage(tmp_path, capsys):
    m = brdf.create("lambert", rho=0.5)
    wo = to_vector(
        *np.meshgrid(np.radians(np.linspace(1, 80, 50)), np.radians(np.linspace(0, 180, 37)))
    )
    wo = wo.reshape(-1, 3)
    tis = np.radians([0.0, 30.0, 60.0])
    wi = np.concatenate([np.broadcast_to(to_vector(t, 0.0), wo.shape) for t in tis])
    wos = np.tile(wo, (3, 1))
    src = write_samples(BRDFSamples.from_directions(wi, wos, m(wi, wos)), tmp_path / "s.csv")
    out = tmp_path / "s.bsdf"
    assert main(["export", "mitsuba", str(src), str(out)]) == 0
    line = capsys.readouterr().out
    assert "% of the grid above the horizon" in line
    cov = gm.read_bsdf(out).meta["coverage"]
    assert f"{100 * cov:.1f} %" in line and 0.5 < cov <= 1.0
    # at the measured incidences (between them θi is interpolated linearly at a fixed half
    # vector, where cos θo is not linear: 2 % low in the median for these 30 deg steps); the
    # piecewise-linear interpolation of the samples is 0.2 % low here (0.8 % with 25 x 19
    # directions per incidence, 0.1 % with 100 x 73)
    rng = np.random.default_rng(2)
    qo = sample_uniform_hemisphere(600, rng)[0]
    qi = to_vector(rng.choice(tis, 600), rng.uniform(-np.pi, np.pi, 600))
    keep = qo[:, 2] > np.cos(np.radians(80))
    got = gm.read_bsdf(out)(qi[keep], qo[keep])
    np.testing.assert_allclose(np.median(got), 0.5 / np.pi, rtol=0.005)


def test_export_mitsuba_errors(tmp_path, capsys):
    src = tmp_path / "s.csv"
    src.write_text("theta_i,phi_i,theta_o,phi_o,value,sigma\n")
    assert main(["export", "mitsuba", str(src)]) == 2
    assert "give OUT.bsdf" in capsys.readouterr().err
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"model": "lambert", "params": {"rho": 0.5}}))
    assert main(["export", "mitsuba", "--fit", str(fit), str(tmp_path / "x.txt")]) == 2
    assert ".bsdf suffix" in capsys.readouterr().err
    assert (
        main(["export", "mitsuba", "--fit", str(fit), str(tmp_path / "x.bsdf"), "--grid", "1"]) == 2
    )
    assert "resolution" in capsys.readouterr().err
    assert not (tmp_path / "x.bsdf").exists()


def test_export_a_spectral_fit_with_per_band_entries(tmp_path, capsys):
    from gonio import materials

    m = materials.get("garnet_red_paint")
    flat = {}
    for k, v in m.params.items():
        a = np.asarray(v) if not isinstance(v, str) else None
        if a is not None and a.dtype.kind == "f" and a.ndim == 1:
            flat.update({f"{k}[{i}]": float(x) for i, x in enumerate(a)})  # as fit.json has
        elif a is not None and a.dtype.kind in "fib" and a.ndim == 0:
            flat[k] = a.item()
        else:
            flat[k] = v
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"model": "li_torrance", "params": flat}))
    out = tmp_path / "g.bsdf"
    assert main(["export", "mitsuba", "--fit", str(fit), str(out), "--grid", "16"]) == 0
    assert "spectral measured BSDF" in capsys.readouterr().out
    t = brdf.create("measured", filename=out)
    np.testing.assert_array_equal(t.wavelengths_nm, m.wavelengths_nm)
    wi = to_vector(gm.THETA_I_MAX * 5 / 15, 0.0)  # a node of θi (16 nodes by default)
    wo = wi * [-1, -1, 1]  # the peak: the half vector at the normal, a node too
    np.testing.assert_allclose(t(wi, wo), m(wi, wo), rtol=1e-5)
