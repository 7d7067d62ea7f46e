"""The uncertainty-budget figure of a campaign (``plots/budget.png``).

One panel per fitted parameter: a horizontal bar per source of uncertainty — the fit's
statistical standard error and each effect's contribution (terms with several components,
such as ``standard_certificate[0..5]``, summed in quadrature under their name) — as a
relative standard uncertainty on a logarithmic axis, with the combined standard uncertainty
and the expanded uncertainty (``k = 2``) as vertical lines. Uncorrected terms are hatched.

References
----------
JCGM 100:2008, Evaluation of measurement data — Guide to the expression of uncertainty in
measurement (GUM), §7.2 (reporting the components of the combined standard uncertainty).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gonio.plots.figures import DOUBLE, _figure, _save, _style

__all__ = ["budget_rows", "plot_budget"]


def budget_rows(budget: Mapping[str, Any]) -> list[tuple[str, dict[str, float], bool]]:
    """``(source, relative contribution per parameter, corrected)``: the statistical term
    first, then the effects (components of one name combined in quadrature)."""
    params = budget["params"]

    def rel(v: float | None, n: str) -> float:
        p = abs(params[n])
        return math.inf if v is None or not math.isfinite(v) else (v / p if p else v)

    rows: list[tuple[str, dict[str, float], bool]] = [
        ("statistical", {n: rel(budget["statistical"][n], n) for n in params}, True)
    ]
    groups: dict[str, tuple[dict[str, float], bool]] = {}
    for name, t in budget["terms"].items():
        base = name.split("[", 1)[0]
        acc, corr = groups.get(base, ({n: 0.0 for n in params}, True))
        for n in params:
            acc[n] = math.hypot(acc[n], rel(t["contribution"][n], n))
        groups[base] = (acc, corr and bool(t.get("corrected", True)))
    rows += [(k, v, c) for k, (v, c) in groups.items()]
    return rows


def _in_view_mask(axis: Any, locs: Any) -> Any:
    """The tick locations an axis draws: within its view interval in the axis's scale, to
    1e-10 of the interval (matplotlib's own test, ``Axis._update_ticks``)."""
    import numpy as np

    t = axis.get_transform()
    a, b = sorted(t.transform(np.asarray(axis.get_view_interval(), dtype=float)))
    tol = (b - a) * 1e-10
    lt = t.transform(np.asarray(locs, dtype=float))
    return (lt >= a - tol) & (lt <= b + tol)


@functools.cache
def _in_view() -> type:
    """A tick locator (class, made on first use: matplotlib is imported lazily) that keeps
    of another's ticks those in the view interval.

    Matplotlib makes a tick (two lines, two labels, a grid line) for every location its
    locator returns and draws those in view; a log locator returns a decade more on each
    side (2 of the 6-7 major ticks per panel here). Same ticks drawn.
    """
    import numpy as np
    from matplotlib.ticker import Locator

    class InView(Locator):
        def __init__(self, base: Any) -> None:
            self.base = base

        def set_axis(self, axis: Any) -> None:
            super().set_axis(axis)
            self.base.set_axis(axis)

        def __call__(self) -> Any:
            locs = np.asarray(self.base())
            return locs[_in_view_mask(self.axis, locs)]

        def tick_values(self, vmin: float, vmax: float) -> Any:
            return self.base.tick_values(vmin, vmax)

        def nonsingular(self, v0: float, v1: float) -> tuple[float, float]:
            return self.base.nonsingular(v0, v1)

        def view_limits(self, vmin: float, vmax: float) -> tuple[float, float]:
            return self.base.view_limits(vmin, vmax)

    return InView


def _minor_marks(ax: Any) -> None:
    """Draw the x axis's minor ticks (the unlabelled 2-9 of each decade) as one line of
    tick markers instead of ~40 matplotlib Tick objects (each two lines, two labels and a
    grid line, the figure's main cost): the marks of a minor tick, at the in-view minor
    locations, the minor locator then off. The same pixels (a test)."""
    import numpy as np
    from matplotlib.lines import Line2D
    from matplotlib.ticker import NullLocator

    xa = ax.xaxis
    locs = np.asarray(xa.get_minor_locator()())
    locs = locs[_in_view_mask(xa, locs)]
    proto = xa.get_minor_ticks(1)[0].tick1line
    marks = Line2D(locs, np.zeros(locs.size))
    marks.update_from(proto)
    marks.set_transform(proto.get_transform())
    ax.add_artist(marks)
    marks.set_clip_on(False)
    marks.set_in_layout(False)
    marks.set_zorder(xa.get_zorder())
    xa.set_minor_locator(NullLocator())


def _unit(budget: Mapping[str, Any], name: str) -> str:
    """The unit of parameter ``name`` (``tau`` -> ``µm``) from the model named by the
    budget's ``model`` entry (its registry spec; ``k_dd[3]`` as ``k_dd``); ``""`` for a
    dimensionless one or an unknown model."""
    model = budget.get("model")
    if not isinstance(model, str):
        return ""
    from gonio import brdf

    try:
        params = brdf.spec(model).params
    except (KeyError, ValueError):
        return ""
    p = params.get(name.split("[", 1)[0].split(" ", 1)[0])
    unit = "" if p is None or p.unit in ("", "1") else p.unit
    return {"um": "µm"}.get(unit, unit)


def plot_budget(
    budget: Mapping[str, Any],
    path: str | os.PathLike,
    *,
    title: str = "",
    dpi: float | None = None,
) -> Path:
    """Draw the budget (a campaign summary's ``budget`` entry) to ``path`` (PNG, atomic).

    The panels share their x range, so that a parameter's budget reads against another's;
    a legend names every colour and line. A parameter's unit comes from the budget's
    ``model`` entry when it has one (:func:`_unit`)."""
    params = list(budget["params"])
    if not params:
        raise ValueError("the budget has no fitted parameter to plot")
    with _style():
        return _draw(budget, params, path, title, dpi)


def _draw(budget, params, path, title, dpi) -> Path:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import LogLocator

    rows = budget_rows(budget)
    n_p = len(params)
    fig = _figure(min(DOUBLE, 1.5 + 1.6 * n_p), 0.16 * len(rows) + 1.7, dpi)
    axes = fig.subplots(1, n_p, sharey=True, sharex=True, squeeze=False)[0]
    ys = list(range(len(rows)))[::-1]
    stat, corr, uncorr = "0.45", "tab:blue", "tab:orange"
    # one x range for every panel: the largest bar or expanded line, four decades below it
    top = 1e-6
    for p in params:
        pv = abs(budget["params"][p])
        top = max([top, *(100 * r[1][p] for r in rows if math.isfinite(r[1][p]))])
        for key in ("combined", "expanded"):
            v = budget[key][p]
            if v is not None and math.isfinite(v) and pv:
                top = max(top, 100 * v / pv)
    left = max(top * 1e-5, 1e-7)
    for ax, p in zip(axes, params):
        uc = budget["combined"][p]
        if uc is None or not math.isfinite(uc):  # undetermined: no bar has a scale
            ax.text(0.5, 0.5, "undetermined", transform=ax.transAxes, ha="center", fontsize=6.5)
            ax.set_title(f"{p} = {budget['params'][p]:.4g}", fontsize=6.5, y=1.0)
            # (not set_xticks([]): the panels share their x axis, whose ticks it would remove
            # from every panel)
            ax.tick_params(axis="x", which="both", bottom=False, labelbottom=False)
            continue
        vals = [max(r[1][p], 1e-9) if math.isfinite(r[1][p]) else 1e-9 for r in rows]
        colours = [stat if i == 0 else (corr if r[2] else uncorr) for i, r in enumerate(rows)]
        bars = ax.barh(ys, [100 * v for v in vals], color=colours, height=0.7, lw=0)
        for bar, r in zip(bars, rows):
            if not r[2]:
                bar.set_hatch("////")
                bar.set_edgecolor("white")
        pv = abs(budget["params"][p])
        told = []
        for key, style, sym in (("combined", "-", "u_c"), ("expanded", "--", "U")):
            v = budget[key][p]
            if v is not None and math.isfinite(v) and pv:
                ax.axvline(100 * v / pv, color="k", ls=style, lw=0.8)
                told.append(f"{sym} {100 * v / pv:.2g}%")
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(_in_view()(LogLocator(numticks=4)))
        ax.set_xlim(left, top * 3)
        for y, v in zip(ys, vals):
            if 100 * v < left:  # a term too small to draw is named as such, not left blank
                ax.text(left * 1.15, y, f"< {left:.1g}%", va="center", fontsize=5.5,
                        color="0.3")  # fmt: skip
        unit = _unit(budget, p)
        name, _, note = p.partition(" (")  # "k_dd (median of 31 bands)": the note below
        head = [f"{name} = {budget['params'][p]:.4g}" + (f" {unit}" if unit else "")]
        head += [f"({note}"] if note else []
        # y given: the title stays above the axes (its place with x ticks at the bottom)
        # without the draw-time search of every y tick label's extent for a clash
        ax.set_title("\n".join(head + [", ".join(told)]), fontsize=6.5, y=1.0)
        ax.set_xlabel("relative u (%)", fontsize=6.5)
        ax.tick_params(labelsize=6.5)
        _minor_marks(ax)
    axes[0].set_yticks(ys)
    axes[0].set_yticklabels([r[0] for r in rows], fontsize=6.5)
    k = budget.get("k", 2.0)
    handles = [
        Patch(facecolor=stat, label="statistical (fit)"),
        Patch(facecolor=corr, label="effect, corrected (residual)"),
        Patch(facecolor=uncorr, hatch="////", edgecolor="white", label="effect, uncorrected"),
        Line2D([], [], color="k", lw=0.8, label="combined u_c"),
        Line2D([], [], color="k", lw=0.8, ls="--", label=f"expanded U (k = {k:g})"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=6, handlelength=1.6,
               columnspacing=1.0, bbox_to_anchor=(0.5, 0.0))  # fmt: skip
    fig.suptitle(f"{title}  uncertainty budget (GUM): relative standard uncertainty u of "
                 "each parameter".strip(), fontsize=7.5)  # fmt: skip
    fig.tight_layout(rect=(0, 0.28 / fig.get_figheight(), 1, 1), w_pad=0.5)
    # the layout is done: without a layout engine (tight_layout leaves a placeholder one)
    # savefig draws the figure once, not once more beforehand (the same pixels)
    fig.set_layout_engine(None)
    return _save(fig, path)
