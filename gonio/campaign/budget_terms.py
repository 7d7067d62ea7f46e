"""The budget's terms: each effect's perturbation of the reduced samples, from what the
laboratory knows.

Every function returns :class:`~gonio.campaign.budget.Perturbation` s computed on the
samples' own geometries (no image is rendered): the change ``δy`` of the sample values per
unit of the effect, and the standard uncertainty ``u`` of the effect after the laboratory's
correction (or, where it applied none, the specification's RMS magnitude: GUM §4.3, a
Type B evaluation from the maker's data). Their physics, in the form the reduction sees it:

``standard_certificate``
    The real standard deviates from its certificate by a smooth function of the angles; the
    certificate's uncertainty ``u`` is stated for a deviation of six orthonormal smooth
    shapes (degree-two polynomials in ``cos θi``, ``cos θo`` and the out-of-plane term,
    :func:`certificate_shapes`), each of weight ``u/√6``. Eq. 2 divides by the standard, so
    ``δy = −y · shape`` at the standard's geometry, which is the sample's ``(θi, θo, Δφ)``.
    Without the certificate correction the standard's known departure from Lambert's law is
    an uncorrected systematic: ``δy = −y (R − 1)`` with ``u = 1``.
``exposure``
    The exposure scale of one capture (iris setting, lamp flicker) is wrong by an
    independent relative error: ``δy = +y`` for the sample's capture, ``−y`` for the
    standard's capture of that incidence (random per capture).
``veiling_glare``
    A veil of ``g`` times the mean image signal in every image: eq. 2 gives
    ``(y + g ȳ)/(1 + g)``, i.e. ``δy = g (ȳ − y)`` with ``ȳ`` the mean of the BRDF over the
    capture's pixels (evaluated with the fitted model on the calibrated pixel geometry).
``geometry``
    The calibrated dome parameters' covariance
    (:class:`~gonio.calibration.mirror.MirrorCalibration`), split into independent
    components; each moves every pixel's reflection direction, and
    ``δy = f(wo + δwo) − f(wo)`` with the fitted model.
``lamp_warmup``, ``lamp_drift``
    The lamp's output ``L(t) = 1 − w e^(−t/τ) + d t`` (warm-up ``w`` with the time constant
    ``τ`` of :data:`gonio.simulator.lbl_effects.LAMP_WARMUP_TAU_S`, drift ``d`` per hour)
    changes between a sample's capture at ``t_m`` and its standard's at ``t_s`` (the
    side-cars' time stamps): eq. 2's ratio is ``L(t_m)/L(t_s)`` too large, so per unit of
    each ``δy = y (e^(−t_s/τ) − e^(−t_m/τ))`` and ``δy = y (t_m − t_s)/1 h``, with the
    specification's RMS magnitudes (uncorrected: the same lamp for every sample, a
    systematic).
``blur``
    An image blur of angular RMS ``σ`` per axis (pixel area, diffraction) changes a smooth
    BRDF by ``δy = ½ σ² ∇²f`` (second order of the Gaussian average; the Laplacian on the
    sphere from the fitted model).
``digitiser``
    Images reduced to fewer pixels than the camera's (Ward's 108 × 80): each is the area
    average of a box of camera pixels, a blur of ``(b² − 1)/12`` pixels² per axis beyond
    the pixel's own (:func:`digitiser_term`).

References
----------
JCGM 100:2008, Evaluation of measurement data — Guide to the expression of uncertainty in
measurement (GUM), §4.3 (Type B evaluation), §5.1.3 (sensitivity coefficients), §F.2.4.5
(uncorrected known systematic effects included in the uncertainty).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.campaign.budget import Perturbation
from gonio.samples import BRDFSamples

__all__ = [
    "BudgetSamples",
    "blur_term",
    "budget_view",
    "capture_groups",
    "certificate_shapes",
    "certificate_terms",
    "digitiser_term",
    "direction_fields",
    "direction_terms",
    "exposure_terms",
    "glare_term",
    "has_direction_fields",
    "keep_direction_fields",
    "lamp_terms",
    "mean_over_pixels",
    "reillumination_term",
    "tilt_terms",
]


def capture_groups(samples: Any) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per sample: the index of its capture (θi, φi) and of its incidence (θi).

    Captures are numbered in the lexicographic order of their rounded ``(θi, φi)``, as
    ``np.unique(axis=0)`` numbers them, from the ranks of each column (a sort of integer
    codes instead of one of row records, which took 0.1 s for 170 000 samples). A
    :class:`BudgetSamples` view computes them once.
    """
    if isinstance(samples, BudgetSamples):
        return samples.groups
    return _capture_groups(samples.theta_i, samples.phi_i)


def _capture_groups(theta_i: NDArray, phi_i: NDArray) -> tuple[NDArray[np.int64], ...]:
    inc = np.unique(np.round(theta_i, 9), return_inverse=True)[1].ravel().astype(np.int64)
    phi = np.unique(np.round(phi_i, 9), return_inverse=True)[1].ravel().astype(np.int64)
    code = inc * (int(phi.max()) + 1 if phi.size else 1) + phi
    cap = np.unique(code, return_inverse=True)[1].ravel().astype(np.int64)
    return cap, inc


class BudgetSamples(BRDFSamples):
    """The budget's view of a samples table: the same columns (not copied), with the
    directions (:attr:`wi`, :attr:`wo`) and the capture groups (:func:`capture_groups`)
    computed once and read-only; the terms and the fit's Jacobian read them a few dozen
    times. Made per budget by :func:`budget_view` (nothing outlives it)."""

    @functools.cached_property
    def wi(self) -> NDArray[np.float64]:  # type: ignore[override]
        """Incident directions, shape ``(N, 3)`` (computed once, read-only)."""
        return _frozen(super().wi)

    @functools.cached_property
    def wo(self) -> NDArray[np.float64]:  # type: ignore[override]
        """Outgoing directions, shape ``(N, 3)`` (computed once, read-only)."""
        return _frozen(super().wo)

    @functools.cached_property
    def groups(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """:func:`capture_groups` of the table (computed once, read-only)."""
        cap, inc = _capture_groups(self.theta_i, self.phi_i)
        return _frozen(cap), _frozen(inc)


def _frozen(a: NDArray) -> NDArray:
    a.setflags(write=False)
    return a


def budget_view(samples: BRDFSamples) -> BudgetSamples:
    """``samples`` as a :class:`BudgetSamples` (itself if it is one already)."""
    if isinstance(samples, BudgetSamples):
        return samples
    return BudgetSamples(**{f.name: getattr(samples, f.name) for f in fields(samples)})


def _relative(samples: Any) -> tuple[NDArray, NDArray, NDArray]:
    d = np.abs(samples.phi_o - samples.phi_i) % (2.0 * math.pi)
    return samples.theta_i, samples.theta_o, np.where(d > math.pi, 2.0 * math.pi - d, d)


def _raw_shapes(ti: NDArray, to: NDArray, dphi: NDArray) -> NDArray:
    xi, xo = np.cos(ti), np.cos(to)
    return np.stack(
        [np.ones_like(xi), xi, xo, xi * xo, np.sin(ti) * np.sin(to) * np.cos(dphi), xo * xo], -1
    )


@functools.cache
def _orthonormaliser(max_deg: float = 85.0) -> NDArray:
    c = math.cos(math.radians(max_deg))
    x = c + (1.0 - c) * (np.arange(12) + 0.5) / 12
    p = (np.arange(12) + 0.5) / 12 * math.pi
    ti, to, dp = np.meshgrid(np.arccos(x), np.arccos(x), p, indexing="ij")
    f = _raw_shapes(ti, to, dp).reshape(-1, 6)
    return np.linalg.inv(np.linalg.cholesky(f.T @ f / f.shape[0])).T


def certificate_shapes(samples: Any) -> NDArray[np.float64]:
    """The six orthonormal deviation shapes at the samples' standard geometries, (n, 6)."""
    return _raw_shapes(*_relative(samples)) @ _orthonormaliser()


def certificate_terms(samples: Any, certificate: Any, corrected: bool) -> list[Perturbation]:
    """The standard's terms: its certificate's uncertainty, or its uncorrected shape."""
    y = samples.value
    if certificate is None:
        return []
    u = float(certificate.expanded_uncertainty) / float(certificate.coverage_factor)
    shapes = certificate_shapes(samples)
    out = [
        Perturbation(
            f"standard_certificate[{j}]",
            u / math.sqrt(6.0),
            "1",
            -y * shapes[:, j],
            note="certificate U/k over six smooth shapes",
        )
        for j in range(6)
    ]
    if not corrected:
        ti, to, dphi = _relative(samples)
        top = math.radians(float(certificate.theta_o_deg[-1]))
        r = certificate.factor_at(ti, np.minimum(to, top), dphi)
        out.append(
            Perturbation("standard_non_lambertian", 1.0, "1", -y * (r - 1.0), corrected=False,
                         note="the certified departure from Lambert's law, not applied")
        )  # fmt: skip
    return out


def exposure_terms(samples: Any, u_capture: float, name: str = "exposure") -> list[Perturbation]:
    """Independent relative errors of each sample capture's and standard capture's scale."""
    if u_capture <= 0:
        return []
    cap, inc = capture_groups(samples)
    y = samples.value
    return [
        Perturbation(f"{name}[sample]", u_capture, "1", y, kind="random", groups=cap,
                     note="per sample capture"),
        Perturbation(f"{name}[standard]", u_capture, "1", -y, kind="random", groups=inc,
                     note="per standard capture (shared by the rotations of an incidence)"),
    ]  # fmt: skip


def mean_over_pixels(model: Any, samples: Any, pixel_wo: NDArray, stride: int = 16) -> NDArray:
    """Per capture group: the mean of ``model`` over the image's pixels (directions
    ``pixel_wo`` (n, 3) in the dome frame, every ``stride``-th), in the sample frame of
    the capture (rotation = −φi for an arm at azimuth 0)."""
    from gonio.calibration.angles import to_sample_frame
    from gonio.geometry import to_vector

    cap, _ = capture_groups(samples)
    w = np.asarray(pixel_wo)[::stride]
    first = np.unique(cap, return_index=True)[1]  # each group's first sample
    out = np.zeros(first.size)
    for g, k in enumerate(first.tolist()):
        ti, pi = float(samples.theta_i[k]), float(samples.phi_i[k])
        wo = to_sample_frame(w, -pi)
        out[g] = float(np.mean(model(to_vector(ti, pi), wo)))
    return out


def glare_term(
    samples: Any, model: Any, pixel_wo: NDArray, u_glare: float, corrected: bool
) -> list[Perturbation]:
    """The veil's term: ``δy = g (ȳ − y)`` per unit glare fraction."""
    if u_glare <= 0:
        return []
    cap, _ = capture_groups(samples)
    ybar = mean_over_pixels(model, samples, pixel_wo)[cap]
    note = "residual after the dark-region estimate" if corrected else "uncorrected veil"
    return [Perturbation("veiling_glare", u_glare, "1", ybar - samples.value,
                         corrected=corrected, note=note)]  # fmt: skip


def lamp_terms(
    samples: Any, t_measured: NDArray, t_standard: NDArray, u_warmup: float, u_drift: float,
    anchors: tuple[NDArray, NDArray] | None = None, u_anchor: float = 0.0,
) -> list[Perturbation]:  # fmt: skip
    """The lamp's warm-up and drift between each sample capture (``t_measured``, s) and its
    standard's (``t_standard``): ``δy`` per unit warm-up and per unit drift (1/h).

    With ``anchors`` — the re-measured standards' times and their first captures' times
    (:mod:`gonio.calibration.drift`) — the samples were divided by the ratios interpolated
    between them: the terms are what the interpolation leaves of the lamp model, and each
    anchor's ratio carries the scatter ``u_anchor`` of its two captures' exposures (the
    interpolation weights of the anchor as ``δy``).
    """
    from gonio.simulator.lbl_effects import LAMP_WARMUP_TAU_S as tau

    y = samples.value
    tm, ts = np.asarray(t_measured, dtype=np.float64), np.asarray(t_standard, dtype=np.float64)
    shapes = {
        "lamp_warmup": (u_warmup, "1", lambda a, b: np.exp(-b / tau) - np.exp(-a / tau)),
        "lamp_drift": (u_drift, "1/h", lambda a, b: (a - b) / 3600.0),
    }
    out = []
    for name, (u, unit, f) in shapes.items():
        if u <= 0:
            continue
        rel = f(tm, ts)
        note = f"{name[5:]} between standard and sample, specification"
        if anchors is not None:
            ta, tsa = (np.asarray(x, dtype=np.float64) for x in anchors)
            order = np.argsort(ta, kind="stable")
            rel = rel - np.interp(tm, ta[order], f(ta, tsa)[order])
            note = f"{name[5:]} left by the re-measured standard, specification"
        out.append(Perturbation(name, u, unit, y * rel, corrected=anchors is not None,
                                note=note))  # fmt: skip
    if anchors is not None and u_anchor > 0:
        ta = np.asarray(anchors[0], dtype=np.float64)
        order = np.argsort(ta, kind="stable")
        for k in range(ta.size):  # the interpolation weight of anchor k at each sample
            unit_k = np.zeros(ta.size)
            unit_k[k] = 1.0
            w = np.interp(tm, ta[order], unit_k[order])
            out.append(Perturbation(f"lamp_anchor[{k}]", u_anchor, "1", -y * w,
                                    note="a re-measured standard's exposures"))  # fmt: skip
    return out


def _tangent(w: NDArray) -> tuple[NDArray, NDArray]:
    ref = np.where(np.abs(w[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(w, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(w, e1)


def blur_term(samples: Any, model: Any, sigma_rad: float, name: str = "blur") -> list[Perturbation]:
    """``δy = ½ σ² ∇²f`` per unit of ``σ²`` (rad²): a Gaussian blur of the reflected
    direction, uncorrected. ``u`` is ``σ²``."""
    if sigma_rad <= 0:
        return []
    wi, wo = samples.wi, samples.wo
    h = 0.01
    f0 = model(wi, wo)
    lap = np.zeros_like(f0)
    for e in _tangent(wo):
        fp = model(wi, _unit(wo + h * e))
        fm = model(wi, _unit(wo - h * e))
        lap += (fp + fm - 2.0 * f0) / (h * h)
    return [Perturbation(name, sigma_rad**2, "rad²", 0.5 * lap, corrected=False,
                         note="image blur: ½ σ² ∇²f")]  # fmt: skip


def digitiser_term(
    samples: Any, model: Any, lens: Any, image_shapes: Any, name: str = "digitiser"
) -> list[Perturbation]:
    """The digitiser's area average, a blur the point-spread model does not hold.

    Ward's images were "reduced before data reduction to a resolution of 108 by 80 pixels"
    (Ward 1992, §3): each digitised pixel is the mean of a box of ``bx × by`` camera pixels
    (``bx`` = the calibrated lens's width over the image's, ``by`` likewise). Beyond one
    camera pixel's own area (in the point-spread model), the box adds ``(b² − 1)/12``
    pixels² of variance per axis (a discrete uniform average of ``b`` pixel centres), i.e.
    an angular RMS ``σ = √((b̄² − 1)/12) / f_x`` with ``f_x`` the lens's pixels per radian
    and ``b̄² = (bx² + by²)/2``; the samples change by ``½ σ² ∇²f`` (:func:`blur_term`).
    Uncorrected. None for full-resolution images.

    Parameters
    ----------
    samples, model
        The samples and the fitted model.
    lens : FisheyeLens
        The calibrated lens at the camera's full resolution.
    image_shapes : iterable of (height, width)
        The shapes of the images the samples were reduced from.

    References
    ----------
    .. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer
       Graphics (Proc. SIGGRAPH '92) 26(2), 265-272, 1992, §3 (the 108 × 80 images).
    """
    shapes = {tuple(int(x) for x in s) for s in image_shapes if s is not None}
    if lens is None or len(shapes) != 1:
        return []
    h, w = shapes.pop()
    bx, by = float(lens.width) / w, float(lens.height) / h
    var_px = ((bx * bx + by * by) / 2.0 - 1.0) / 12.0
    if not var_px > 1e-12:
        return []
    terms = blur_term(samples, model, math.sqrt(var_px) / float(lens.fx), name)
    return [
        Perturbation(t.name, t.u, t.unit, t.dy, corrected=False,
                     note=f"area average of {bx:.3g} x {by:.3g} camera pixels (Ward 1992, §3)")
        for t in terms
    ]  # fmt: skip


def _unit(w: NDArray) -> NDArray:
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


#: cells per side of the equal-area square in which direction changes are averaged
GRID = 48
#: realisations of a random dome figure averaged for its term (Monte Carlo of its model;
#: the same realisations for every instrument, so too few are a bias shared by all of
#: them, not a scatter between them; reported as one row, ``dome_figure``). The figure's
#: effect is heavy-tailed (a few realisations whose waves meet the lobe dominate its
#: RMS), so the RMS converges slowly: rolled brass, modern, instrument 54, 3 angles x 2
#: rotations (``benchmarks/bench_dome_figure.py``), the alpha_x RMS of the first 4, 16,
#: 32, 64, 128 and 256 realisations 5.21, 5.76, 5.74, 6.99, 8.13 and 8.18 x 1e-5 (rho_s
#: 5.87, 6.53, 6.45, 7.70, 9.00 and 9.15 x 1e-4): 64 are 15 % below 256 there, 4 were 36 %
#: below. Each realisation's samples' change is kept for the budget and the design (0.7
#: MB each on the default campaign, single precision), so more would cost memory as well
#: as time (about 11 ms of processor time each in :func:`direction_fields`, kept with the
#: calibration by :mod:`gonio.campaign.calcache`, and 3.5 ms each in
#: :func:`direction_terms`).
FIGURE_REALISATIONS = 64
#: the budget's row of the dome figure's realisations (``dome_figure[k]`` each)
FIGURE_ROW = "dome_figure"
#: every how many pixels of the image circle the direction fields use
FIELD_STRIDE = 4
#: of those, every how many a ray is traced through a random dome figure (4: the same
#: instrument's U within 1.2 % of every second ray's, 128 realisations, 0.8 s less)
FIGURE_STRIDE = 4
#: RMS rim slope (rad) of the random figures traced for the term (then per unit slope): small
#: enough that the direction change is linear in it (1 rad turned rays by 2 rad)
FIGURE_STEP_RAD = 1e-3


def _cell(w: NDArray, grid: int = GRID) -> NDArray[np.int64]:
    from gonio.calibration.thinning import hemisphere_to_square

    q = np.clip((hemisphere_to_square(w) + 1.0) / 2.0, 0.0, 1.0 - 1e-12)
    return (q[:, 0] * grid).astype(np.int64) * grid + (q[:, 1] * grid).astype(np.int64)


def _cell_means(w0: NDArray, w1: NDArray, grid: int = GRID) -> NDArray:
    """Mean change ``w1 − w0`` of dome directions per cell (grid², 3)."""
    pc = _cell(w0, grid)
    d = w1 - w0
    cnt = np.bincount(pc, minlength=grid * grid)
    out = np.stack([np.bincount(pc, d[:, k], grid * grid) for k in range(3)], 1)
    return out / np.maximum(cnt, 1)[:, None]


def direction_fields(cal: Any) -> list[tuple[str, float, str, NDArray, bool]]:
    """The direction-change fields of the geometric terms, per unit of each (cached on
    ``cal``): ``(name, u, unit, cell means (grid², 3), corrected)``.

    * ``geometry[j]``: the mirror calibration's principal components (1 σ each);
    * ``lens_scale``: the lens calibration's focal-length uncertainty (both axes, 1 σ);
    * ``dome_figure[k]``: random dome figures of the specified RMS slope error
      (:func:`gonio.simulator.lbl_effects.slope_field`, realisations that are not the
      instrument's), each with ``u = 1/√K`` so that their sum of squares is the mean.
    """
    got = cal.__dict__.get("_direction_fields")
    if got is not None:
        return got

    out: list[tuple[str, float, str, NDArray, bool]] = []
    lens = cal.lens_model()
    mc = cal.mirror
    if lens is None or mc is None:
        cal.__dict__["_direction_fields"] = out
        return out
    from gonio.calibration.angles import reflection_directions

    # every FIELD_STRIDE-th pixel of the image circle: a cell mean needs a few, and the
    # Kannala-Brandt inverse of the whole grid takes a second
    uv = lens.pixel_grid().reshape(-1, 2)
    pix = np.flatnonzero(lens.in_field(uv))[::FIELD_STRIDE]
    cam = lens.unproject(uv[pix])
    wo0, ok0 = reflection_directions(cam, mc.geometry, mc.method)

    def field(cam1: NDArray, geo1: Any) -> NDArray:
        wo1, ok1 = reflection_directions(cam1, geo1, mc.method)
        both = ok0 & ok1
        return _cell_means(wo0[both], wo1[both])

    vals, vecs = np.linalg.eigh(np.asarray(mc.covariance, dtype=np.float64))
    for j in range(vals.size):
        if vals[j] > 0:
            g = mc.geometry
            for name, dv in zip(mc.names, vecs[:, j] * math.sqrt(vals[j])):
                g = _moved(g, name, dv)
            out.append((f"geometry[{j}]", 1.0, "σ", field(cam, g), True))
    u_f = float((cal.lens or {}).get("fx_u_rel", 0.0))
    if u_f > 0:
        from dataclasses import replace

        scaled = replace(lens, fx=lens.fx * (1 + u_f), fy=lens.fy * (1 + u_f))
        cam1 = scaled.unproject(uv[pix])
        out.append(("lens_scale", u_f, "1", field(cam1, mc.geometry) / u_f, True))
    slope = spec_rms(cal.specification.get("dome_slope_error"))
    if slope > 0:
        out += _figure_fields(mc, cam, wo0, ok0, slope, lens, uv[pix])
    cal.__dict__["_direction_fields"] = out
    return out


def keep_direction_fields(cal: Any, fields: list) -> None:
    """Give ``cal`` its direction fields made before (:func:`direction_fields` then returns
    them): those of the same calibration kept by :mod:`gonio.campaign.calcache`."""
    cal.__dict__["_direction_fields"] = list(fields)


def has_direction_fields(cal: Any) -> bool:
    """Whether ``cal`` holds its direction fields (made or kept): :func:`direction_fields`
    returns them without tracing."""
    return "_direction_fields" in getattr(cal, "__dict__", {})


def _figure_fields(
    mc: Any, cam: NDArray, wo0: NDArray, ok0: NDArray, slope: float, lens: Any, uv: NDArray
) -> list:
    """The dome figure's direction errors *after* the mirror calibration: each random
    figure also moves the calibration's spots, the refitted geometry absorbs part of the
    figure and adds a smooth error of its own (a wrong D/R scales every angle), and the
    reduction's error is the perturbed direction minus the refitted geometry's."""
    from gonio.simulator import lbl_effects as le
    from gonio.simulator.optics import Mirror

    g = mc.geometry
    mirror = Mirror(g.kind, g.radius, g.half_separation, 0.5, 0.45)
    keep = np.flatnonzero(ok0)[::FIGURE_STRIDE]  # a few rays per cell are enough
    r = max(mirror.semi_axes)
    spots = _spot_pixels(mc, lens, uv, wo0, ok0)
    out = []
    k_n = FIGURE_REALISATIONS
    h = FIGURE_STEP_RAD  # a small figure, so that the direction change is linear in it
    frame = le.dome_frame(mirror, cam[keep])  # the rays' dome points, shared by the figures
    tr0 = le.to_plane(*le.frame_rays(frame), 0.0)
    spot_rays = None if spots is None else _spot_rays(lens, spots, mirror)
    for k in range(k_n):
        seed = 2**40 + k  # a realisation of the dome-figure model, not this instrument's

        def sl(p, seed=seed):
            return le.slope_field(p, h, r, seed)

        tr = le.to_plane(*le.tilted_rays(frame, sl), 0.0)
        ok = tr["valid"] & tr0["valid"]
        wo_red = wo0[keep]
        if spots is not None:
            g1 = _refit_geometry(mc, lens, spots, mirror, sl, spot_rays)
            if g1 is not None:
                from gonio.calibration.angles import reflection_directions

                wo_red, ok1 = reflection_directions(cam[keep], g1, mc.method)
                ok = ok & ok1
        # per unit slope: the true direction's change minus the reduction's
        err = ((tr["wo"] - tr0["wo"]) - (wo_red - wo0[keep])) / h
        out.append((f"{FIGURE_ROW}[{k}]", slope / math.sqrt(k_n), "rad",
                    _cell_means(wo0[keep][ok], wo0[keep][ok] + err[ok]), False))  # fmt: skip
    return out


def _spot_pixels(
    mc: Any, lens: Any, uv: NDArray, wo: NDArray, ok: NDArray
) -> tuple[NDArray, NDArray, NDArray] | None:
    """The mirror calibration's spots (the directions of
    :data:`gonio.campaign.calibrate.MIRROR_ANGLES_DEG` at the arm's opposite azimuth) as
    the calibrated geometry images them: pixels, directions and ``∂wo/∂uv`` (n, 3, 2);
    searched from the pixels ``uv`` of :func:`direction_fields` and their directions."""
    from gonio.campaign.calibrate import MIRROR_ANGLES_DEG
    from gonio.geometry import to_vector

    dirs = to_vector(np.radians(MIRROR_ANGLES_DEG), math.pi)
    if not ok.any():
        return None
    uv_s, wo_s = uv[ok], wo[ok]
    out_uv, out_j = [], []
    for d in dirs:
        u = uv_s[int(np.argmax(wo_s @ d))].astype(np.float64)
        for _ in range(3):  # Newton steps on the pixel: wo(u) = d
            w, jac = _direction_jacobian(lens, mc, u)
            u = u + np.linalg.lstsq(jac, d - w, rcond=None)[0]
        out_uv.append(u)
        out_j.append(_direction_jacobian(lens, mc, u)[1])
    return np.array(out_uv), dirs, np.array(out_j)


def _direction_jacobian(lens: Any, mc: Any, u: NDArray) -> tuple[NDArray, NDArray]:
    from gonio.calibration.angles import reflection_directions

    pts = np.array([u, u + [0.5, 0.0], u - [0.5, 0.0], u + [0.0, 0.5], u - [0.0, 0.5]])
    w, _ = reflection_directions(lens.unproject(pts), mc.geometry, mc.method)
    return w[0], np.stack([w[1] - w[2], w[3] - w[4]], axis=1)


def _spot_rays(lens: Any, spots: tuple, mirror: Any) -> tuple:
    """The spots' camera rays through the dome without a figure: their directions and their
    :func:`~gonio.simulator.lbl_effects.dome_frame` (the same for every figure)."""
    from gonio.simulator import lbl_effects as le

    frame = le.dome_frame(mirror, lens.unproject(spots[0]))
    return le.to_plane(*le.frame_rays(frame), 0.0)["wo"], frame


def _refit_geometry(
    mc: Any, lens: Any, spots: tuple, mirror: Any, slope: Any, rays: tuple | None = None
) -> Any:
    """The mirror fit to the spots as a dome of figure ``slope`` moves them (first order:
    each spot's pixel shifted by ``−J⁺ δwo``), or None if the fit fails. ``rays``:
    :func:`_spot_rays` if made before."""
    from gonio.calibration.mirror import fit_mirror
    from gonio.simulator import lbl_effects as le

    uv, dirs, jac = spots
    w0, frame = _spot_rays(lens, spots, mirror) if rays is None else rays
    w1 = le.to_plane(*le.tilted_rays(frame, slope), 0.0)["wo"]
    moved = np.array([u - np.linalg.lstsq(j, dw, rcond=None)[0]
                      for u, j, dw in zip(uv, jac, w1 - w0)])  # fmt: skip
    try:
        return fit_mirror(moved, dirs, lens, mc.geometry, method=mc.method).geometry
    except (ValueError, np.linalg.LinAlgError):
        return None


def direction_terms(
    samples: Any, model: Any, cal: Any, fields: list | None = None
) -> list[Perturbation]:
    """Each direction field of :func:`direction_fields` as the samples' ``δy`` (per unit):
    ``∇f · δwo`` at each sample's dome direction (an arm at azimuth 0), the field
    interpolated bilinearly between the cells' means (a lookup of the cell's own mean is a
    piecewise-constant shift: a lobe inside one or two cells was moved, not stretched, and
    alpha's sensitivity to a direction *scale* came out 40-150 times too small). ``∇f``,
    the gradient on the sphere, once for every field: central differences of ``f`` along two
    tangents at a step of :data:`DIRECTION_STEP_RAD`. (Each field was differenced on its
    own before, ``(f(wo + ε δwo) − f(wo)) / ε`` with ``ε δwo`` of that RMS step: the same
    first order, 0.32 s for 36 fields on the default campaign's samples; the gradient and
    one sparse product take 0.24 s for 68, the dome figure's :data:`FIGURE_REALISATIONS`
    among them.)
    ``fields``: :func:`direction_fields` of ``cal`` if computed elsewhere."""
    fields = direction_fields(cal) if fields is None else fields
    if not fields:
        return []
    rot = -samples.phi_i
    w_s = samples.wo
    c, s = np.cos(rot), np.sin(rot)
    w_dome = np.stack([c * w_s[:, 0] - s * w_s[:, 1], s * w_s[:, 0] + c * w_s[:, 1], w_s[:, 2]], 1)
    # f's gradient on the sphere at each sample (central differences along two tangents,
    # DIRECTION_STEP_RAD), as the coefficients of a dome-frame change's components
    wi = samples.wi
    h = DIRECTION_STEP_RAD
    coef = np.zeros((3, len(w_s)))
    for e in _tangent(w_s):
        g = (model(wi, _unit(w_s + h * e)) - model(wi, _unit(w_s - h * e))) / (2.0 * h)
        # the dome frame's unit changes turned back into the sample frame, along e
        coef[0] += g * (c * e[:, 0] - s * e[:, 1])
        coef[1] += g * (s * e[:, 0] + c * e[:, 1])
        coef[2] += g * e[:, 2]
    # δy of every field: one sparse (n, 3 grid²) matrix, each sample's four corners'
    # bilinear weights times its gradient's three coefficients, times the fields' cells
    from scipy.sparse import csr_matrix

    corners, weights = _bilinear(w_dome)
    n = len(w_s)
    cols = (3 * corners[:, :, None] + np.arange(3)).reshape(n, 12)
    vals = (weights[:, :, None] * coef.T[:, None, :]).reshape(n, 12)
    grad = csr_matrix((vals.ravel(), cols.ravel(), np.arange(0, 12 * n + 1, 12)),
                      shape=(n, 3 * GRID * GRID))  # fmt: skip
    out = []
    figure = f"{FIGURE_ROW}["
    for k in range(0, len(fields), _FIELD_CHUNK):  # a few fields at once: (chunk, n)
        part = fields[k : k + _FIELD_CHUNK]
        cells = np.stack([f[3].ravel() for f in part])  # (chunk, 3 grid²)
        rows = np.ascontiguousarray((grad @ cells.T).T)  # each field's δy a row
        if any(f[0].startswith(figure) for f in part):  # the dome figure's realisations:
            single = rows.astype(np.float32)  # many, kept for the design
        for j, (name, u, unit, _means, corrected) in enumerate(part):
            row = FIGURE_ROW if name.startswith(figure) else None
            dy = rows[j] if row is None else single[j]
            note = ("direction change of the calibrated geometry" if corrected else
                    "dome figure" if row is None else "dome figure, Monte Carlo of its "
                    "specification (the realisations' root sum of squares)")  # fmt: skip
            out.append(Perturbation(name, u, unit, dy, corrected=corrected, note=note, row=row))
    return out


#: direction fields whose δy are made together (:func:`direction_terms`)
_FIELD_CHUNK = 8


#: the step (rad) of the central differences of f along two tangents: its gradient on the
#: sphere, which every direction field's δy is (:func:`direction_terms`)
DIRECTION_STEP_RAD = 1e-4


def _bilinear(w: NDArray, grid: int = GRID) -> tuple[NDArray[np.int64], NDArray]:
    """The four cells around each direction's point of the equal-area square and their
    bilinear weights (an empty cell at the rim counts as no change)."""
    from gonio.calibration.thinning import hemisphere_to_square

    q = np.clip((hemisphere_to_square(w) + 1.0) / 2.0, 0.0, 1.0 - 1e-12) * grid - 0.5
    i0 = np.clip(np.floor(q).astype(np.int64), 0, grid - 2)
    t = np.clip(q - i0, 0.0, 1.0)
    corners = np.stack([(i0[:, 0] + a) * grid + (i0[:, 1] + b) for a in (0, 1) for b in (0, 1)], 1)
    weights = np.stack([(1 - t[:, 0] if a == 0 else t[:, 0]) * (1 - t[:, 1] if b == 0 else t[:, 1])
                        for a in (0, 1) for b in (0, 1)], 1)  # fmt: skip
    return corners, weights


def tilt_terms(samples: Any, model: Any, tilt_rms: float) -> list[Perturbation]:
    """An unknown tilt of the sample's normal (RMS ``tilt_rms`` rad, random azimuth): two
    components, about the sample's x and y axes, each ``u = tilt_rms/√2``.

    The sample sees ``T wi`` and ``T wo`` and is lit by ``cos θi'`` instead of the standard's
    ``cos θi``: ``y = f(T wi, T wo) cos θi' / cos θi``; ``δy`` per radian by a difference.
    """
    if tilt_rms <= 0:
        return []
    wi, wo = samples.wi, samples.wo
    f0 = model(wi, wo)
    h = 1e-3
    out = []
    for axis, name in ((0, "sample_tilt[x]"), (1, "sample_tilt[y]")):
        ca, sa = math.cos(h), math.sin(h)
        if axis == 0:
            rm = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
        else:
            rm = np.array([[ca, 0.0, sa], [0.0, 1.0, 0.0], [-sa, 0.0, ca]])
        wi1, wo1 = wi @ rm.T, wo @ rm.T
        cos_ratio = np.clip(wi1[:, 2], 0.0, None) / np.maximum(wi[:, 2], 1e-12)
        dy = (model(wi1, wo1) * cos_ratio - f0) / h
        out.append(Perturbation(name, tilt_rms / math.sqrt(2.0), "rad", dy, corrected=False,
                                note="sample tilt, specification"))  # fmt: skip
    return out


def _albedo_grid(model: Any, theta: NDArray, n: int = 48) -> NDArray:
    """Directional albedo at polar angles ``theta`` (φ = 0) by a midpoint rule in
    (cos² θo, φo), ``n × 2n`` directions (rolled brass: within 2.3 % of the quadrature)."""
    u = (np.arange(n) + 0.5) / n  # cos² θo: dω cos θo = ½ d(cos²θo) dφ
    p = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * math.pi
    ct = np.sqrt(u)[:, None]
    st = np.sqrt(1.0 - u)[:, None]
    wo = np.stack(np.broadcast_arrays(st * np.cos(p), st * np.sin(p), ct), -1).reshape(-1, 3)
    out = []
    for t in theta:
        wi = np.array([math.sin(t), 0.0, math.cos(t)])
        f = np.asarray(model(wi, wo), dtype=np.float64)
        out.append(float(f.mean()) * math.pi)
    return np.array(out)


def reillumination_term(
    samples: Any, model: Any, r: float, rho_standard: float, lit_fraction: NDArray
) -> list[Perturbation]:
    """Light the dome returns to the sample (fraction ``r`` of what it reflects): an extra
    diffuse radiance ``r A a(θi) a(θo) / π`` on the sample and ``r A ρ² / π`` on the
    standard (``a`` the directional albedo, ``A`` the lit fraction of the sample disk), so
    ``δy = A [a(θi) a(θo) / π − y ρ]`` per unit ``r`` (uncorrected, specification)."""
    if r <= 0:
        return []
    th = np.radians(np.linspace(0.0, 89.0, 12))
    a = _albedo_grid(model, th)
    ai = np.interp(samples.theta_i, th, a)
    ao = np.interp(samples.theta_o, th, a)
    dy = lit_fraction * (ai * ao / math.pi - samples.value * rho_standard)
    return [Perturbation("reillumination", r, "1", dy, corrected=False,
                         note="dome -> lens front -> sample, specification")]  # fmt: skip


def _moved(g: Any, name: str, dv: float) -> Any:
    from gonio.calibration.mirror import _apply, _get

    return _apply(g, {name: _get(g, name) + float(dv)})


def spec_rms(spec: Mapping[str, Any] | None) -> float:
    """RMS of a specification entry ``{"typical", "spread"}`` (0 if absent)."""
    if not spec:
        return 0.0
    return float(math.hypot(float(spec.get("typical", 0.0)), float(spec.get("spread", 0.0))))
