"""BRDF sample tables: the tidy one-row-per-sample data type.

Columns (``docs/architecture.md``, File formats): ``theta_i, phi_i, theta_o, phi_o`` (radians),
``value`` (sr⁻¹), ``sigma`` (its standard error), optional ``wavelength_nm``. The files (CSV
with a commented metadata header, ``.npz``) are read and written by
:mod:`gonio.io.samples_table`; :meth:`BRDFSamples.read` and :meth:`BRDFSamples.write` call it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.geometry import to_spherical, to_vector

__all__ = ["COLUMNS", "BRDFSamples"]

COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o", "value", "sigma")

#: Largest accepted |phi| (radians): one turn either way, with rounding room. Azimuths in
#: degrees (up to 360) would otherwise wrap silently and fit to garbage.
_PHI_LIMIT = 2.0 * np.pi * (1.0 + 1e-9)


def _degrees_hint(a: NDArray[np.float64]) -> str:
    return " (degrees? angles are radians)" if a.size and float(np.abs(a).max()) > 6.3 else ""


@dataclass
class BRDFSamples:
    """A table of BRDF samples; every column a 1-D float64 array of the same length.

    ``sigma`` may hold ``nan`` only if the whole column is unknown (then it is all ``nan``);
    ``wavelength_nm`` is ``None`` for grey data. ``metadata`` is a JSON-serialisable dict.
    """

    theta_i: NDArray[np.float64]
    phi_i: NDArray[np.float64]
    theta_o: NDArray[np.float64]
    phi_o: NDArray[np.float64]
    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    wavelength_nm: NDArray[np.float64] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = None
        for name in (*COLUMNS, "wavelength_nm"):
            col = getattr(self, name)
            if col is None and name == "wavelength_nm":
                continue
            arr = np.atleast_1d(np.asarray(col, dtype=np.float64))
            if arr.ndim != 1:
                raise ValueError(f"column {name} must be 1-D, got shape {arr.shape}")
            if n is None:
                n = arr.shape[0]
            elif arr.shape[0] != n:
                raise ValueError(f"column {name} has {arr.shape[0]} rows, expected {n}")
            if name == "sigma":
                if np.isnan(arr).any() and not np.isnan(arr).all():
                    raise ValueError("column sigma mixes known and unknown (nan) errors")
                if (arr < 0).any():
                    raise ValueError("column sigma has negative standard errors")
                if np.isinf(arr).any():
                    k = int(np.flatnonzero(np.isinf(arr))[0])
                    raise ValueError(
                        f"column sigma has {int(np.isinf(arr).sum())} infinite value(s) (first "
                        f"at row {k}): a sample without weight is a row to drop, an unknown "
                        "error is nan for the whole column"
                    )
            elif not np.isfinite(arr).all():
                raise ValueError(f"column {name} contains non-finite values")
            setattr(self, name, arr)
        for name in ("theta_i", "theta_o"):
            a = getattr(self, name)
            if ((a < 0) | (a > np.pi / 2)).any():
                raise ValueError(
                    f"column {name} must lie in [0, pi/2] radians, got values in "
                    f"[{a.min():.6g}, {a.max():.6g}]{_degrees_hint(a)}"
                )
        for name in ("phi_i", "phi_o"):
            a = getattr(self, name)
            if (np.abs(a) > _PHI_LIMIT).any():
                raise ValueError(
                    f"column {name} must lie in [-2 pi, 2 pi] radians, got values in "
                    f"[{a.min():.6g}, {a.max():.6g}]{_degrees_hint(a)}"
                )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_directions(
        cls,
        wi: ArrayLike,
        wo: ArrayLike,
        value: ArrayLike,
        sigma: ArrayLike | None = None,
        wavelength_nm: ArrayLike | None = None,
        metadata: dict | None = None,
    ) -> BRDFSamples:
        """Build a table from unit direction arrays ``(N, 3)`` (local sample frame)."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        ti, pi = to_spherical(wi.reshape(-1, 3))
        to, po = to_spherical(wo.reshape(-1, 3))
        value = np.asarray(value, float).ravel()
        sig = np.full(value.shape, np.nan) if sigma is None else np.asarray(sigma, float).ravel()
        return cls(ti, pi, to, po, value, sig, wavelength_nm, dict(metadata or {}))

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return self.value.shape[0]

    @property
    def wi(self) -> NDArray[np.float64]:
        """Incident directions, shape ``(N, 3)``."""
        return to_vector(self.theta_i, self.phi_i)

    @property
    def wo(self) -> NDArray[np.float64]:
        """Outgoing directions, shape ``(N, 3)``."""
        return to_vector(self.theta_o, self.phi_o)

    @property
    def has_sigma(self) -> bool:
        """Whether standard errors are known."""
        return not np.isnan(self.sigma).all() if len(self) else False

    def subset(self, mask: ArrayLike) -> BRDFSamples:
        """Rows selected by a boolean mask or index array."""
        m = np.asarray(mask)
        wl = None if self.wavelength_nm is None else self.wavelength_nm[m]
        return BRDFSamples(
            *(getattr(self, c)[m] for c in COLUMNS),
            wavelength_nm=wl,
            metadata=dict(self.metadata),
        )

    @classmethod
    def concatenate(cls, tables: list[BRDFSamples], metadata: dict | None = None) -> BRDFSamples:
        """Stack tables row-wise (all grey or all spectral)."""
        if not tables:
            raise ValueError("concatenate needs at least one table")
        spectral = {t.wavelength_nm is not None for t in tables}
        if len(spectral) > 1:
            raise ValueError("cannot concatenate grey and spectral tables")
        cols = [np.concatenate([getattr(t, c) for t in tables]) for c in COLUMNS]
        wl = np.concatenate([t.wavelength_nm for t in tables]) if spectral == {True} else None
        return cls(*cols, wavelength_nm=wl, metadata=dict(metadata or tables[0].metadata))

    def to_array(self) -> NDArray[np.float64]:
        """All columns stacked, shape ``(N, 6)`` or ``(N, 7)`` with ``wavelength_nm`` last."""
        cols = [getattr(self, c) for c in COLUMNS]
        if self.wavelength_nm is not None:
            cols.append(self.wavelength_nm)
        return np.stack(cols, axis=1)

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names in file order."""
        return COLUMNS + (("wavelength_nm",) if self.wavelength_nm is not None else ())

    # ------------------------------------------------------------------ files
    def write(self, path: str | os.PathLike) -> Path:
        """Write to ``.csv`` or ``.npz`` (by suffix) atomically; return the path."""
        from gonio.io.samples_table import write_samples

        return write_samples(self, path)

    @classmethod
    def read(cls, path: str | os.PathLike) -> BRDFSamples:
        """Read a ``.csv`` or ``.npz`` table written by :meth:`write` (or by hand)."""
        from gonio.io.samples_table import read_samples

        return read_samples(path)
