"""MERL measured-BRDF binary files: read, write, index and tabulate.

The MERL format (W. Matusik, H. Pfister, M. Brand, L. McMillan, "A Data-Driven Reflectance
Model", SIGGRAPH 2003; the reference reader ``BRDFRead.cpp`` distributed with the MERL
database) is a little-endian file holding three ``int32`` dimensions ``(90, 90, 180)``
(θh, θd, φd) followed by ``3 × 90 × 90 × 180`` ``float64`` values, red block then green then
blue, each in C order over (θh, θd, φd). Stored values are multiplied by
``1/1500``, ``1.15/1500`` and ``1.66/1500`` (red, green, blue) to give the BRDF in sr⁻¹.

Lookup (``BRDFRead.cpp``), on the Rusinkiewicz half/difference angles of
:func:`gonio.geometry.difference_half_angles`:

* θh index ``floor(90 sqrt(θh / (π/2)))`` (finer near the specular peak), 0 for θh ≤ 0;
* θd index ``floor(90 θd / (π/2))``;
* φd folded to [0, π) by reciprocity, index ``floor(180 φd / π)``. ``BRDFRead.cpp`` adds π to
  negative φd and clamps φd = π to the last cell; here φd = π wraps to cell 0 (the same cell
  by the fold). θd and φd are computed in a form that is exactly symmetric under swapping
  ``wi`` and ``wo`` (see :func:`merl_angles`), so the lookup is reciprocal bit for bit, also
  for pairs on a cell boundary (in-plane directions have φd = 0 or π).

All indices are clamped to the grid. Arrays in this module use the file's layout:
``(3, 90, 90, 180)`` for colour data, ``(90, 90, 180)`` for a grey table; values in sr⁻¹
unless ``raw=True``. MERL stores unmeasured bins as negative numbers; they are kept by
:func:`read_merl` and treated as missing (value 0) by the ``tabulated`` model.

>>> import numpy as np
>>> from gonio.io.merl import SHAPE, merl_index
>>> SHAPE
(90, 90, 180)
>>> int(merl_index([0, 0, 1.0], [0, 0, 1.0])[1])
0
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio.geometry import from_difference_half_angles
from gonio.io.atomic import atomic_write_bytes

__all__ = [
    "N_PHI_D",
    "N_THETA_D",
    "N_THETA_H",
    "SCALES",
    "SHAPE",
    "WAVELENGTHS_NM",
    "cell_centres",
    "merl_angles",
    "merl_index",
    "read_merl",
    "tabulate",
    "write_merl",
]

N_THETA_H = 90
N_THETA_D = 90
N_PHI_D = 180
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
N_CELLS = N_THETA_H * N_THETA_D * N_PHI_D
#: factors turning stored values into sr⁻¹ (red, green, blue), from ``BRDFRead.cpp``
SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
#: band centres gonio assigns to MERL's red, green and blue channels (nm); a documented choice,
#: MERL gives no wavelengths (its camera filters are broad RGB bands)
WAVELENGTHS_NM = np.array([610.0, 550.0, 465.0])
_HEADER = np.dtype("<i4")
_DATA = np.dtype("<f8")
_FILE_BYTES = 3 * _HEADER.itemsize + 3 * N_CELLS * _DATA.itemsize


def read_merl(path: str | os.PathLike, raw: bool = False) -> NDArray[np.float64]:
    """Read a MERL binary file into an array of shape ``(3, 90, 90, 180)``.

    Parameters
    ----------
    path : str or path-like
        The ``.binary`` file.
    raw : bool
        Return the stored numbers instead of sr⁻¹ (no channel scale factors).

    Raises
    ------
    ValueError
        If the header dimensions are not ``(90, 90, 180)``, the file is truncated or too long,
        or holds non-finite values. Nothing partial is ever returned.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read MERL file {str(p)!r}: {exc}") from None
    if len(data) < 3 * _HEADER.itemsize:
        raise ValueError(
            f"MERL file {str(p)!r} is {len(data)} bytes, too short for its 12-byte header"
        )
    dims = tuple(int(d) for d in np.frombuffer(data[:12], dtype=_HEADER))
    if dims != SHAPE:
        raise ValueError(
            f"MERL file {str(p)!r} has header dimensions {dims}; expected {SHAPE} "
            "(theta_h, theta_d, phi_d)"
        )
    if len(data) != _FILE_BYTES:
        what = "truncated" if len(data) < _FILE_BYTES else "longer than its header says"
        raise ValueError(
            f"MERL file {str(p)!r} is {what}: {len(data)} bytes, expected {_FILE_BYTES} "
            f"(12-byte header + 3 x {N_CELLS} float64)"
        )
    arr = np.frombuffer(data, dtype=_DATA, offset=12).reshape((3, *SHAPE)).astype(np.float64)
    if not np.isfinite(arr).all():
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"MERL file {str(p)!r} holds {bad} non-finite value(s)")
    if not raw:
        arr *= SCALES[:, None, None, None]
    return arr


def _as_table(array: ArrayLike, name: str = "array") -> NDArray[np.float64]:
    """Validate a table on the MERL grid: ``(90, 90, 180)`` or ``(n, 90, 90, 180)``."""
    try:
        a = np.asarray(array, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array on the MERL grid: {exc}") from None
    if a.shape != SHAPE and not (a.ndim == 4 and a.shape[1:] == SHAPE and a.shape[0] >= 1):
        raise ValueError(
            f"{name} must have shape {SHAPE} (grey) or (n_bands, *{SHAPE}), got shape {a.shape}"
        )
    if not np.isfinite(a).all():
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(
            f"{name} contains {bad} non-finite value(s); MERL marks missing "
            "bins with negative numbers instead"
        )
    return a


def write_merl(path: str | os.PathLike, array: ArrayLike, raw: bool = False) -> Path:
    """Write ``array`` as a MERL binary file, atomically; return the path.

    Parameters
    ----------
    path : str or path-like
        Destination.
    array : array_like
        ``(3, 90, 90, 180)`` in sr⁻¹ (divided by :data:`SCALES` on writing), or a grey
        ``(90, 90, 180)`` table, written to all three channels.
    raw : bool
        ``array`` already holds stored numbers (no scale factors applied).
    """
    a = _as_table(array)
    if a.shape == SHAPE:
        a = np.broadcast_to(a, (3, *SHAPE))
    if a.shape[0] != 3:
        raise ValueError(f"array must have 3 channels (R, G, B) for MERL, got {a.shape[0]}")
    if not raw:
        a = a / SCALES[:, None, None, None]
    body = np.ascontiguousarray(a, dtype=_DATA).tobytes()
    header = np.asarray(SHAPE, dtype=_HEADER).tobytes()
    return atomic_write_bytes(path, header + body)


def merl_angles(wi: ArrayLike, wo: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """``(theta_h, theta_d, phi_d)`` with φd folded to [0, π), exactly symmetric in wi, wo.

    The same angles as :func:`gonio.geometry.difference_half_angles` (MERL's convention: the
    difference vector is wi rotated by −φh about z, then by −θh about y), computed without
    building rotated vectors: ``θh`` from the half vector, ``θd = atan2(|wi − wo|, |wi + wo|)``
    and ``φd`` the azimuth of ``wi − wo`` in the half-vector frame (that difference is twice
    the tangential part of the difference vector). The sign of ``wi − wo`` is canonicalised
    before ``atan2``, so the swapped pair — whose difference is the exact negative — gives
    bit-identical angles, also on a cell boundary. ``wi = −wo`` takes the normal as half
    vector (as :func:`~gonio.geometry.half_vector` does).
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    hx = wi[..., 0] + wo[..., 0]
    hy = wi[..., 1] + wo[..., 1]
    hz = wi[..., 2] + wo[..., 2]
    ux = wi[..., 0] - wo[..., 0]
    uy = wi[..., 1] - wo[..., 1]
    uz = wi[..., 2] - wo[..., 2]
    rxy = np.sqrt(hx * hx + hy * hy)
    hn = np.sqrt(rxy * rxy + hz * hz)
    zero = hn == 0.0
    th = np.where(zero, 0.0, np.arctan2(rxy, hz))
    td = np.arctan2(np.sqrt(ux * ux + uy * uy + uz * uz), hn)
    flat = rxy == 0.0
    r_safe = np.where(flat, 1.0, rxy)
    c_p = np.where(flat, 1.0, hx / r_safe)  # cos φh (φh = 0 on the pole)
    s_p = np.where(flat, 0.0, hy / r_safe)
    h_safe = np.where(zero, 1.0, hn)
    c_t = np.where(zero, 1.0, hz / h_safe)
    s_t = np.where(zero, 0.0, rxy / h_safe)
    x1 = c_p * ux + s_p * uy  # rotate by -φh about z
    y1 = c_p * uy - s_p * ux
    x2 = c_t * x1 - s_t * uz  # rotate by -θh about y
    flip = (y1 < 0.0) | ((y1 == 0.0) & (x2 < 0.0))
    pd = np.arctan2(np.where(flip, -y1, y1), np.where(flip, -x2, x2))
    pd = np.where(pd >= np.pi, 0.0, np.maximum(pd, 0.0))
    return th, td, pd


def merl_index(wi: ArrayLike, wo: ArrayLike) -> tuple[NDArray[np.bool_], NDArray[np.intp]]:
    """MERL cell of each direction pair: ``(valid, flat_index)``.

    ``flat_index`` indexes a ``(90*90*180,)`` table (C order over θh, θd, φd); ``valid`` is
    false where ``wi`` or ``wo`` is at or below the horizon (their index is 0). Angles from
    :func:`merl_angles`.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    th, td, pd = merl_angles(wi, wo)
    valid = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    valid = np.broadcast_to(valid, th.shape)
    i_h = np.sqrt(th * (1.0 / (0.5 * np.pi))) * N_THETA_H
    i_h = np.minimum(i_h, N_THETA_H - 1).astype(np.intp)
    i_d = np.minimum(td * (N_THETA_D / (0.5 * np.pi)), N_THETA_D - 1).astype(np.intp)
    i_p = np.minimum(pd * (N_PHI_D / np.pi), N_PHI_D - 1).astype(np.intp)
    flat = (i_h * N_THETA_D + i_d) * N_PHI_D + i_p
    return valid, np.where(valid, flat, 0)


def cell_centres() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(theta_h, theta_d, phi_d)`` of the centre of every cell (each of shape ``SHAPE``).

    Centres in MERL's index space: ``theta_h = ((i + ½)/90)² π/2``, ``theta_d = (j + ½)/90 π/2``,
    ``phi_d = (k + ½)/180 π``.
    """
    th = ((np.arange(N_THETA_H) + 0.5) / N_THETA_H) ** 2 * (0.5 * np.pi)
    td = (np.arange(N_THETA_D) + 0.5) / N_THETA_D * (0.5 * np.pi)
    pd = (np.arange(N_PHI_D) + 0.5) / N_PHI_D * np.pi
    return np.meshgrid(th, td, pd, indexing="ij")


def tabulate(model: Any, phi_h: float = 0.0, **params: Any) -> NDArray[np.float64]:
    """Evaluate a model at the centre of every MERL cell.

    Parameters
    ----------
    model : BRDF, str or callable
        Anything :func:`gonio.brdf.as_brdf` accepts (with ``params`` for a name).
    phi_h : float
        Azimuth of the half vector used for every cell (MERL tables are isotropic; an
        anisotropic model is sampled along this azimuth only).

    Returns
    -------
    ndarray
        ``(90, 90, 180)`` for a grey model, ``(n_bands, 90, 90, 180)`` for a spectral one,
        in sr⁻¹; 0 where the cell centre puts a direction below the horizon. Feeding it to
        ``brdf.create("tabulated", data=...)`` reproduces the model at cell resolution.
    """
    from gonio.brdf import as_brdf

    m = as_brdf(model, **params)
    th, td, pd = cell_centres()
    nb = m.n_bands
    out = np.empty(((nb,) if nb else ()) + SHAPE)
    for i in range(N_THETA_H):
        wi, wo = from_difference_half_angles(th[i], phi_h, td[i], pd[i])
        v = np.asarray(m(wi, wo), dtype=np.float64)
        if nb:
            out[:, i] = np.moveaxis(v, -1, 0)
        else:
            out[i] = v
    return out
