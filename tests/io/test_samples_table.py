"""The samples-table reader against hostile files (issue 15): a result or a ValueError, never
another exception, never a NaN."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.io.samples_table import read_samples
from gonio.samples import BRDFSamples

GOOD = (
    '# source: "test"\n'
    "theta_i,phi_i,theta_o,phi_o,value,sigma\n"
    "0.5,0,0.6,3.0,0.31,0.002\n"
    "0.5,0,0.7,-2.0,0.25,0.002\n"
    "0.2,1.0,0.1,0.5,0.40,0.003\n"
)


def _check(samples: BRDFSamples) -> None:
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "value"):
        assert np.isfinite(getattr(samples, name)).all()
    assert not np.isnan(samples.sigma).any() or np.isnan(samples.sigma).all()


def test_utf8_byte_order_mark_is_not_part_of_the_header(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes("\ufeff".encode() + GOOD.encode())
    s = read_samples(p)
    assert len(s) == 3 and s.metadata["source"] == "test"


def test_phi_in_degrees_and_infinite_sigma_are_refused(tmp_path):
    p = tmp_path / "deg.csv"
    p.write_text(GOOD.replace("0.6,3.0,", "0.6,171.9,"))
    with pytest.raises(ValueError, match=r"phi_o must lie in \[-2 pi, 2 pi\] .*degrees\?"):
        read_samples(p)
    p.write_text(GOOD.replace("0.31,0.002", "0.31,inf"))
    with pytest.raises(ValueError, match=r"sigma has 1 infinite value\(s\) \(first at row 0\)"):
        read_samples(p)


@settings(max_examples=200, deadline=None)
@given(text=st.text(max_size=300))
def test_random_text_gives_a_table_or_a_value_error(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("t") / "x.csv"
    p.write_text(text, encoding="utf-8")
    try:
        s = read_samples(p)
    except ValueError:
        return
    _check(s)


_MUTATIONS = st.lists(
    st.tuples(st.integers(0, len(GOOD) - 1), st.sampled_from(
        ["", ",", "\n", "#", "nan", "inf", "-", "1e999", "9", ".", "\ufeff", "\x00", "é", ";"]
    )), min_size=1, max_size=6,
)  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(edits=_MUTATIONS, raw=st.binary(max_size=8))
def test_mutated_tables_give_a_table_or_a_value_error(write_mutated, edits, raw):
    p = write_mutated(GOOD, edits, raw)
    try:
        s = read_samples(p)
    except ValueError:
        return
    _check(s)


@settings(max_examples=100, deadline=None)
@given(raw=st.binary(max_size=200))
def test_random_npz_bytes_give_a_table_or_a_value_error(tmp_path_factory, raw):
    p = tmp_path_factory.mktemp("t") / "x.npz"
    p.write_bytes(raw)
    try:
        s = read_samples(p)
    except ValueError:
        return
    _check(s)


@pytest.mark.parametrize("spectral", [False, True])
def test_csv_header_gives_units_and_reads_back_identically(tmp_path, spectral):
    from gonio.io.samples_table import write_samples

    rng = np.random.default_rng(3)
    n = 50
    cols = [rng.uniform(0, 1.5, n), rng.uniform(-3, 3, n), rng.uniform(0, 1.5, n)]
    cols += [rng.uniform(-3, 3, n), rng.lognormal(size=n), rng.uniform(0, 0.1, n)]
    wl = rng.choice([400.0, 550.0, 700.0], n) if spectral else None
    meta = {"material": "x", "seed": 0, "note": "units: rad"}
    s = BRDFSamples(*cols, wavelength_nm=wl, metadata=meta)
    p = tmp_path / "t.csv"
    write_samples(s, p)
    first = p.read_text().splitlines()[0]
    assert first.startswith("# units: ") and '"theta_i": "rad"' in first
    assert '"value": "sr^-1"' in first and ('"wavelength_nm": "nm"' in first) == spectral
    back = read_samples(p)
    assert back.metadata == meta
    for c in s.columns:
        assert np.array_equal(getattr(back, c), getattr(s, c)), c
