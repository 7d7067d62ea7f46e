"""The LBL instrument's angular resolution against the lobe it is asked to measure.

An imaging gonioreflectometer sees the reflected hemisphere through pixels, each of which
averages the BRDF over a patch of directions: its footprint through the mirror (eq. 3:
the camera's angular pitch times the dome's magnification ``dθr/dθc``), widened by the
image blur (pixel fill, diffraction, defocus: the point-spread model of the instrument's
specification) and by the source's cone of directions (Ward 1992, §3: the lamp's beam).
A lobe narrower than that is rendered at the instrument's width, not its own: its width
parameter is then *bounded* (the lobe is at least this narrow), not measured, and its
fitted value and uncertainty mean nothing more.

:func:`angular_resolution` combines the three as root-sum-square angular RMS widths (a
uniform pixel footprint ``w``: ``w/√12``; a uniform cone of half-angle ``γ``: ``γ/√2``; a
Gaussian blur of ``σ`` pixels: ``σ`` footprints) and states it as a half width at half
maximum (``1.1774 σ``). :func:`lobe_hwhm` measures a model's narrowest lobe numerically
(the half width at half maximum above the diffuse floor, around the mirror direction, in
and across the plane of incidence), so it holds for any model. :func:`resolution_warnings`
says, before any capture, which width parameter will be bounded and where the bound lies
(e.g. ``n >= 1.2e+03``). Everything here is the design and the maker's specification (what
a laboratory knows before measuring) and the material the plan names.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §3 (the imaging gonioreflectometer: dome, fisheye camera, the lamp's beam), eq. 3.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "Resolution",
    "angular_resolution",
    "lbl_resolution",
    "lobe_hwhm",
    "resolution_warnings",
]

#: FWHM / (2 σ) of a Gaussian: an RMS width as a half width at half maximum
_HWHM_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))

#: Lobe-width parameters by model: name -> +1 if a larger value is a narrower lobe, -1 if
#: a smaller one is
WIDTH_PARAMS: dict[str, dict[str, int]] = {
    "ward": {"alpha_x": -1, "alpha_y": -1},
    "ward_gmd": {"alpha_x": -1, "alpha_y": -1},
    "ward_duer": {"alpha_x": -1, "alpha_y": -1},
    "ward_neumann": {"alpha_x": -1, "alpha_y": -1},
    "metal_neumann": {"n": +1},
    "plastic_neumann": {"n": +1},
    "phong": {"n": +1},
    "blinn_phong": {"n": +1},
    "phong_neumann": {"n": +1},
    "blinn_neumann": {"n": +1},
    "torrance_sparrow": {"sigma": -1},
    "cook_torrance": {"m": -1},
}


@dataclass(frozen=True)
class Resolution:
    """An instrument's angular resolution (radians): its parts and their sum as a HWHM."""

    footprint: float  # the pixel's width in reflected direction (median over the field)
    blur: float  # RMS of the image blur, as an angle
    source: float  # half-angle of the source's cone

    @property
    def rms(self) -> float:
        return math.sqrt(self.footprint**2 / 12.0 + self.blur**2 + self.source**2 / 2.0)

    @property
    def hwhm(self) -> float:
        return _HWHM_PER_SIGMA * self.rms

    def to_dict(self) -> dict[str, float]:
        """JSON-ready, in degrees."""
        return {k: round(math.degrees(v), 6) for k, v in
                (("footprint_deg", self.footprint), ("blur_rms_deg", self.blur),
                 ("source_half_angle_deg", self.source), ("hwhm_deg", self.hwhm))}  # fmt: skip


def angular_resolution(
    mirror: Mapping[str, Any], focal_px: float, width_px: int, binning: Sequence[int] | None,
    source_half_angle: float, blur_px: float = 0.0,
) -> Resolution:  # fmt: skip
    """The resolution of an imaging instrument of design ``mirror`` (its ``to_dict``), a
    fisheye of ``focal_px`` pixels per radian on ``width_px`` columns, digitised to
    ``binning = (width, height)`` (None: full resolution), a source cone of half-angle
    ``source_half_angle`` and an image blur of ``blur_px`` RMS (full-resolution pixels).

    The footprint is the median over the reflected hemisphere (θr 5-80°) of
    ``(dθr/dθc) · b / focal_px`` (``b`` = full-resolution pixels per digitised pixel),
    with ``θr(θc)`` the traced reflection angle of eq. 3's mirror."""
    from gonio.simulator.optics import traced_reflection_angles

    b = 1.0 if not binning or not binning[0] else width_px / float(binning[0])
    tc = np.linspace(0.01, 1.5, 600)
    tr, _phi, _off = traced_reflection_angles(tc, np.zeros_like(tc), float(mirror["radius"]),
                                              float(mirror["half_separation"]),
                                              str(mirror.get("type", "ellipsoid")))  # fmt: skip
    ok = (tr > math.radians(5)) & (tr < math.radians(80))
    mag = np.abs(np.gradient(tr, tc))[ok]
    per_px = float(np.median(mag)) / float(focal_px) if mag.size else 1.0 / float(focal_px)
    return Resolution(per_px * b, per_px * float(blur_px), float(source_half_angle))


def lobe_hwhm(model: Any, theta_i: float = math.radians(30.0)) -> float:
    """The half width at half maximum (radians of reflected direction) of the narrowest
    lobe of ``model`` at incidence ``theta_i``: around the mirror direction, in and across
    the plane of incidence, above the floor (the smallest value within 35° of it); ``inf``
    for a model whose value there does not rise 5 % above its floor (no lobe). A broad
    diffuse variation (Oren-Nayar's) reads as a lobe of 10° or more: never one an
    instrument fails to resolve."""
    d = np.concatenate([[0.0], np.geomspace(1e-5, 0.6, 400)])
    st, ct = math.sin(theta_i), math.cos(theta_i)
    wi = np.array([st, 0.0, ct])
    widths = []
    for across in (False, True):
        if across:  # the mirror direction turned about the plane's normal... across it
            wo = np.stack([-st * np.cos(d), np.sin(d), ct * np.cos(d)], axis=-1)
        else:
            th = theta_i + d
            wo = np.stack([-np.sin(th), np.zeros_like(d), np.cos(th)], axis=-1)
        wo = wo[wo[:, 2] > 1e-3]
        f = np.asarray(model(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64)
        if f.ndim > 1:
            f = f.mean(axis=-1)
        floor = float(np.min(f))
        peak = float(f[0]) - floor
        if not (peak > 0.05 * max(floor, 1e-300)) or not np.isfinite(peak):
            widths.append(math.inf)
            continue
        g = f - floor - 0.5 * peak
        below = np.flatnonzero(g < 0)
        if not below.size:
            widths.append(math.inf)
            continue
        k = int(below[0])  # g[k - 1] >= 0 > g[k]: linear between them
        widths.append(float(d[k - 1] + (d[k] - d[k - 1]) * g[k - 1] / (g[k - 1] - g[k])))
    return min(widths)


def resolution_warnings(truth: Any, template: Any, res: Resolution,
                        theta_i: float = math.radians(30.0)) -> list[str]:  # fmt: skip
    """What the instrument will bound rather than measure: for each lobe-width parameter of
    the fitted model (:data:`WIDTH_PARAMS`), when the material's lobe (``truth``) is
    narrower than the resolution, the value of the parameter at which the model's lobe is
    as wide as the resolution (the model at the truth's values when it is the truth's
    family, else at its start values). Empty when the lobe is resolved."""
    width = lobe_hwhm(truth, theta_i)
    if not width < res.hwhm:
        return []
    base = truth if truth.name == template.name else template
    why = (
        f"the lobe is narrower than the instrument resolves (its half width "
        f"{math.degrees(width):.3g} deg against the instrument's {math.degrees(res.hwhm):.3g} "
        f"deg: pixel {math.degrees(res.footprint):.3g} deg, blur {math.degrees(res.blur):.3g} "
        f"deg RMS, source cone {math.degrees(res.source):.3g} deg)"
    )
    out = []
    for name, sign in WIDTH_PARAMS.get(template.name, {}).items():
        bound = _bound(base, name, sign, res.hwhm, theta_i)
        if bound is not None:  # (a width the narrowest lobe does not depend on: no bound)
            rel = ">=" if sign > 0 else "<="
            out.append(f"{name} {rel} {bound:.3g}: {why}: it will be bounded, not measured")
    if not out:
        out.append(f"{why}: {template.name}'s lobe parameters will be bounded, not measured")
    return out


def _bound(model: Any, name: str, sign: int, hwhm: float, theta_i: float) -> float | None:
    """The value of ``name`` (others as in ``model``) at which the lobe's half width is
    ``hwhm`` (bisection in log of the value between its bounds), None if not bracketed."""
    from gonio import brdf

    p = brdf.spec(model.name).params[name]
    lo = max(p.lower, 1e-6)
    hi = min(p.upper, 1e8)

    def w(v: float) -> float:
        return lobe_hwhm(type(model)(**{**model.params, name: v}), theta_i)

    a, b = math.log(lo), math.log(hi)
    wa, wb = w(lo), w(hi)
    if not ((wa - hwhm) * (wb - hwhm) < 0 or math.isinf(wa) != math.isinf(wb)):
        return None
    for _ in range(40):
        m = 0.5 * (a + b)
        wm = w(math.exp(m))
        if (wm > hwhm) == (wa > hwhm):
            a, wa = m, wm
        else:
            b = m
    return math.exp(0.5 * (a + b))


def lbl_resolution(plan: Any, instrument: Any) -> Resolution | None:
    """The resolution of a campaign's LBL instrument from its design (mirror, lens, the
    plan's digitiser) and the specification of its preset (the blur's pixel fill,
    diffraction and focus error at their typical values, at the median f-stop of a
    bracket); None for an instrument that is not the simulated LBL one."""
    sim = getattr(instrument, "inst", None)
    if sim is None or not hasattr(sim, "lens"):
        return None
    from gonio.campaign.calibrate import specification
    from gonio.simulator.lbl import F_STOPS
    from gonio.simulator.lbl_effects import psf_sigma_px

    spec = {k: v["typical"] for k, v in specification(plan.preset).items()}
    lens = sim.lens
    blur = psf_sigma_px(float(np.median(F_STOPS)), spec, sim.sensor.pixel_pitch, lens.fx,
                        0.5 * sim.mirror.radius)  # fmt: skip
    b = plan.binning if plan.binning and tuple(plan.binning) != (0, 0) else None
    return angular_resolution(sim.mirror.to_dict(), lens.fx, lens.width, b,
                              sim.source.divergence, blur)  # fmt: skip
