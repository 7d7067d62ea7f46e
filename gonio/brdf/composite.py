"""Sums of models, e.g. ``lambert + ward`` for fitting.

Parameter names of a sum are ``"<model>.<param>"`` (``"lambert.rho"``, ``"ward.rho_d"``);
a model appearing twice gets ``#2``, ``#3`` … (``"ward#2.rho_s"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, Param


class Sum(BRDF):
    """The sum of several BRDF models; values, albedos and delta parts add."""

    name: ClassVar[str] = "sum"

    def __init__(self, models: Sequence[BRDF]) -> None:
        flat: list[BRDF] = []
        for m in models:
            if not isinstance(m, BRDF):
                raise ValueError(f"Sum terms must be BRDF models, got {type(m).__name__}")
            flat.extend(m.models if isinstance(m, Sum) else [m])
        if not flat:
            raise ValueError("Sum needs at least one model")
        bands = {m.n_bands for m in flat} - {None}
        if len(bands) > 1:
            raise ValueError(f"Sum terms have different band counts: {sorted(bands)}")
        self.models = tuple(flat)
        self.prefixes = _prefixes([m.name for m in flat])
        self._params = {
            f"{pre}.{k}": v for pre, m in zip(self.prefixes, flat) for k, v in m.params.items()
        }

    @property
    def label(self) -> str:
        """``"lambert + ward"``-style description."""
        return " + ".join(m.name for m in self.models)

    @property
    def PARAMS(self) -> tuple[Param, ...]:  # type: ignore[override]
        out = []
        for pre, m in zip(self.prefixes, self.models):
            for p in type(m).PARAMS:
                out.append(
                    Param(
                        f"{pre}.{p.name}",
                        p.default,
                        p.lower,
                        p.upper,
                        p.unit,
                        p.doc,
                        p.kind,
                        p.spectral,
                        p.optional,
                    )
                )
        return tuple(out)

    def with_params(self, **params: Any) -> Sum:
        """A new sum with some ``"<prefix>.<param>"`` values replaced."""
        per = [dict(m.params) for m in self.models]
        for key, v in params.items():
            pre, _, name = key.partition(".")
            if pre not in self.prefixes or name not in per[self.prefixes.index(pre)]:
                raise ValueError(f"unknown parameter {key!r}; expected {list(self._params)}")
            per[self.prefixes.index(pre)][name] = v
        return Sum([type(m)(**p) for m, p in zip(self.models, per)])

    @property
    def wavelengths_nm(self):
        for m in self.models:
            if m.wavelengths_nm is not None:
                return m.wavelengths_nm
        return None

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        nb = self.n_bands
        total = 0.0
        for m in self.models:
            v = m._eval(wi, wo)
            if nb and m.n_bands is None:
                v = v[..., None]
            total = total + v
        return np.asarray(total, dtype=np.float64)

    def albedo(self, wi, rtol=None):
        nb = self.n_bands
        total = 0.0
        for m in self.models:
            a = m.albedo(wi, rtol)
            total = total + (a[..., None] if nb and m.n_bands is None else a)
        return np.asarray(total)

    @property
    def has_delta(self) -> bool:
        return any(m.has_delta for m in self.models)

    def delta(self, wi):
        d, r = None, 0.0
        for m in self.models:
            d, rm = m.delta(wi)
            r = r + rm
        return d, np.asarray(r)

    def __repr__(self) -> str:
        return "Sum(" + ", ".join(repr(m) for m in self.models) + ")"


def _prefixes(names: Sequence[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out
