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
from collections.abc import Sequence
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


#: Resolution of the PNGs (dots per inch) unless a function is given ``dpi`` or the
#: environment sets ``GONIO_PLOT_DPI`` (``gonio campaign --plot-dpi``): 150 dpi puts a
#: single-column figure (3.5 in, 89 mm) at 525 pixels, enough for slides and a draft; 300 for
#: print (the figures took 1.1 s at 80 dpi and 3.9 s at 200 dpi in a small campaign).
DPI = 150.0

#: Width of a single-column figure and of a double-column one, inches (a journal's 89 mm and
#: 183 mm columns).
SINGLE, DOUBLE = 3.5, 7.2

#: Font sizes (points) for figures printed at their size: 8 pt text, 7 pt ticks and legends.
STYLE = {
    "font.size": 8.0,
    "axes.titlesize": 8.0,
    "axes.labelsize": 8.0,
    "xtick.labelsize": 7.0,
    "ytick.labelsize": 7.0,
    "legend.fontsize": 7.0,
    "figure.titlesize": 8.5,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "xtick.major.width": 0.6,
    "ytick.major.width": 0.6,
    "xtick.minor.width": 0.4,
    "ytick.minor.width": 0.4,
    "legend.frameon": False,
}


def plot_dpi(dpi: float | None = None) -> float:
    """``dpi``, else ``GONIO_PLOT_DPI`` from the environment, else :data:`DPI`; a value that
    is not a number in [50, 1200] raises ``ValueError`` naming it."""
    text = os.environ.get("GONIO_PLOT_DPI") if dpi is None else dpi
    if text is None or text == "":
        return DPI
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"plot dpi {text!r} is not a number") from None
    if not 50.0 <= v <= 1200.0:
        raise ValueError(f"plot dpi {v:g} is outside [50, 1200]")
    return v


def _figure(w: float, h: float, dpi: float | None = None):
    """A ``w x h`` inch figure on the Agg canvas, fonts of :data:`STYLE`."""
    import matplotlib as mpl
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with mpl.rc_context(STYLE):
        fig = Figure(figsize=(w, h), dpi=plot_dpi(dpi))
    FigureCanvasAgg(fig)
    return fig


def _style():
    """The context in which a figure's artists are made (:data:`STYLE`)."""
    import matplotlib as mpl

    return mpl.rc_context(STYLE)


def _save(fig: Any, path: str | os.PathLike) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
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


def _bands(samples: BRDFSamples, bands: Sequence[float] | None) -> list[float | None]:
    """The wavelengths (nm) to draw one panel each: ``bands`` (each the table's nearest), by
    default three spread over a spectral table (nearest 450, 550 and 650 nm); ``[None]`` for
    a grey table."""
    if samples.wavelength_nm is None:
        return [None]
    have = np.unique(samples.wavelength_nm)
    want = [450.0, 550.0, 650.0] if bands is None else list(bands)
    return sorted({float(have[np.abs(have - w).argmin()]) for w in want})


def _model_band(model: Any, f: NDArray, wl: float | None) -> NDArray:
    """A spectral model's values ``f`` (..., bands) at band ``wl`` (nm); the mean over bands
    for a grey table; ``f`` itself for a grey model."""
    if f.ndim == 1:
        return f
    mwl = getattr(model, "wavelengths_nm", None)
    if wl is None or mwl is None:
        return f.mean(axis=-1)
    return f[..., int(np.abs(np.asarray(mwl, float) - wl).argmin())]


def plot_incidence_plane(
    samples: BRDFSamples,
    model: Any | None,
    path: str | os.PathLike,
    *,
    n_angles: int = 6,
    tol: float = np.radians(0.5),
    max_points: int = 300,
    title: str = "",
    bands: Sequence[float] | None = None,
    dpi: float | None = None,
) -> Path:
    """Ward Fig. 6: BRDF in the plane of incidence at up to six θi, log axis.

    ``model`` (a BRDF or ``None``) is drawn as continuous curves; measured points are the
    samples within ``tol`` of the plane (at most ``max_points`` per θi, a seeded subset; the
    figure says how many it shows). One panel per distinct sample azimuth φi, or, for a
    spectral table, one per band of ``bands`` (nm; default three: :func:`_bands`), all
    panels on one BRDF axis. The band is narrow because near grazing an
    anisotropic lobe is narrow across the plane: for rolled brass (α = 0.05 across) at
    θi = 80°, a point 1.5° of azimuth off the plane has a BRDF 2.0× below the in-plane value
    at θo = 66° and 8.9× below at θo = 80°, so a 2° band scattered the points far from the
    in-plane curve.
    """
    _check(samples)
    with _style():
        return _incidence_plane(samples, model, path, n_angles, tol, max_points, title,
                                bands, dpi)  # fmt: skip


def _incidence_plane(samples, model, path, n_angles, tol, max_points, title, bands, dpi):
    import matplotlib as mpl
    from matplotlib.lines import Line2D

    wls = _bands(samples, bands)
    if wls == [None]:
        panels = [(phi, None) for phi in pick_angles(samples.phi_i, 4)]
    else:  # a spectral table: one panel per band, every φi (θo is signed from each φi)
        panels = [(None, wl) for wl in wls]
    n = len(panels)
    w = SINGLE if n == 1 else min(DOUBLE, 2.5 * n + 0.4)
    fig = _figure(w, 3.2 if n == 1 else 2.9, dpi)
    axes = fig.subplots(1, n, sharey=True, squeeze=False)[0]
    cmap = mpl.colormaps["viridis"]
    inplane = incidence_plane_mask(samples, tol)
    shown = total = 0
    y_lo, y_hi = np.inf, 0.0
    by_theta: dict[float, Any] = {}  # one legend entry and colour per θi, in every panel
    t_lo, t_hi = float(samples.theta_i.min()), float(samples.theta_i.max())
    for ax, (phi, wl) in zip(axes, panels):
        rows = inplane.copy()
        if phi is not None:
            rows &= np.isclose(samples.phi_i, phi, atol=1e-6)
        if wl is not None:
            rows &= np.isclose(samples.wavelength_nm, wl, atol=1e-6)
        angles = pick_angles(samples.theta_i[rows], n_angles) if rows.any() else []
        ok_y = np.empty(0)
        for j, ti in enumerate(angles):
            c = cmap(0.9 * (ti - t_lo) / (t_hi - t_lo) if t_hi > t_lo else 0.0)
            sel = np.flatnonzero(rows & np.isclose(samples.theta_i, ti, atol=1e-6))
            total += len(sel)
            if len(sel) > max_points:  # a fixed-seed subset keeps the curves visible
                sel = np.sort(np.random.default_rng(j).choice(sel, max_points, replace=False))
            shown += len(sel)
            sub = samples.subset(sel)
            pos = sub.value > 0
            if pos.any():
                ok_y = np.r_[ok_y, sub.value[pos].min(), sub.value[pos].max()]
            ax.plot(np.degrees(_signed_theta_o(sub))[pos], sub.value[pos], "o", ms=2.0,
                    mew=0, color=c, alpha=0.7)  # fmt: skip
            by_theta[round(np.degrees(ti), 6)] = Line2D(
                [], [], color=c, marker="o", ms=3, mew=0, label=f"θi = {np.degrees(ti):.0f}°"
            )
            if model is not None:
                p0 = phi if phi is not None else float(np.median(samples.phi_i[sel]))
                t = np.radians(np.linspace(-89.5, 89.5, 359))
                wo = to_vector(np.abs(t), np.where(t >= 0, p0 + np.pi, p0))
                wi = to_vector(np.full_like(t, ti), np.full_like(t, p0))
                f = _model_band(model, np.asarray(model(wi, wo), dtype=float), wl)
                ok = f > 0
                ax.plot(np.degrees(t)[ok], f[ok], "-", color=c, lw=1.0)
        ax.set_xlim(-90, 90)
        ax.set_xticks(np.arange(-60, 61, 30))
        ax.set_xlabel("θo in the plane of incidence (°)")
        head = f"φi = {np.degrees(phi):.0f}°" if phi is not None else f"λ = {wl:.0f} nm"
        # y given: the title stays above the axes (its place with the x ticks at the bottom)
        # without the draw-time extent of every log tick label (0.17 s of a 0.4 s figure)
        ax.set_title(head if n > 1 or not title else f"{title}, {head}", y=1.0)
        ax.grid(True, which="major", alpha=0.25, lw=0.5)
        if ok_y.size:
            y_lo, y_hi = min(y_lo, *ok_y), max(y_hi, *ok_y)
    log_axis(axes[0])
    if y_hi > 0:  # the measured range (a model tail may fall to 1e-300 at grazing)
        axes[0].set_ylim(y_lo / 1.6, y_hi * 1.6)
    axes[0].set_ylabel("BRDF (sr⁻¹)")
    handles = [by_theta[k] for k in sorted(by_theta)]
    if model is not None:
        handles = handles + [Line2D([], [], color="0.3", lw=1.0, label="fitted model"),
                             Line2D([], [], color="0.3", ls="", marker="o", ms=3, mew=0,
                                    label="measured")]  # fmt: skip
    n_leg = len(handles)
    ncol = min(n_leg, 4 if n == 1 else 8)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=6, handlelength=1.2,
               columnspacing=1.0,
               bbox_to_anchor=(0.5, (0.16 + 0.1 * (n == 1)) / fig.get_figheight()))  # fmt: skip
    note = f"measured: the {total:,} samples within {np.degrees(tol):.1f}° of the plane"
    note += f", {shown:,} shown" if shown < total else ""
    note += ";\n" if n == 1 else "; "
    note += "θo > 0 on the specular side"
    fig.text(0.01, 0.005, note, fontsize=6, color="0.35", ha="left", va="bottom")
    if title and n > 1:
        fig.suptitle(title)
    rows_leg = -(-n_leg // ncol)
    # fixed margins in inches (a layout engine's search of every label's extent doubled
    # the figure's drawing time): tick labels and axis label below, the legend, the note
    bottom = 0.22 + 0.1 * (n == 1) + 0.15 * rows_leg + 0.4
    _margins(fig, left=0.55, right=0.1, bottom=bottom, top=0.45 if title and n > 1 else 0.25,
             wspace=0.12)  # fmt: skip
    return _save(fig, path)


def _margins(
    fig: Any, *, left: float, right: float, bottom: float, top: float, wspace: float = 0.0
) -> None:
    """Place the subplots of ``fig`` with margins and gaps between them in inches."""
    w, h = fig.get_figwidth(), fig.get_figheight()
    n = max(len(fig.axes), 1)
    panel = (w - left - right - wspace * (n - 1)) / n
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=wspace / panel if panel > 0 else 0.2)  # fmt: skip


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


#: Colour of a hemisphere cell without a sample: a blue-grey that the magma scale does not
#: contain (its ends are black and pale yellow), so a hole never reads as a value.
EMPTY = "#9db4c8"


def plot_hemisphere(
    samples: BRDFSamples,
    path: str | os.PathLike,
    *,
    max_panels: int = 24,
    bins: int | None = None,
    title: str = "",
    dpi: float | None = None,
) -> Path:
    """One map per (θi, φi) of the reduced samples over the outgoing hemisphere.

    Azimuthal equidistant projection (radius ∝ θo, angle = φo in the sample frame, +x to
    the right); colour = mean log10 of the BRDF over the samples in each of ``bins × bins``
    cells (:func:`hemisphere_map`; by default the finest grid of 12-45 cells across (whole
    degrees per cell) with
    about 10 samples per cell of the disc, so that the holes are few: 18 (10° cells) for the
    default campaign's ~2,800 samples per incidence); cells without a sample in
    :data:`EMPTY`, outside the colour scale. Each map marks the source direction (×), the
    specular direction (○) and rings at θo = 30°, 60° and 90°; the figure says how many of
    the incidences it shows. The
    maps are laid out as one mosaic image in one axes (12 separate axes took 0.2 s of CPU to
    draw, most of it matplotlib's per-axes bookkeeping).
    """
    _check(samples)
    with _style():
        return _hemisphere(samples, path, max_panels, bins, title, dpi)


def _hemisphere(samples, path, max_panels, bins, title, dpi):
    import matplotlib as mpl
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Patch

    keys = hemisphere_keys(samples, max_panels)
    if bins is None:
        per = len(samples) / max(len(hemisphere_keys(samples, 10**9)), 1)
        fit = math.sqrt(per * 4 / math.pi / 10)  # cells across for ~10 samples per cell
        bins = max([b for b in (12, 15, 18, 20, 24, 30, 36, 45) if b <= fit] or [12])
    n_all = len(hemisphere_keys(samples, 10**9)) if len(keys) == max_panels else len(keys)
    n = len(keys)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    pos = samples.value > 0
    lv = np.log10(samples.value[pos]) if pos.any() else np.array([0.0])
    vmin, vmax = np.percentile(lv, [1, 99.9])
    if not vmax > vmin:
        vmin, vmax = vmin - 0.5, vmax + 0.5
    gap = max(2, bins // 5)  # blank pixels between maps, room for the titles
    step = bins + gap
    cmap = mpl.colormaps["magma"]
    norm = Normalize(vmin, vmax)
    rgba = np.ones((rows * step, cols * step, 4))  # white paper between the maps
    # the disc of the hemisphere (θo <= 90°): cells whose centre lies inside it
    c = (np.arange(bins) + 0.5) * (180.0 / bins) - 90.0
    disc = np.hypot(c[None, :], c[:, None]) <= 90.0
    empty = np.array(mpl.colors.to_rgba(EMPTY))
    panel_w = (DOUBLE - 0.9) / 4
    top_in, bottom_in = (0.3 if title else 0.05), 0.5  # title; the note and the legend
    fig_w, fig_h = 0.9 + panel_w * cols, top_in + bottom_in + (panel_w + 0.14) * rows
    fig = _figure(fig_w, fig_h, dpi)
    ax = fig.add_axes((0.0, bottom_in / fig_h, 1 - 0.9 / fig_w, 1 - (top_in + bottom_in) / fig_h))
    rings, marks_src, marks_spec = [], [], []
    for k, (ti, pi) in enumerate(keys):
        r0, c0 = (k // cols) * step + gap, (k % cols) * step + gap // 2
        img = hemisphere_map(samples, ti, pi, bins)[::-1]
        cell = cmap(norm(np.nan_to_num(img, nan=vmin)))
        cell[~np.isfinite(img) & disc[::-1]] = empty
        cell[~disc[::-1]] = (1.0, 1.0, 1.0, 1.0)
        rgba[r0 : r0 + bins, c0 : c0 + bins] = cell
        cx, cy = c0 + bins / 2 - 0.5, r0 + bins / 2 - 0.5
        scale = bins / 180.0  # pixels per degree
        for t in (30.0, 60.0, 90.0):
            rings.append(Circle((cx, cy), t * scale, fill=False))
        d = np.degrees(ti) * scale  # image rows grow downwards: y = -θ sin φ
        marks_src.append((cx + d * np.cos(pi), cy - d * np.sin(pi)))
        marks_spec.append((cx - d * np.cos(pi), cy + d * np.sin(pi)))
        ax.text(cx, r0 - 0.6, f"θi {np.degrees(ti):.0f}°, φi {np.degrees(pi):.0f}°",
                ha="center", va="bottom", fontsize=6.5)  # fmt: skip
    # as 8-bit RGBA: matplotlib checks and converts a float image pixel by pixel (0.38 s)
    ax.imshow((rgba * 255.0 + 0.5).astype(np.uint8), interpolation="nearest")
    ax.add_collection(PatchCollection(rings, match_original=False, facecolor="none",
                                      edgecolor="0.55", lw=0.4, linestyle=(0, (2, 2))))  # fmt: skip
    if marks_src:
        xs, ys = np.array(marks_src).T
        ax.plot(xs, ys, "x", color="#00c0ff", ms=4, mew=1.0)
        xs, ys = np.array(marks_spec).T
        ax.plot(xs, ys, "o", mfc="none", mec="#00c0ff", ms=5, mew=0.9)
    ax.set_xlim(-0.5, cols * step - 0.5)
    ax.set_ylim(rows * step - 0.5, -0.5)
    ax.set_axis_off()
    cax = fig.add_axes((1 - 0.75 / fig_w, (bottom_in + 0.1) / fig_h, 0.12 / fig_w,
                        1 - (top_in + bottom_in + 0.2) / fig_h))  # fmt: skip
    fig.colorbar(ScalarMappable(norm, cmap), cax=cax, label="log₁₀ BRDF (BRDF in sr⁻¹)")
    handles = [
        Line2D([], [], color="#00c0ff", ls="", marker="x", ms=4, mew=1.0,
               label="source direction"),
        Line2D([], [], color="#00c0ff", ls="", marker="o", mfc="none", ms=5, mew=0.9,
               label="specular direction"),
        Line2D([], [], color="0.55", lw=0.6, ls=(0, (2, 2)), label="θo = 30°, 60°, 90°"),
        Patch(facecolor=EMPTY, edgecolor="none", label="no sample"),
    ]  # fmt: skip
    fig.legend(handles=handles, loc="lower left", ncol=4, fontsize=6.5, handlelength=1.5,
               bbox_to_anchor=(0.0, 0.0), columnspacing=1.2)  # fmt: skip
    note_y = 0.3 / fig_h
    shown = f"{n} of {n_all} incidences shown" if n < n_all else f"{n} incidences"
    fig.text(0.01, note_y, f"{shown}; view from above, radius = θo, angle = φo "
             f"(+x right); {180 / bins:.3g}° cells", fontsize=6, color="0.35", ha="left",
             va="bottom")  # fmt: skip
    if title:
        fig.suptitle(title, y=1 - 0.04 / fig_h, va="top")
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


def _span(axis: Any) -> float:
    """Decades the view of a log ``axis`` spans (inf if it is not positive)."""
    lo, hi = sorted(axis.get_view_interval())
    return math.log10(hi) - math.log10(lo) if lo > 0 and math.isfinite(hi) else math.inf


def _major_label(axis: Any, value: float) -> str:
    """A decade's label: ``10⁻²`` (:func:`decade_label`), or ``0.01`` when the axis spans
    less than two decades and its minor ticks are labelled in that notation too."""
    if _span(axis) < 2.0 and value > 0 and math.isfinite(value):
        return f"{value:.3g}"
    return decade_label(value)


def _minor_label(axis: Any, value: float) -> str:
    """Label of a minor tick (2-9 × 10^k) of a log axis: none when the view spans two
    decades or more (the decades read alone), the 2, 3 and 5 when it spans more than one,
    the 2, 3, 4, 5, 6 and 8 when it spans more than half a decade (wall plaster's
    0.14-0.52 sr⁻¹ reads 0.2, 0.3, 0.4, 0.5), every one below that."""
    span = _span(axis)
    if span >= 2.0 or not (value > 0 and math.isfinite(value)):
        return ""
    digit = round(value / 10 ** math.floor(math.log10(value) + 1e-9))
    if (span > 1.0 and digit not in (2, 3, 5)) or (span > 0.5 and digit in (7, 9)):
        return ""
    return f"{value:.3g}"


def log_axis(ax: Any, which: str = "y") -> None:
    """Make the ``which`` axis of ``ax`` logarithmic and readable whatever its range:
    decades labelled by :func:`decade_label`, unlabelled minor ticks at 2-9 × 10^k, and
    labels on some minor ticks when the axis spans less than two decades
    (:func:`_minor_label`), so that an axis without a decade inside still has numbers."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    axis = ax.yaxis if which == "y" else ax.xaxis
    (ax.set_yscale if which == "y" else ax.set_xscale)("log")
    axis.set_major_locator(LogLocator(base=10.0, numticks=12))
    axis.set_major_formatter(FuncFormatter(lambda v, _p=None: _major_label(axis, v)))
    axis.set_minor_locator(LogLocator(base=10.0, subs=tuple(range(2, 10)), numticks=12))
    axis.set_minor_formatter(FuncFormatter(lambda v, _p=None: _minor_label(axis, v)))


def plot_residuals(
    samples: BRDFSamples,
    model: Any,
    path: str | os.PathLike,
    *,
    max_points: int = 6000,
    title: str = "",
    dpi: float | None = None,
) -> Path:
    """Residuals of ``model`` against θo (coloured by θi) and their histogram.

    Normalised ``(f − y)/σ`` when the table has σ (a standard normal for a good fit and
    honest errors; the histogram shows that normal for comparison), else relative
    ``(f − y)/y`` in per cent; the figure defines f, y and σ. Both panels share a robust range (the
    central 99.5 % of the residuals, widened to ±4 for normalised ones) so that a few
    outliers do not flatten the rest: points beyond it are drawn on its edge as triangles
    and the histogram's end bins, hatched, count them, with their number written. The
    scatter shows a fixed-seed subset of at most ``max_points`` samples (drawing 20 000
    points took 0.11 s of the plot's 0.22 s), and says so; the histogram and the rms use all.
    """
    _check(samples)
    with _style():
        return _residuals(samples, model, path, max_points, title, dpi)


def _residuals(samples, model, path, max_points, title, dpi):
    from gonio.fit import predict

    f = predict(model, samples)
    if samples.has_sigma:
        r = (f - samples.value) / samples.sigma
        label = "(f − y)/σ"
        define = "f: fitted model, y: measured BRDF, σ: its standard uncertainty (sr⁻¹)"
    else:
        y = samples.value
        ok = np.abs(y) > 0
        r = 100.0 * np.where(ok, (f - y) / np.where(ok, y, 1.0), 0.0)  # in per cent
        label = "(f − y)/y (%)"
        define = "f: fitted model, y: measured BRDF (sr⁻¹)"
    r = np.where(np.isfinite(r), r, 0.0)
    n = len(r)
    lim = float(np.percentile(np.abs(r), 99.5)) if n else 1.0
    if samples.has_sigma:
        lim = max(lim, 4.0)
    lim = lim * 1.05 if lim > 0 else 1.0
    fig = _figure(DOUBLE, 2.7, dpi)
    ax, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": (1.45, 1.0)})
    # scatter at most max_points residuals (a fixed-seed subset), the histogram uses all
    idx = np.arange(n)
    if n > max_points:
        idx = np.sort(np.random.default_rng(0).choice(n, max_points, replace=False))
    rs = r[idx]
    inside = np.abs(rs) <= lim
    x = np.degrees(samples.theta_o[idx])
    ci = np.degrees(samples.theta_i[idx])
    norm = (float(ci.min()), float(max(ci.max(), ci.min() + 1e-9)))
    sc = ax.scatter(x[inside], rs[inside], s=1.5, c=ci[inside], cmap="viridis",
                    vmin=norm[0], vmax=norm[1], rasterized=True, linewidths=0)  # fmt: skip
    for sign, marker in ((1, "^"), (-1, "v")):
        out = sign * rs > lim
        if out.any():
            ax.scatter(x[out], np.full(out.sum(), sign * lim * 0.985), s=8, marker=marker,
                       c=ci[out], cmap="viridis", vmin=norm[0], vmax=norm[1],
                       linewidths=0)  # fmt: skip
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylim(-lim, lim)
    ax.set_xlim(0, 90)
    ax.set_xticks(np.arange(0, 91, 15))
    ax.set_xlabel("θo (°)")
    ax.set_ylabel(label)
    cax = ax.inset_axes((1.02, 0.0, 0.03, 1.0))
    fig.colorbar(sc, cax=cax, label="θi (°)")
    n_out = int((np.abs(r) > lim).sum())
    shown = f"{len(idx):,} of {n:,} points shown" if len(idx) < n else f"all {n:,} points"
    beyond = f"; ▲▼ {int((~inside).sum())} beyond the axis" if (~inside).any() else ""
    ax.set_title(shown + beyond, y=1.0)  # (y given: as in _incidence_plane)
    edges = np.linspace(-lim, lim, 61)
    counts, _ = np.histogram(np.clip(r, -lim, lim), bins=edges)
    widths = np.diff(edges)
    bars = ax2.bar(edges[:-1], counts, width=widths, align="edge", color="C0", lw=0)
    for i in (0, len(bars) - 1):
        bars[i].set_hatch("////")
        bars[i].set_facecolor("C1")
        bars[i].set_edgecolor("white")
    handles = [bars[0]]
    bars[0].set_label(f"end bins also hold |residual| > {lim:.3g} ({n_out:,} samples)")
    if samples.has_sigma:
        g = np.linspace(-lim, lim, 301)
        (line,) = ax2.plot(g, n * widths[0] * np.exp(-0.5 * g**2) / np.sqrt(2 * np.pi),
                           color="k", lw=0.8, label="standard normal (ideal)")  # fmt: skip
        handles.insert(0, line)
    ax2.set_xlim(-lim, lim)
    peak = max(float(counts.max()), n * widths[0] / np.sqrt(2 * np.pi) if samples.has_sigma else 0)
    ax2.set_ylim(0, 1.45 * peak if peak > 0 else 1.0)  # headroom for the legend
    ax2.set_xlabel(label)
    ax2.set_ylabel("samples")
    ax2.set_title(f"rms {np.sqrt(np.mean(r**2)):.3g}, n = {n:,}", y=1.0)
    ax2.legend(handles=handles, loc="upper left", fontsize=6, handlelength=1.2)
    fig.text(0.01, 0.005, define, fontsize=6.5, color="0.3", ha="left", va="bottom")
    if title:
        fig.suptitle(title)
    fig.subplots_adjust(left=0.6 / DOUBLE, right=1 - 0.1 / DOUBLE, bottom=0.62 / 2.7,
                        top=1 - (0.5 if title else 0.3) / 2.7, wspace=0.55)  # fmt: skip
    return _save(fig, path)
