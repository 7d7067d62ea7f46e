"""Measured BRDFs on the MERL half/difference grid.

``tabulated(data, wavelengths_nm=None)``: ``data`` is a MERL binary file path or an array on
the MERL grid (:mod:`gonio.io.merl`): ``(90, 90, 180)`` for a grey table or
``(n_bands, 90, 90, 180)`` for a spectral one, in sr⁻¹ (already scaled — :func:`read_merl`
applies MERL's 1/1500, 1.15/1500, 1.66/1500 channel factors).

Grey or spectral. A MERL file (three colour channels) gives a **spectral** model with three
bands, values of shape ``(..., 3)`` in the file's order red, green, blue, at the nominal band
centres :data:`gonio.io.merl.WAVELENGTHS_NM` = [610, 550, 465] nm (a documented choice: MERL's
channels are broad camera bands with no stated wavelengths). A ``(90, 90, 180)`` array gives a
**grey** model (values of shape ``(...)``), which is what :func:`gonio.io.merl.tabulate` returns
for a grey model, so ``tabulated(tabulate(m))`` has the same kind of output as ``m``. A user
array with a number of bands other than 3 needs ``wavelengths_nm``.

Evaluation is MERL's nearest-cell lookup (:func:`gonio.io.merl.merl_index`). Directions at or
below the horizon give 0; negative table entries (MERL's marker for unmeasured bins) read
as 0. The lookup is isotropic (no φh) and reciprocal (φd is folded by π).

References
----------
W. Matusik et al., "A Data-Driven Reflectance Model", SIGGRAPH 2003, and its ``BRDFRead.cpp``
(format and lookup). ``docs/architecture.md`` "File formats": measured BRDF as MERL binary.
"""

from __future__ import annotations

import os
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, Param, register

__all__ = ["Tabulated"]


@register
class Tabulated(BRDF):
    """A measured BRDF on the MERL grid, evaluated by MERL's nearest-cell lookup.

    Parameters
    ----------
    data : str, path-like or array_like
        MERL binary file, or an array of shape ``(90, 90, 180)`` (grey) or
        ``(n_bands, 90, 90, 180)`` (spectral), in sr⁻¹.
    wavelengths_nm : array_like or None
        Band centres of a spectral table; ``None`` gives [610, 550, 465] nm for 3 bands.

    Attributes
    ----------
    n_missing : int
        Number of negative (unmeasured) table entries, read as 0.

    Examples
    --------
    >>> from gonio import brdf
    >>> from gonio.io.merl import tabulate
    >>> m = brdf.create("tabulated", data=tabulate("lambert", rho=0.5))
    >>> round(float(m([0.3, 0, 0.95], [0, 0.2, 0.97])), 6)
    0.159155

    References
    ----------
    ``BRDFRead.cpp`` of the MERL database (lookup and channel scales).
    """

    name: ClassVar[str] = "tabulated"
    PARAMS = (
        Param("data", None, kind="object", doc="MERL file path or array on the MERL grid"),
        Param(
            "wavelengths_nm",
            None,
            kind="object",
            optional=True,
            unit="nm",
            doc="band centres of a spectral table (default [610, 550, 465] for 3 bands)",
        ),
    )
    REFERENCE = "MERL BRDF database binary format (Matusik et al. 2003), nearest-cell lookup"
    SUMMARY = "measured BRDF on the MERL (theta_h, theta_d, phi_d) grid"
    ALBEDO_RTOL = 1e-3

    def _setup(self) -> None:
        from gonio.io.merl import N_CELLS, WAVELENGTHS_NM, _as_table, read_merl

        data = self._params["data"]
        if isinstance(data, str | os.PathLike):
            table = read_merl(data)
        elif data is None:
            raise ValueError("tabulated: parameter data is required (a MERL path or an array)")
        else:
            table = _as_table(data, "tabulated: parameter data")
        self.n_missing = int(np.count_nonzero(table < 0.0))
        table = np.maximum(table, 0.0)
        wl = self._params["wavelengths_nm"]
        if table.ndim == 3:
            if wl is not None:
                raise ValueError(
                    "tabulated: wavelengths_nm given for a grey (90, 90, 180) table; "
                    "pass a (n_bands, 90, 90, 180) array for a spectral one"
                )
            self._wl = None
            self._table = np.ascontiguousarray(table.reshape(N_CELLS))
        else:
            nb = table.shape[0]
            if wl is None:
                if nb != 3:
                    raise ValueError(
                        f"tabulated: a table with {nb} bands needs wavelengths_nm "
                        "(the default [610, 550, 465] nm is for 3 bands)"
                    )
                wl = WAVELENGTHS_NM
            wl = np.asarray(wl, dtype=np.float64)
            if wl.shape != (nb,) or not np.isfinite(wl).all() or np.any(wl <= 0.0):
                raise ValueError(
                    f"tabulated: wavelengths_nm must be {nb} positive finite numbers, "
                    f"got {self._params['wavelengths_nm']!r}"
                )
            self._wl = wl.copy()
            self._table = np.ascontiguousarray(table.reshape(nb, N_CELLS).T)

    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        """Band centres (nm) of a spectral table, ``None`` for a grey one."""
        return None if self._wl is None else self._wl.copy()

    @property
    def table(self) -> NDArray[np.float64]:
        """The table on the MERL grid (sr⁻¹), as passed: ``(90, 90, 180)`` or ``(nb, …)``."""
        from gonio.io.merl import SHAPE

        if self._wl is None:
            return self._table.reshape(SHAPE).copy()
        return self._table.T.reshape((-1, *SHAPE)).copy()

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        from gonio.io.merl import merl_index

        valid, idx = merl_index(wi, wo)
        v = self._table[idx]
        if self._wl is not None:
            return np.where(valid[..., None], v, 0.0)
        return np.where(valid, v, 0.0)
