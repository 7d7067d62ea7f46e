"""Spectra of the 31 Cornell bands (400-700 nm, 10 nm) to CIE XYZ and linear sRGB.

Li & Torrance measure "31 convolved wavelength samples" and "also convert them to RGB values"
(Li and Torrance 2005, §5.1). This module does that conversion with the CIE tables shipped
here as constants (31 rows, small enough to read):

* CIE 1931 2° standard observer x̄, ȳ, z̄ (CIE 15:2004 "Selected colorimetric tables", 5 nm
  table sampled every 10 nm);
* illuminant D65 computed with the CIE daylight procedure from the S0, S1, S2 basis at the D65
  chromaticity (x, y) = (0.31271, 0.32902), M1 and M2 rounded to three decimals (CIE 15:2004
  §3.1); it differs from the tabulated D65 by less than 0.3 % in these bands;
* the sRGB (IEC 61966-2-1) XYZ → linear RGB matrix, D65 white.

A reflectance (or BRDF times π) spectrum ``R(λ)`` gives ``X = Σ R S x̄ / Σ S ȳ`` (likewise Y, Z).
Because 400-700 nm at 10 nm truncates the CMFs, the white of this sum is not exactly D65's
(0.95047, 1, 1.08883); a Bradford adaptation from the band-limited white to D65 is folded into
the conversion so that a flat spectrum maps to a neutral colour (R = G = B = its value). All
matrices are combined once into a ``(3, 31)`` matrix; a grey input (no band axis) costs one
multiplication by the white.

>>> import numpy as np
>>> from gonio import colour
>>> np.round(colour.spectrum_to_linear_srgb(np.full(31, 0.5)), 6).tolist()
[0.5, 0.5, 0.5]

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   §5.1: the 31 convolved wavelength samples, also converted to RGB values.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_finite_array

__all__ = [
    "CMF_1931_2DEG",
    "D65",
    "WAVELENGTHS_NM",
    "XYZ_TO_LINEAR_SRGB",
    "encode_srgb",
    "spectrum_to_linear_srgb",
    "spectrum_to_xyz",
    "xyz_to_linear_srgb",
]

#: Band centres of the Cornell instrument, 400..700 nm step 10 (31 bands).
WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)

# fmt: off
#: CIE 1931 2° colour matching functions x̄, ȳ, z̄ at ``WAVELENGTHS_NM`` (CIE 15:2004).
CMF_1931_2DEG = np.array([
    [0.014310, 0.000396, 0.067850], [0.043510, 0.001210, 0.207400],
    [0.134380, 0.004000, 0.645600], [0.283900, 0.011600, 1.385600],
    [0.348280, 0.023000, 1.747060], [0.336200, 0.038000, 1.772110],
    [0.290800, 0.060000, 1.669200], [0.195360, 0.090980, 1.287640],
    [0.095640, 0.139020, 0.812950], [0.032010, 0.208020, 0.465180],
    [0.004900, 0.323000, 0.272000], [0.009300, 0.503000, 0.158200],
    [0.063270, 0.710000, 0.078250], [0.165500, 0.862000, 0.042160],
    [0.290400, 0.954000, 0.020300], [0.433450, 0.994950, 0.008750],
    [0.594500, 0.995000, 0.003900], [0.762100, 0.952000, 0.002100],
    [0.916300, 0.870000, 0.001650], [1.026300, 0.757000, 0.001100],
    [1.062200, 0.631000, 0.000800], [1.002600, 0.503000, 0.000340],
    [0.854450, 0.381000, 0.000190], [0.642400, 0.265000, 0.000050],
    [0.447900, 0.175000, 0.000020], [0.283500, 0.107000, 0.000000],
    [0.164900, 0.061000, 0.000000], [0.087400, 0.032000, 0.000000],
    [0.046770, 0.017000, 0.000000], [0.022700, 0.008210, 0.000000],
    [0.011359, 0.004102, 0.000000],
])

# CIE daylight basis S0, S1, S2 at WAVELENGTHS_NM (CIE 15:2004 table T.2)
_S012 = np.array([
    [94.80, 43.40, -1.10], [104.80, 46.30, -0.50], [105.90, 43.90, -0.70],
    [96.80, 37.10, -1.20], [113.90, 36.70, -2.60], [125.60, 35.90, -2.90],
    [125.50, 32.60, -2.80], [121.30, 27.90, -2.60], [121.30, 24.30, -2.60],
    [113.50, 20.10, -1.80], [113.10, 16.20, -1.50], [110.80, 13.20, -1.30],
    [106.50, 8.60, -1.20], [108.80, 6.10, -1.00], [105.30, 4.20, -0.50],
    [104.40, 1.90, -0.30], [100.00, 0.00, 0.00], [96.00, -1.60, 0.20],
    [95.10, -3.50, 0.50], [89.10, -3.50, 2.10], [90.50, -5.80, 3.20],
    [90.30, -7.20, 4.10], [88.40, -8.60, 4.70], [84.00, -9.50, 5.10],
    [85.10, -10.90, 6.70], [81.90, -10.70, 7.30], [82.60, -12.00, 8.60],
    [84.90, -14.00, 9.80], [81.30, -13.60, 10.20], [71.90, -12.00, 8.30],
    [74.30, -13.30, 9.60],
])
# fmt: on


def _daylight(x: float, y: float) -> NDArray[np.float64]:
    den = 0.0241 + 0.2562 * x - 0.7341 * y
    m1 = round((-1.3515 - 1.7703 * x + 5.9114 * y) / den, 3)
    m2 = round((0.0300 - 31.4424 * x + 30.0717 * y) / den, 3)
    return _S012[:, 0] + m1 * _S012[:, 1] + m2 * _S012[:, 2]


#: Relative spectral power of CIE illuminant D65 at ``WAVELENGTHS_NM`` (100 at 560 nm).
D65 = _daylight(0.31271, 0.32902)

#: IEC 61966-2-1 (sRGB) matrix from XYZ (D65 white, Y = 1) to linear RGB.
XYZ_TO_LINEAR_SRGB = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)
_D65_WHITE = np.array([0.95047, 1.0, 1.08883])
_BRADFORD = np.array(
    [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]]
)


def _spectrum_matrix() -> tuple[NDArray, NDArray]:
    w = D65[:, None] * CMF_1931_2DEG  # (31, 3)
    to_xyz = (w / np.sum(D65 * CMF_1931_2DEG[:, 1])).T  # (3, 31)
    white = to_xyz.sum(axis=1)
    cone_src, cone_dst = _BRADFORD @ white, _BRADFORD @ _D65_WHITE
    adapt = np.linalg.inv(_BRADFORD) @ np.diag(cone_dst / cone_src) @ _BRADFORD
    return adapt @ to_xyz, XYZ_TO_LINEAR_SRGB @ adapt @ to_xyz


_TO_XYZ, _TO_RGB = _spectrum_matrix()


def _bands(values: ArrayLike, wavelengths_nm: ArrayLike | None, name: str) -> NDArray:
    v = as_finite_array(values, name)
    if wavelengths_nm is None:
        if v.ndim == 0 or v.shape[-1] != len(WAVELENGTHS_NM):
            raise ValueError(
                f"{name} must have a last axis of {len(WAVELENGTHS_NM)} bands (400..700 nm), "
                f"got shape {v.shape}; pass wavelengths_nm for other bands or grey=True"
            )
        return v
    wl = as_finite_array(wavelengths_nm, "wavelengths_nm")
    if wl.ndim != 1 or v.ndim == 0 or v.shape[-1] != wl.shape[0] or wl.shape[0] < 2:
        raise ValueError(
            f"wavelengths_nm of shape {wl.shape} does not match {name} of shape {v.shape}; "
            "expected one wavelength per band (at least 2)"
        )
    if np.any(np.diff(wl) <= 0):
        raise ValueError(f"wavelengths_nm must increase strictly, got {wl.tolist()}")
    flat = v.reshape(-1, wl.shape[0])
    out = np.stack([np.interp(WAVELENGTHS_NM, wl, row) for row in flat])
    return out.reshape(v.shape[:-1] + (len(WAVELENGTHS_NM),))


def spectrum_to_xyz(
    values: ArrayLike, wavelengths_nm: ArrayLike | None = None, *, grey: bool = False
) -> NDArray[np.float64]:
    """CIE XYZ (D65-adapted, Y of a perfect white = 1) of reflectance-like spectra.

    Parameters
    ----------
    values : array_like
        Shape ``(..., 31)`` on ``WAVELENGTHS_NM``, ``(..., n)`` with ``wavelengths_nm``
        (linearly interpolated, held constant outside), or ``(...)`` with ``grey=True``
        (a flat spectrum: computed once from the white point, no band axis needed).
    wavelengths_nm : array_like, optional
        Band centres of ``values`` when they are not the 31 default bands.
    grey : bool
        Treat ``values`` as flat spectra.

    Returns
    -------
    ndarray, shape ``(..., 3)``
    """
    if grey:
        v = as_finite_array(values, "values")
        return v[..., None] * _TO_XYZ.sum(axis=1)
    return _bands(values, wavelengths_nm, "values") @ _TO_XYZ.T


def xyz_to_linear_srgb(xyz: ArrayLike) -> NDArray[np.float64]:
    """Linear sRGB (IEC 61966-2-1, D65) of XYZ values ``(..., 3)``; not clipped."""
    x = as_finite_array(xyz, "xyz")
    if x.ndim == 0 or x.shape[-1] != 3:
        raise ValueError(f"xyz must have shape (..., 3), got {x.shape}")
    return x @ XYZ_TO_LINEAR_SRGB.T


def spectrum_to_linear_srgb(
    values: ArrayLike, wavelengths_nm: ArrayLike | None = None, *, grey: bool = False
) -> NDArray[np.float64]:
    """Linear sRGB of spectra, shape ``(..., 3)`` (see :func:`spectrum_to_xyz`)."""
    if grey:
        v = as_finite_array(values, "values")
        return v[..., None] * _TO_RGB.sum(axis=1)
    return _bands(values, wavelengths_nm, "values") @ _TO_RGB.T


def encode_srgb(linear: ArrayLike) -> NDArray[np.float64]:
    """The sRGB transfer function (IEC 61966-2-1) on linear values clipped to [0, 1]."""
    c = np.clip(as_finite_array(linear, "linear"), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)
