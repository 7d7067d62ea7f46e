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
    The calibrated dome parameters' covariance (:class:`~gonio.calibration.mirror.
    MirrorCalibration`), split into independent components; each moves every pixel's
    reflection direction, and ``δy = f(wo + δwo) − f(wo)`` with the fitted model.
``blur``
    An image blur of angular RMS ``σ`` per axis (pixel area, diffraction) changes a smooth
    BRDF by ``δy = ½ σ² ∇²f`` (second order of the Gaussian average; the Laplacian on the
    sphere from the fitted model).

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
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio.campaign.budget import Perturbation

__all__ = [
    "blur_term",
    "capture_groups",
    "certificate_shapes",
    "certificate_terms",
    "exposure_terms",
    "geometry_terms",
    "glare_term",
    "mean_over_pixels",
]


def capture_groups(samples: Any) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per sample: the index of its capture (θi, φi) and of its incidence (θi)."""
    key = np.round(np.stack([samples.theta_i, samples.phi_i], 1), 9)
    cap = np.unique(key, axis=0, return_inverse=True)[1].ravel()
    inc = np.unique(np.round(samples.theta_i, 9), return_inverse=True)[1].ravel()
    return cap.astype(np.int64), inc.astype(np.int64)


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
    out = np.zeros(int(cap.max()) + 1 if cap.size else 0)
    for g in range(out.size):
        k = int(np.flatnonzero(cap == g)[0])
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


def _unit(w: NDArray) -> NDArray:
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def geometry_terms(
    samples: Any, model: Any, lens: Any, mirror_cal: Any, *, grid: int = 48
) -> list[Perturbation]:
    """The calibrated dome parameters' terms (one per principal component of their
    covariance, ``u = 1`` standard deviation along it).

    Each component's change of the pixels' dome-frame reflection directions is averaged in
    cells of the equal-area square (``grid²`` cells) and looked up at each sample's dome
    direction.
    """
    from gonio.calibration.reduce import pixel_geometry
    from gonio.calibration.thinning import hemisphere_to_square

    if mirror_cal is None or lens is None:
        return []
    cov = np.asarray(mirror_cal.covariance, dtype=np.float64)
    vals, vecs = np.linalg.eigh(cov)
    wo0, ok0 = pixel_geometry(lens, mirror_cal.geometry, mirror_cal.method)
    # the samples' dome directions (arm at azimuth 0: rotation = -φi)
    rot = -samples.phi_i
    w_s = samples.wo
    c, s = np.cos(rot), np.sin(rot)
    w_dome = np.stack([c * w_s[:, 0] - s * w_s[:, 1], s * w_s[:, 0] + c * w_s[:, 1], w_s[:, 2]], 1)

    def cell(w: NDArray) -> NDArray:
        q = np.clip((hemisphere_to_square(w) + 1.0) / 2.0, 0.0, 1.0 - 1e-12)
        return (q[:, 0] * grid).astype(np.int64) * grid + (q[:, 1] * grid).astype(np.int64)

    sample_cell = cell(w_dome)
    f0 = model(samples.wi, w_s)
    out = []
    for j in range(vals.size):
        if not vals[j] > 0:
            continue
        step = vecs[:, j] * math.sqrt(vals[j])
        g = mirror_cal.geometry
        for name, dv in zip(mirror_cal.names, step):
            g = _moved(g, name, dv)
        wo1, ok1 = pixel_geometry(lens, g, mirror_cal.method)
        both = (ok0 & ok1).ravel()
        a0 = wo0.reshape(-1, 3)[both]
        d = wo1.reshape(-1, 3)[both] - a0
        pc = cell(a0)
        cnt = np.bincount(pc, minlength=grid * grid)
        mean_d = np.stack([np.bincount(pc, d[:, k], grid * grid) for k in range(3)], 1)
        mean_d /= np.maximum(cnt, 1)[:, None]
        dd = mean_d[sample_cell]
        w1 = _unit(w_dome + dd)
        back = np.stack([c * w1[:, 0] + s * w1[:, 1], -s * w1[:, 0] + c * w1[:, 1], w1[:, 2]], 1)
        out.append(
            Perturbation(f"geometry[{j}]", 1.0, "σ", model(samples.wi, back) - f0,
                         note="mirror calibration covariance, principal component")
        )  # fmt: skip
    return out


def _moved(g: Any, name: str, dv: float) -> Any:
    from gonio.calibration.mirror import _apply, _get

    return _apply(g, {name: _get(g, name) + float(dv)})


def spec_rms(spec: Mapping[str, Any] | None) -> float:
    """RMS of a specification entry ``{"typical", "spread"}`` (0 if absent)."""
    if not spec:
        return 0.0
    return float(math.hypot(float(spec.get("typical", 0.0)), float(spec.get("spread", 0.0))))
