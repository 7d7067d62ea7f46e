"""The reduction pipeline: raw LBL captures (+ side-cars) → :class:`~gonio.samples.BRDFSamples`.

For one incidence (θi, φi) a lab has three captures — the sample, the diffuse standard and the
background (source on, no sample) — each possibly a bracket of exposures, optionally with
dark frames. :func:`reduce_capture` runs Ward's §3.2 chain on them:

1. merge each bracket into a linear signal with its standard error (:mod:`.merge`; a linear
   CCD by the noise-optimal weighted mean, a non-linear camera by OpenCV's Debevec method);
2. eq. 2 at every pixel with error propagation; pixels where the standard is not
   significantly above the background are masked (:func:`.radiometry.eq2`);
3. pixel → camera direction by the (calibrated) fisheye lens, → reflection direction by eq. 3
   or the exact traced map, → sample frame (:mod:`.angles`);
4. thinning to a uniform density with the specular peak kept at high resolution
   (:mod:`.thinning`).

Only what a real instrument's files hold is used: the images and their side-cars (exposure,
sensor gain/read noise/black level, lens, mirror, θi, φi, sample rotation, ρ_standard), a lens
calibration file and a mirror calibration if the lab made them. See ``/work/notes``'s
``calibration.md`` for the keys.

References
----------
003_0632ad07325ce89d.txt (Ward 1992) §3.2: eq. 2, eq. 3, data thinning.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from gonio.calibration.angles import (
    MirrorGeometry,
    reflection_directions,
    to_sample_frame,
)
from gonio.calibration.merge import calibrate_response, merge_debevec, merge_linear
from gonio.calibration.radiometry import Measurement, Reflectance, _meta_get, eq2
from gonio.calibration.thinning import thin
from numpy.typing import ArrayLike, NDArray

from gonio.geometry import to_spherical, to_vector
from gonio.samples import BRDFSamples

__all__ = [
    "Capture",
    "ReductionResult",
    "is_linear",
    "load_capture",
    "load_lens",
    "measure",
    "pixel_geometry",
    "reduce_capture",
    "reduce_many",
]


@dataclass
class Capture:
    """One scene (sample, standard or background) at one incidence: a bracket of frames.

    Attributes
    ----------
    frames : list of (image, metadata)
        Raw frames (2-D arrays of DN) and their side-car dicts, one per exposure.
    darks : list of arrays or None, optional
        A dark frame per exposure (``None`` entries allowed).
    """

    frames: list[tuple[NDArray, dict[str, Any]]]
    darks: list[NDArray | None] | None = None

    def __post_init__(self) -> None:
        if not self.frames:
            raise ValueError("a Capture needs at least one frame, got none")
        fr = []
        for k, f in enumerate(self.frames):
            if not (isinstance(f, tuple | list) and len(f) == 2 and isinstance(f[1], Mapping)):
                raise ValueError(f"frames[{k}] must be an (image, metadata dict) pair")
            fr.append((np.asarray(f[0]), dict(f[1])))
        self.frames = fr
        if self.darks is not None and len(self.darks) != len(self.frames):
            raise ValueError(f"got {len(self.frames)} frames but {len(self.darks)} dark frames")

    @classmethod
    def single(cls, image: ArrayLike, meta: Mapping[str, Any], dark: ArrayLike | None = None):
        """A capture of one frame."""
        return cls([(np.asarray(image), dict(meta))], None if dark is None else [dark])

    @property
    def meta(self) -> dict[str, Any]:
        """The first frame's metadata (geometry is shared by the bracket)."""
        return self.frames[0][1]

    @property
    def images(self) -> list[NDArray]:
        """The raw frames."""
        return [f[0] for f in self.frames]

    @property
    def metas(self) -> list[dict[str, Any]]:
        """The frames' metadata."""
        return [f[1] for f in self.frames]


def load_capture(
    paths: Sequence[str | os.PathLike] | str | os.PathLike,
    dark_paths: Sequence[str | os.PathLike | None] | None = None,
) -> Capture:
    """Read image files and their JSON side-cars (``image.png.json``) into a :class:`Capture`."""
    from gonio.imageio import read_image

    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    frames = []
    for p in paths:
        img, meta = read_image(p, require_metadata=True)
        if img.ndim != 2:
            raise ValueError(f"{p}: expected a single-channel raw image, got shape {img.shape}")
        frames.append((img, meta))
    darks = None
    if dark_paths is not None:
        darks = [None if d is None else read_image(d)[0] for d in dark_paths]
    return Capture(frames, darks)


def is_linear(meta: Mapping[str, Any]) -> bool:
    """Whether the side-car describes a linear sensor (no ``response`` / gamma ≠ 1)."""
    resp = _meta_get(meta, ("response",))
    gamma = _meta_get(meta, ("response_gamma",), 1.0)
    return resp in (None, "linear") and float(gamma) == 1.0


def measure(capture: Capture, *, response: ArrayLike | None = None) -> Measurement:
    """Merge a capture's bracket into one linear signal (linear or Debevec path)."""
    if is_linear(capture.meta):
        return merge_linear(capture.images, capture.metas, capture.darks)
    imgs = [_to_u8(a, m) for a, m in capture.frames]
    if response is None:
        response = calibrate_response(imgs, capture.metas)
    return merge_debevec(imgs, capture.metas, response)


def _to_u8(img: NDArray, meta: Mapping[str, Any]) -> NDArray[np.uint8]:
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    top = float(_meta_get(meta, ("max_dn",), 0) or 0)
    if not top:
        top = 2 ** int(_meta_get(meta, ("adc_bits",), 16)) - 1
    return np.clip(np.rint(a.astype(np.float64) * (255.0 / top)), 0, 255).astype(np.uint8)


def load_lens(lens: Any, width: int | None = None, height: int | None = None):
    """A :class:`~gonio.simulator.lenses.FisheyeLens` from a lens, a dict, or a JSON file.

    A lens-calibration file (``gonio calibrate-lens``) holds ``{"lens": {...}, ...}``. If
    ``width``/``height`` differ from the lens's image size the lens is rescaled (binning).
    """
    from gonio.simulator.lenses import FisheyeLens

    if isinstance(lens, str | os.PathLike):
        p = Path(lens)
        if not p.is_file():
            raise ValueError(f"lens calibration file {str(p)!r} does not exist")
        try:
            lens = json.loads(p.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{p}: not a JSON lens calibration ({exc})") from None
    if isinstance(lens, Mapping):
        lens = FisheyeLens.from_dict(dict(lens.get("lens", lens)))
    if not isinstance(lens, FisheyeLens):
        raise ValueError(f"lens must be a FisheyeLens, dict or file path, got {lens!r}")
    if width is not None and (lens.width, lens.height) != (width, height):
        lens = lens.resized(width, height)
    return lens


@lru_cache(maxsize=16)
def _geometry_cached(lens_json: str, mirror_json: str, method: str):
    from gonio.simulator.lenses import FisheyeLens

    lens = FisheyeLens.from_dict(json.loads(lens_json))
    md = json.loads(mirror_json)
    geom = MirrorGeometry.from_metadata(md)
    uv = lens.pixel_grid()
    cam = lens.unproject(uv)
    inf = lens.in_field(uv)
    wo, ok = reflection_directions(cam, geom, method)
    valid = inf & ok & (wo[..., 2] > 0.0)
    for a in (wo, valid):
        a.setflags(write=False)
    return wo, valid


def pixel_geometry(
    lens: Any, mirror: MirrorGeometry | Mapping[str, Any], method: str = "eq3"
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Dome-frame reflection direction of every pixel and its validity (cached).

    Returns ``wo (H, W, 3)`` and ``valid (H, W)`` — inside the image circle, hitting the
    dome, above the sample plane.
    """
    lens = load_lens(lens)
    geom = mirror if isinstance(mirror, MirrorGeometry) else MirrorGeometry.from_metadata(mirror)
    return _geometry_cached(
        json.dumps(lens.to_dict(), sort_keys=True), json.dumps(geom.to_dict()), method
    )


@dataclass
class ReductionResult:
    """Output of :func:`reduce_capture`.

    Attributes
    ----------
    samples : BRDFSamples
        The reduced (thinned) table, sample frame.
    pixels : dict
        Per-pixel data before thinning: ``wo`` (N, 3) sample frame, ``value``, ``sigma``,
        ``uv`` (N, 2) pixel coordinates, ``wi`` (3,).
    reflectance : Reflectance
        The eq. 2 images (value, sigma, mask) over the full frame.
    stats : dict
        JSON-ready counts and timings.
    """

    samples: BRDFSamples
    pixels: dict[str, NDArray]
    reflectance: Reflectance
    stats: dict[str, Any] = field(default_factory=dict)


def _angle(meta: Mapping[str, Any], key: str, default: float | None = None) -> float:
    v = meta.get(key, default)
    if v is None:
        raise ValueError(f"image metadata lacks {key!r} (radians)")
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"metadata {key!r} must be a number (radians), got {v!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"metadata {key!r} must be finite, got {v!r}")
    return v


def reduce_capture(
    measured: Capture,
    standard: Capture,
    background: Capture,
    *,
    lens: Any = None,
    mirror: MirrorGeometry | Mapping[str, Any] | None = None,
    method: str = "eq3",
    rho_standard: float | None = None,
    thinning: bool | Mapping[str, Any] = True,
    threshold: float = 5.0,
    response: ArrayLike | None = None,
) -> ReductionResult:
    """Reduce one incidence: sample, standard and background captures → BRDF samples.

    Parameters
    ----------
    measured, standard, background : Capture
        The three captures at the same incidence (brackets allowed; exposures may differ).
    lens : FisheyeLens, dict or path, optional
        Lens model or a lens-calibration JSON file; default: ``measured.meta["lens"]``.
    mirror : MirrorGeometry or dict, optional
        Dome geometry (nominal or calibrated); default ``measured.meta["mirror"]``.
    method : {"eq3", "exact"}
        Reflection angles by Ward's eq. 3 or by the exact traced map.
    rho_standard : float, optional
        Reflectance of the standard; default the side-cars' ``rho_standard``.
    thinning : bool or dict
        ``True``: :func:`~gonio.calibration.thinning.thin` with defaults; a dict: its keyword
        arguments; ``False``: one row per unmasked pixel.
    threshold : float
        Eq. 2 masking threshold in standard errors.
    response : array_like (256,), optional
        Camera response for a non-linear camera; recovered from the standard's bracket
        if not given.

    Returns
    -------
    ReductionResult
    """
    t0 = time.perf_counter()
    for name, c in (("measured", measured), ("standard", standard), ("background", background)):
        if not isinstance(c, Capture):
            raise ValueError(f"{name} must be a Capture, got {type(c).__name__}")
    meta = measured.meta
    shape = measured.frames[0][0].shape
    for name, c in (("standard", standard), ("background", background)):
        if c.frames[0][0].shape != shape:
            raise ValueError(
                f"{name} image shape {c.frames[0][0].shape} differs from the measurement's {shape}"
            )
    if rho_standard is None:
        for c in (standard, measured, background):
            if c.meta.get("rho_standard") is not None:
                rho_standard = c.meta["rho_standard"]
                break
    if rho_standard is None:
        raise ValueError("rho_standard not given and not found in the side-cars")

    nonlinear = not is_linear(meta)
    if nonlinear and response is None:
        imgs = [_to_u8(a, m) for a, m in standard.frames]
        response = calibrate_response(imgs, standard.metas)
    m_meas = measure(measured, response=response)
    m_std = measure(standard, response=response)
    m_bg = measure(background, response=response)
    t1 = time.perf_counter()
    refl = eq2(m_meas, m_std, m_bg, float(rho_standard), threshold=threshold)
    t2 = time.perf_counter()

    lens_obj = load_lens(meta.get("lens") if lens is None else lens, shape[1], shape[0])
    if mirror is None:
        if "mirror" not in meta:
            raise ValueError("mirror geometry not given and not in the side-car ('mirror')")
        mirror = meta["mirror"]
    wo_dome, gvalid = pixel_geometry(lens_obj, mirror, method)
    theta_i = _angle(meta, "theta_i")
    phi_i = _angle(meta, "phi_i", 0.0)
    rotation = _angle(meta, "sample_rotation", 0.0)
    if not 0.0 <= theta_i < math.pi / 2:
        raise ValueError(f"theta_i = {theta_i!r} rad must be in [0, pi/2)")

    keep = refl.mask & gvalid
    if not keep.any():
        n_sat = sum(int(np.count_nonzero(~m.valid & gvalid)) for m in (m_meas, m_std, m_bg))
        raise ValueError(
            f"no pixel survived eq. 2 masking ({int(np.count_nonzero(gvalid))} pixels see the "
            f"dome; {n_sat} saturated readings): every standard pixel is saturated or not "
            "significantly above the background — check exposures"
        )
    wo = to_sample_frame(wo_dome[keep], rotation)
    value = refl.value[keep]
    sigma = refl.sigma[keep]
    vv, uu = np.nonzero(keep)
    wi = to_vector(theta_i, phi_i)
    t3 = time.perf_counter()

    thin_stats: dict[str, Any] | None = None
    if thinning is False:
        w_out, v_out, s_out = wo, value, sigma
    else:
        kw = {} if thinning is True else dict(thinning)
        tr = thin(wo, value, sigma, **kw)
        w_out, v_out, s_out = tr.wo, tr.value, tr.sigma
        thin_stats = tr.summary()
    t4 = time.perf_counter()

    to, po = to_spherical(w_out)
    to = np.clip(to, 0.0, math.pi / 2)
    n = v_out.shape[0]
    md = {
        "source": "gonio.calibration.reduce_capture",
        "method": method,
        "rho_standard": float(rho_standard),
        "mirror": mirror.to_dict() if isinstance(mirror, MirrorGeometry) else dict(mirror),
        "lens_model": lens_obj.model,
    }
    for k in ("instrument", "seed", "noise"):
        if k in meta:
            md[k] = meta[k]
    samples = BRDFSamples(np.full(n, theta_i), np.full(n, phi_i), to, po, v_out, s_out, metadata=md)
    stats = {
        "theta_i": theta_i,
        "phi_i": phi_i,
        "sample_rotation": rotation,
        "nonlinear_camera": nonlinear,
        "n_pixels": int(np.prod(shape)),
        "n_geometry_valid": int(np.count_nonzero(gvalid)),
        "n_masked_eq2": int(np.count_nonzero(gvalid & ~refl.mask)),
        "n_before": int(value.size),
        "n_after": int(n),
        "thinning": thin_stats,
        "timings_s": {
            "merge": t1 - t0,
            "eq2": t2 - t1,
            "angles": t3 - t2,
            "thinning": t4 - t3,
            "total": t4 - t0,
        },
    }
    pixels = {"wo": wo, "value": value, "sigma": sigma, "uv": np.stack([uu, vv], 1), "wi": wi}
    return ReductionResult(samples, pixels, refl, stats)


def reduce_many(
    triples: Sequence[tuple[Capture, Capture, Capture]], **kwargs: Any
) -> tuple[BRDFSamples, list[dict[str, Any]]]:
    """Reduce several incidences and concatenate: returns the table and per-capture stats."""
    if not triples:
        raise ValueError("triples must hold at least one (measured, standard, background)")
    results = [reduce_capture(*t, **kwargs) for t in triples]
    table = BRDFSamples.concatenate([r.samples for r in results])
    return table, [r.stats for r in results]
