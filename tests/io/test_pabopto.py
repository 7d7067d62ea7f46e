"""PAB-Opto export and Radiance BSDF builds (pabopto2bsdf, bsdf2klems, bsdf2ttree, checkBSDF)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from gonio import brdf
from gonio.io import pabopto
from gonio.samples import BRDFSamples

ISO = dict(rho_d=0.3, rho_s=0.05, alpha_x=0.15, alpha_y=0.15)


def _table(model, thetas, phis, n_o: int = 15, n_p: int = 24) -> BRDFSamples:
    """Exact samples of ``model`` on a (θo, φo) grid for each incident (θi, φi) in degrees."""
    to = np.radians(np.linspace(2.5, 87.5, n_o))
    po = np.radians(np.arange(n_p) * 360.0 / n_p)
    T, P = (a.ravel() for a in np.meshgrid(to, po, indexing="ij"))
    cols = [[], [], [], []]
    for t in thetas:
        for p in phis:
            for c, v in zip(
                cols, (np.full(T.size, math.radians(t)), np.full(T.size, math.radians(p)), T, P)
            ):
                c.append(v)
    ti, pi, to_, po_ = (np.concatenate(c) for c in cols)
    s = BRDFSamples(ti, pi, to_, po_, np.zeros(ti.size), np.full(ti.size, np.nan))
    s.value = model(s.wi, s.wo)
    return s


def _dir_many(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def _dir(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


# ----------------------------------------------------------------------------- symmetry rule
@pytest.mark.parametrize(
    ("phis", "sym"),
    [
        ([0.0], "I"),
        ([90.0], "I"),
        ([0.0, 45.0, 90.0], "Q"),
        ([30.0, 60.0], "Q"),
        ([0.0, 30.0, 120.0], "B"),
        ([30.0, 300.0], "B"),
        ([30.0, 120.0, 210.0, 300.0], "A"),
    ],
)
def test_symmetry_inferred_as_pabopto2bsdf_does(phis, sym):
    inc = [(0.0, 0.0)] + [(t, p) for t in (20.0, 50.0) for p in phis]
    assert pabopto.pabopto_symmetry(inc) == sym


def test_boundary_azimuths_are_refused_with_the_rotation_to_add():
    """The LBL default for an anisotropic sample (rotations 0 and 90) cannot form a symmetry."""
    with pytest.raises(ValueError, match=r"\{0, 90\}.*0, 45, 90"):
        pabopto.pabopto_symmetry([(20.0, 0.0), (20.0, 90.0), (40.0, 0.0), (40.0, 90.0)])
    with pytest.raises(ValueError, match="no symmetry"):
        pabopto.pabopto_symmetry([(20.0, 30.0), (20.0, 210.0)])  # opposite quadrants
    # incidences within 1 degree of the normal carry no azimuth
    assert pabopto.pabopto_symmetry([(0.5, 0.0), (0.5, 45.0), (30.0, 10.0)]) == "I"


# ----------------------------------------------------------------------------- file content
def test_files_follow_the_pabopto_header_and_data_conventions():
    m = brdf.create("ward_gmd", **ISO)
    s = _table(m, [0.0, 30.0], [0.0, 45.0, 90.0], n_o=4, n_p=6)
    files = pabopto.pabopto_files(s, "tile", cells=None)  # every sample
    # normal incidence is one direction whatever the rotation
    assert sorted(files) == [
        "tile_t000.000_p000.000.dat",
        "tile_t030.000_p000.000.dat",
        "tile_t030.000_p045.000.dat",
        "tile_t030.000_p090.000.dat",
    ]
    text = files["tile_t030.000_p045.000.dat"]
    head = [ln for ln in text.splitlines() if ln.startswith("#")]
    assert head == [
        '#sample_name "tile"',
        "#format: theta phi BRDF",
        "#intheta 30.000000",
        "#inphi 45.000000",
        "#upphi 90",
        "#colorimetry: CIE-Y",
    ]
    data = np.array([ln.split() for ln in text.splitlines() if not ln.startswith("#")], float)
    assert data.shape == (24, 3)
    wo = np.stack([_dir(t, p) for t, p in data[:, :2]])
    np.testing.assert_allclose(data[:, 2], m(_dir(30.0, 45.0), wo), rtol=2e-6)
    assert len(files["tile_t000.000_p000.000.dat"].splitlines()) == 6 + 3 * 24


def test_binning_averages_in_pabopto2bsdfs_equal_solid_angle_cells():
    """cells x cells cells of the concentric map of (x, y)/sqrt(1 + z): equal solid angle,
    unions of pabopto2bsdf's 256 x 256 cells; one point per occupied cell, at the normalised
    mean direction with the mean value."""
    rng = np.random.default_rng(1)
    n = 200_000
    z = rng.random(n)  # uniform in solid angle over the hemisphere
    phi = rng.uniform(0.0, 2 * math.pi, n)
    theta = np.arccos(z)
    value = rng.random(n)
    t, p, v, count = pabopto.bin_directions(theta, phi, value, 16)
    assert t.shape == p.shape == v.shape == (256,) and count.sum() == n
    # equal solid angle: the counts are Poisson about n / 256 (chi-square, 255 dof: 255 ± 23)
    chi2 = float(np.sum((count - n / 256) ** 2 / (n / 256)))
    assert chi2 < 255 + 4 * 23, chi2
    # one sample per cell is returned unchanged; two in one cell are averaged
    one = pabopto.bin_directions(np.array([0.3]), np.array([1.0]), np.array([2.5]), 32)
    np.testing.assert_allclose([one[0][0], one[1][0], one[2][0]], [0.3, 1.0, 2.5], rtol=1e-12)
    two = pabopto.bin_directions(
        np.array([0.6, 0.6]), np.array([1.0, 1.001]), np.array([1.0, 3.0]), 8
    )
    assert two[2].tolist() == [2.0] and two[1][0] == pytest.approx(1.0005, abs=1e-9)


def test_files_bound_the_points_per_incident_direction():
    m = brdf.create("ward_gmd", **ISO)
    s = _table(m, [0.0, 30.0, 60.0], [0.0], n_o=60, n_p=120)  # 7200 samples per direction

    def counts(**kw):
        return [len(t.splitlines()) - 6 for t in pabopto.pabopto_files(s, **kw).values()]

    assert counts(cells=None) == [7200] * 3
    assert max(counts(cells=8, spread=None)) <= 64
    assert 500 < min(counts(cells=32, spread=None)) <= max(counts(cells=32, spread=None)) <= 1024
    # spread: cells across a lobe (values differing by more than 2x) are split, flat ones
    # kept, so the points follow the peak: within 15 deg of the mirror direction 183 of the
    # 341 measured points stay (54 %), elsewhere 348 of 6859 (5 %)
    brass = brdf.create("ward_gmd", rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)
    b = _table(brass, [30.0], [0.0], n_o=60, n_p=120)
    t, p, _, n = pabopto.bin_directions(b.theta_o, b.phi_o, b.value, 8, 2.0)
    assert 64 < t.size < 1500 and n.sum() == 7200
    cos15 = math.cos(math.radians(15.0))
    raw = _dir_many(b.theta_o, b.phi_o) @ _dir(30.0, 180.0) > cos15
    near = _dir_many(t, p) @ _dir(30.0, 180.0) > cos15
    assert near.sum() > 0.4 * raw.sum() and (~near).sum() < 0.1 * (~raw).sum()
    with pytest.raises(ValueError, match="spread 1"):
        pabopto.pabopto_files(s, spread=1)
    with pytest.raises(ValueError, match="cells 12"):
        pabopto.pabopto_files(s, cells=12)
    with pytest.raises(ValueError, match="cells True"):
        pabopto.pabopto_files(s, cells=True)


def test_bad_tables_are_refused():
    m = brdf.create("ward_gmd", **ISO)
    with pytest.raises(ValueError, match="at least two"):
        pabopto.pabopto_files(_table(m, [30.0], [0.0], 4, 6))
    s = _table(m, [0.0, 30.0], [0.0], 4, 6)
    s.value[3] = -1e-3
    with pytest.raises(ValueError, match="1 values below 0"):
        pabopto.pabopto_files(s)
    dropped = pabopto.pabopto_files(s, negative="drop", cells=None)
    n_rows = sum(len(t.splitlines()) for t in dropped.values())
    assert n_rows == 2 * 6 + 2 * 24 - 1
    clipped = pabopto.pabopto_files(s, negative="clip", cells=None)
    assert " 0\n" in "".join(clipped.values())
    with pytest.raises(ValueError, match="negative"):
        pabopto.pabopto_files(s, negative="zero")
    spec = BRDFSamples(
        s.theta_i,
        s.phi_i,
        s.theta_o,
        s.phi_o,
        np.abs(s.value),
        s.sigma,
        np.full(s.value.size, 550.0),
    )
    with pytest.raises(ValueError, match="spectral"):
        pabopto.pabopto_files(spec)
    with pytest.raises(ValueError, match="quadrant boundaries"):
        pabopto.pabopto_files(_table(m, [20.0, 40.0], [0.0, 90.0], 4, 6))
    with pytest.raises(ValueError, match="BRDFSamples"):
        pabopto.pabopto_files({"theta_i": [0.0]})


def test_write_pabopto_never_leaves_a_partial_set(tmp_path, monkeypatch):
    m = brdf.create("ward_gmd", **ISO)
    s = _table(m, [0.0, 30.0, 60.0], [0.0], 4, 6)
    paths = pabopto.write_pabopto(s, tmp_path / "out", "tile")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(p.name for p in paths)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ValueError, match="cannot be created"):
        pabopto.write_pabopto(s, blocker / "sub", "tile")
    calls = []

    def failing(path, data, **kw):
        if calls:
            raise OSError("disk full")
        calls.append(path)
        return real(path, data, **kw)

    real = pabopto.atomic_write_bytes
    monkeypatch.setattr(pabopto, "atomic_write_bytes", failing)
    with pytest.raises(OSError, match="disk full"):
        pabopto.write_pabopto(s, tmp_path / "partial", "tile")
    assert list((tmp_path / "partial").iterdir()) == []
    with pytest.raises(ValueError, match="sample_name"):
        pabopto.write_pabopto(s, tmp_path / "x", "two words")
    # a folder the process may not write (root ignores permission bits, so os.access says no)
    (tmp_path / "ro").mkdir()
    monkeypatch.setattr(pabopto.os, "access", lambda *a, **k: False)
    with pytest.raises(ValueError, match="is not writable"):
        pabopto.write_pabopto(s, tmp_path / "ro", "tile")
    with pytest.raises(ValueError, match="is not writable"):  # before any Radiance program
        pabopto.build_bsdf(s, tmp_path / "ro", "tile")
    assert list((tmp_path / "ro").iterdir()) == []


# ----------------------------------------------------------------------------- real Radiance
def _hemispherical_errors(build, model, max_theta: float) -> np.ndarray:
    r = pabopto.klems_hemispherical(build.xml)
    sel = r["theta_deg"] <= max_theta
    got = r["Reflection Back"][sel]
    want = np.array(
        [float(model.albedo(_dir(t, p))) for t, p in zip(r["theta_deg"][sel], r["phi_deg"][sel])]
    )
    return got / want - 1.0


def test_measured_route_klems_and_checkbsdf(tmp_path):
    """pabopto2bsdf and bsdf2klems accept the files, checkBSDF reads the XML; the Klems
    hemispherical reflectance follows gonio's albedo to within pabopto2bsdf's interpolation
    of this coarse table (15 × 24 exiting directions at 5 incidences: measured +8 % at the
    normal, within 3 % from 30 to 70 deg)."""
    pytest.importorskip("pyradiance")
    m = brdf.create("ward_gmd", **ISO)
    s = _table(m, [0.0, 20.0, 40.0, 60.0, 75.0], [0.0])
    b = pabopto.build_bsdf(s, tmp_path, "tile", kind="klems", samples_per_patch=16)
    assert b.symmetry == "I" and b.xml.stat().st_size > 100_000
    assert "void BSDF tile\n6 0 tile.xml 0 1 0 .\n" in b.rad.read_text()
    refl = b.components["Interior Refl"]
    assert refl["lambertian"][0] == pytest.approx(0.3, abs=0.02)
    err = _hemispherical_errors(b, m, 70.0)
    assert np.max(np.abs(err)) < 0.1, err
    assert list(tmp_path.glob("gonio_bsdf_*")) == []  # the interpolant's folder is gone


def test_quadrilateral_set_builds(tmp_path):
    """Rotations 0, 45, 90 of an anisotropic sample: pabopto2bsdf infers quadrilateral
    symmetry and bsdf2klems converts it."""
    pytest.importorskip("pyradiance")
    m = brdf.create("ward_gmd", rho_d=0.1, rho_s=0.33, alpha_x=0.1, alpha_y=0.2)
    s = _table(m, [20.0, 50.0], [0.0, 45.0, 90.0], n_o=8, n_p=16)
    b = pabopto.build_bsdf(s, tmp_path, "brass", kind="klems", samples_per_patch=4)
    assert b.symmetry == "Q" and b.components["Interior Refl"]["max_total"] > 0.2


def test_model_route_klems_and_ttree(tmp_path):
    """The fitted model's .cal through bsdf2klems -f: hemispherical reflectance equal to
    gonio's albedo up to bsdf2klems's random sampling of each patch pair (16 samples:
    measured ≤ 2.3 % per patch and ≤ 0.6 % per ring of patches up to 70 deg);
    bsdf2ttree -t3 -f builds an isotropic tree whose largest directional reflectance is
    the albedo's."""
    pytest.importorskip("pyradiance")
    m = brdf.create("ward_gmd", **ISO)
    b = pabopto.build_model_bsdf(m, tmp_path, "tile", kind="klems", samples_per_patch=16)
    err = _hemispherical_errors(b, m, 70.0)
    assert np.max(np.abs(err)) < 0.04, err
    ring = pabopto.klems_hemispherical(b.xml)["theta_deg"]
    ring = ring[ring <= 70.0]
    ring_err = [abs(err[ring == t].mean()) for t in np.unique(ring)]
    assert max(ring_err) < 0.01, ring_err
    assert (tmp_path / "tile_bsdf.cal").exists()
    t = pabopto.build_model_bsdf(m, tmp_path, "tree", kind="ttree", resolution=5)
    assert t.symmetry == "I" and "Isotropic_Tensor_Tree" in t.check
    alb = max(float(m.albedo(_dir(a))) for a in (0.0, 30.0, 60.0))
    assert t.components["Interior Refl"]["max_total"] == pytest.approx(alb, abs=0.01)
    with pytest.raises(ValueError, match="no Radiance translation"):
        pabopto.build_model_bsdf(brdf.create("phong"), tmp_path, "x")
    with pytest.raises(ValueError, match="kind"):
        pabopto.build_model_bsdf(m, tmp_path, "x", kind="matrix")
    with pytest.raises(ValueError, match="resolution"):
        pabopto.build_model_bsdf(m, tmp_path, "x", kind="ttree", resolution=9)
    with pytest.raises(ValueError, match="up must"):
        pabopto.build_model_bsdf(m, tmp_path, "x", up=(0, 0, 0))


@pytest.mark.slow
def test_bsdf_values_read_the_tree_in_the_sample_frame(tmp_path):
    """bsdf_values (SDevalBSDF through pyradiance, light direction incident) reads an
    anisotropic tree built from the model's .cal in gonio's frame: on the diffuse floor it
    is the model's value, and the lobe is wide along the axis of alpha_y; the error table
    compares it with the model."""
    pytest.importorskip("pyradiance")
    m = brdf.create("ward_gmd", rho_d=0.1, rho_s=0.33, alpha_x=0.08, alpha_y=0.2)
    t = pabopto.build_model_bsdf(m, tmp_path, "tree", kind="ttree", resolution=5)
    assert t.symmetry == "A"
    for wi in ((30.0, 0.0), (30.0, 90.0), (60.0, 45.0)):
        wo = np.array([[40.0, wi[1] + 90.0]])  # far from the lobe
        got = pabopto.bsdf_values(t.xml, wi, wo)
        want = m(_dir(*wi), _dir_many(*np.radians(wo).T))
        np.testing.assert_allclose(got, want, rtol=0.05)  # measured <= 2.5 %
    # the anisotropy is where the model has it: 20 deg of azimuth off the mirror direction
    # tilts the half vector along y (alpha_y = 0.2: model 1.68 sr^-1) for light in the xz
    # plane, along x (alpha_x = 0.08: 0.51 sr^-1) for light in the yz plane
    wide = pabopto.bsdf_values(t.xml, (30.0, 0.0), np.array([[30.0, 160.0]]))[0]
    narrow = pabopto.bsdf_values(t.xml, (30.0, 90.0), np.array([[30.0, 250.0]]))[0]
    assert wide > 2.0 * narrow, (wide, narrow)
    rows = pabopto.bsdf_error_table(t.xml, {"model": m}, theta_i_deg=(0.0, 30.0))
    assert [(r["theta_i"], r["phi_i"]) for r in rows] == [(0, 0), (30, 0), (30, 45), (30, 90)]
    assert all(
        set(r) == {"theta_i", "phi_i", "peak", "model_peak", "model_off_peak", "model_grazing"}
        for r in rows
    )
    assert all(-1.0 < r["model_peak"] < 0.0 for r in rows)  # a coarse tree averages the peak


def test_a_tool_is_killed_when_an_interrupt_comes_while_its_reader_starts(tmp_path, monkeypatch):
    """(A KeyboardInterrupt in ``Thread.start``, which waits for the new thread, came before
    the ``try`` whose ``finally`` kills the tool: the tool ran on after gonio had ended.)"""
    import os
    import threading

    from gonio.io import radiance

    slow = tmp_path / "slowtool"
    slow.write_text(f"#!/bin/sh\necho $$ > {tmp_path}/child.pid\nexec sleep 60\n")
    slow.chmod(0o755)
    monkeypatch.setattr(radiance, "radiance_tool", lambda name: str(slow))

    class Interrupted(threading.Thread):
        def start(self):
            pid_file = tmp_path / "child.pid"
            for _ in range(400):  # the tool has started (its pid written)
                if pid_file.is_file() and pid_file.read_text().strip():
                    break
                time.sleep(0.01)
            raise KeyboardInterrupt

    monkeypatch.setattr(threading, "Thread", Interrupted)
    with pytest.raises(KeyboardInterrupt):
        pabopto._run_reporting(["slowtool"], tmp_path, 60.0, None, 1.0)
    monkeypatch.undo()
    pid = int((tmp_path / "child.pid").read_text())
    with pytest.raises(ProcessLookupError):  # killed and reaped
        os.kill(pid, 0)
