"""ASTM E1392 tables: round trips exact to the printed digits, and bad files refused."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import brdf
from gonio.geometry import to_vector
from gonio.io.astm import ANGLE_DIGITS, VALUE_DIGITS, read_astm, write_astm
from gonio.io.samples_table import read_samples, write_samples
from gonio.samples import BRDFSamples

BANDS = np.arange(400.0, 701.0, 10.0)  # the Cornell instrument's 31 bands


def _spectral(n_geo=12, bands=BANDS, sigma=True, seed=0):
    rng = np.random.default_rng(seed)
    ti = np.radians(rng.uniform(0, 80, n_geo))
    to = np.radians(rng.uniform(0, 85, n_geo))
    po = rng.uniform(-np.pi, np.pi, n_geo)
    nb = len(bands)
    vals = rng.uniform(1e-4, 3.0, n_geo * nb)
    sig = vals * 0.01 if sigma else np.full(vals.shape, np.nan)
    rep = lambda a: np.repeat(a, nb)  # noqa: E731
    return BRDFSamples(
        rep(ti), rep(0 * ti), rep(to), rep(po), vals, sig, np.tile(bands, n_geo),
        {"material": "garnet_red_paint", "seed": 3},
    )  # fmt: skip


def test_spectral_round_trip_exact_to_the_printed_digits(tmp_path):
    s = _spectral()
    p = write_astm(s, tmp_path / "a.astm", instrument="test", date="2026-01-02")
    text = p.read_text()
    back = read_astm(p)
    assert len(back) == len(s)
    np.testing.assert_array_equal(back.wavelength_nm, s.wavelength_nm)
    # angles: the printed degrees (ANGLE_DIGITS decimals), values: VALUE_DIGITS significant
    np.testing.assert_allclose(
        np.degrees(back.theta_i), np.degrees(s.theta_i), rtol=0, atol=0.5 * 10.0**-ANGLE_DIGITS
    )
    np.testing.assert_allclose(back.value, s.value, rtol=0.5 * 10.0 ** (1 - VALUE_DIGITS))
    np.testing.assert_allclose(back.sigma, s.sigma, rtol=0.5 * 10.0 ** (1 - VALUE_DIGITS))
    # every number read is exactly the printed one
    rows = [ln.split() for ln in text.splitlines() if ln[:1].isdigit()]
    assert float(rows[0][4]) == back.value[0] and np.radians(float(rows[0][2])) == back.theta_o[0]
    # and writing what was read gives the same text
    assert write_astm(back, tmp_path / "b.astm").read_text() == text
    assert back.metadata["material"] == "garnet_red_paint" and back.metadata["seed"] == 3
    assert back.metadata["astm_date"] == "2026-01-02"
    for key in ("SAMPLE\tgarnet_red_paint", "INCIDENT_POLARIZATION\tU", "UNITS\t1/sr"):
        assert key in text


def test_grey_without_sigma_and_read_samples_dispatch(tmp_path):
    m = brdf.create("lambert", rho=0.4)
    wo = to_vector(np.radians([10.0, 30.0, 50.0]), np.radians([0.0, 90.0, 180.0]))
    wi = to_vector(np.radians(20.0), 0.0) + 0 * wo
    s = BRDFSamples.from_directions(wi, wo, m(wi, wo), metadata={"material": "lambert"})
    p = write_samples(s, tmp_path / "g.astm")
    back = read_samples(p)
    assert back.wavelength_nm is None and not back.has_sigma
    np.testing.assert_allclose(back.value, s.value, rtol=1e-8)
    assert "SIGMA" not in p.read_text()
    assert BRDFSamples.read(p).value.shape == (3,)


def test_fit_reads_astm(tmp_path, capsys):
    from gonio.cli import main

    m = brdf.create("lambert", rho=0.4)
    rng = np.random.default_rng(1)
    wi = to_vector(np.radians(rng.uniform(0, 60, 50)), rng.uniform(-3, 3, 50))
    wo = to_vector(np.radians(rng.uniform(0, 60, 50)), rng.uniform(-3, 3, 50))
    s = BRDFSamples.from_directions(wi, wo, m(wi, wo), sigma=np.full(50, 1e-3))
    p = write_astm(s, tmp_path / "f.astm")
    assert main(["fit", str(p), "--model", "lambert"]) == 0
    assert "0.4" in capsys.readouterr().out


def test_bad_tables_are_refused(tmp_path):
    s = _spectral(3)
    good = write_astm(s, tmp_path / "g.astm").read_text()

    def bad(text, match):
        p = tmp_path / "bad.astm"
        p.write_text(text)
        with pytest.raises(ValueError, match=match):
            read_astm(p)

    bad("hello\n", "not an ASTM E1392 table")
    bad(good.replace("DATA\t", "DAT\t"), "no DATA line")
    bad(good.replace("NUM_POINTS\t3", "NUM_POINTS\t4"), "NUM_POINTS 4 but 3")
    bad(good.replace("THETA_I PHI_I", "PHI_I THETA_I"), "first columns")
    bad(good.rstrip("\n") + " 1.0\n", "not .* numbers")
    bad(good.replace("ANGLE_UNITS\tdeg", "ANGLE_UNITS\trad"), "ANGLE_UNITS")
    lines = good.splitlines()
    lines[-1] = lines[-1].replace(lines[-1].split()[0], "95.000000", 1)
    bad("\n".join(lines) + "\n", "theta_i must lie in")
    with pytest.raises(ValueError, match="does not exist"):
        read_astm(tmp_path / "none.astm")
    twice = BRDFSamples.concatenate([s, s])
    with pytest.raises(ValueError, match="exactly once"):
        write_astm(twice, tmp_path / "t.astm")
    assert not (tmp_path / "t.astm").exists()
