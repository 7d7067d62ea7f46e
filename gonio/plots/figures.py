"""Campaign plots (matplotlib, Agg, PNG): Ward Fig. 6 slices, hemisphere maps, residuals.

- :func:`plot_incidence_plane`: measured samples near the plane of incidence and the fitted
  model along that plane, for six incidence angles, log BRDF axis (Ward's Figure 6,
  Ward 1992, §4; one panel per sample rotation φi).
- :func:`plot_hemisphere`: the reduced samples of each incidence angle on the hemisphere of
  outgoing directions (azimuthal equidistant map, colour = log10 BRDF).
- :func:`plot_residuals`: normalised residuals ``(f − y)/σ`` (or relative ones without σ)
  against θo and their histogram.

Every function writes the PNG atomically and returns its path. Matplotlib is imported
inside the functions (its import costs ~0.5 s) and only the object-oriented API with the
Agg canvas is used, so nothing depends on a display.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §4, Figure 6: measured data and the fitted model near the plane of incidence.
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.geometry import to_vector
from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = [
    "hemisphere_keys",
    "hemisphere_map",
    "incidence_plane_mask",
    "pick_angles",
    "plot_hemisphere",
    "plot_incidence_plane",
    "plot_residuals",
]


def _figure(w: float, h: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=80)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: str | os.PathLike) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return atomic_write_bytes(path, buf.getvalue())


def _check(samples: BRDFSamples) -> None:
    if not isinstance(samples, BRDFSamples):
        raise ValueError(f"samples must be a BRDFSamples table, got {type(samples).__name__}")
    if len(samples) == 0:
        raise ValueError("samples is empty; nothing to plot")


def pick_angles(values: NDArray, n: int = 6) -> list[float]:
    """Up to ``n`` of the distinct values, spread evenly over their range."""
    u = np.unique(np.round(np.asarray(values, float), 9))
    if len(u) <= n:
        return u.tolist()
    idx = np.unique(np.round(np.linspace(0, len(u) - 1, n)).astype(int))
    return u[idx].tolist()


def incidence_plane_mask(samples: BRDFSamples, tol: float = np.radians(5.0)) -> NDArray:
    """Rows whose outgoing direction lies within ``tol`` (rad) of the plane of incidence."""
    d = samples.phi_o - samples.phi_i
    # distance of the azimuth difference from 0 or pi, measured on the hemisphere
    off = np.abs(np.sin(d)) * np.sin(samples.theta_o)
    return off <= np.sin(tol)


def _signed_theta_o(samples: BRDFSamples) -> NDArray:
    """θo, positive on the specular side of the normal, negative towards the source."""
    side = np.cos(samples.phi_o - samples.phi_i) < 0
    return np.where(side, samples.theta_o, -samples.theta_o)


def plot_incidence_plane(
    samples: BRDFSamples,
    model: Any | None,
    path: str | os.PathLike,
    *,
    n_angles: int = 6,
    tol: float = np.radians(0.5),
    max_points: int = 300,
    title: str = "",
) -> Path:
    """Ward Fig. 6: BRDF in the plane of incidence at up to six θi, log axis.

    ``model`` (a BRDF or ``None``) is drawn as continuous curves; measured points are the
    samples within ``tol`` of the plane (at most ``max_points`` per θi, a seeded subset).
    One panel per distinct sample azimuth φi. The band is narrow because near grazing an
    anisotropic lobe is narrow across the plane: for rolled brass (α = 0.05 across) at
    θi = 80°, a point 1.5° of azimuth off the plane has a BRDF 2.0× below the in-plane value
    at θo = 66° and 8.9× below at θo = 80°, so a 2° band scattered the points far from the
    in-plane curve.
    """
    _check(samples)
    phis = pick_angles(samples.phi_i, 4)
    fig = _figure(5.5 * len(phis), 4.5)
    import matplotlib as mpl

    cmap = mpl.colormaps["viridis"]
    inplane = incidence_plane_mask(samples, tol)
    for k, phi in enumerate(phis):
        ax = fig.add_subplot(1, len(phis), k + 1)
        rows = np.isclose(samples.phi_i, phi, atol=1e-6)
        angles = pick_angles(samples.theta_i[rows], n_angles)
        for j, ti in enumerate(angles):
            c = cmap(j / max(len(angles) - 1, 1))
            sel = np.flatnonzero(rows & inplane & np.isclose(samples.theta_i, ti, atol=1e-6))
            if len(sel) > max_points:  # a fixed-seed subset keeps the curves visible
                sel = np.sort(np.random.default_rng(j).choice(sel, max_points, replace=False))
            sub = samples.subset(sel)
            pos = sub.value > 0
            ax.plot(
                np.degrees(_signed_theta_o(sub))[pos],
                sub.value[pos],
                "o",
                ms=2.5,
                color=c,
                alpha=0.6,
                label=f"θi = {np.degrees(ti):.0f}°",
            )
            if model is not None:
                t = np.radians(np.linspace(-89.5, 89.5, 359))
                wo = to_vector(np.abs(t), np.where(t >= 0, phi + np.pi, phi))
                wi = to_vector(np.full_like(t, ti), np.full_like(t, phi))
                f = np.asarray(model(wi, wo), dtype=float)
                if f.ndim > 1:
                    f = f.mean(axis=-1)
                ok = f > 0
                ax.plot(np.degrees(t)[ok], f[ok], "-", color=c, lw=1.2)
        log_axis(ax)
        ax.set_xlim(-90, 90)
        ax.set_xlabel("θo in the plane of incidence (deg; + = specular side)")
        ax.set_ylabel("BRDF (sr⁻¹)")
        ax.set_title(f"{title}  φi = {np.degrees(phi):.0f}°".strip())
        ax.legend(fontsize=7, loc="upper left")
        ax.grid(True, which="major", alpha=0.3)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.12, top=0.92, wspace=0.22)
    return _save(fig, path)


def hemisphere_keys(samples: BRDFSamples, max_panels: int = 24) -> NDArray[np.float64]:
    """The distinct (θi, φi) of ``samples`` (rows, sorted), at most ``max_panels`` of them
    spread evenly over the sorted list."""
    pairs = np.round(np.stack([samples.phi_i, samples.theta_i], 1), 9)
    # a table holds runs of equal incidence (one per capture): sort only the run heads
    head = np.ones(len(pairs), dtype=bool)
    head[1:] = (pairs[1:] != pairs[:-1]).any(axis=1)
    keys = np.unique(pairs[head], axis=0)[:, ::-1]
    if len(keys) > max_panels:
        keys = keys[np.unique(np.round(np.linspace(0, len(keys) - 1, max_panels)).astype(int))]
    return keys


def hemisphere_map(
    samples: BRDFSamples, theta_i: float, phi_i: float, bins: int = 36
) -> NDArray[np.float64]:
    """Mean log10 BRDF of the samples at (``theta_i``, ``phi_i``) on a ``bins × bins`` grid.

    Azimuthal equidistant projection of the outgoing direction: ``x = θo cos φo``,
    ``y = θo sin φo`` in degrees, cells of width ``180/bins`` over ``[-90, 90]²`` (the last
    cell includes 90, as :func:`numpy.histogram2d` counts). Row ``k`` is ``y`` bin ``k``
    (origin at the bottom). Cells without a positive sample are NaN.
    """
    sel = np.isclose(samples.theta_i, theta_i, atol=1e-6) & np.isclose(
        samples.phi_i, phi_i, atol=1e-6
    )
    sel &= samples.value > 0
    r = np.degrees(samples.theta_o[sel])
    phi = samples.phi_o[sel]
    scale = bins / 180.0
    ix = np.clip(((r * np.cos(phi) + 90.0) * scale).astype(np.int64), 0, bins - 1)
    iy = np.clip(((r * np.sin(phi) + 90.0) * scale).astype(np.int64), 0, bins - 1)
    cell = iy * bins + ix
    tot = np.bincount(cell, weights=np.log10(samples.value[sel]), minlength=bins * bins)
    cnt = np.bincount(cell, minlength=bins * bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        img = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return img.reshape(bins, bins)


def plot_hemisphere(
    samples: BRDFSamples,
    path: str | os.PathLike,
    *,
    max_panels: int = 24,
    bins: int = 24,
    title: str = "",
) -> Path:
    """One map per (θi, φi) of the reduced samples over the outgoing hemisphere.

    Azimuthal equidistant projection (radius ∝ θo, angle = φo in the sample frame);
    colour = mean log10 of the BRDF over the samples in each of ``bins × bins`` cells
    (:func:`hemisphere_map`; empty cells and non-positive values blank). The maps are laid
    out as one mosaic image in one axes (12 separate axes took 0.2 s of CPU to draw, most
    of it matplotlib's per-axes bookkeeping).
    """
    from matplotlib.patches import Circle

    _check(samples)
    keys = hemisphere_keys(samples, max_panels)
    n = len(keys)
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    pos = samples.value > 0
    lv = np.log10(samples.value[pos]) if pos.any() else np.array([0.0])
    vmin, vmax = np.percentile(lv, [1, 99.9])
    gap = max(2, bins // 6)  # blank pixels between maps, room for the titles
    step = bins + gap
    mosaic = np.full((rows * step, cols * step), np.nan)
    fig = _figure(2.4 * cols + 1.0, 2.4 * rows + 0.5)
    ax = fig.add_axes((0.01, 0.02, 0.86, 0.9 if title else 0.96))
    for k, (ti, pi) in enumerate(keys):
        r0, c0 = (k // cols) * step + gap, (k % cols) * step + gap // 2
        mosaic[r0 : r0 + bins, c0 : c0 + bins] = hemisphere_map(samples, ti, pi, bins)[::-1]
        centre = (c0 + bins / 2 - 0.5, r0 + bins / 2 - 0.5)
        ax.add_patch(Circle(centre, bins / 2, fill=False, lw=0.5, color="0.5"))
        ax.text(centre[0], r0 - 0.5, f"θi {np.degrees(ti):.0f}° φi {np.degrees(pi):.0f}°",
                ha="center", va="bottom", fontsize=8)  # fmt: skip
    im = ax.imshow(mosaic, cmap="magma", vmin=vmin, vmax=vmax, interpolation="nearest")
    ax.set_axis_off()
    cax = fig.add_axes((0.89, 0.15, 0.025, 0.7))
    fig.colorbar(im, cax=cax, label="log10 BRDF (sr⁻¹)")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def decade_label(value: float, _pos: Any = None) -> str:
    """Tick label of a log axis without mathtext: ``10⁻²`` at a power of ten, else ``%g``.

    Matplotlib's default log labels are mathtext (``$10^{-2}$``), whose parser costs ~0.3 s
    of CPU to build in each new process; these unicode labels read the same.
    """
    if not (value > 0 and math.isfinite(value)):
        return ""
    e = math.log10(value)
    k = round(e)
    if abs(e - k) > 1e-9:
        return f"{value:g}"
    return "10" + str(k).translate(_SUPERSCRIPT)


def log_axis(ax: Any) -> None:
    """Make the y axis of ``ax`` logarithmic with decade ticks labelled by
    :func:`decade_label` and no minor ticks (they took half the drawing time)."""
    from matplotlib.ticker import FuncFormatter, NullLocator

    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(decade_label))
    ax.yaxis.set_minor_locator(NullLocator())


def plot_residuals(
    samples: BRDFSamples,
    model: Any,
    path: str | os.PathLike,
    *,
    max_points: int = 6000,
    title: str = "",
) -> Path:
    """Residuals of ``model`` against θo (coloured by θi) and their histogram.

    Normalised ``(f − y)/σ`` when the table has σ (a standard normal for a good fit and
    honest errors), else relative ``(f − y)/y``. The scatter shows a fixed-seed subset of
    at most ``max_points`` samples (drawing 20 000 points took 0.11 s of the plot's 0.22 s);
    the histogram and the rms use all.
    """
    _check(samples)
    from gonio.fit import predict

    f = predict(model, samples)
    if samples.has_sigma:
        r = (f - samples.value) / samples.sigma
        label = "(f − y)/σ"
    else:
        y = samples.value
        ok = np.abs(y) > 0
        r = np.where(ok, (f - y) / np.where(ok, y, 1.0), 0.0)
        label = "(f − y)/y"
    fig = _figure(10, 4)
    ax = fig.add_subplot(1, 2, 1)
    # scatter at most max_points residuals (a fixed-seed subset), the histogram uses all
    idx = np.arange(len(r))
    if len(r) > max_points:
        idx = np.sort(np.random.default_rng(0).choice(len(r), max_points, replace=False))
    sc = ax.scatter(
        np.degrees(samples.theta_o[idx]), r[idx], s=2, c=np.degrees(samples.theta_i[idx]),
        cmap="viridis", rasterized=True,
    )  # fmt: skip
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("θo (deg)")
    ax.set_ylabel(label)
    fig.colorbar(sc, ax=ax, label="θi (deg)")
    ax2 = fig.add_subplot(1, 2, 2)
    lim = np.percentile(np.abs(r), 99.5) if len(r) else 1.0
    ax2.hist(np.clip(r, -lim, lim), bins=60, color="C0")
    ax2.set_xlabel(label)
    ax2.set_ylabel("samples")
    ax2.set_title(f"rms {np.sqrt(np.mean(r**2)):.3g}, n = {len(r)}", fontsize=9)
    if title:
        fig.suptitle(title)
    fig.subplots_adjust(left=0.08, right=0.97, bottom=0.13, top=0.88, wspace=0.3)
    return _save(fig, path)
