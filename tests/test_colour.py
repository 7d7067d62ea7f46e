"""Tests of gonio.colour: 31 bands -> CIE XYZ -> linear sRGB."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import colour


def test_tables_are_the_cie_values():
    assert colour.CMF_1931_2DEG.shape == (31, 3)
    # y-bar peaks at 555 nm (=1); at the 10 nm grid the largest samples are 550/560 nm
    assert colour.CMF_1931_2DEG[15:17, 1].tolist() == [0.99495, 0.995]
    assert colour.CMF_1931_2DEG[20, 0] == 1.0622  # x-bar at 600 nm
    # D65 from the daylight basis: 100 at 560 nm, within 0.3 % of CIE's tabulated values
    tab = {400: 82.7549, 450: 117.008, 500: 109.354, 550: 104.046, 600: 90.0062, 700: 71.6091}
    for wl, v in tab.items():
        assert colour.D65[(wl - 400) // 10] == pytest.approx(v, rel=3e-3)
    assert colour.D65[16] == 100.0


def test_flat_spectra_are_neutral_and_grey_is_computed_once():
    rgb = colour.spectrum_to_linear_srgb(np.full((4, 31), 0.3))
    np.testing.assert_allclose(rgb, 0.3, rtol=2e-7)
    np.testing.assert_allclose(colour.spectrum_to_xyz(np.ones(31)), [0.95047, 1.0, 1.08883])
    grey = colour.spectrum_to_linear_srgb(np.array([0.1, 0.7]), grey=True)
    np.testing.assert_allclose(grey, [[0.1] * 3, [0.7] * 3], rtol=2e-7)


def test_colours_of_coloured_spectra():
    wl = colour.WAVELENGTHS_NM
    red = colour.spectrum_to_linear_srgb(np.where(wl >= 600, 0.8, 0.05))
    blue = colour.spectrum_to_linear_srgb(np.where(wl <= 480, 0.8, 0.05))
    assert red[0] > 3 * red[1] and red[0] > 3 * red[2]
    assert blue[2] > 3 * blue[0] and blue[2] > 2 * blue[1]
    # linear in the spectrum
    a, b = np.linspace(0, 1, 31), np.linspace(1, 0, 31)
    np.testing.assert_allclose(
        colour.spectrum_to_xyz(a + 2 * b), colour.spectrum_to_xyz(a) + 2 * colour.spectrum_to_xyz(b)
    )
    # other band grids are interpolated
    three = colour.spectrum_to_xyz([0.2, 0.2, 0.2], wavelengths_nm=[450, 550, 650])
    np.testing.assert_allclose(three, 0.2 * np.array([0.95047, 1.0, 1.08883]))
    assert colour.encode_srgb(1.0) == pytest.approx(1.0)
    assert colour.encode_srgb(0.001) == pytest.approx(0.01292)


def test_bad_input():
    with pytest.raises(ValueError, match="31 bands"):
        colour.spectrum_to_xyz(np.ones(30))
    with pytest.raises(ValueError, match="non-finite"):
        colour.spectrum_to_xyz(np.full(31, np.nan))
    with pytest.raises(ValueError, match="wavelengths_nm"):
        colour.spectrum_to_xyz(np.ones(3), wavelengths_nm=[400, 500])
    with pytest.raises(ValueError, match="increase"):
        colour.spectrum_to_xyz(np.ones(3), wavelengths_nm=[400, 500, 450])
    with pytest.raises(ValueError, match="xyz"):
        colour.xyz_to_linear_srgb(np.ones(4))
