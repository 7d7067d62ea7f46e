import numpy as np
import pytest

from gonio.geometry import to_vector
from gonio.io.samples_table import read_samples
from gonio.samples import BRDFSamples


def _table(spectral=False):
    rng = np.random.default_rng(0)
    n = 50
    wi = to_vector(rng.uniform(0, 1.4, n), rng.uniform(-3, 3, n))
    wo = to_vector(rng.uniform(0, 1.4, n), rng.uniform(-3, 3, n))
    wl = rng.choice([450.0, 550.0], n) if spectral else None
    return BRDFSamples.from_directions(
        wi,
        wo,
        rng.random(n),
        rng.random(n) * 0.01,
        wavelength_nm=wl,
        metadata={"material": "x", "seed": 1},
    )


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("spectral", [False, True])
def test_roundtrip(tmp_path, suffix, spectral):
    t = _table(spectral)
    p = t.write(tmp_path / f"s{suffix}")
    r = read_samples(p)
    np.testing.assert_array_equal(r.to_array(), t.to_array())
    assert r.metadata == t.metadata
    np.testing.assert_allclose(r.wi, t.wi, atol=1e-15)


def test_malformed_files(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("theta_i,phi_i,theta_o,phi_o,value\n0,0,0,0,1\n")
    with pytest.raises(ValueError, match="missing column"):
        read_samples(bad)
    bad.write_text("theta_i,phi_i,theta_o,phi_o,value,sigma\n0,0,0,0,abc,0\n")
    with pytest.raises(ValueError, match="non-numeric"):
        read_samples(bad)
    bad.write_text("theta_i,phi_i,theta_o,phi_o,value,sigma\n0,0,0,0,nan,0\n")
    with pytest.raises(ValueError, match="non-finite"):
        read_samples(bad)
    z = tmp_path / "bad.npz"
    z.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"bad\.npz"):
        read_samples(z)
    with pytest.raises(ValueError, match="suffix"):
        _table().write(tmp_path / "x.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "bad.npz"]  # no leftovers


def test_validation():
    with pytest.raises(ValueError, match="theta_i"):
        BRDFSamples([2.0], [0], [0], [0], [1], [0.1])
    with pytest.raises(ValueError, match="rows"):
        BRDFSamples([0.1, 0.2], [0], [0], [0], [1], [0.1])


@pytest.mark.parametrize("n", [1, 3, 200])
@pytest.mark.parametrize("constant", [(), ("theta_i", "phi_i"), ("theta_i", "value", "sigma")])
def test_csv_rows_matches_savetxt(n, constant):
    """csv_rows pastes constant columns once; the text must equal numpy.savetxt's %.17g."""
    import io

    from gonio.io.samples_table import csv_rows

    rng = np.random.default_rng(n)
    cols = {c: rng.random(n) for c in ("theta_i", "phi_i", "theta_o", "phi_o")}
    cols.update(value=rng.random(n) * 10.0 ** rng.integers(-8, 3), sigma=rng.random(n) * 1e-5)
    for c in constant:
        cols[c] = np.full(n, cols[c][0])
    cols["phi_i"] = -cols["phi_i"] if "phi_i" not in constant else np.full(n, -0.0)
    t = BRDFSamples(**cols, wavelength_nm=np.full(n, 550.0))
    buf = io.StringIO()
    np.savetxt(buf, t.to_array(), delimiter=",", fmt="%.17g")
    assert csv_rows(t) == buf.getvalue()
    back = np.loadtxt(io.StringIO(csv_rows(t)), delimiter=",", ndmin=2)
    np.testing.assert_array_equal(back, t.to_array())  # bit for bit, -0.0 included
    assert np.signbit(back[:, 1]).all()


def test_atomic_write_not_durable_and_fsync_files(tmp_path):
    from gonio.io.atomic import atomic_write_bytes, fsync_files

    paths = [atomic_write_bytes(tmp_path / "d" / f"f{k}.bin", bytes([k]) * 10, durable=False)
             for k in range(3)]  # fmt: skip
    assert [p.read_bytes() for p in paths] == [bytes([k]) * 10 for k in range(3)]
    assert not list((tmp_path / "d").glob(".*.tmp"))  # no temporary file left behind
    assert fsync_files(paths) == 3
    assert fsync_files([]) == 0
    with pytest.raises(FileNotFoundError):
        fsync_files([tmp_path / "missing.bin"])
