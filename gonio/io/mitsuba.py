"""Mitsuba 3's measured BSDF files (the RGL material database's ``.bsdf`` tensor files).

A tensor file (Mitsuba's ``TensorFile``, written by ``mitsuba.tensor_io``) is the 12 bytes
``tensor_file\\0``, the version bytes 1, 0, a ``uint32`` field count and, per field, its name
(``uint16`` length and UTF-8 bytes), its number of dimensions (``uint16``), its type (one byte,
Mitsuba's ``Struct`` type codes: 1 ``uint8`` ... 10 ``float32``, 11 ``float64``), the ``uint64``
offset of its data and its shape (``uint64`` each), all little-endian; the data follow, each
field aligned to 8 bytes. The ``measured`` plugin (Dupuy and Jakob 2018) reads the fields

* ``description`` (``uint8`` text), ``jacobian`` (one ``uint8``: the flag below);
* ``theta_i`` ``(n_ti,)`` and ``phi_i`` ``(n_pi,)`` (``float32``, radians): the incident
  directions of the slices; two or fewer ``phi_i`` make the file isotropic (the half vector's
  azimuth is then relative to the incident one), else ``phi_i`` spans 2π / r for a symmetry
  reduction r (1 = none, 2, 4: the plugin mirrors directions into the first slice);
* ``ndf`` and ``sigma`` (2-D), ``vndf`` and ``luminance`` ``(n_pi, n_ti, n_y, n_x)``: the
  microfacet distribution, its projected area, the visible-normal warp and the luminance used
  for sampling; ``rgb`` ``(n_pi, n_ti, 3, n_y, n_x)``, or ``spectra`` with ``wavelengths``
  ``(n_bands,)`` nm: values of f_r cos θo at the nodes of a regular grid over the warped
  square.

A query (wi, wo) is evaluated (``Measured::eval``) at the half vector m = normalize(wi + wo):
its unit coordinates u = (sqrt(2 θm / π), (φm [- φi] + π) / 2π) are mapped through the inverse
of the VNDF warp (a bilinear 2-D distribution per slice, :class:`Warp2D`) to a point of the
square, where the ``rgb``/``spectra`` table is interpolated bilinearly, and linearly between
the slices ``theta_i``, ``phi_i`` (and ``wavelengths``); with ``jacobian`` set the value is
multiplied by D(m) / (4 σ(wi)) (``ndf``, ``sigma``). The value is f_r cos θo.

gonio writes the simplest valid form: a **uniform** VNDF (its warp is the identity, so the
grid is the regular grid of u: θm = u² π/2 is dense at the surface normal where glossy lobes
are), the Jacobian flag off, ``ndf`` and ``sigma`` uniform (unused), and a ``luminance`` for
Mitsuba's importance sampling (the luminance of f_r cos θo times the Jacobian of the map from
u to wo, so its samples follow the BSDF). (A warped VNDF, half the lobe's density and half
uniform, was measured on rolled brass at grid 64: near its peak the median error fell from
0.46 to 0.26 %, but at random pairs it rose from 0.58 to 0.82 % and the worst below 80° from
18 to 51 %: the slices' warps differ, and Mitsuba interpolates between slices at the same
warped coordinate.) A grey model is written as ``rgb`` with three equal
channels (Mitsuba's RGB variants read ``rgb``; the spectral ones ``spectra``). An extra field
``gonio`` (JSON text; Mitsuba ignores fields it does not read) records what the file holds
(grey, rgb or spectral; the source; the coverage of measured samples).

:func:`read_bsdf` reads any such file, gonio's or the RGL database's (non-uniform VNDF and
the Jacobian), and evaluates it as the plugin does (:class:`MeasuredTable`); the
``measured`` BRDF model (:mod:`gonio.brdf.measured`) makes it a campaign's truth.

References
----------
J. Dupuy and W. Jakob, "An adaptive parameterization for efficient material acquisition and
rendering", ACM Transactions on Graphics 37(6), 274, 2018. https://doi.org/10.1145/3272127.3275059
Sec. 4-5: the VNDF-warped parameterisation and its Jacobian; the file layout is that of
Mitsuba 3's ``src/bsdfs/measured.cpp``, ``include/mitsuba/core/distr_2d.h`` (``Marginal2D``)
and ``src/python/python/tensor_io.py``.
"""

from __future__ import annotations

import io
import json
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.io.atomic import atomic_write_bytes

__all__ = [
    "DEFAULT_RESOLUTION",
    "DEFAULT_THETA_I",
    "MeasuredTable",
    "Warp2D",
    "coverage_summary",
    "is_isotropic",
    "model_table",
    "read_bsdf",
    "read_tensor",
    "samples_table",
    "write_bsdf",
    "write_tensor",
]

MAGIC = b"tensor_file\0"
#: Mitsuba's ``Struct::Type`` codes of the tensor file
_DTYPES = {
    1: np.uint8,
    2: np.int8,
    3: np.uint16,
    4: np.int16,
    5: np.uint32,
    6: np.int32,
    7: np.uint64,
    8: np.int64,
    9: np.float16,
    10: np.float32,
    11: np.float64,
}
_CODES = {np.dtype(v): k for k, v in _DTYPES.items()}

#: half-vector grid (n_u × n_u nodes over the unit square) of an exported table. Measured
#: (benchmarks/bench_mitsuba.py, Mitsuba's eval at 10,000 random pairs against the model):
#: rolled brass's median relative error 1.05 % at 32, 0.59 % at 64, 0.46 % at 128 (4x the
#: file: 47 MB); the diffuse clay vase 0.73 / 0.28 / 0.18 %. 64 is the smallest under 1 %.
DEFAULT_RESOLUTION = 64
#: incident elevations of an exported model table (rolled brass at grid 64: 16 -> 32 moved
#: the median from 0.58 to 0.52 % for twice the file)
DEFAULT_THETA_I = 16
#: incident azimuths of an anisotropic model table (both ends of its range: [-π, π], or
#: [-π, -π/2] for a mirror-symmetric model); rolled brass at grid 64: 5 -> 9 -> 17 gave a
#: median of 1.6 -> 0.58 -> 0.32 % (6.6, 11.8, 22.3 MB)
DEFAULT_PHI_I = 9
#: largest incident elevation of a model table (rad): the slice at the horizon would hold a
#: model's 0 (or its 1/sqrt(cos θi) limit) and spoil the interpolation below it
THETA_I_MAX = np.deg2rad(87.5)


# --------------------------------------------------------------------------- tensor files
def write_tensor(path: str | os.PathLike, fields: dict[str, Any], align: int = 8) -> Path:
    """Write a Mitsuba tensor file atomically (the layout of ``mitsuba.tensor_io.write``).

    ``fields`` maps names to arrays (their dtype is kept; one of Mitsuba's types) or
    ``str`` (stored as ``uint8`` UTF-8).
    """
    arrays: dict[str, np.ndarray] = {}
    for name, v in fields.items():
        a = np.frombuffer(v.encode(), np.uint8) if isinstance(v, str) else np.asarray(v)
        if a.dtype not in _CODES:
            raise ValueError(f"tensor field {name!r}: dtype {a.dtype} is not one Mitsuba reads")
        arrays[name] = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<"), copy=False))
    head = bytearray(MAGIC + struct.pack("<BBI", 1, 0, len(arrays)))
    offsets = {}
    for name, a in arrays.items():
        label = name.encode()
        head += struct.pack("<H", len(label)) + label
        head += struct.pack("<HB", a.ndim, _CODES[a.dtype])
        offsets[name] = len(head)
        head += struct.pack("<Q", 0) + struct.pack("<" + "Q" * a.ndim, *a.shape)
    out = io.BytesIO()
    out.write(head)
    for name, a in arrays.items():
        pos = (out.tell() + align - 1) // align * align
        out.seek(offsets[name])
        out.write(struct.pack("<Q", pos))
        out.seek(pos)
        out.write(a.tobytes())
    return atomic_write_bytes(path, out.getvalue())


def read_tensor(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a Mitsuba tensor file; ``ValueError`` naming the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"tensor file {str(path)!r} does not exist")
    data = path.read_bytes()

    def bad(what: str) -> ValueError:
        return ValueError(f"{path}: not a Mitsuba tensor file ({what})")

    if data[:12] != MAGIC:
        raise bad("header 'tensor_file' not found")
    if len(data) < 18 or data[12:14] != b"\x01\x00":
        raise bad("unrecognised version")
    (count,) = struct.unpack_from("<I", data, 14)
    pos = 18
    out: dict[str, np.ndarray] = {}
    try:
        for _ in range(count):
            (n,) = struct.unpack_from("<H", data, pos)
            name = data[pos + 2 : pos + 2 + n].decode()
            pos += 2 + n
            ndim, code = struct.unpack_from("<HB", data, pos)
            pos += 3
            (offset,) = struct.unpack_from("<Q", data, pos)
            shape = struct.unpack_from("<" + "Q" * ndim, data, pos + 8)
            pos += 8 + 8 * ndim
            if code not in _DTYPES:
                raise bad(f"field {name!r} has unknown type code {code}")
            dt = np.dtype(_DTYPES[code]).newbyteorder("<")
            size = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
            if offset + size > len(data):
                raise bad(f"field {name!r} runs past the end of the file (truncated?)")
            out[name] = np.frombuffer(data, dt, int(np.prod(shape)), offset).reshape(shape)
    except (struct.error, UnicodeDecodeError) as exc:
        raise bad(f"truncated or corrupt field table: {exc}") from None
    return out


# --------------------------------------------------------------------------- Marginal2D
class Warp2D:
    """Mitsuba's ``Marginal2D`` (continuous, bilinear) over a regular grid, in numpy.

    ``data`` has shape ``(*params, n_y, n_x)``; ``params`` are the node values of the
    conditioning parameters (linear interpolation between slices, clamped at the ends, as
    ``Distribution2D::interpolate_weights``). :meth:`eval` is the bilinear interpolant (of the
    data normalised per slice when ``normalize``), :meth:`invert` the inverse of the sample
    warp (the point of the unit square that the warp maps to ``u``).
    """

    def __init__(self, data: NDArray, params: list[NDArray], normalize: bool = True) -> None:
        d = np.asarray(data, dtype=np.float64)
        self.params = [np.asarray(p, dtype=np.float64) for p in params]
        self.ny, self.nx = d.shape[-2:]
        if self.nx < 2 or self.ny < 2:
            raise ValueError(f"a 2-D table needs at least 2 x 2 nodes, got {d.shape[-2:]}")
        d = d.reshape(-1, self.ny, self.nx)
        # cumulative tables per slice (Marginal2D's constructor, Continuous = true)
        cond = np.cumsum(0.5 / (self.nx - 1) * (d[..., :-1] + d[..., 1:]), axis=-1)
        rows = cond[..., -1]
        marg = np.cumsum(0.5 / (self.ny - 1) * (rows[..., :-1] + rows[..., 1:]), axis=-1)
        norm = np.ones(d.shape[0])
        if normalize:
            total = marg[:, -1]
            norm = np.divide(1.0, total, out=np.full_like(total, np.inf), where=total > 0)
        self.normalize = normalize
        self.data = d * norm[:, None, None]
        self.cond = cond * norm[:, None, None]
        self.marg = marg * norm[:, None]

    def _weights(self, param: list[NDArray], shape: tuple) -> tuple[NDArray, NDArray]:
        """Slice indices ``(2^D, ...)`` and their weights (interpolate_weights)."""
        idx = [np.zeros(shape, np.int64)]
        wts = [np.ones(shape)]
        for values, p in zip(self.params, param):
            n = len(values)
            stride_idx = [i * n for i in idx]
            if n == 1:
                idx, wts = stride_idx, wts
                continue
            p = np.broadcast_to(p, shape)
            i0 = np.clip(np.searchsorted(values, p, side="left") - 1, 0, n - 2)
            p0, p1 = values[i0], values[i0 + 1]
            w1 = np.clip((p - p0) / (p1 - p0), 0.0, 1.0)
            idx = [s + i0 + b for s in stride_idx for b in (0, 1)]
            wts = [w * ww for w in wts for ww in (1.0 - w1, w1)]
        return np.stack(idx), np.stack(wts)

    @staticmethod
    def _lookup(table: NDArray, sl: NDArray, wt: NDArray, *index: NDArray) -> NDArray:
        return np.sum(wt * table[(sl, *index)], axis=0)

    def eval(self, pos: NDArray, param: list[NDArray]) -> NDArray:
        """Bilinear interpolant at ``pos`` ``(..., 2)`` = (x, y) in [0, 1]²."""
        sl, wt = self._weights(param, pos.shape[:-1])
        x = np.clip(pos[..., 0], 0.0, 1.0) * (self.nx - 1)
        y = np.clip(pos[..., 1], 0.0, 1.0) * (self.ny - 1)
        ix = np.minimum(x.astype(np.int64), self.nx - 2)
        iy = np.minimum(y.astype(np.int64), self.ny - 2)
        fx, fy = x - ix, y - iy
        v00 = self._lookup(self.data, sl, wt, iy, ix)
        v10 = self._lookup(self.data, sl, wt, iy, ix + 1)
        v01 = self._lookup(self.data, sl, wt, iy + 1, ix)
        v11 = self._lookup(self.data, sl, wt, iy + 1, ix + 1)
        return (1 - fy) * ((1 - fx) * v00 + fx * v10) + fy * ((1 - fx) * v01 + fx * v11)

    def invert(self, u: NDArray, param: list[NDArray]) -> NDArray:
        """The unit-square point that the warp maps to ``u`` (``Marginal2D::invert``)."""
        sl, wt = self._weights(param, u.shape[:-1])
        s = np.clip(u, 0.0, 1.0) * [self.nx - 1, self.ny - 1]
        ix = np.minimum(s[..., 0].astype(np.int64), self.nx - 2)
        iy = np.minimum(s[..., 1].astype(np.int64), self.ny - 2)
        sx, sy = s[..., 0] - ix, s[..., 1] - iy
        look = self._lookup
        v00 = look(self.data, sl, wt, iy, ix)
        v10 = look(self.data, sl, wt, iy, ix + 1)
        v01 = look(self.data, sl, wt, iy + 1, ix)
        v11 = look(self.data, sl, wt, iy + 1, ix + 1)
        c0 = v00 + (v01 - v00) * sy
        c1 = v10 + (v11 - v10) * sy
        wx, wy = 1.0 / (self.nx - 1), 1.0 / (self.ny - 1)
        x = sx * (c0 + (c1 - c0) * 0.5 * sx) * wx
        prev = np.maximum(ix - 1, 0)
        has = ix > 0
        x = x + np.where(
            has,
            look(self.cond, sl, wt, iy, prev) * (1 - sy)
            + look(self.cond, sl, wt, iy + 1, prev) * sy,
            0.0,
        )
        r0 = look(self.cond, sl, wt, iy, np.full_like(ix, self.nx - 2))
        r1 = look(self.cond, sl, wt, iy + 1, np.full_like(ix, self.nx - 2))
        x = x / (r0 + (r1 - r0) * sy)
        y = sy * (r0 + (r1 - r0) * 0.5 * sy) * wy
        y = y + np.where(iy > 0, look(self.marg, sl, wt, np.maximum(iy - 1, 0)), 0.0)
        if not self.normalize:
            y = y / look(self.marg, sl, wt, np.full_like(iy, self.ny - 2))
        return np.stack([x, y], axis=-1)


# --------------------------------------------------------------------------- the BSDF
def _elevation(d: NDArray) -> NDArray:
    """θ of unit vectors, stable near the pole (Measured::elevation)."""
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, -1.0, 1.0))


@dataclass
class MeasuredTable:
    """A measured BSDF file in memory, evaluated as Mitsuba's ``measured`` plugin does.

    Attributes
    ----------
    fields : dict
        The tensor file's fields.
    kind : str
        ``"grey"`` (an ``rgb`` file gonio wrote from a grey source), ``"rgb"`` or
        ``"spectral"``.
    wavelengths_nm : ndarray or None
        Band centres of a spectral file.
    meta : dict
        The ``gonio`` field (empty for other files).
    """

    fields: dict[str, np.ndarray]
    kind: str
    wavelengths_nm: NDArray[np.float64] | None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = self.fields
        self.theta_i = np.asarray(f["theta_i"], np.float64)
        self.phi_i = np.asarray(f["phi_i"], np.float64)
        self.isotropic = len(self.phi_i) <= 2
        self.reduction = 1
        if not self.isotropic:
            self.reduction = int(np.rint(2 * np.pi / (self.phi_i[-1] - self.phi_i[0])))
        self.jacobian = bool(f["jacobian"][0])
        spectra = f["spectra"] if "spectra" in f else f["rgb"]
        self.n_channels = spectra.shape[2]
        self.description = bytes(f["description"]).decode(errors="replace")
        vndf = np.asarray(f["vndf"], np.float64)
        flat = vndf.reshape(vndf.shape[0] * vndf.shape[1], -1)
        # a uniform VNDF warps u to itself: its inversion is skipped (exactly the identity)
        self._uniform = bool(np.all(flat == flat[:, :1]) and np.all(flat[:, 0] > 0))
        self._vndf = Warp2D(vndf, [self.phi_i, self.theta_i])
        # spectra: one Warp2D per channel (the wavelength parameter's nodes are the channels)
        self._spectra = [
            Warp2D(spectra[:, :, c], [self.phi_i, self.theta_i], normalize=False)
            for c in range(self.n_channels)
        ]
        if self.jacobian:
            self._ndf = Warp2D(f["ndf"], [], normalize=False)
            self._sigma = Warp2D(f["sigma"], [], normalize=False)

    @property
    def shape(self) -> tuple[int, ...]:
        """``(n_phi_i, n_theta_i, n_channels, n_y, n_x)`` of the value table."""
        s = self.fields["spectra"] if "spectra" in self.fields else self.fields["rgb"]
        return tuple(int(x) for x in s.shape)

    def eval_cos(self, wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
        """f_r cos θo per channel, shape ``(..., n_channels)`` (``Measured::eval``)."""
        wi = np.array(wi, dtype=np.float64, copy=True)
        wo = np.array(wo, dtype=np.float64, copy=True)
        wi, wo = np.broadcast_arrays(wi, wo)
        wi, wo = wi.copy(), wo.copy()
        active = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
        if self.reduction >= 2:
            sy = np.where(wi[..., 1] >= 0, -1.0, 1.0)  # mulsign_neg: x * -sign(s), sign(0) = 1
            sx = np.where(wi[..., 0] >= 0, -1.0, 1.0) if self.reduction == 4 else sy
            for d in (wi, wo):
                d[..., 0] *= sx
                d[..., 1] *= sy
        m = wi + wo
        m = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
        theta_i = _elevation(wi)
        phi_i = np.arctan2(wi[..., 1], wi[..., 0])
        theta_m = _elevation(m)
        phi_m = np.arctan2(m[..., 1], m[..., 0])
        if self.isotropic:
            phi_m = phi_m - phi_i
        um = np.stack([np.sqrt(theta_m * (2 / np.pi)), (phi_m + np.pi) / (2 * np.pi)], -1)
        um[..., 1] -= np.floor(um[..., 1])
        par = [phi_i, theta_i]
        sample = um if self._uniform else self._vndf.invert(um, par)
        out = np.stack([w.eval(sample, par) for w in self._spectra], axis=-1)
        if self.jacobian:
            u_wi = np.stack([np.sqrt(theta_i * (2 / np.pi)), (phi_i + np.pi) / (2 * np.pi)], -1)
            out = out * (self._ndf.eval(um, []) / (4 * self._sigma.eval(u_wi, [])))[..., None]
        return np.where(active[..., None], out, 0.0)

    def __call__(self, wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
        """f_r (sr⁻¹): :meth:`eval_cos` / cos θo; ``(...)`` for a grey file, else ``(..., n)``."""
        wo = np.asarray(wo, dtype=np.float64)
        v = self.eval_cos(wi, wo)
        cos_o = wo[..., 2]
        f = np.where(cos_o[..., None] > 0, v / np.where(cos_o > 0, cos_o, 1.0)[..., None], 0.0)
        return f[..., 0] if self.kind == "grey" else f


def read_bsdf(path: str | os.PathLike) -> MeasuredTable:
    """Read a measured BSDF file (gonio's or the RGL database's), checked as the plugin does."""
    path = Path(path)
    f = read_tensor(path)
    need = ("description", "theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "jacobian")
    missing = [k for k in need if k not in f]
    spectral = "wavelengths" in f
    values = "spectra" if spectral else "rgb"
    if values not in f:
        missing.append(values)
    if missing:
        raise ValueError(f"{path}: not a measured BSDF file, missing field(s) {missing}")
    v = f[values]
    nti, npi = len(f["theta_i"]), len(f["phi_i"])
    nch = len(f["wavelengths"]) if spectral else 3
    f32 = np.dtype("<f4")
    checks = [
        (f["description"].ndim == 1 and f["description"].dtype == np.uint8, "description"),
        (f["theta_i"].ndim == 1 and f["theta_i"].dtype == f32, "theta_i: 1-D float32"),
        (f["phi_i"].ndim == 1 and f["phi_i"].dtype == f32, "phi_i: 1-D float32"),
        (f["ndf"].ndim == 2 and f["ndf"].dtype == f32, "ndf: 2-D float32"),
        (f["sigma"].ndim == 2 and f["sigma"].dtype == f32, "sigma: 2-D float32"),
        (
            f["vndf"].ndim == 4 and f["vndf"].dtype == f32 and f["vndf"].shape[:2] == (npi, nti),
            "vndf: float32 (n_phi_i, n_theta_i, n_y, n_x)",
        ),
        (
            f["luminance"].ndim == 4
            and f["luminance"].dtype == f32
            and f["luminance"].shape[:2] == (npi, nti),
            "luminance: float32 (n_phi_i, n_theta_i, n, n)",
        ),
        (
            v.ndim == 5 and v.dtype == f32 and v.shape[:3] == (npi, nti, nch),
            f"{values}: float32 (n_phi_i, n_theta_i, {nch}, n_y, n_x)",
        ),
        (f["jacobian"].shape == (1,) and f["jacobian"].dtype == np.uint8, "jacobian: 1 uint8"),
    ]
    if spectral:
        checks.append((f["wavelengths"].ndim == 1 and f["wavelengths"].dtype == f32, "wl"))
    bad = [what for ok, what in checks if not ok]
    if bad:
        raise ValueError(f"{path}: invalid measured BSDF file structure: {bad}")
    for k in ("theta_i", "phi_i", values):
        if not np.isfinite(f[k]).all():
            raise ValueError(f"{path}: field {k!r} holds non-finite values")
    meta: dict = {}
    if "gonio" in f:
        from gonio.io.jsonfile import loads

        try:
            meta = loads(bytes(f["gonio"]).decode(), f"{path}: field 'gonio'")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: field 'gonio' is not JSON ({exc})") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: field 'gonio' is not a JSON object")
    kind = "spectral" if spectral else ("grey" if meta.get("channels") == "grey" else "rgb")
    wl = np.asarray(f["wavelengths"], np.float64) if spectral else None
    return MeasuredTable(f, kind, wl, meta)


# --------------------------------------------------------------------------- writing
def _check_resolution(n: int, name: str, least: int = 2) -> int:
    if isinstance(n, bool) or int(n) != n or n < least:
        raise ValueError(f"{name} must be an integer >= {least}, got {n!r}")
    return int(n)


def _half_vector_grid(n_y: int, n_x: int) -> tuple[NDArray, NDArray]:
    """(θm, φm) of the nodes ``(n_y, n_x)``: x = sqrt(2θ/π), y = (φ + π)/2π."""
    ux = np.linspace(0.0, 1.0, n_x)
    uy = np.linspace(0.0, 1.0, n_y)
    return np.broadcast_to(ux**2 * (np.pi / 2), (n_y, n_x)), np.broadcast_to(
        (2 * uy - 1) * np.pi, (n_x, n_y)
    ).T


def _slice_directions(
    theta_i: float, phi_i: float, theta_m: NDArray, phi_m: NDArray, isotropic: bool
) -> tuple[NDArray, NDArray, NDArray]:
    """wi, the grid's wo (reflected about m), and wi·m, for one incident slice."""
    st = np.sin(theta_i)
    wi = np.array([st * np.cos(phi_i), st * np.sin(phi_i), np.cos(theta_i)])
    pm = phi_m + (phi_i if isotropic else 0.0)
    m = np.stack([np.sin(theta_m) * np.cos(pm), np.sin(theta_m) * np.sin(pm), np.cos(theta_m)], -1)
    dot = m @ wi
    wo = 2.0 * dot[..., None] * m - wi
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    return np.broadcast_to(wi, wo.shape), wo, dot


def _luminance(values: NDArray, kind: str, theta_m: NDArray, dot: NDArray) -> NDArray:
    """Sampling density per slice: the luminance of f_r cos θo times the Jacobian of u -> wo.

    ``Measured::pdf`` divides the luminance warp's density by 2π² u sin θm · 4 (wi·m); a
    luminance proportional to that product samples wo in proportion to f_r cos θo. A floor
    of 1e-3 of the slice's mean keeps every slice (and its dark cells) sampleable.
    """
    if kind == "spectral":
        y = values.mean(axis=0)
    else:
        y = 0.2126 * values[0] + 0.7152 * values[1] + 0.0722 * values[2]
    y = np.maximum(y, 0.0)
    y = y + 1e-3 * max(float(y.mean()), 1e-12)
    ux = np.sqrt(theta_m * 2 / np.pi)
    jac = np.maximum(2 * np.pi**2 * ux * np.sin(theta_m), 1e-6) * 4 * np.maximum(dot, 1e-6)
    return y * jac


def _fields(
    values: NDArray,
    theta_i: NDArray,
    phi_i: NDArray,
    kind: str,
    wavelengths: NDArray | None,
    luminance: NDArray,
    description: str,
    meta: dict,
) -> dict[str, Any]:
    """The tensor fields of a uniform-VNDF, Jacobian-off table of f_r cos θo."""
    npi, nti, _, ny, nx = values.shape
    f: dict[str, Any] = {
        "description": description,
        "jacobian": np.zeros(1, np.uint8),
        "phi_i": np.asarray(phi_i, np.float32),
        "theta_i": np.asarray(theta_i, np.float32),
        "ndf": np.ones((ny, nx), np.float32),
        "sigma": np.ones((ny, nx), np.float32),
        "vndf": np.ones((npi, nti, ny, nx), np.float32),
        "luminance": np.asarray(luminance, np.float32),
    }
    if kind == "spectral":
        f["wavelengths"] = np.asarray(wavelengths, np.float32)
        f["spectra"] = np.asarray(values, np.float32)
    else:
        f["rgb"] = np.asarray(values, np.float32)
    f["gonio"] = json.dumps({"channels": kind, **meta})
    return f


def _channels_of(values: NDArray, wl: NDArray | None, channels: str) -> tuple[NDArray, str]:
    """Values ``(..., n)`` (or ``(...)`` grey) as the file's channels first: ``(c, ...)``."""
    from gonio.colour import spectrum_to_linear_srgb

    if wl is None:
        if channels == "spectral":
            raise ValueError("channels='spectral' needs a spectral source; this one is grey")
        if channels == "rgb":
            return np.broadcast_to(values, (3, *values.shape)), "rgb"
        return np.broadcast_to(values, (3, *values.shape)), "grey"
    if channels in ("grey",):
        raise ValueError("channels='grey' needs a grey source; this one is spectral")
    if channels == "rgb":
        return np.moveaxis(spectrum_to_linear_srgb(values, wl), -1, 0), "rgb"
    return np.moveaxis(values, -1, 0), "spectral"


def _source_wavelengths(wl: NDArray | None, channels: str | None) -> str:
    if channels is None:
        return "grey" if wl is None else "spectral"
    if channels not in ("grey", "rgb", "spectral"):
        raise ValueError(f"channels must be 'grey', 'rgb' or 'spectral', got {channels!r}")
    if channels == "spectral" and wl is None:
        raise ValueError("channels='spectral' needs a spectral source; this one is grey")
    if channels == "grey" and wl is not None:
        raise ValueError("channels='grey' needs a grey source; this one is spectral")
    return channels


def model_table(
    model,
    resolution: int = DEFAULT_RESOLUTION,
    n_theta_i: int = DEFAULT_THETA_I,
    n_phi_i: int | None = None,
    channels: str | None = None,
    description: str | None = None,
) -> dict[str, Any]:
    """The tensor fields of a BRDF model tabulated on the measured plugin's grid.

    Parameters
    ----------
    model : gonio.brdf.BRDF
        Any model (grey or spectral).
    resolution : int
        Half-vector grid: ``resolution × resolution`` nodes of the unit square.
    n_theta_i : int
        Incident elevations, evenly spaced over [0, :data:`THETA_I_MAX`].
    n_phi_i : int or None
        ``None``: isotropic (the model is evaluated at φi = 0 and the half vector's azimuth
        is relative to the incident one; for isotropic models). Else that many incident
        azimuths over [-π, π] (an anisotropic table, no symmetry assumed).
    channels : {"grey", "rgb", "spectral"} or None
        ``None``: grey for a grey model, spectral for a spectral one; ``"rgb"``: linear sRGB
        (:func:`gonio.colour.spectrum_to_linear_srgb`, D65-adapted).
    """
    n = _check_resolution(resolution, "resolution")
    nti = _check_resolution(n_theta_i, "n_theta_i")
    iso = n_phi_i is None
    npi = 1 if iso else _check_resolution(n_phi_i, "n_phi_i", 3)
    wl = model.wavelengths_nm
    kind = _source_wavelengths(wl, channels)
    theta_i = np.linspace(0.0, THETA_I_MAX, nti)
    reduction = 1 if iso else (4 if _mirror_symmetric(model) else 1)
    phi_i = np.array([0.0]) if iso else np.linspace(-np.pi, -np.pi + 2 * np.pi / reduction, npi)
    theta_m, phi_m = _half_vector_grid(n, n)
    nch = len(wl) if kind == "spectral" else 3
    values = np.zeros((npi, nti, nch, n, n))
    lum = np.zeros((npi, nti, n, n))
    for a, p in enumerate(phi_i):
        for b, t in enumerate(theta_i):
            wi, wo, dot = _slice_directions(t, p, theta_m, phi_m, iso)
            fc = _cosine_weighted(model, wi, wo, wl is None)
            v, kind = _channels_of(fc, wl, kind)
            values[a, b] = v
            lum[a, b] = _luminance(v, kind, theta_m, dot)
    meta = {"source": "model", "model": model.name, "params": _jsonable(model.params)}
    if not iso:
        meta["symmetry_reduction"] = reduction
    desc = description or f"gonio: model {model.name} tabulated ({kind})"
    wl_out = wl if kind == "spectral" else None
    return _fields(values, theta_i, phi_i, kind, wl_out, lum, desc, meta)


def is_isotropic(model, n: int = 512) -> bool:
    """Whether f_r is unchanged by a rotation of wi and wo together about the normal.

    Checked at ``n`` random direction pairs and random rotations to 1e-9 relative.
    """
    from gonio.geometry import sample_uniform_hemisphere

    rng = np.random.default_rng(54321)
    wi = sample_uniform_hemisphere(n, rng)[0]
    wo = sample_uniform_hemisphere(n, rng)[0]
    a = rng.uniform(0, 2 * np.pi, n)
    c, s = np.cos(a), np.sin(a)

    def rot(w: NDArray) -> NDArray:
        return np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], -1)

    f = np.asarray(model(wi, wo))
    g = np.asarray(model(rot(wi), rot(wo)))
    return bool(np.allclose(f, g, rtol=1e-9, atol=1e-12 * float(np.abs(f).max() or 1.0)))


def _mirror_symmetric(model, n: int = 512) -> bool:
    """Whether f_r is unchanged by the mirrors x -> -x and y -> -y (of wi and wo together).

    Then an anisotropic table holds a quarter of the incident azimuths, φi in [-π, -π/2]
    (Mitsuba's symmetry reduction 4, which mirrors every query into that quarter).
    Checked at ``n`` random direction pairs to 1e-9 relative.
    """
    from gonio.geometry import sample_uniform_hemisphere

    rng = np.random.default_rng(12345)
    wi = sample_uniform_hemisphere(n, rng)[0]
    wo = sample_uniform_hemisphere(n, rng)[0]
    f = np.asarray(model(wi, wo))
    for s in ([-1.0, 1.0, 1.0], [1.0, -1.0, 1.0]):
        g = np.asarray(model(wi * s, wo * s))
        if not np.allclose(f, g, rtol=1e-9, atol=1e-12 * float(np.abs(f).max() or 1.0)):
            return False
    return True


def _cosine_weighted(model, wi: NDArray, wo: NDArray, grey: bool) -> NDArray:
    """f_r cos θo at the nodes; 0 where wo is below the horizon.

    (A continuation below the horizon, f_r at the horizon times a negative cos θo, was tried:
    for a Ward lobe f_r grows as 1/sqrt(cos θo) at the horizon and the continued nodes
    spoiled their cells, worst error 613x instead of 173x on 2000 random pairs.)
    """
    up = wo[..., 2] > 0
    f = np.asarray(model(wi, np.where(up[..., None], wo, [0.0, 0.0, 1.0])), np.float64)
    if not np.isfinite(f).all():
        raise ValueError(f"model {model.name!r} gave non-finite values on the grid")
    cos_o = np.where(up, wo[..., 2], 0.0)
    return f * (cos_o if grey else cos_o[..., None])


def _jsonable(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        a = np.asarray(v) if not isinstance(v, str | os.PathLike) else None
        if a is not None and a.dtype.kind in "fiu":
            out[k] = a.tolist()
        else:
            out[k] = str(v)
    return out


def samples_table(
    samples,
    resolution: int = DEFAULT_RESOLUTION,
    channels: str | None = None,
    isotropic: bool | None = None,
    description: str | None = None,
) -> dict[str, Any]:
    """The tensor fields of measured samples interpolated onto the plugin's grid.

    Each incident direction of the samples is one slice (``theta_i``/``phi_i`` are the
    measured ones; Mitsuba interpolates linearly between them and holds the end slices
    beyond them). In a slice, f_r cos θo of the samples is interpolated linearly (Delaunay
    triangles) in the plane of the half vector's coordinates (sqrt(2θm/π) as radius, φm as
    angle: continuous through the normal); an isotropic slice is mirrored (φm -> -φm, the
    bilateral symmetry of an isotropic BRDF). Nodes outside the measured region take the
    nearest measured value; the ``coverage`` (the fraction of nodes whose wo is above the
    horizon that lie inside it), per slice and overall, is in the file's ``gonio`` field.

    Parameters
    ----------
    samples : gonio.samples.BRDFSamples
        Grey or spectral (every direction pair with every band).
    resolution : int
        Half-vector grid ``resolution × resolution``.
    channels : {"grey", "rgb", "spectral"} or None
        As :func:`model_table`.
    isotropic : bool or None
        ``None``: isotropic when all samples share one incident azimuth or when their incident
        directions are not on a θi × φi product grid (``isotropic_assumed`` in the metadata);
        anisotropic otherwise. An anisotropic table needs the product grid. Samples all in
        one plane (an incidence-plane plan) cover only the nodes on that plane; the others
        take the nearest sample.
    """
    import scipy.interpolate  # noqa: F401  (loads SciPy's OpenBLAS before it is limited)
    from threadpoolctl import threadpool_limits

    # Delaunay's barycentric transforms are one tiny LAPACK call per triangle: on a threaded
    # OpenBLAS each waits for its threads (6.4 s for 6774 triangles on a shared 2-core
    # machine, 0.018 s on one thread). threadpoolctl limits the libraries loaded when it
    # starts, hence the import above.
    with threadpool_limits(1, "blas"):
        return _samples_table(samples, resolution, channels, isotropic, description)


def _samples_table(samples, resolution, channels, isotropic, description) -> dict[str, Any]:
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
    from scipy.spatial import QhullError

    n = _check_resolution(resolution, "resolution")
    if len(samples) == 0:
        raise ValueError("samples: the table is empty")
    geo = np.stack([samples.theta_i, samples.phi_i, samples.theta_o, samples.phi_o], -1)
    geo = np.round(geo, 9)
    if samples.wavelength_nm is None:
        wl = None
        key, inv = np.unique(geo, axis=0, return_inverse=True)
        inv = inv.ravel()
        vals = np.bincount(inv, samples.value) / np.bincount(inv)
        vals = vals[:, None]
    else:
        wl, band = np.unique(samples.wavelength_nm, return_inverse=True)
        key, inv = np.unique(geo, axis=0, return_inverse=True)
        inv = inv.ravel()
        sums = np.zeros((len(key), len(wl)))
        counts = np.zeros_like(sums)
        np.add.at(sums, (inv, band.ravel()), samples.value)
        np.add.at(counts, (inv, band.ravel()), 1.0)
        if np.any(counts == 0):
            raise ValueError(
                "samples: a spectral table needs every band at every direction pair; "
                f"{int(np.count_nonzero((counts == 0).any(axis=1)))} pair(s) miss band(s)"
            )
        vals = sums / counts
    kind = _source_wavelengths(wl, channels)
    ti_all, pi_all = key[:, 0], np.mod(key[:, 1] + np.pi, 2 * np.pi) - np.pi
    pi_all = np.where(np.isclose(pi_all, -np.pi), np.pi, pi_all)
    inc, inc_inv = np.unique(np.stack([ti_all, pi_all], -1), axis=0, return_inverse=True)
    inc_inv = inc_inv.ravel()
    thetas = np.unique(inc[:, 0])
    phis = np.unique(inc[:, 1])
    grid = len(thetas) * len(phis) == len(inc)
    assumed = isotropic is None and len(phis) > 1 and not grid
    if isotropic is None:
        # one incident azimuth, or azimuths not on a θi × φi grid (an incidence-plane plan
        # of an isotropic sample): isotropic, and the metadata says it was assumed
        isotropic = len(phis) == 1 or not grid
    if isotropic:
        phis = np.array([0.0])
    elif len(thetas) * len(phis) != len(inc):
        raise ValueError(
            f"samples: an anisotropic table needs the incident directions on a θi × φi grid; "
            f"got {len(inc)} directions over {len(thetas)} θi and {len(phis)} φi"
        )
    theta_m, phi_m = _half_vector_grid(n, n)
    nch = len(wl) if kind == "spectral" else 3
    values = np.zeros((len(phis), len(thetas), nch, n, n))
    lum = np.zeros((len(phis), len(thetas), n, n))
    covered = np.zeros((len(phis), len(thetas)))
    wi_s, wo_s = samples_dirs(key)
    quarter = not isotropic and bool(np.all((phis >= -1e-9) & (phis <= np.pi / 2 + 1e-9)))
    phis_out = phis
    if quarter:
        # incident azimuths within [0, π/2]: the measurement's assumption of a BRDF symmetric
        # under the x and y mirrors, which Mitsuba applies as symmetry reduction 4 (queries
        # mirrored into φi in [-π, -π/2]); the data are turned by π (a symmetry then) to it
        wi_s, wo_s = wi_s * [-1.0, -1.0, 1.0], wo_s * [-1.0, -1.0, 1.0]
        phis_out = phis - np.pi
    for b, t in enumerate(thetas):
        for a, p in enumerate(phis):
            sel = (inc[:, 0] == t) & (isotropic | (inc[:, 1] == p))
            rows = np.isin(inc_inv, np.flatnonzero(sel))
            if not rows.any():
                raise ValueError(f"samples: no samples at θi = {t:.6g} rad")
            wi, wo = wi_s[rows], wo_s[rows]
            m = wi + wo
            m /= np.linalg.norm(m, axis=-1, keepdims=True)
            r = np.sqrt(_elevation(m) * 2 / np.pi)
            az = np.arctan2(m[:, 1], m[:, 0])
            if isotropic:
                az = az - np.arctan2(wi[:, 1], wi[:, 0])
            fc = vals[rows] * wo[:, 2:3]
            pts = np.stack([r * np.cos(az), r * np.sin(az)], -1)
            if isotropic:
                pts = np.concatenate([pts, pts * [1.0, -1.0]])
                fc = np.concatenate([fc, fc])
            pts, first = np.unique(np.round(pts, 12), axis=0, return_index=True)
            fc = fc[first]
            if len(pts) < 3:
                raise ValueError(f"samples: fewer than 3 directions at θi = {t:.6g} rad")
            p_out = 0.0 if isotropic else phis_out[a]
            _, wo_g, dot = _slice_directions(t, p_out, theta_m, phi_m, isotropic)
            up = wo_g[..., 2] > 0
            ur = np.sqrt(theta_m * 2 / np.pi)
            q = np.stack([ur * np.cos(phi_m), ur * np.sin(phi_m)], -1)
            try:
                inside = LinearNDInterpolator(pts, fc)(q)
            except QhullError:  # all on a line (an in-plane plan): no triangle covers a node
                inside = np.full((*q.shape[:-1], fc.shape[1]), np.nan)
            hit = np.isfinite(inside).all(axis=-1)
            near = NearestNDInterpolator(pts, fc)(q)
            g = np.where(hit[..., None], inside, near)
            g = np.where(up[..., None], g, 0.0)
            covered[a, b] = np.count_nonzero(hit & up) / max(np.count_nonzero(up), 1)
            v, kind = _channels_of(g if wl is not None else g[..., 0], wl, kind)
            values[a, b] = v
            lum[a, b] = _luminance(v, kind, theta_m, dot)
    if quarter:
        values, lum, phis = _pad_quarter(values, lum, phis_out)
    elif not isotropic:
        # wrap the azimuths around: Mitsuba reads φi in [-π, π] and holds the end slices
        values, lum, phis = _wrap_phi(values, lum, phis)
    meta = {
        "source": "samples",
        "coverage": float(covered.mean()),
        "coverage_per_slice": covered.round(4).tolist(),
        "isotropic": bool(isotropic),
        "isotropic_assumed": bool(assumed),
        "symmetry_reduction": 4 if quarter else 1,
    }
    desc = description or f"gonio: measured samples ({kind})"
    return _fields(values, thetas, phis, kind, wl if kind == "spectral" else None, lum, desc, meta)


def samples_dirs(key: NDArray) -> tuple[NDArray, NDArray]:
    """wi, wo of rows (θi, φi, θo, φo)."""
    from gonio.geometry import to_vector

    return to_vector(key[:, 0], key[:, 1]), to_vector(key[:, 2], key[:, 3])


def _pad_quarter(values: NDArray, lum: NDArray, phis: NDArray):
    """End slices at exactly -π and -π/2 (copies: Mitsuba holds the end slices anyway)."""
    if phis[0] > -np.pi + 1e-9:
        values, lum = np.concatenate([values[:1], values]), np.concatenate([lum[:1], lum])
        phis = np.concatenate([[-np.pi], phis])
    if phis[-1] < -np.pi / 2 - 1e-9:
        values, lum = np.concatenate([values, values[-1:]]), np.concatenate([lum, lum[-1:]])
        phis = np.concatenate([phis, [-np.pi / 2]])
    phis = phis.copy()
    phis[0], phis[-1] = -np.pi, -np.pi / 2
    return values, lum, phis


def _wrap_phi(values: NDArray, lum: NDArray, phis: NDArray):
    """Add the periodic copies of the first/last azimuth slices at φ ∓ 2π."""
    if phis[0] > -np.pi:
        values = np.concatenate([values[-1:], values])
        lum = np.concatenate([lum[-1:], lum])
        phis = np.concatenate([[phis[-1] - 2 * np.pi], phis])
    if phis[-1] < np.pi:
        values = np.concatenate([values, values[1:2] if phis[0] < -np.pi else values[:1]])
        lum = np.concatenate([lum, lum[1:2] if phis[0] < -np.pi else lum[:1]])
        phis = np.concatenate([phis, [(phis[1] if phis[0] < -np.pi else phis[0]) + 2 * np.pi]])
    return values, lum, phis


def coverage_summary(fields: dict[str, Any]) -> dict:
    """The ``gonio`` metadata of a table made by :func:`model_table`/:func:`samples_table`."""
    return json.loads(fields["gonio"])


def write_bsdf(path: str | os.PathLike, fields: dict[str, Any]) -> Path:
    """Write the fields of :func:`model_table` or :func:`samples_table` (atomic)."""
    path = Path(path)
    if path.suffix.lower() != ".bsdf":
        raise ValueError(f"measured BSDF file {str(path)!r}: expected a .bsdf suffix")
    return write_tensor(path, fields)
