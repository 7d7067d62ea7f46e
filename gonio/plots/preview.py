"""The renderer's view: the true and the fitted material on a sphere, rendered by Radiance.

:func:`plot_preview` draws ``plots/preview.png``: the truth and the fit side by side, each a
sphere rendered by Radiance's ``rtrace`` (through pyradiance's binaries,
:func:`gonio.io.radiance.trace`) from the Radiance material gonio writes for it
(:func:`gonio.io.radiance.model_material`: the fit's is the campaign's ``material.rad``), and
their relative difference in false colour. What a user looks at first: does the fitted
material look like the real one?

The scene is chosen to be exact and cheap rather than pretty: one distant disc light (the
key, 2° across, from the upper left in front of the sphere) and a dim environment of five
distant lights (above, below, left, right, behind), with every sampled term of the renderer
off (no ambient bounces, no specular sampling, no jitter): light sources only, because a
``BRTDfunc``'s function applies to light sources only (indirect light sees its Lambertian
part alone; a uniform ambient glow compared the ``.cal`` files' Lambertian parts, not the
models: −8 % on the shadowed side of an Oren-Nayar fit good to 1 % where lit). So the same
pixel of the two renders differs only by the two materials' BRDFs, without Monte-Carlo
noise. The material's
``u`` vector (the sample's x axis, the direction of ``alpha_x``) points up the picture.

A model Radiance cannot render exactly (no ``plastic2``/``metal2`` nor ``.cal`` translation:
``gonio.io.radiance.CAL_MODELS``) is not replaced by another one: its half says why and the
difference is not drawn (:func:`preview_notes` says it beforehand, for the campaign's
summary); without pyradiance or a Radiance installation the preview is skipped
(:func:`unavailable`).

References
----------
.. [Radiance] G. J. Ward et al., Radiance 6.0 (LBNL): reference manual (``ray.html``:
   ``light``, ``source``, ``BRTDfunc``; ``rtrace`` options ``-av``, ``-ab``, ``-st``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ENVIRONMENT",
    "KEY_DIRECTION",
    "SIZE",
    "PreviewHalf",
    "plot_preview",
    "preview_materials",
    "preview_notes",
    "relative_difference",
    "render_sphere",
    "unavailable",
]

#: Pixels across each render (the sphere covers 59 % of the square): rtrace took 0.07 s of
#: processor time for Ward eq. 5a, 0.23 s for Oren-Nayar eq. 27-29 (0.11 and 0.42 s at 256).
SIZE = 192

#: The key light's direction (towards it) in the scene: x up the picture, the camera on -y.
KEY_DIRECTION = (0.55, -0.6, 0.58)

#: The key light's angular diameter (degrees) and its irradiance (π: a white Lambertian
#: surface facing it has radiance 1).
KEY_DIAMETER_DEG, KEY_IRRADIANCE = 2.0, math.pi

#: The environment: dim distant lights (direction towards each, as the key's), 10° across,
#: each of irradiance ``ENVIRONMENT_IRRADIANCE``: above, below, left, right and behind the
#: sphere, as from the walls of a room, so that no part the camera sees is dark and every
#: pixel is lit by light sources alone, whose BRDFs Radiance evaluates exactly.
ENVIRONMENT = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0),
               (0.0, 1.0, 0.0))  # fmt: skip
ENVIRONMENT_DIAMETER_DEG, ENVIRONMENT_IRRADIANCE = 10.0, 0.03 * math.pi

_CAMERA_Y, _HALF_FOV_DEG = -6.0, 11.0


def unavailable() -> str | None:
    """Why a preview cannot be rendered here, or ``None``: Radiance's ``rtrace`` is looked for
    where :func:`gonio.io.radiance.radiance_tool` looks (pyradiance's ``bin`` folder, then
    ``PATH``), without importing pyradiance (0.2 s: this runs in the campaign's process)."""
    import importlib.util
    import shutil

    try:
        spec = importlib.util.find_spec("pyradiance")
    except (ImportError, ValueError):
        spec = None
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        rtrace = Path(folder) / "bin" / "rtrace"
        if rtrace.is_file() and os.access(rtrace, os.X_OK):
            return None
    if shutil.which("rtrace") is not None:
        return None
    why = "pyradiance is not installed" if spec is None else "pyradiance has no rtrace"
    return (
        f"plots/preview.png not drawn: {why} (pip install 'gonio[radiance]') and no Radiance "
        "rtrace is on PATH"
    )


class PreviewHalf:
    """One half of the preview: a label and its Radiance material, or why it has none."""

    def __init__(self, label: str, material: Any = None, reason: str | None = None) -> None:
        if (material is None) == (reason is None):
            raise ValueError("a preview half has a material or a reason, not both or neither")
        self.label, self.material, self.reason = label, material, reason


def preview_materials(
    truth: Any, fit: Any, material_class: str = "dielectric", fit_material: Any = None
) -> tuple[PreviewHalf, PreviewHalf]:
    """The truth's and the fit's :class:`PreviewHalf` (``fit_material``: the fit's material as
    written, e.g. ``material.rad``'s; else made from ``fit`` like it)."""
    from gonio.io.radiance import model_material

    halves = []
    for label, model, given in (("truth", truth, None), ("fit", fit, fit_material)):
        if given is not None:
            halves.append(PreviewHalf(label, given))
            continue
        try:
            mat = model_material(model, material_class, name=f"gonio_{label}")
        except ValueError as exc:
            halves.append(PreviewHalf(label, reason=f"{label} not rendered: {exc}"))
        else:
            halves.append(PreviewHalf(label, mat))
    return halves[0], halves[1]


def preview_notes(truth: Any, fit: Any, material_class: str = "dielectric") -> list[str]:
    """One line per part of the preview that will not be drawn, and why (none if all will)."""
    why = unavailable()
    if why is not None:
        return [why]
    return [
        f"plots/preview.png: {h.reason}"
        for h in preview_materials(truth, fit, material_class)
        if h.reason is not None
    ]


def _camera(size: int) -> tuple[NDArray, NDArray, NDArray]:
    """Rays of a pinhole camera on -y looking at the unit sphere at the origin (x up the
    picture, z to the left), and the mask of the pixels whose ray hits the sphere."""
    f = 1.0 / math.tan(math.radians(_HALF_FOV_DEG))
    j, i = np.mgrid[0:size, 0:size]
    up = 1.0 - (j + 0.5) * (2.0 / size)
    right = (i + 0.5) * (2.0 / size) - 1.0
    d = np.stack([up, np.full(up.shape, f), -right], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.broadcast_to(np.array([0.0, _CAMERA_Y, 0.0]), d.shape)
    b = np.einsum("...k,...k", o, d)  # |o + t d| = 1
    hit = b * b - (_CAMERA_Y**2 - 1.0) > 0.0
    return o.reshape(-1, 3), d.reshape(-1, 3), hit


def _scene() -> str:
    k = np.asarray(KEY_DIRECTION, dtype=np.float64)
    lights = [(k, KEY_DIAMETER_DEG, KEY_IRRADIANCE)]
    lights += [(e, ENVIRONMENT_DIAMETER_DEG, ENVIRONMENT_IRRADIANCE) for e in ENVIRONMENT]
    text = []
    for n, (v, diameter, irradiance) in enumerate(lights):
        v = [float(x) for x in np.asarray(v, dtype=np.float64) / np.linalg.norm(v)]
        omega = 2.0 * math.pi * (1.0 - math.cos(math.radians(diameter / 2.0)))
        L = irradiance / omega
        text.append(
            f"void light gonio_light{n} 0 0 3 {L!r} {L!r} {L!r}\n"
            f"gonio_light{n} source gonio_source{n} 0 0 4 {v[0]!r} {v[1]!r} {v[2]!r} "
            f"{float(diameter)!r}\n"
        )
    return "".join(text) + "{material} sphere gonio_ball 0 0 4 0 0 0 1\n"


def render_sphere(material: Any, size: int = SIZE) -> tuple[NDArray, NDArray]:
    """``(radiance, mask)``: the sphere in ``material`` under the key light and the
    environment, ``(size, size)`` (the mean of R, G, B) and the pixels that see the sphere.

    Raises
    ------
    ValueError
        ``size`` outside [16, 1024].
    FileNotFoundError
        No Radiance (:func:`gonio.io.radiance.radiance_tool`).
    """
    from gonio.io.radiance import trace

    if not isinstance(size, int) or not 16 <= size <= 1024:
        raise ValueError(f"size {size!r} must be an integer in [16, 1024] pixels")
    o, d, hit = _camera(size)
    rgb = trace(material, _scene(), o, d)
    return rgb.mean(axis=1).reshape(size, size), hit


def relative_difference(
    truth: NDArray, fit: NDArray, mask: NDArray, floor: float = 1e-4
) -> tuple[NDArray, NDArray]:
    """``(Δ, defined)``: ``Δ = (L_fit − L_truth) / L_truth`` per pixel, defined on the sphere
    where the truth is brighter than ``floor`` times its brightest pixel (NaN elsewhere)."""
    top = float(np.max(truth[mask])) if np.any(mask) else 0.0
    defined = mask & (truth > floor * top) & (top > 0.0)
    delta = np.full(truth.shape, np.nan)
    delta[defined] = (fit[defined] - truth[defined]) / truth[defined]
    return delta, defined


def _pct(x: float) -> str:
    """A fraction as a percentage with two significant digits, never in e-notation."""
    v = 100.0 * x
    return f"{v:.0f} %" if v >= 10.0 else f"{v:.2g} %"


def _tone(v: NDArray, scale: float) -> NDArray:
    """Display values: ``x / (1 + x)`` of ``x = v / scale`` (Reinhard's global operator),
    then the sRGB-like gamma 1/2.2; the same ``scale`` for both halves."""
    x = np.maximum(v, 0.0) / scale
    return (x / (1.0 + x)) ** (1.0 / 2.2)


def plot_preview(
    truth: Any,
    fit: Any,
    path: str | os.PathLike,
    title: str = "",
    material_class: str = "dielectric",
    fit_material: Any = None,
    size: int = SIZE,
    dpi: float | None = None,
) -> dict[str, Any]:
    """Draw the preview (see the module docstring) to ``path``; return what it measured.

    Parameters
    ----------
    truth, fit : BRDF
        The true and the fitted model.
    path : path
        The PNG (written atomically).
    title : str
        The figure's title.
    material_class : str
        ``metal`` picks ``metal2`` for a ``ward_gmd`` model, else ``plastic2``.
    fit_material : RadianceMaterial, optional
        The fit's material as written (``material.rad``); default made from ``fit``.
    size : int
        Pixels across each render (16-1024).
    dpi : float, optional
        The PNG's resolution (default :func:`gonio.plots.figures.plot_dpi`).

    Returns
    -------
    dict
        ``mean_abs_rel_diff`` and ``p95_abs_rel_diff`` (of ``|Δ|`` over the sphere's pixels
        where it is defined; ``None`` when a half is not rendered), ``n_pixels``, the
        ``notes`` of the halves not rendered, and the renders (``truth``, ``fit``, ``mask``).
    """
    halves = preview_materials(truth, fit, material_class, fit_material)
    renders: dict[str, NDArray] = {}
    mask = None
    for h in halves:
        if h.material is not None:
            renders[h.label], mask = render_sphere(h.material, size)
    out: dict[str, Any] = {
        "mean_abs_rel_diff": None,
        "p95_abs_rel_diff": None,
        "n_pixels": 0,
        "notes": [h.reason for h in halves if h.reason is not None],
        **renders,
        "mask": mask,
    }
    delta = defined = None
    if len(renders) == 2:
        delta, defined = relative_difference(renders["truth"], renders["fit"], mask)
        a = np.abs(delta[defined])
        out.update(
            mean_abs_rel_diff=float(a.mean()),
            p95_abs_rel_diff=float(np.percentile(a, 95)),
            n_pixels=int(defined.sum()),
        )
    _draw(halves, renders, mask, delta, defined, out, Path(path), title, dpi)
    return out


def _draw(halves, renders, mask, delta, defined, stats, path, title, dpi) -> None:
    import textwrap

    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    from gonio.plots.figures import DOUBLE, _figure, _save, _style

    fig = _figure(DOUBLE, 3.1, dpi)
    with _style():
        axes = fig.subplots(1, 3, gridspec_kw={"left": 0.01, "right": 0.89, "top": 0.8,
                                               "bottom": 0.2, "wspace": 0.06})  # fmt: skip
        ref = renders.get("truth", renders.get("fit"))
        scale = float(np.mean(ref[mask])) if ref is not None else 1.0
        for ax, h in zip(axes[:2], halves):
            ax.set_xticks([])
            ax.set_yticks([])
            if h.material is None:
                ax.text(0.5, 0.5, "\n".join(textwrap.wrap(h.reason, 34)), ha="center",
                        va="center", fontsize=6.5, transform=ax.transAxes)  # fmt: skip
                ax.set_title(f"{h.label}: not rendered")
                continue
            ax.imshow(_tone(renders[h.label], scale), cmap="gray", vmin=0.0, vmax=1.0)
            kind = h.material.kind
            ax.set_title(f"{h.label} ({kind})")
        ax = axes[2]
        ax.set_xticks([])
        ax.set_yticks([])
        if delta is None:
            ax.text(0.5, 0.5, "no difference:\none half is not rendered", ha="center",
                    va="center", transform=ax.transAxes)  # fmt: skip
        else:
            a = np.abs(delta[defined])
            lim = float(np.clip(np.percentile(a, 99), 0.01, 1.0))
            lim = float(np.ceil(lim * 100.0) / 100.0)  # whole percent
            ax.imshow(np.where(mask, np.nan, 0.0), cmap=ListedColormap(["0.82"]), vmin=0, vmax=1)
            dark = np.where(mask & ~defined, 0.0, np.nan)
            ax.imshow(dark, cmap=ListedColormap(["0.35"]), vmin=0, vmax=1)
            im = ax.imshow(100.0 * delta, cmap="RdBu_r", vmin=-100 * lim, vmax=100 * lim)
            cax = fig.add_axes((0.9, 0.25, 0.013, 0.5))
            cb = fig.colorbar(im, cax=cax, extend="both")
            cb.set_label("Δ (%)")
            ax.set_title(
                "Δ = (L_fit − L_truth) / L_truth\n"
                f"mean |Δ| {_pct(stats['mean_abs_rel_diff'])}, "
                f"95th percentile {_pct(stats['p95_abs_rel_diff'])}"
            )
            keys = [Patch(color="0.82", label="background")]
            if np.any(mask & ~defined):
                keys.append(Patch(color="0.35", label="truth < 0.01 % of its peak: Δ undefined"))
            ax.legend(
                handles=keys,
                loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=2, fontsize=6,
                handlelength=1.0, borderaxespad=0.3,
            )  # fmt: skip
        k = np.asarray(KEY_DIRECTION) / np.linalg.norm(KEY_DIRECTION)
        px = ref.shape[0] if ref is not None else 0
        fig.text(
            0.01, 0.015,
            f"Radiance rtrace, {px}×{px} px, light sources only (BRDFs exact, no noise): a "
            f"{KEY_DIAMETER_DEG:g}° disc light {math.degrees(math.acos(-k[1])):.0f}° off the view "
            f"axis from the upper left, and {len(ENVIRONMENT)} lights of "
            f"{ENVIRONMENT_IRRADIANCE / KEY_IRRADIANCE:g}× its irradiance\nabove, below, left, "
            "right and behind the sphere. Both halves tone-mapped alike: x/(1 + x), x = L / mean "
            f"L of the {'truth' if 'truth' in renders else 'fit'}. The material's x axis: up.",
            fontsize=6,
        )  # fmt: skip
        if title:
            fig.suptitle(title)
    _save(fig, path)
