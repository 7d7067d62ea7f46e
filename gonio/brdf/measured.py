"""Measured BSDFs in Mitsuba 3's tensor format (the RGL material database's ``.bsdf`` files).

``measured(filename)`` evaluates the file as Mitsuba's ``measured`` plugin does
(:class:`gonio.io.mitsuba.MeasuredTable`: the VNDF warp's inverse, bilinear interpolation on
the warped grid, linear between the incident slices), divided by cos θo to give f_r. An RGB
file gives a **spectral** model of three bands at the nominal [610, 550, 465] nm (red, green,
blue; the convention of the MERL model, :mod:`gonio.brdf.tabulated`), a spectral file its
own bands, and a file gonio wrote from a grey source a grey model.

References
----------
J. Dupuy and W. Jakob, "An adaptive parameterization for efficient material acquisition and
rendering", ACM Transactions on Graphics 37(6), 274, 2018. https://doi.org/10.1145/3272127.3275059
Sec. 4-5 (the parameterisation the file holds).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, Param, register

__all__ = ["Measured"]


@register
class Measured(BRDF):
    """A Mitsuba 3 / RGL measured BSDF file (``.bsdf``), evaluated as Mitsuba does.

    Parameters
    ----------
    filename : str or path-like
        The tensor file.
    """

    name: ClassVar[str] = "measured"
    PARAMS = (Param("filename", None, kind="object", doc="Mitsuba 3 measured BSDF (.bsdf) file"),)
    REFERENCE = "Dupuy and Jakob 2018 (RGL measured BSDF, Mitsuba 3's measured plugin)"
    SUMMARY = "measured BSDF file of the RGL database / Mitsuba 3 (tensor format)"
    RECIPROCAL = False
    ENERGY_CONSERVING = False
    ALBEDO_RTOL = 1e-3

    def _setup(self) -> None:
        from gonio.io.merl import WAVELENGTHS_NM
        from gonio.io.mitsuba import read_bsdf

        if self._params["filename"] is None:
            raise ValueError("measured: parameter filename is required (a .bsdf file)")
        self.table = read_bsdf(self._params["filename"])
        t = self.table
        self._wl = {"grey": None, "rgb": np.asarray(WAVELENGTHS_NM, float)}.get(
            t.kind, t.wavelengths_nm
        )

    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        """Band centres (nm), ``None`` for a grey file."""
        return None if self._wl is None else self._wl.copy()

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        return self.table(wi, wo)
