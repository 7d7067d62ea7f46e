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
calibration file and a mirror calibration if the lab made them. The side-car keys a real
instrument writes are :data:`gonio.campaign.knowledge.SIDECAR_FIELDS` and
:data:`gonio.campaign.knowledge.SENSOR_FIELDS`; the formats are in ``docs/architecture.md``
("File formats").

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992 §3.2: eq. 2, eq. 3, data thinning.
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
from gonio.calibration.consistency import sidecar_angle
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
    "reduce_selected",
    "standard_factor",
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
    sources : list of str, optional
        Where each frame came from (its file; :func:`load_capture` fills it in), named by
        the side-car consistency errors (:mod:`gonio.calibration.consistency`).
    """

    frames: list[tuple[NDArray, dict[str, Any]]]
    darks: list[NDArray | None] | None = None
    sources: list[str] | None = None

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
        if self.sources is not None and len(self.sources) != len(self.frames):
            raise ValueError(f"got {len(self.frames)} frames but {len(self.sources)} sources")

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
    from gonio.io.images import read_image

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
    return Capture(frames, darks, [str(p) for p in paths])


def is_linear(meta: Mapping[str, Any]) -> bool:
    """Whether the side-car describes a linear sensor (no ``response`` / gamma ≠ 1)."""
    resp = _meta_get(meta, ("response",))
    gamma = _meta_get(meta, ("response_gamma",), 1.0)
    return resp in (None, "linear") and float(gamma) == 1.0


def measure(
    capture: Capture, *, response: ArrayLike | None = None, variance: str = "own"
) -> Measurement:
    """Merge a capture's bracket into one linear signal (linear or Debevec path).

    ``variance`` is :func:`~gonio.calibration.merge.merge_linear`'s (linear path). The linear
    merge is cached on the capture, so a standard or background shared by several sample
    rotations is merged once.
    """
    if is_linear(capture.meta):
        cache = capture.__dict__.setdefault("_merged", {})
        if variance not in cache:
            cache[variance] = merge_linear(
                capture.images, capture.metas, capture.darks, variance=variance
            )
        return cache[variance]
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
        from gonio.io.jsonfile import read_document

        return read_document(p, lambda d: load_lens(d, width, height), what="lens calibration")
    if isinstance(lens, Mapping):
        lens = FisheyeLens.from_dict(dict(lens.get("lens", lens)))
    if not isinstance(lens, FisheyeLens):
        raise ValueError(f"lens must be a FisheyeLens, dict or file path, got {lens!r}")
    if width is not None and (lens.width, lens.height) != (width, height):
        lens = lens.resized(width, height)
    return lens


@lru_cache(maxsize=4)
def _lens_grid(lens_json: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Camera rays ``(H, W, 3)`` and field angles ``(H, W)`` of a lens's pixel grid, from one
    inverse of its radial map (cached per lens: :func:`pixel_geometry` and
    :func:`grid_field_angle` need the same inverse of the same grid)."""
    from gonio.simulator.lenses import FisheyeLens

    lens = FisheyeLens.from_dict(json.loads(lens_json))
    cam, theta = lens.unproject_with_angle(lens.pixel_grid())
    for a in (cam, theta):
        a.setflags(write=False)
    return cam, theta


def grid_field_angle(lens: Any) -> NDArray[np.float64]:
    """Field angle θ of every pixel of ``lens`` (a lens, its dict or file), ``(H, W)``,
    read-only and cached per lens (the rays of :func:`pixel_geometry` come from the same
    inverse of the radial map)."""
    lens = load_lens(lens)
    return _lens_grid(json.dumps(lens.to_dict(), sort_keys=True))[1]


@lru_cache(maxsize=16)
def _geometry_cached(lens_json: str, mirror_json: str, method: str):
    from gonio.simulator.lenses import FisheyeLens

    lens = FisheyeLens.from_dict(json.loads(lens_json))
    md = json.loads(mirror_json)
    geom = MirrorGeometry.from_metadata(md)
    uv = lens.pixel_grid()
    cam = _lens_grid(lens_json)[0]
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
    reflectance : Reflectance or None
        The eq. 2 images (value, sigma, mask) over the full frame (``None`` from
        :func:`reduce_selected`, which reduces only the selected pixels).
    stats : dict
        JSON-ready counts and timings.
    """

    samples: BRDFSamples
    pixels: dict[str, NDArray]
    reflectance: Reflectance | None
    stats: dict[str, Any] = field(default_factory=dict)


def _check_triple(
    measured: Capture, standard: Capture, background: Capture, rho_standard: float | None
) -> tuple[dict[str, Any], tuple[int, ...], float]:
    """Type, shape and side-car consistency checks of the three captures
    (:func:`~gonio.calibration.consistency.check_captures`); ρ_standard from the side-cars
    if needed."""
    from gonio.calibration.consistency import check_captures

    triple = {"measured": measured, "standard": standard, "background": background}
    for name, c in triple.items():
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
    check_captures(triple)
    try:
        rho = float(rho_standard)
    except (TypeError, ValueError):
        raise ValueError(f"rho_standard must be a number in (0, 1], got {rho_standard!r}") from None
    if not 0.0 < rho <= 1.0:
        raise ValueError(f"rho_standard must be a number in (0, 1], got {rho_standard!r}")
    return meta, shape, rho


def _scene(meta: Mapping[str, Any], shape: tuple[int, ...], lens: Any, mirror: Any, method: str):
    """Lens, mirror, cached pixel geometry and the incidence/rotation angles of a capture."""
    lens_obj = load_lens(meta.get("lens") if lens is None else lens, shape[1], shape[0])
    if mirror is None:
        if "mirror" not in meta:
            raise ValueError("mirror geometry not given and not in the side-car ('mirror')")
        mirror = meta["mirror"]
    wo_dome, gvalid = pixel_geometry(lens_obj, mirror, method)
    theta_i = sidecar_angle(meta, "theta_i", "image metadata")
    phi_i = sidecar_angle(meta, "phi_i", "image metadata", 0.0)
    rotation = sidecar_angle(meta, "sample_rotation", "image metadata", 0.0)
    if not 0.0 <= theta_i < math.pi / 2:
        raise ValueError(f"theta_i = {theta_i!r} rad must be in [0, pi/2)")
    return lens_obj, mirror, wo_dome, gvalid, theta_i, phi_i, rotation


def _table(wo, value, sigma, meta, theta_i, phi_i, method, rho_standard, mirror, lens_obj, src):
    """The reduced samples of one capture as a :class:`BRDFSamples` with provenance."""
    to, po = to_spherical(wo)
    to = np.clip(to, 0.0, math.pi / 2)
    n = value.shape[0]
    md = {
        "source": src,
        "method": method,
        "rho_standard": float(rho_standard),
        "mirror": mirror.to_dict() if isinstance(mirror, MirrorGeometry) else dict(mirror),
        "lens_model": lens_obj.model,
    }
    for k in ("instrument", "seed", "noise"):
        if k in meta:
            md[k] = meta[k]
    return BRDFSamples(np.full(n, theta_i), np.full(n, phi_i), to, po, value, sigma, metadata=md)


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
    variance: str = "neighbours",
    debias: bool = False,
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
    variance : {"neighbours", "own"}
        Where the noise model is evaluated for each pixel's σ (merge and eq. 2): at the mean
        of its valid neighbours (default; σ independent of the pixel's own noise, so σ-weighted
        fits are unbiased) or at its own reading (biases weighted fits towards low values:
        rolled brass ρd −0.36 %, −72 standard errors, over 2.1 M pixels).
    debias : bool
        Remove the second-order bias of the eq. 2 ratio (:func:`.radiometry.eq2`): the values
        are otherwise high by about ``(σ_d/d)²`` relative, which a fit pooling 10⁵ samples
        sees (rolled brass ρs about +1 standard error).

    Returns
    -------
    ReductionResult
    """
    t0 = time.perf_counter()
    meta, shape, rho_standard = _check_triple(measured, standard, background, rho_standard)
    nonlinear = not is_linear(meta)
    if nonlinear and response is None:
        imgs = [_to_u8(a, m) for a, m in standard.frames]
        response = calibrate_response(imgs, standard.metas)
    m_meas = measure(measured, response=response, variance=variance)
    m_std = measure(standard, response=response, variance=variance)
    m_bg = measure(background, response=response, variance=variance)
    t1 = time.perf_counter()
    refl = eq2(m_meas, m_std, m_bg, float(rho_standard), threshold=threshold, variance=variance,
               debias=debias)  # fmt: skip
    t2 = time.perf_counter()

    lens_obj, mirror, wo_dome, gvalid, theta_i, phi_i, rotation = _scene(
        meta, shape, lens, mirror, method
    )
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

    samples = _table(w_out, v_out, s_out, meta, theta_i, phi_i, method, rho_standard, mirror,
                     lens_obj, "gonio.calibration.reduce_capture")  # fmt: skip
    n = len(samples)
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


@dataclass
class _SelectionGeometry:
    """The valid pixels of a capture geometry at one sample rotation: flat indices, sample-
    frame directions, equal-area square coordinates in ``[0, 1]²`` and their cell indices
    per quadtree level (computed once per level)."""

    cand: NDArray[np.int64]
    wo: NDArray[np.float64]
    sq: NDArray[np.float64]
    _cells: dict[int, NDArray[np.int64]] = field(default_factory=dict)

    def cells(self, level: int) -> NDArray[np.int64]:
        """Index of each point's cell of the ``2^level × 2^level`` grid."""
        got = self._cells.get(level)
        if got is None:
            n = 1 << level
            ix = np.minimum((self.sq[:, 0] * n).astype(np.int64), n - 1)
            iy = np.minimum((self.sq[:, 1] * n).astype(np.int64), n - 1)
            got = self._cells[level] = ix * n + iy
        return got


_SELECTION_CACHE: dict[tuple[int, float], tuple[NDArray, _SelectionGeometry]] = {}


def _selection_geometry(wo_dome: NDArray, gvalid: NDArray, rotation: float) -> _SelectionGeometry:
    """:class:`_SelectionGeometry` of a cached pixel geometry at a sample rotation (cached:
    a campaign has a few rotations)."""
    from gonio.calibration.thinning import hemisphere_to_square

    key = (id(wo_dome), float(rotation))
    hit = _SELECTION_CACHE.get(key)
    if hit is not None and hit[0] is wo_dome:
        return hit[1]
    cand = np.flatnonzero(gvalid.ravel())
    wo_all = to_sample_frame(wo_dome.reshape(-1, 3)[cand], rotation)
    sq = np.clip((hemisphere_to_square(wo_all) + 1.0) / 2.0, 0.0, 1.0)
    for arr in (cand, wo_all, sq):
        arr.setflags(write=False)
    if len(_SELECTION_CACHE) >= 16:
        _SELECTION_CACHE.clear()
    geo = _SelectionGeometry(cand, wo_all, sq)
    _SELECTION_CACHE[key] = (wo_dome, geo)
    return geo


def _darkest_signal(capture: Capture) -> NDArray[np.float64]:
    """The capture's shortest-exposure frame, black level removed, per unit exposure scale
    (flat; cached on the capture)."""
    from gonio.calibration.radiometry import SensorModel, exposure_scale

    got = capture.__dict__.get("_darkest")
    if got is None:
        scales = [exposure_scale(m) for m in capture.metas]
        k = int(np.argmin(scales))
        black = SensorModel.from_metadata(capture.metas[k]).black_level
        img = np.asarray(capture.images[k], dtype=np.float64).ravel()
        got = capture.__dict__["_darkest"] = (img - black) / scales[k]
    return got


def _select(
    geo: _SelectionGeometry, num: NDArray, den: NDArray, base_level: int, peak_level: int,
    peak_fraction: float, gen: np.random.Generator,
) -> NDArray[np.int64]:  # fmt: skip
    """One random index per equal-area cell; finer cells inside peak base cells.

    A base cell is in the peak when its ratio ``Σ num / Σ den`` (sample over standard
    signal, summed over the cell's pixels: robust where single standard pixels are dark)
    exceeds the median cell ratio (the diffuse level) by ``peak_fraction`` of the range up
    to the largest; a sample whose largest cell is not twice the median has no peak.
    """
    base = geo.cells(base_level)
    nb = 1 << (2 * base_level)
    sn = np.bincount(base, weights=num, minlength=nb)
    sd = np.bincount(base, weights=den, minlength=nb)
    # cells whose standard signal is a small fraction of a typical cell's are not judged
    ok = sd > 0.05 * np.median(sd[sd > 0]) if (sd > 0).any() else sd > 0
    ratio = np.where(ok, sn / np.where(ok, sd, 1.0), 0.0)
    floor = float(np.median(ratio[ok])) if ok.any() else 0.0  # the typical (diffuse) level
    top = float(ratio.max())
    if top > 2.0 * floor:  # a peak at least twice the diffuse level
        peak = (ratio > floor + peak_fraction * (top - floor))[base]
    else:  # no peak (a matte sample): a uniform density everywhere
        peak = np.zeros(base.size, dtype=bool)
    cell = np.where(peak, nb + geo.cells(peak_level), base)
    key = gen.random(cell.size)
    best = np.full(nb + (1 << (2 * peak_level)), -1.0)
    np.maximum.at(best, cell, key)
    return np.flatnonzero(key == best[cell])


def standard_factor(
    certificate: Any, standard: Capture, theta_i: float, wo_dome: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The certified reflectance factor ``R = π f / ρ`` of the standard at dome directions.

    The directions are turned into the standard's frame (its capture's ``sample_rotation``
    and ``phi_i``); returns ``R`` (1 where not covered) and where the certificate covers the
    viewing angle. An incidence outside the certificate raises ``ValueError``.
    """
    certificate.check_covers(np.array([theta_i]))
    rot = sidecar_angle(standard.meta, "sample_rotation", "standard metadata", 0.0)
    phi_s = sidecar_angle(standard.meta, "phi_i", "standard metadata", 0.0)
    w = to_sample_frame(wo_dome, rot)
    to, po = to_spherical(w)
    dphi = np.abs(po - phi_s) % (2.0 * math.pi)
    dphi = np.where(dphi > math.pi, 2.0 * math.pi - dphi, dphi)
    top = math.radians(float(certificate.theta_o_deg[-1]))
    covered = to <= top
    fac = np.ones(to.shape)
    if covered.any():
        fac[covered] = certificate.factor_at(
            np.full(int(covered.sum()), theta_i), to[covered], dphi[covered]
        )
    return fac, covered


def reduce_selected(
    measured: Capture,
    standard: Capture,
    background: Capture,
    *,
    lens: Any = None,
    mirror: MirrorGeometry | Mapping[str, Any] | None = None,
    method: str = "eq3",
    rho_standard: float | None = None,
    threshold: float = 5.0,
    base_level: int = 5,
    peak_level: int = 8,
    peak_fraction: float = 0.1,
    rng: int | np.random.Generator | None = None,
    debias: bool = False,
    certificate: Any = None,
    glare: tuple[float, float] | None = None,
) -> ReductionResult:
    """Reduce one incidence by *selection*: one pixel per equal-solid-angle cell, reduced alone.

    Ward's thinning (§3.2) keeps "the peak ... recorded at a high enough angular resolution
    while the rest of the usable distribution is recorded at a uniform density". Here the
    hemisphere is cut into the equal-area cells of
    :func:`~gonio.calibration.thinning.hemisphere_to_square` — ``4^base_level`` cells, and
    ``4^peak_level`` inside the peak's base cells (signal ratio of the shortest exposures,
    sample over standard, background removed, above the median cell by ``peak_fraction`` of the
    range up to the largest) — and one random pixel of each cell is reduced (merge, eq. 2) with
    its 8 neighbours, which set its σ. Only ~1-4 % of the pixels are merged, and every sample is
    the single-pixel eq. 2 value at its own direction (with ``debias=True`` also free of the
    ratio's second-order noise bias, :func:`~gonio.calibration.radiometry.eq2`): averaging pixels
    over a curved
    lobe (:func:`~gonio.calibration.thinning.thin`) widens fitted lobes, and σ evaluated at a
    pixel's own reading biases weighted fits low (rolled brass, 6 θi × 2 rotations, default
    noise: averaging α +0.057 % = +7.5 s.e.; own-reading σ on all pixels ρd −0.36 % = −72 s.e.;
    selection with neighbour σ: every parameter within 2.2 s.e.).

    Parameters are those of :func:`reduce_capture` (linear cameras only) plus the cell
    levels, ``peak_fraction``, the selection ``rng`` and ``debias`` (default off; rolled brass,
    21 θi × 2 rotations, default noise: mean ρs pull +1.03 ± 0.15 over 49 seeds without it,
    −0.02 ± 0.14 over 60 with it). ``pixels`` of the result hold the
    selected pixels; ``reflectance`` is ``None``.

    ``certificate`` (the diffuse standard's calibration certificate, e.g.
    :class:`gonio.io.certificate.Certificate`: ``rho`` and ``factor_at(θi, θo, Δφ)``) makes
    eq. 2 use the certified BRDF ``ρ R / π`` of the standard at each pixel's direction (in the
    standard's frame) instead of a Lambertian ``ρ / π`` (:func:`standard_factor`); pixels whose
    viewing angle lies beyond the certified range are dropped, an incidence beyond it is a
    ``ValueError``. ``glare`` = ``(measured, standard)`` veils per unit exposure scale
    (scalars or flat per-pixel images, :func:`gonio.calibration.glare.veil`) are subtracted
    from the two signals before eq. 2.
    """
    t0 = time.perf_counter()
    if certificate is not None and rho_standard is None:
        rho_standard = float(certificate.rho)
    meta, shape, rho_standard = _check_selected(
        measured, standard, background, rho_standard, base_level, peak_level, peak_fraction
    )
    gen = np.random.default_rng(rng)
    lens_obj, mirror, wo_dome, gvalid, theta_i, phi_i, rotation = _scene(
        meta, shape, lens, mirror, method
    )
    h, w = shape
    geo = _selection_geometry(wo_dome, gvalid, rotation)
    bg0 = _darkest_signal(background)[geo.cand]
    num = _darkest_signal(measured)[geo.cand] - bg0
    den = _darkest_signal(standard)[geo.cand] - bg0
    pick = _select(geo, num, den, base_level, peak_level, peak_fraction, gen)
    sel = geo.cand[pick]
    t1 = time.perf_counter()

    nb = _Neighbourhood.of(sel, h, w)
    ms, ratio_at = _merge_selected((measured, standard, background), nb, gvalid, glare)
    t2 = time.perf_counter()
    refl = eq2(ms[0], ms[1], ms[2], rho_standard, threshold=threshold, ratio_at=ratio_at,
               debias=debias)  # fmt: skip
    keep = refl.mask[0]
    if certificate is not None:
        keep = keep & _certified(refl, certificate, standard, theta_i, wo_dome.reshape(-1, 3)[sel])
    if not keep.any():
        raise ValueError(
            f"no selected pixel survived eq. 2 masking (θi {math.degrees(theta_i):.2f}°, "
            f"φi {math.degrees(phi_i):.2f}°, rotation {math.degrees(rotation):.2f}°, "
            f"{sel.size} selected): every standard pixel is saturated or not significantly "
            "above the background — check exposures"
        )
    wo = geo.wo[pick][keep]
    value = refl.value[0][keep]
    sigma = refl.sigma[0][keep]
    samples = _table(wo, value, sigma, meta, theta_i, phi_i, method, rho_standard, mirror,
                     lens_obj, "gonio.calibration.reduce_selected")  # fmt: skip
    t3 = time.perf_counter()
    stats = {
        "theta_i": theta_i,
        "phi_i": phi_i,
        "sample_rotation": rotation,
        "nonlinear_camera": False,
        "n_pixels": int(h * w),
        "n_geometry_valid": int(geo.cand.size),
        "n_selected": int(sel.size),
        "n_merged": int(nb.region.size),
        "n_masked_eq2": int(sel.size - np.count_nonzero(keep)),
        "n_before": int(geo.cand.size),
        "n_after": len(samples),
        "thinning": {
            "mode": "select",
            "base_level": int(base_level),
            "peak_level": int(peak_level),
            "peak_fraction": float(peak_fraction),
        },
        "timings_s": {"select": t1 - t0, "merge": t2 - t1, "eq2": t3 - t2, "total": t3 - t0},
    }
    vv, uu = np.divmod(sel[keep], w)
    wi = to_vector(theta_i, phi_i)
    pixels = {"wo": wo, "value": value, "sigma": sigma, "uv": np.stack([uu, vv], 1), "wi": wi}
    return ReductionResult(samples, pixels, None, stats)


def _check_selected(
    measured: Capture, standard: Capture, background: Capture, rho_standard: float | None,
    base_level: int, peak_level: int, peak_fraction: float,
) -> tuple[dict[str, Any], tuple[int, ...], float]:  # fmt: skip
    """:func:`reduce_selected`'s input checks: the triple (side-cars against images), a
    linear camera, the cell levels and ``peak_fraction``; returns the measured side-car,
    the image shape and ρ of the standard."""
    meta, shape, rho_standard = _check_triple(measured, standard, background, rho_standard)
    for name, c in (("measured", measured), ("standard", standard), ("background", background)):
        if not is_linear(c.meta):
            raise ValueError(f"reduce_selected needs a linear camera; {name} is not linear")
    for name, v in (("base_level", base_level), ("peak_level", peak_level)):
        if not (isinstance(v, int | np.integer) and 1 <= v <= 12):
            raise ValueError(f"{name} must be an integer in [1, 12], got {v!r}")
    if not peak_level >= base_level:
        raise ValueError(f"peak_level ({peak_level}) must be >= base_level ({base_level})")
    if not (0.0 < float(peak_fraction) < 1.0):
        raise ValueError(f"peak_fraction must be in (0, 1), got {peak_fraction!r}")
    return meta, shape, rho_standard


@dataclass(frozen=True)
class _Neighbourhood:
    """The selected pixels and their 8-neighbours inside the image: ``region`` (flat indices
    of every pixel merged), ``pos`` (each neighbour's position in ``region``, (n, 8)),
    ``inside`` (the neighbour lies in the image, (n, 8)) and ``sel``."""

    sel: NDArray[np.int64]
    region: NDArray[np.int64]
    pos: NDArray[np.int64]
    inside: NDArray[np.bool_]

    @classmethod
    def of(cls, sel: NDArray[np.int64], h: int, w: int) -> _Neighbourhood:
        r, c = np.divmod(sel, w)
        offs = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
        nbr = np.stack([r + dr for dr, _ in offs], 1)
        nbc = np.stack([c + dc for _, dc in offs], 1)
        inside = (nbr >= 0) & (nbr < h) & (nbc >= 0) & (nbc < w)
        nb_flat = np.where(inside, nbr * w + nbc, sel[:, None])
        mark = np.zeros(h * w, dtype=bool)
        mark[sel] = True
        mark[nb_flat] = True
        region = np.flatnonzero(mark)
        lut = np.empty(h * w, dtype=np.int64)
        lut[region] = np.arange(region.size)
        return cls(sel, region, lut[nb_flat], inside)

    def mean(self, x: NDArray, ok: NDArray) -> NDArray:
        """Mean of ``x`` (over ``region``) over each selected pixel's usable neighbours
        (NaN where none is usable)."""
        use = ok[self.pos] & self.inside
        cnt = use.sum(1)
        s = np.where(use, x[self.pos], 0.0).sum(1)
        return np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)


def _merged(cap: Capture, idx: NDArray, at: NDArray | None = None) -> Measurement:
    """The bracket of ``cap`` merged at the flat pixels ``idx`` (variance at ``at``)."""
    imgs = [np.asarray(a).ravel()[idx][None, :] for a in cap.images]
    darks = None
    if cap.darks is not None:
        darks = [None if d is None else np.asarray(d).ravel()[idx][None, :] for d in cap.darks]
    return merge_linear(imgs, cap.metas, darks, variance_at=None if at is None else at[None, :])


def _merge_selected(
    caps: tuple[Capture, Capture, Capture], nb: _Neighbourhood, gvalid: NDArray,
    glare: tuple[Any, Any] | None,
) -> tuple[list[Measurement], tuple[NDArray, NDArray]]:  # fmt: skip
    """The measured, standard and background brackets merged at the selected pixels, each
    pixel's variance evaluated at its neighbours' mean signal (a pixel's own reading biases
    a weighted fit low), with the veils removed; and the neighbours' mean numerator and
    denominator of eq. 2 (its ``ratio_at``)."""
    reg_ok = gvalid.ravel()[nb.region]
    mr = [_merged(cap, nb.region) for cap in caps]
    ests = [nb.mean(m.value[0], m.valid[0] & reg_ok) for m in mr]
    ms = [_merged(cap, nb.sel, est) for cap, est in zip(caps, ests)]
    ok_all = mr[0].valid[0] & mr[1].valid[0] & mr[2].valid[0] & reg_ok
    num_r = mr[0].value[0] - mr[2].value[0]
    den_r = mr[1].value[0] - mr[2].value[0]
    if glare is not None:  # the veils of the sample's and the standard's own light
        g_m, g_s = (np.asarray(x, dtype=np.float64) for x in glare)
        if g_m.ndim:  # per-pixel veils (flat images)
            num_r, den_r = num_r - g_m[nb.region], den_r - g_s[nb.region]
            ms[0].value -= g_m[nb.sel]
            ms[1].value -= g_s[nb.sel]
        else:
            num_r, den_r = num_r - g_m, den_r - g_s
            ms[0].value -= g_m
            ms[1].value -= g_s
    return ms, (nb.mean(num_r, ok_all)[None, :], nb.mean(den_r, ok_all)[None, :])


def _certified(
    refl: Reflectance, certificate: Any, standard: Capture, theta_i: float, wo_std: NDArray
) -> NDArray[np.bool_]:
    """Eq. 2's standard as ``ρR/π``, not ``ρ/π``: ``refl`` (one row) times the certified
    factor at the selected pixels' directions ``wo_std``, in place; returns where the
    certificate covers them (0 elsewhere)."""
    fac, covered = standard_factor(certificate, standard, theta_i, wo_std)
    refl.value[0] = np.where(covered, refl.value[0] * fac, 0.0)
    refl.sigma[0] = np.where(covered, refl.sigma[0] * fac, 0.0)
    return covered
