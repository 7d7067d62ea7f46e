"""The LBL imaging gonioreflectometer (Ward 1992 §3), simulated.

A collimated beam passes through the half-silvered dome and lights a spot on the sample;
light the sample reflects in direction d̂_r is reflected by the dome into a fisheye lens on
a CCD. One image therefore holds the whole hemisphere of reflected directions.

Each capture is a function of (instrument, sample, θ_i, φ_i, exposure, f-number, seed).
The per-instrument geometry — pixel → camera ray → mirror point → sample point and reflected
direction — is traced exactly once and cached (:class:`Geometry`); a capture then costs one
BRDF evaluation over the pixels that see the sample, a background fill and the ADC. Skipped
when the scene does not need them: pixels outside the image circle or seeing no sample (never
evaluated), pixels outside the beam footprint (the generic path evaluates the BRDF only on
lit pixels; the Ward kernel masks them), the beam-footprint test itself when every pixel sees
the sample centre (ellipsoid), the float image and a second pass when noise is off (the ADC
is fused into the render pass), spectral bands of a grey BRDF
(:meth:`LBLInstrument.capture_bands` evaluates once), random draws when noise is off,
f-stops adding no unsaturated pixel (:meth:`LBLInstrument.plan_bracket`), re-rendering per
f-stop (a bracket renders the noise-free scene once at f/1 and composes every stop from it:
signal and background scale with 1/N², dark current does not), and the source-cone average
when the lobe is much wider than the source. With noise on, the float electrons are
composed in one compiled pass and shot + read noise and the ADC drawn in a second
(:mod:`gonio.simulator.sensor` explains the noise draw, :mod:`gonio.simulator._kernels`
the passes).
``rays_per_pixel`` supersamples each pixel with an s × s grid of traced rays.

Radiometry (photon units, see :mod:`gonio.simulator.source`): a sample point lit by the beam
(irradiance ``E`` normal to the beam, dome transmittance ``T``) reflects radiance
``L = f_r(wi, wo) T E cos θ_i``; the dome reflects ``R_m L`` into the lens; a pixel collects
``QE (1 + PRNU) (π / 4N²) p² R_m L t`` electrons (``p`` the pixel pitch). Background:
``ambient · T`` over the image circle plus the glow where the beam crosses the dome, present
with or without a sample. A mirror (delta) component of reflectance ρ_δ gives radiance
``ρ_δ T E / Ω_s`` over the image of the source cone, rendered with sub-pixel sampling.

Then eq. 2 holds: ``(V - V_bg)/(V_std - V_bg) · ρ_std/π = f_r`` at every lit pixel.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3 (device, Figure 2-4), eq. 2 (calibration against a diffuse
standard and a background image), eq. 3 (angle recovery), "reduced ... to a resolution of
108 by 80 pixels", "two or more f-stops may be used to capture the full dynamic range".
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
from gonio.simulator.lenses import LENS_MODELS, FisheyeLens, make_lens
from gonio.simulator.lenses import _pos_finite as _check_positive
from gonio.simulator.optics import MIRRORS, Mirror
from gonio.simulator.sensor import Sensor
from gonio.simulator.source import Background, Source, cone_directions
from numpy.typing import NDArray

from gonio.brdf.base import BRDF, as_brdf

__all__ = [
    "STANDARD",
    "WARD_BINNING",
    "Geometry",
    "LBLInstrument",
    "capture",
    "default_instrument",
    "reproduce",
]

#: the ``sample`` value that images the diffuse reflectance standard
STANDARD = "standard"
#: Ward's reduced image size (width, height)
WARD_BINNING = (108, 80)
#: default f-stop ladder for bracketing (darkest first)
F_STOPS = (32.0, 22.0, 16.0, 11.0, 8.0, 5.6, 4.0, 2.8, 2.0)


# ---------------------------------------------------------------------------- geometry cache
@dataclass
class Geometry:
    """Per-instrument traced geometry, computed once.

    Flat pixel index ``i = row * width + col``. Arrays of the candidate pixels (inside the
    image circle, ray returning to the sample plane within the sample disk) are contiguous.
    """

    height: int
    width: int
    field_idx: NDArray[np.int64]  # pixels inside the image circle
    field_dirs: NDArray[np.float64]  # their camera (= dome) directions, (n_f, 3)
    idx: NDArray[np.int64]  # candidate pixels (see the sample disk)
    wx: NDArray[np.float64]  # dome-frame reflected direction of each candidate
    wy: NDArray[np.float64]
    wz: NDArray[np.float64]
    qx: NDArray[np.float64]  # sample point seen, relative to the sample centre
    qy: NDArray[np.float64]
    isq: NDArray[np.float64]  # 1 / sqrt(cos theta_o) of each candidate
    q_max: float  # largest |Q - S| among candidates
    seconds: float  # time taken to build

    @property
    def n_pixels(self) -> int:
        """Number of pixels of the full image."""
        return self.height * self.width

    @property
    def pixel_angle(self) -> float:
        """Largest angular pitch between neighbouring candidate pixels (radians; computed
        on first use: only the mirror component's render needs it); 0 for a supersampled
        geometry, whose pixels have several entries (the mirror-component render uses the
        one-ray geometry)."""
        ang = self.__dict__.get("_pixel_angle")
        if ang is None:
            ang = self._pixel_angle = 0.0 if self.runs() is None else _pitch(self)
        return ang

    def runs(self) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
        """Runs of consecutive candidate pixels: (first pixel, first index into ``idx``) of
        each, or None when a pixel has several entries (supersampled). Cached."""
        r = self.__dict__.get("_runs", False)
        if r is False:
            idx = self.idx
            if idx.size and (np.diff(idx) <= 0).any():
                r = None
            else:
                rj = np.flatnonzero(np.diff(idx) != 1) + 1
                rj = np.concatenate([np.zeros(min(idx.size, 1), dtype=np.int64), rj])
                r = (np.ascontiguousarray(idx[rj], dtype=np.int64), rj.astype(np.int64))
            self.__dict__["_runs"] = r
        return r


#: most sub-pixel rays a supersampled geometry may hold (about 60 bytes each)
MAX_RAYS = 1 << 23


@dataclass
class _Scene:
    """A noise-free scene rendered once, for any f-number.

    Electrons at f-number ``N`` (``tk = exposure/N²``, ``k = k0 · tk``)::

        e = bg · tk + dark · exposure + rc · lit · (k·kd0 + k·ks0 · g · isq)  (at idx)
            [+ k · delta value at the delta pixels]

    i.e. the signal and the background scale with 1/N², the dark current does not. A capture
    and every stop of a bracket compose from the same scene with the same arithmetic, so a
    bracket's noise-free frames equal separate captures bit for bit.
    """

    bg: NDArray  # background electrons per second at f/1, per pixel (flat)
    dark: NDArray  # dark electrons per second, per pixel (flat)
    exposure: float
    k0: float  # beam irradiance x dome transmittance x dome reflectance
    idx: NDArray  # candidate pixels (sorted; repeated per ray when supersampled)
    rc: NDArray  # their response (electrons per unit radiance-time at f/1, / rays)
    lit: NDArray  # uint8: inside the beam footprint
    g: NDArray
    isq: NDArray
    kd0: float
    ks0: float
    delta: tuple[NDArray, NDArray] | None
    rays: int = 1
    runs: tuple[NDArray, NDArray] | None = None  # idx as runs (Geometry.runs), if unique


def _check_rays(rays_per_pixel: Any) -> int:
    """``rays_per_pixel`` as an int that is a perfect square in [1, 64]."""
    try:
        n = int(rays_per_pixel)
        ok = n == rays_per_pixel
    except (TypeError, ValueError):
        ok = False
    if not ok or not (1 <= n <= 64) or math.isqrt(n) ** 2 != n:
        raise ValueError(
            f"rays_per_pixel must be a square number 1, 4, 9, ..., 64 (an s x s sub-pixel "
            f"grid), got {rays_per_pixel!r}"
        )
    return n


def _base_radii(base: list) -> NDArray:
    """The radii ``hypot(qx, qy)`` of the unmoved sample points of a posed geometry's cached
    base (:meth:`LBLInstrument._posed`), computed once a base."""
    if len(base) == 7:
        base.append(np.hypot(base[3], base[4]))
    return base[7]


def _near_rim(g: Any, r_min: float) -> NDArray[np.int64]:
    """Ascending indices of the candidates of ``g`` whose sample point lies farther than
    ``r_min`` from the axis, ``hypot(qx, qy) > r_min``. A raised sample's points are its
    unmoved points shifted by at most ``shift``: only those unmoved beyond ``r_min -
    shift`` are tested (the same values, a fraction of the work)."""
    r_q = g.__dict__.get("_r_q")
    if r_q is not None:
        return np.flatnonzero(r_q > r_min)
    bound = g.__dict__.get("_r_bound")
    if bound is None:
        r_q = g.__dict__["_r_q"] = np.hypot(g.qx, g.qy)
        return np.flatnonzero(r_q > r_min)
    base, shift = bound
    cand = np.flatnonzero(_base_radii(base) > r_min - shift - 1e-9 * (1.0 + shift))
    return cand[np.hypot(g.qx[cand], g.qy[cand]) > r_min]


def _trace_geometry(
    mirror: Mirror,
    lens: FisheyeLens,
    sample_radius: float,
    rays: int = 1,
    tracer: Callable[[NDArray], dict[str, NDArray]] | None = None,
    keep: Callable[[dict[str, NDArray], NDArray], NDArray] | None = None,
    field: Geometry | None = None,
) -> Geometry:
    """Trace every pixel; ``tracer`` replaces :meth:`Mirror.trace` (an imperfect dome, another
    sample plane) and ``keep(trace, q)`` further selects the candidates (occlusion); both
    only with one ray per pixel. ``field``: a geometry of the same lens whose image-circle
    pixels and camera rays are taken instead of being unprojected again."""
    t0 = time.perf_counter()
    h, w = lens.height, lens.width
    if field is not None and rays == 1:
        field_idx, dirs = field.field_idx, field.field_dirs
    else:
        uv = lens.pixel_grid().reshape(-1, 2)
        field_idx = np.flatnonzero(lens.in_field(uv))
        dirs = lens.unproject(uv[field_idx])
    if rays > 1:
        return _trace_supersampled(mirror, lens, sample_radius, rays, field_idx, dirs, t0)
    tr = mirror.trace(dirs) if tracer is None else tracer(dirs)
    q = tr["sample_point"] - mirror.sample_position
    on_sample = tr["valid"] & (q[:, 0] ** 2 + q[:, 1] ** 2 <= sample_radius**2)
    if keep is not None:
        on_sample &= keep(tr, q)
    wo = tr["wo"]
    sel = np.flatnonzero(on_sample)
    idx = field_idx[sel]
    return Geometry(
        height=h,
        width=w,
        field_idx=field_idx,
        field_dirs=dirs,
        idx=idx,
        wx=np.ascontiguousarray(wo[sel, 0]),
        wy=np.ascontiguousarray(wo[sel, 1]),
        wz=np.ascontiguousarray(wo[sel, 2]),
        qx=np.ascontiguousarray(q[sel, 0]),
        qy=np.ascontiguousarray(q[sel, 1]),
        isq=1.0 / np.sqrt(wo[sel, 2]),
        q_max=float(np.sqrt((q[sel, 0] ** 2 + q[sel, 1] ** 2).max(initial=0.0))),
        seconds=time.perf_counter() - t0,
    )


def _pitch(g: Geometry) -> float:
    """:attr:`Geometry.pixel_angle` of a one-ray geometry: the largest angle between the
    reflected directions of a candidate pixel and its right-hand or lower neighbour."""
    h, w = g.height, g.width
    full = np.zeros((h * w, 3))
    full[g.idx] = np.stack([g.wx, g.wy, g.wz], axis=-1)
    has = np.zeros(h * w, dtype=bool)
    has[g.idx] = True
    full = full.reshape(h, w, 3)
    has = has.reshape(h, w)
    ang = 0.0
    for a, b, ha, hb in (
        (full[:, 1:], full[:, :-1], has[:, 1:], has[:, :-1]),
        (full[1:], full[:-1], has[1:], has[:-1]),
    ):
        both = ha & hb
        if both.any():
            dots = np.clip(np.sum(a[both] * b[both], axis=-1), -1.0, 1.0)
            ang = max(ang, float(np.arccos(dots).max()))
    return ang


def _trace_supersampled(mirror, lens, sample_radius, rays, field_idx, dirs, t0) -> Geometry:
    """Geometry of an ``s x s`` grid of sub-pixel rays per pixel (``rays = s²``).

    Each candidate entry is one ray that sees the sample; ``idx`` repeats its pixel (sorted,
    a pixel's rays contiguous). Traced in chunks of pixels to bound the temporary memory.
    """
    h, w = lens.height, lens.width
    s = math.isqrt(rays)
    if h * w * rays > MAX_RAYS:
        raise ValueError(
            f"rays_per_pixel = {rays} on a {w} x {h} image is {h * w * rays} rays; at most "
            f"{MAX_RAYS} are traced (use fewer rays or a smaller image)"
        )
    off = (np.arange(s) + 0.5) / s - 0.5
    ou, ov = (a.ravel() for a in np.meshgrid(off, off))
    parts: dict[str, list[NDArray]] = {k: [] for k in ("idx", "wo", "q")}
    chunk = max(1, (1 << 18) // rays)
    for start in range(0, h * w, chunk):
        pix = np.arange(start, min(start + chunk, h * w))
        rows, cols = np.divmod(pix, w)
        uv = np.stack(
            [(cols[:, None] + ou[None, :]).ravel(), (rows[:, None] + ov[None, :]).ravel()],
            axis=-1,
        ).astype(np.float64)
        inf = lens.in_field(uv)
        ray_pix = np.repeat(pix, rays)
        cand = np.flatnonzero(inf)
        if cand.size == 0:
            continue
        tr = mirror.trace(lens.unproject(uv[cand]))
        q = tr["sample_point"] - mirror.sample_position
        ok = tr["valid"] & (q[:, 0] ** 2 + q[:, 1] ** 2 <= sample_radius**2)
        parts["idx"].append(ray_pix[cand[ok]])
        parts["wo"].append(tr["wo"][ok])
        parts["q"].append(q[ok, :2])
    idx = np.concatenate(parts["idx"]) if parts["idx"] else np.zeros(0, dtype=np.int64)
    wo = np.concatenate(parts["wo"]) if parts["wo"] else np.zeros((0, 3))
    q = np.concatenate(parts["q"]) if parts["q"] else np.zeros((0, 2))
    return Geometry(
        height=h,
        width=w,
        field_idx=field_idx,
        field_dirs=dirs,
        idx=idx.astype(np.int64),
        wx=np.ascontiguousarray(wo[:, 0]),
        wy=np.ascontiguousarray(wo[:, 1]),
        wz=np.ascontiguousarray(wo[:, 2]),
        qx=np.ascontiguousarray(q[:, 0]),
        qy=np.ascontiguousarray(q[:, 1]),
        isq=1.0 / np.sqrt(wo[:, 2]),
        q_max=float(np.sqrt((q[:, 0] ** 2 + q[:, 1] ** 2).max(initial=0.0))),
        seconds=time.perf_counter() - t0,
    )


_GEOMETRY_CACHE: dict[tuple, Geometry] = {}
#: most instrument geometries kept (a 1024 x 1024 one takes about 60 MB)
_GEOMETRY_CACHE_SIZE = 8


# ---------------------------------------------------------------------------- helpers
def _check_angle(value: Any, name: str, lo: float, hi: float, hi_open: bool) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number (radians), got {value!r}") from None
    if not math.isfinite(v) or v < lo or (v >= hi if hi_open else v > hi):
        br = ")" if hi_open else "]"
        raise ValueError(f"{name} must be in [{lo:.6g}, {hi:.6g}{br} radians, got {value!r}")
    return v


def _json_value(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        if v.size > 64:  # e.g. a measured table: record its identity, not its content
            import hashlib

            a = np.ascontiguousarray(v, dtype=np.float64)
            return {"ndarray_shape": list(v.shape), "sha256": hashlib.sha256(a).hexdigest()}
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, int | float | str | bool) or v is None:
        return v
    if isinstance(v, list | tuple):
        return [_json_value(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _json_value(x) for k, x in v.items()}
    return repr(v)


def _resolve_sample(sample: Any) -> tuple[str, BRDF | None, str | None]:
    """``(kind, model, material_name)`` with kind in {"brdf", "standard", "none"}."""
    if sample is None:
        return "none", None, None
    if isinstance(sample, str):
        if sample == STANDARD:
            return "standard", None, None
        from gonio import brdf, materials

        if sample in materials.names():
            return "brdf", materials.get(sample), sample
        if sample in brdf.names():
            return "brdf", brdf.create(sample), None
        raise ValueError(
            f"sample {sample!r} is neither a material preset ({', '.join(materials.names())}) "
            f"nor a BRDF model ({', '.join(brdf.names())}); use 'standard' for the diffuse "
            "standard or None for the background"
        )
    try:
        return "brdf", as_brdf(sample), None
    except ValueError:
        raise ValueError(
            f"sample must be a BRDF, a callable f(wi, wo), a preset or model name, "
            f"'standard' or None; got {type(sample).__name__}"
        ) from None


def _rng_and_seed(rng: Any) -> tuple[np.random.Generator, int | None]:
    if isinstance(rng, np.random.Generator):
        return rng, None
    if rng is None:
        seed = int(np.random.SeedSequence().entropy)
    elif isinstance(rng, int | np.integer) and int(rng) >= 0:
        seed = int(rng)
    else:
        raise ValueError(f"rng must be a non-negative int, a numpy Generator or None, got {rng!r}")
    return np.random.default_rng(seed), seed


def _frame_key(kind, theta_i, phi_i, exposure, f_number, seed, index) -> str:
    """Name of one frame, for the per-frame effects' deterministic draws."""
    return f"{kind}/{theta_i:.12g}/{phi_i:.12g}/{exposure:.12g}/{f_number:.6g}/{seed}/{index}"


def _ward_kernel_params(model: BRDF) -> tuple[float, float, float, float, bool] | None:
    """(kd, ks, 1/αx², 1/αy², approx) if the model has a specialised kernel, else None."""
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.ward import Ward, WardApprox

    t = type(model)
    if t is Ward or t is WardApprox:
        p = model.params
        return (
            p["rho_d"] / math.pi,
            p["rho_s"] / (4.0 * math.pi * p["alpha_x"] * p["alpha_y"]),
            1.0 / p["alpha_x"] ** 2,
            1.0 / p["alpha_y"] ** 2,
            t is WardApprox,
        )
    if t is Lambert:
        return (model.params["rho"] / math.pi, 0.0, 1.0, 1.0, False)
    return None


def _lobe_width(model: BRDF) -> float | None:
    """Smallest lobe width (radians) of models that declare one, else None."""
    p = model.params
    if "alpha_x" in p and "alpha_y" in p:
        return float(min(p["alpha_x"], p["alpha_y"]))
    if "alpha" in p and isinstance(p["alpha"], float):
        return float(p["alpha"])
    if model.name == "lambert":
        return math.inf
    return None


# ---------------------------------------------------------------------------- the instrument
class LBLInstrument:
    """The simulated LBL imaging gonioreflectometer.

    Parameters
    ----------
    mirror : {"ellipsoid", "hemisphere"} or Mirror
        Dome shape (a :class:`~gonio.simulator.optics.Mirror` for full control).
    radius, half_separation : float
        Dome radius ``R`` (ellipsoid: semi-major axis) and ``D`` in metres.
    lens : str or FisheyeLens
        A lens model name (:data:`~gonio.simulator.lenses.LENS_MODELS`, built with
        :func:`~gonio.simulator.lenses.make_lens` for ``width × height``) or a lens.
    width, height : int
        Sensor size in pixels (ignored when ``lens`` is a :class:`FisheyeLens`).
    sensor, source, background : optional
        :class:`Sensor`, :class:`Source`, :class:`Background` (defaults if omitted).
    sample_radius : float
        Radius of the (round) sample, metres; must be smaller than ``2D`` so the sample
        does not overlap the lens.
    rho_standard : float
        Directional-hemispherical reflectance of the diffuse standard, in (0, 1]
        (Lambertian unless the effects make it a PTFE standard).
    mirror_reflectance, mirror_transmittance : float
        Half-silvering (used when ``mirror`` is given by name).
    effects : mapping of str to float, optional
        Magnitudes of the instrument's imperfections by name
        (:data:`gonio.simulator.effects.EFFECTS`, e.g. from
        :func:`gonio.simulator.effects.realise`); missing names are 0. None or all zero is
        the ideal instrument (bit-identical images, none of the effects' work done). A
        magnitude outside its valid range is a ``ValueError``.
    instrument_seed : int
        Seed of the effects' realisation (the dome's figure map, the standard's deviation
        from its certificate, each f-stop's error, the tilt's azimuth): the same seed and
        magnitudes are the same physical instrument.

    Notes
    -----
    The side-car (:meth:`metadata`) records what a real instrument writes (the marked
    f-number, the nominal optics), not the effects: :func:`reproduce` and
    :meth:`from_metadata` rebuild the ideal instrument. The campaign's clock for the lamp's
    warm-up and drift is :attr:`clock_s` (seconds since the first capture; captures and
    brackets take ``clock_s`` too).
    """

    def __init__(
        self,
        mirror: str | Mirror = "ellipsoid",
        radius: float = 0.15,
        half_separation: float = 0.01,
        lens: str | FisheyeLens = "equidistant",
        width: int = 640,
        height: int = 480,
        *,
        sensor: Sensor | None = None,
        source: Source | None = None,
        background: Background | None = None,
        sample_radius: float = 0.008,
        rho_standard: float = 0.99,
        mirror_reflectance: float = 0.5,
        mirror_transmittance: float = 0.45,
        effects: Mapping[str, float] | None = None,
        instrument_seed: int = 0,
    ) -> None:
        if isinstance(mirror, Mirror):
            self.mirror = mirror
        else:
            if mirror not in MIRRORS:
                raise ValueError(
                    f"mirror {mirror!r} is unknown; expected one of {', '.join(MIRRORS)}"
                )
            self.mirror = Mirror(
                mirror, radius, half_separation, mirror_reflectance, mirror_transmittance
            )
        if isinstance(lens, FisheyeLens):
            self.lens = lens
        elif isinstance(lens, str):
            if lens not in LENS_MODELS:
                raise ValueError(
                    f"lens {lens!r} is unknown; expected one of {', '.join(LENS_MODELS)}"
                )
            self.lens = make_lens(lens, width, height)
        else:
            raise ValueError(f"lens must be a model name or a FisheyeLens, got {lens!r}")
        self.sensor = sensor if sensor is not None else Sensor()
        self.source = source if source is not None else Source()
        self.background = background if background is not None else Background()
        for name, obj, cls in (
            ("sensor", self.sensor, Sensor),
            ("source", self.source, Source),
            ("background", self.background, Background),
        ):
            if not isinstance(obj, cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(obj).__name__}")
        self.sample_radius = _check_positive(sample_radius, "sample_radius")
        if self.sample_radius >= 2.0 * self.mirror.half_separation:
            raise ValueError(
                f"sample_radius = {sample_radius!r} must be smaller than 2D = "
                f"{2.0 * self.mirror.half_separation!r} (the sample would overlap the lens)"
            )
        rs = _check_positive(rho_standard, "rho_standard")
        if rs > 1.0:
            raise ValueError(f"rho_standard must be in (0, 1], got {rho_standard!r}")
        self.rho_standard = rs
        self._drop_caches()
        self._set_effects(effects, instrument_seed)

    #: attributes that describe the instrument; every per-instrument cache derives from them
    _CONFIG: ClassVar[frozenset[str]] = frozenset(
        {"mirror", "lens", "sensor", "source", "background", "sample_radius", "rho_standard"}
    )
    _CONFIG_TYPES: ClassVar[dict[str, type]] = {
        "sensor": Sensor,
        "source": Source,
        "background": Background,
    }

    def __setattr__(self, name: str, value: Any) -> None:
        """Reassigning a part of the instrument (``inst.sensor = Sensor(...)``) drops every
        cache derived from the old parts, so the next capture is that of a fresh instrument
        (the parts themselves are frozen dataclasses, so reassignment is the only change)."""
        if name in self._CONFIG:
            cls = self._CONFIG_TYPES.get(name)
            if cls is not None and not isinstance(value, cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
            if name in self.__dict__ and self.__dict__[name] is not value:
                self._drop_caches()
        object.__setattr__(self, name, value)

    def _drop_caches(self) -> None:
        """Forget every per-instrument cache (the traced geometry is keyed by the optics
        in the module-level cache and needs no dropping)."""
        d = self.__dict__
        d["_bg_cache"] = {}
        d["_resp"] = None
        d["_resp_c"] = None
        for name in ("_resp_rays_cache", "_dark_map", "_ones_c", "_field_arrays"):
            d.pop(name, None)
        # the effects' caches (their realisation is redrawn from the same seed)
        for name in (
            "_true_geometry", "_dome_trace", "_std_model", "_albedo_cache", "_albedo_images",
            "_resp_field", "_box",
        ):  # fmt: skip
            d.pop(name, None)

    # ------------------------------------------------------------------ description
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready instrument description (the instrument part of the metadata)."""
        return {
            "instrument": "lbl",
            "mirror": self.mirror.to_dict(),
            "lens": self.lens.to_dict(),
            "sensor": self.sensor.to_dict(),
            "source": self.source.to_dict(),
            "background": self.background.to_dict(),
            "sample_radius": self.sample_radius,
            "rho_standard": self.rho_standard,
        }

    @classmethod
    def from_metadata(cls, meta: dict[str, Any]) -> LBLInstrument:
        """Rebuild the instrument a capture's metadata describes."""
        try:
            return cls(
                Mirror.from_dict(meta["mirror"]),
                lens=FisheyeLens.from_dict(
                    meta["full_lens"] if "full_lens" in meta else meta["lens"]
                ),
                sensor=Sensor.from_dict(meta["sensor"]),
                source=Source.from_dict(meta["source"]),
                background=Background.from_dict(meta["background"]),
                sample_radius=meta["sample_radius"],
                rho_standard=meta["rho_standard"],
            )
        except KeyError as exc:
            raise ValueError(f"metadata lacks {exc}; not an LBL capture") from None

    def __repr__(self) -> str:
        m = self.mirror
        return (
            f"LBLInstrument({m.kind}, R={m.radius:g}, D={m.half_separation:g}, "
            f"lens={self.lens.model} {self.lens.width}x{self.lens.height})"
        )

    # ------------------------------------------------------------------ caches
    @property
    def geometry(self) -> Geometry:
        """The traced per-pixel geometry (computed on first use, then cached)."""
        return self._geometry(1)

    def _geometry(self, rays: int = 1) -> Geometry:
        """Traced geometry with ``rays`` sub-pixel rays per pixel (cached per instrument optics)."""
        key = (
            tuple(sorted(self.mirror.to_dict().items())),
            tuple(
                (k, tuple(v) if isinstance(v, list) else v) for k, v in self.lens.to_dict().items()
            ),
            self.sample_radius,
        ) + ((("rays", rays),) if rays != 1 else ())
        g = _GEOMETRY_CACHE.get(key)
        if g is None:
            g = _trace_geometry(self.mirror, self.lens, self.sample_radius, rays)
            while len(_GEOMETRY_CACHE) >= _GEOMETRY_CACHE_SIZE:  # drop the oldest
                _GEOMETRY_CACHE.pop(next(iter(_GEOMETRY_CACHE)))
            _GEOMETRY_CACHE[key] = g
        return g

    def _response(self) -> tuple[NDArray, NDArray]:
        """Per-pixel electrons per (photon s⁻¹ m⁻² sr⁻¹ · s) at f/1: full image and candidates."""
        if self._resp is None:
            g = self.geometry
            prnu, _ = self.sensor.maps(g.height, g.width)
            k = self.sensor.qe * (math.pi / 4.0) * self.sensor.pixel_pitch**2
            self._resp = (prnu * k).ravel()
            v = self._fx.get("vignetting", 0.0)
            if v:  # the fisheye's relative illumination, 1 - v (θ / θ_max)²
                th = self.lens.field_angle(self.lens.pixel_grid().reshape(-1, 2))
                self._resp = self._resp * (1.0 - v * np.minimum(th / self.lens.theta_max, 1) ** 2)
            self._resp_c = np.ascontiguousarray(self._resp[g.idx])
        return self._resp, self._resp_c

    def _resp_rays(self, g: Geometry, rays: int) -> NDArray:
        """Per-candidate response of a supersampled geometry: each ray has 1/rays of its pixel."""
        if rays == 1:
            return self._response()[1]
        cache = self.__dict__.setdefault("_resp_rays_cache", {})
        r = cache.get(rays)
        if r is None or r.size != g.idx.size:
            r = self._response()[0][g.idx] * (1.0 / rays)
            cache.clear()
            cache[rays] = r
        return r

    def _background_photons(self, wi_dome: NDArray) -> NDArray:
        """Background electrons per second at f/1, per pixel (cached per beam direction)."""
        key = tuple(np.round(wi_dome, 12))
        bg = self._bg_cache.get(key)
        if bg is None:
            g = self.geometry
            resp, _ = self._response()
            rad = np.zeros(g.n_pixels)
            b = self.background
            vals = np.full(len(g.field_idx), b.ambient * self.mirror.transmittance)
            if b.stray > 0.0:
                # where the beam (from the source towards S) crosses the dome, seen from C
                cross = self._dome_crossing(wi_dome)
                to = cross - self.mirror.camera_position
                to /= np.linalg.norm(to)
                cosang = np.clip(g.field_dirs @ to, -1.0, 1.0)
                ang = np.arccos(cosang)
                vals += b.stray * np.exp(-0.5 * (ang / b.stray_width) ** 2)
            rad[g.field_idx] = vals
            bg = rad * resp
            if len(self._bg_cache) > 64:
                self._bg_cache.clear()
            self._bg_cache[key] = bg
        return bg

    def _dome_crossing(self, wi_dome: NDArray) -> NDArray:
        """Point where the ray from the sample centre along ``wi_dome`` meets the dome."""
        ax, ay, az = self.mirror.semi_axes
        inv2 = np.array([1 / ax**2, 1 / ay**2, 1 / az**2])
        s = self.mirror.sample_position
        qa = float(np.dot(wi_dome * wi_dome, inv2))
        qb = float(np.dot(wi_dome, s * inv2))
        qc = float(np.dot(s * s, inv2) - 1.0)
        t = (-qb + math.sqrt(qb * qb - qa * qc)) / qa
        return s + t * wi_dome

    # ------------------------------------------------------------------ effects
    _GEOMETRY_FX = ("dome_slope_error", "lens_body_height", "holder_rim_height")
    _FRAME_FX = (
        "fstop_series", "fstop_error", "iris_repeatability", "lamp_warmup", "lamp_drift",
        "lamp_flicker", "pixel_fill", "diffraction_wavelength", "focus_error",
    )  # fmt: skip
    _SCENE_FX = ("veiling_glare", "reillumination", "ambient_on_sample")

    def _set_effects(self, effects: Mapping[str, float] | None, seed: Any) -> None:
        from gonio.simulator.effects import EFFECTS, check_magnitudes

        if not isinstance(seed, int | np.integer) or int(seed) < 0:
            raise ValueError(f"instrument_seed must be a non-negative integer, got {seed!r}")
        self.instrument_seed = int(seed)
        fx: dict[str, float] = {}
        if effects is not None:
            check_magnitudes(effects)
            fx = {k: float(v) for k, v in effects.items() if float(v) != 0.0}
        #: every effect's magnitude (0 = off)
        self.effects = {name: fx.get(name, 0.0) for name in EFFECTS}
        self._fx = fx
        self._frame_fx = any(k in fx for k in self._FRAME_FX)
        self._scene_fx = any(k in fx for k in self._SCENE_FX)
        #: campaign time of the next capture (s), for the lamp's warm-up and drift
        self.clock_s = 0.0

    def certificate(self):
        """The calibration certificate that comes with this instrument's diffuse standard
        (:class:`gonio.io.certificate.Certificate`: what the laboratory knows of it)."""
        from gonio.simulator.standard import make_certificate

        fx = self._fx
        return make_certificate(
            self.rho_standard, fx.get("standard_non_lambertian", 0.0),
            fx.get("standard_certificate_u", 0.0),
        )  # fmt: skip

    def _standard_model(self) -> BRDF:
        """The real standard: Lambertian, or the PTFE shape times its deviation from the
        certificate (drawn once from the instrument seed)."""
        m = self.__dict__.get("_std_model")
        if m is None:
            fx = self._fx
            scale = fx.get("standard_non_lambertian", 0.0)
            u = fx.get("standard_certificate_u", 0.0)
            if scale == 0.0 and u == 0.0:
                from gonio.brdf.lambert import Lambert

                m = Lambert(rho=self.rho_standard)
            else:
                from gonio.simulator.effects import effect_rng
                from gonio.simulator.standard import true_standard

                from gonio.brdf.base import CallableBRDF

                rng = effect_rng(self.instrument_seed, "standard_certificate_u")
                f = true_standard(self.rho_standard, scale, u, rng)
                m = CallableBRDF(f, "ptfe_standard")
            self._std_model = m
        return m

    def _scene_geometry(self, kind: str, rays: int) -> Geometry:
        """The true geometry: the dome's figure error, occlusion, and (for a sample) the
        sample plane at its height; the ideal traced geometry when none applies."""
        fx = self._fx
        h = fx.get("sample_height", 0.0) if kind == "brdf" else 0.0
        if h == 0.0 and not any(k in fx for k in self._GEOMETRY_FX):
            return self._geometry(rays)
        if rays != 1:
            raise ValueError(
                "rays_per_pixel > 1 is not supported with the dome, occlusion or sample-height "
                "effects (set them to 0 or use one ray per pixel)"
            )
        cache = self.__dict__.setdefault("_true_geometry", {})
        g = cache.get(h)
        if g is None:
            from gonio.simulator import lbl_effects as le

            m = self.mirror
            slope = None
            if fx.get("dome_slope_error", 0.0):
                r = max(m.semi_axes)
                mag, seed = fx["dome_slope_error"], self.instrument_seed
                slope = lambda p: le.slope_field(p, mag, r, seed)  # noqa: E731
            hit = self.__dict__.get("_dome_trace")  # (mirror points, reflected rays): once

            def tracer(dirs):
                nonlocal hit
                if hit is None:
                    hit = self._dome_trace = le.dome_rays(m, dirs, slope)
                return le.to_plane(*hit, h)

            keep = None
            if fx.get("lens_body_height", 0.0) or fx.get("holder_rim_height", 0.0):

                def keep(tr, q):
                    return ~le.view_blocked(
                        tr["sample_point"], tr["wo"], tr["point"], m, self.sample_radius, fx
                    )

            # the ideal trace's camera rays: the same lens and pixels
            g = _trace_geometry(m, self.lens, self.sample_radius, 1, tracer, keep, self.geometry)
            cache[h] = g
        return g

    def _candidate_response(self, g: Geometry, rays: int) -> NDArray:
        """Response of the candidates of ``g`` (the ideal geometry's is cached as before)."""
        if g is self._geometry(rays):
            return self._resp_rays(g, rays)
        rc = g.__dict__.get("_rc")
        if rc is None:
            rc = np.ascontiguousarray(self._response()[0][g.idx])
            g.__dict__["_rc"] = rc
        return rc

    def _posed(self, g: Geometry, theta_i: float, wi_local, wi_dome, psi: float):
        """The sample's geometry in its own (tilted, raised) frame: ``(geometry, wi_local)``.

        The tilt is fixed in the sample (azimuth from the instrument seed), so it turns with
        the holder: reflected directions are rotated by ``Rz(ψ) T Rz(-ψ)`` in the dome frame
        (the kernels then apply ``Rz(-ψ)``) and the incidence by ``T``; candidates whose
        direction falls below the tilted horizon are dropped. A raised sample moves the
        beam footprint by ``h tan θi`` towards the source (the plane's tilt within the
        footprint, below 0.1 mm, is neglected).
        """
        from dataclasses import replace

        from gonio.simulator import lbl_effects as le
        from gonio.simulator.effects import effect_rng

        fx = self._fx
        tilt = fx.get("sample_tilt", 0.0)
        h = fx.get("sample_height", 0.0)
        c_arr = np.ascontiguousarray
        tilted = g.__dict__.setdefault("_tilted", {})
        base = tilted.get(psi)  # the tilted directions, once per holder rotation
        if base is None:
            rc = self._candidate_response(g, 1)
            if tilt:
                az = effect_rng(self.instrument_seed, "sample_tilt").uniform(0, 2 * math.pi)
                t = le.tilt_rotation(tilt, float(az))
                c, s = math.cos(psi), math.sin(psi)
                rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                mm = rz @ t @ rz.T
                w = [mm[j, 0] * g.wx + mm[j, 1] * g.wy + mm[j, 2] * g.wz for j in range(3)]
                keep = np.flatnonzero(w[2] > 1e-9)
                if keep.size == g.idx.size:
                    keep = None
                else:
                    w = [a[keep] for a in w]
            else:
                t, w, keep = np.eye(3), [g.wx, g.wy, g.wz], None
            sub = (lambda a: a) if keep is None else (lambda a: c_arr(a[keep]))
            base = tilted[psi] = [
                t, [c_arr(a) for a in w], sub(g.idx), sub(g.qx), sub(g.qy), sub(rc),
                1.0 / np.sqrt(w[2]),
            ]  # fmt: skip
        t, (wx, wy, wz), idx, qx, qy, rc, isq = base[:7]
        if h:
            qx = qx - h * wi_dome[0] / wi_dome[2]
            qy = qy - h * wi_dome[1] / wi_dome[2]
        posed = replace(
            g, idx=idx, wx=wx, wy=wy, wz=wz, qx=qx, qy=qy, isq=isq,
            q_max=float(np.sqrt((qx * qx + qy * qy).max(initial=0.0))),
        )  # fmt: skip
        posed.__dict__["_rc"] = rc
        posed.__dict__["_runs"] = g.runs() if idx is g.idx else False
        # its points' radii lie within |h| tan θi of the unmoved ones' (see _near_rim)
        shift = abs(h) * math.hypot(wi_dome[0] / wi_dome[2], wi_dome[1] / wi_dome[2]) if h else 0.0
        posed.__dict__["_r_bound"] = (base, shift)
        posed.__dict__["_theta_o_key"] = (id(g), psi)  # (one albedo map per rotation)
        return posed, t @ wi_local

    def _albedo_fn(self, kind: str, model: BRDF) -> Callable[[NDArray], NDArray]:
        """``ρ_dh(θ)`` of the sample (interpolated over 7 polar angles at φ = 0, to 0.1 %;
        anisotropy neglected) or of the standard (``ρ_standard``: its PTFE shape keeps its
        albedo)."""
        if kind == "standard":
            rho = self.rho_standard
            return lambda th: np.full(np.shape(th), rho)
        cache = self.__dict__.setdefault("_albedo_cache", {})
        key = (model.name, repr(sorted(model.params.items())))
        hit = cache.get(key)
        if hit is None:
            th = np.radians(np.linspace(0.0, 89.0, 7))
            wi = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=-1)
            a = np.asarray(model.albedo(wi, rtol=1e-3), dtype=np.float64)
            if a.ndim == 2:
                a = a.mean(axis=-1)
            hit = (model, th, a)
            cache[key] = hit
        _, th, a = hit
        return lambda t: np.interp(t, th, a)

    def _scene_background(self, bg, kind, model, theta_i, g, rc, lit, gv, isq, kd0, ks0, k0):
        """The scene's background electrons plus re-illumination and ambient light on the
        sample (over every candidate pixel: the whole sample disk) and the veiling glare of
        the whole image (over the image circle). A new array; ``bg`` is not changed."""
        fx = self._fx
        r = fx.get("reillumination", 0.0)
        a = fx.get("ambient_on_sample", 0.0)
        if model is not None and (r or a):
            alb = self._albedo_fn(kind, model)
            coef = 0.0
            if r:
                rs, rspot = self.sample_radius, self.source.spot_radius
                lit_area = min(math.pi * rspot**2 / math.cos(theta_i), math.pi * rs**2)
                e_re = r * float(alb(np.array(theta_i))) * math.cos(theta_i) * lit_area
                coef += k0 * e_re / (math.pi * rs**2) / math.pi
            if a:
                m = self.mirror
                coef += a * m.transmittance * m.reflectance * self.background.ambient
            bg = bg + coef * self._albedo_image(kind, model, g, rc, alb)
        glare = fx.get("veiling_glare", 0.0)
        if glare:
            cached = self.__dict__.get("_resp_field")
            if cached is None:  # the response inside the image circle (0 outside), its sum
                resp_field = np.zeros_like(self._response()[0])
                fi = self.geometry.field_idx
                resp_field[fi] = self._response()[0][fi]
                cached = self._resp_field = (resp_field, float(resp_field.sum()))
            resp_field, resp_sum = cached
            # (a plain sum, not BLAS's dot: a woken BLAS thread pool costs more than the sum)
            sig = k0 * float(np.sum(rc * lit * (kd0 + ks0 * gv * isq)))
            total = float(bg.sum()) + sig  # (the background is 0 outside the image circle)
            bg = bg + resp_field * (glare * total / resp_sum)
        return bg

    def _albedo_image(self, kind, model, g, rc, alb) -> NDArray:
        """Full image of ``response x ρ_dh(θo)`` over the candidates of ``g`` (0 elsewhere):
        the pixels' electrons per unit diffuse irradiance on the sample (cached per
        geometry, holder rotation and model)."""
        cache = self.__dict__.setdefault("_albedo_images", {})
        key = (g.__dict__.get("_theta_o_key", id(g)), kind, model.name,
               repr(sorted(model.params.items())) if kind == "brdf" else "")  # fmt: skip
        img = cache.get(key)
        if img is None:
            if len(cache) > 8:
                cache.clear()
            img = np.zeros(g.n_pixels)
            np.add.at(img, g.idx, rc * alb(np.arccos(np.clip(g.wz, -1.0, 1.0))))
            cache[key] = img
        return img

    def _frame_electrons(
        self, sc: _Scene, f_number: float, key: str = "", clock_s: float | None = None
    ) -> NDArray:
        """Noise-free electrons of one frame: the scene at the lens's true aperture (the
        engraved series, this lens's stop error, the iris's repeatability), the lamp's
        output at :attr:`clock_s` (warm-up, drift, flicker), then the point-spread function
        (pixel area, diffraction, defocus). Just :meth:`_compose` when none is on."""
        fx = self._fx
        if not self._frame_fx:
            return self._compose(sc, f_number)
        from gonio.simulator import lbl_effects as le
        from gonio.simulator.effects import effect_rng

        n = le.true_f_number(f_number, fx.get("fstop_series", 0.0))
        area = le.fstop_area_factor(f_number, fx.get("fstop_error", 0.0), self.instrument_seed)
        t = self.clock_s if clock_s is None else float(clock_s)
        lamp = le.lamp_factor(t, fx.get("lamp_warmup", 0.0), fx.get("lamp_drift", 0.0))
        iris, flick = fx.get("iris_repeatability", 0.0), fx.get("lamp_flicker", 0.0)
        if iris or flick:
            rng = effect_rng(self.instrument_seed, "frame", key)
            area *= max(1.0 + iris * float(rng.normal()), 0.05)
            lamp *= max(1.0 + flick * float(rng.normal()), 0.05)
        e = self._compose(sc, n / math.sqrt(area), lamp=lamp)
        sigma = le.psf_sigma_px(
            n, fx, self.sensor.pixel_pitch, self.lens.fx, 0.5 * self.mirror.radius
        )
        if sigma > 0.0:  # (the dark current is the pixel's own: not blurred)
            import cv2

            dark = sc.dark * sc.exposure
            e -= dark
            img = e.reshape(self.lens.height, self.lens.width)
            r0, r1, c0, c1 = self._light_box()
            box = img[r0:r1, c0:c1].astype(np.float32)  # (float32: 1e-7 of the signal)
            img[r0:r1, c0:c1] = cv2.GaussianBlur(box, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
            e += dark
        return e

    def _light_box(self) -> tuple[int, int, int, int]:
        """Rows and columns of the image circle, with an 8-pixel margin (light falls nowhere
        else, so the point-spread function need not be applied outside)."""
        box = self.__dict__.get("_box")
        if box is None:
            h, w = self.lens.height, self.lens.width
            rows, cols = np.divmod(self.geometry.field_idx, w)
            box = self._box = (
                max(int(rows.min()) - 8, 0), min(int(rows.max()) + 9, h),
                max(int(cols.min()) - 8, 0), min(int(cols.max()) + 9, w),
            )  # fmt: skip
        return box

    # ------------------------------------------------------------------ rendering core
    def _frames(self, theta_i: float, phi_i: float) -> tuple[NDArray, NDArray, float]:
        """(wi_local, wi_dome, psi): psi = dome azimuth of the sample's x axis."""
        psi = self.source.arm_azimuth - phi_i
        st = math.sin(theta_i)
        wi_local = np.array([st * math.cos(phi_i), st * math.sin(phi_i), math.cos(theta_i)])
        a = self.source.arm_azimuth
        wi_dome = np.array([st * math.cos(a), st * math.sin(a), math.cos(theta_i)])
        return wi_local, wi_dome, psi

    def _source_dirs(
        self, model: BRDF, wi_local: NDArray, n: int | None
    ) -> tuple[NDArray, NDArray]:
        if n is None:
            width = _lobe_width(model)
            n = 1 if (width is None or width >= 5.0 * self.source.divergence) else 19
        return cone_directions(wi_local, self.source.divergence, int(n))

    def _signal_terms(
        self,
        g: Geometry,
        model: BRDF,
        theta_i: float,
        phi_i: float,
        k: float,
        band: int | None,
        source_samples: int | None,
        kernel: bool,
        visible_only: bool,
        wi_local: NDArray | None = None,
    ) -> tuple[NDArray, NDArray, NDArray, float, float]:
        """Per-candidate signal terms ``(lit, g, isq, kdc, ksc)``.

        A candidate pixel j gains ``resp[j] · lit[j] · (kdc + ksc · g[j] · isq[j])``
        electrons; ``k`` = E T R_m t / N². Ward/Lambert with one source direction use the
        numba exponent kernel and numpy's exp (``g`` = the exponential, ``isq`` = 1/√cos θ_o);
        everything else evaluates ``model.evaluate_unchecked`` on the lit pixels only
        (``g`` = Σ w f_r cos θ_i, ``isq`` = 1). ``g`` (the argument) is the traced geometry
        (one ray per pixel, or supersampled).
        """
        wi_nominal, wi_dome, psi = self._frames(theta_i, phi_i)
        if wi_local is None:  # (a tilted sample passes its own)
            wi_local = wi_nominal
        c, s = math.cos(psi), math.sin(psi)
        bx, by = float(wi_dome[0]), float(wi_dome[1])
        r2 = self.source.spot_radius**2
        wis, wsrc = self._source_dirs(model, wi_local, source_samples)
        kp = _ward_kernel_params(model) if kernel else None
        n = g.idx.size
        foot = g.q_max**2 > r2
        if kp is not None and visible_only:
            from gonio.simulator import _kernels

            kd, ks, iax2, iay2, approx = kp
            lit = np.empty(n, dtype=np.uint8)
            buf = np.empty(n)
            if len(wis) == 1:
                ix, iy, iz = (float(x) for x in wis[0])
                if ks == 0.0:  # Lambertian: no exponent needed
                    _kernels.ward_exponent(
                        g.wx, g.wy, g.wz, g.qx, g.qy, foot, ix, iy, iz, c, s, bx, by, r2,
                        0.0, 0.0, False, buf, lit,
                    )  # fmt: skip
                    return lit, buf, g.isq, k * kd * iz, 0.0
                _kernels.ward_exponent(
                    g.wx, g.wy, g.wz, g.qx, g.qy, foot, ix, iy, iz, c, s, bx, by, r2,
                    iax2, iay2, approx, buf, lit,
                )  # fmt: skip
                np.exp(buf, out=buf)
                return lit, buf, g.isq, k * kd * iz, k * ks * math.sqrt(iz)
            _kernels.ward_cone(
                g.wx, g.wy, g.wz, g.qx, g.qy, np.ascontiguousarray(wis), wsrc, c, s, bx, by,
                r2, kd, ks, iax2, iay2, approx, buf, lit,
            )  # fmt: skip
            return lit, buf, self._ones(n), 0.0, k
        if visible_only:
            wx, wy, wz, qx, qy = g.wx, g.wy, g.wz, g.qx, g.qy
        else:
            # the "no skip" reference of the benchmark: evaluate the BRDF on every pixel of
            # the image, mask afterwards, then keep the candidates' values
            wx, wy, wz, qx, qy, on, pos = self._all_field_arrays()
        p = qx * bx + qy * by
        litb = (qx * qx + qy * qy - p * p <= r2) & (wz > 0.0)
        if visible_only:  # the lit candidates' directions only
            on = np.flatnonzero(litb)
            wx, wy, wz = wx[on], wy[on], wz[on]
        wo = np.stack([c * wx + s * wy, -s * wx + c * wy, wz], axis=-1)
        acc = np.zeros(wo.shape[0])
        for wi_m, w_m in zip(wis, wsrc):
            f = np.asarray(model.evaluate_unchecked(wi_m, wo), dtype=np.float64)
            if f.ndim == 2:
                f = f.mean(axis=-1) if band is None else f[:, band]
            acc += w_m * f * max(float(wi_m[2]), 0.0)
        if not np.isfinite(acc).all():
            raise ValueError(f"BRDF {model!r} returned non-finite values")
        if visible_only:
            full = np.zeros(n)
            full[on] = acc
            return litb.astype(np.uint8), full, self._ones(n), 0.0, k
        masked = np.where(litb & on, acc, 0.0)
        return (litb & on)[pos].astype(np.uint8), masked[pos], self._ones(n), 0.0, k

    def _ones(self, n: int) -> NDArray:
        if getattr(self, "_ones_c", None) is None or self._ones_c.size != n:
            self._ones_c = np.ones(n)
        return self._ones_c

    def _all_field_arrays(self):
        """Traced arrays for EVERY pixel of the image (benchmark reference for the skip of
        pixels outside the image circle or seeing no illuminated sample)."""
        if getattr(self, "_field_arrays", None) is None:
            g = self.geometry
            uv = self.lens.pixel_grid().reshape(-1, 2)
            tr = self.mirror.trace(self.lens.unproject(uv))
            q = tr["sample_point"] - self.mirror.sample_position
            on = (
                tr["valid"]
                & self.lens.in_field(uv)
                & (q[:, 0] ** 2 + q[:, 1] ** 2 <= self.sample_radius**2)
            )
            wo = tr["wo"]
            self._field_arrays = (wo[:, 0], wo[:, 1], wo[:, 2], q[:, 0], q[:, 1], on, g.idx)
        return self._field_arrays

    def _delta_terms(
        self, model: BRDF, wi_local: NDArray, wi_dome: NDArray, psi: float, band: int | None,
        sub: int = 8,
    ) -> tuple[NDArray, NDArray] | None:  # fmt: skip
        """Mirror component: radiance ρ_δ E/Ω_s over the image of the source cone.

        Returns ``(pixels, electrons per unit k)`` (add ``k · value``; ``k`` = E T R_m t/N²),
        or None when the model has no mirror reflectance here.
        """
        d_local, rho = model.delta(wi_local)
        rho = np.asarray(rho, dtype=np.float64)
        if rho.ndim == 1:
            rho = rho.mean() if band is None else rho[band]
        rho = float(rho)
        if rho <= 0.0:
            return None
        g = self.geometry
        resp, _ = self._response()
        c, s = math.cos(psi), math.sin(psi)
        d = np.asarray(d_local, dtype=np.float64)
        d_dome = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]])
        gam = self.source.divergence
        cosang = g.wx * d_dome[0] + g.wy * d_dome[1] + g.wz * d_dome[2]
        near = np.flatnonzero(cosang >= math.cos(min(gam + 2.0 * g.pixel_angle, math.pi)))
        if near.size == 0:
            return None
        pix = g.idx[near]
        rows, cols = np.divmod(pix, g.width)
        off = (np.arange(sub) + 0.5) / sub - 0.5
        ou, ov = np.meshgrid(off, off)
        uv = np.stack(
            [cols[:, None] + ou.ravel()[None, :], rows[:, None] + ov.ravel()[None, :]], axis=-1
        )
        dirs = self.lens.unproject(uv)
        tr = self.mirror.trace(dirs)
        q = tr["sample_point"] - self.mirror.sample_position
        p = q[..., 0] * wi_dome[0] + q[..., 1] * wi_dome[1]
        ok = (
            tr["valid"]
            & self.lens.in_field(uv)
            & (q[..., 0] ** 2 + q[..., 1] ** 2 <= self.sample_radius**2)
            & (q[..., 0] ** 2 + q[..., 1] ** 2 - p * p <= self.source.spot_radius**2)
            & (tr["wo"] @ d_dome >= math.cos(gam))
        )
        cover = ok.mean(axis=-1)
        radiance = rho / self.source.solid_angle  # per unit beam irradiance (k carries E)
        return pix, resp[pix] * radiance * cover

    def electrons(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        band: int | None = None,
        source_samples: int | None = None,
        kernel: bool = True,
        visible_only: bool = True,
        rays_per_pixel: int = 1,
    ) -> NDArray[np.float64]:
        """Noise-free expected electrons per pixel, ``(height, width)`` float64.

        Same arguments as :meth:`capture`; ``kernel`` / ``visible_only`` switch off the
        specialised kernel and the visible-pixel skip (for benchmarks and tests).
        """
        kind, model, _ = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = self._check_args(theta_i, phi_i, exposure, f_number)
        return self._electrons(
            kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
            kernel, visible_only, _check_rays(rays_per_pixel),
        ).reshape(self.lens.height, self.lens.width)  # fmt: skip

    def _check_args(self, theta_i, phi_i, exposure, f_number):
        theta_i = _check_angle(theta_i, "theta_i", 0.0, math.pi / 2, True)
        try:
            phi_i = float(phi_i)
        except (TypeError, ValueError):
            raise ValueError(f"phi_i must be a number (radians), got {phi_i!r}") from None
        if not math.isfinite(phi_i):
            raise ValueError(f"phi_i must be finite, got {phi_i!r}")
        exposure = _check_positive(exposure, "exposure")
        f_number = _check_positive(f_number, "f_number")
        if f_number < 0.5:
            raise ValueError(f"f_number must be >= 0.5, got {f_number!r}")
        return theta_i, phi_i, exposure, f_number

    def _scene(
        self, kind, model, theta_i, phi_i, exposure, band, source_samples, kernel=True,
        visible_only=True, rays=1,
    ) -> _Scene:  # fmt: skip
        """The noise-free scene, independent of the f-number (see :class:`_Scene`)."""
        if rays != 1 and not visible_only:
            raise ValueError("rays_per_pixel > 1 needs visible_only=True")
        fx = self._fx
        g = self._scene_geometry(kind, rays) if fx else self._geometry(rays)
        wi_local, wi_dome, psi = self._frames(theta_i, phi_i)
        wi_sig = None
        if kind == "brdf" and (fx.get("sample_tilt") or fx.get("sample_height")):
            g, wi_sig = self._posed(g, theta_i, wi_local, wi_dome, psi)
        bg = self._background_photons(wi_dome)
        dark = self._dark()
        if kind == "standard":
            model = self._standard_model()
        if model is not None and model.n_bands and band is not None:
            if not (0 <= band < model.n_bands):
                raise ValueError(f"band must be in [0, {model.n_bands}), got {band!r}")
        k0 = self.source.irradiance * self.mirror.transmittance * self.mirror.reflectance
        if model is None:
            rc = self._response()[1][:0]
            idx = g.idx[:0]
            lit, gv, isq, kd0, ks0 = idx.astype(np.uint8), rc, rc, 0.0, 0.0
            runs = (idx, idx)
        else:
            idx = g.idx
            rc = self._candidate_response(g, rays) if fx else self._resp_rays(g, rays)
            lit, gv, isq, kd0, ks0 = self._signal_terms(
                g, model, theta_i, phi_i, 1.0, band, source_samples, kernel, visible_only,
                wi_sig,
            )  # fmt: skip
            if fx.get("holder_rim_height"):
                from gonio.simulator.lbl_effects import beam_shadowed

                # only points within h tan θi of the rim can be in its shadow
                h_rim = fx["holder_rim_height"]
                near = _near_rim(g, 1.25 * self.sample_radius - h_rim * math.tan(theta_i) - 1e-12)
                if near.size:
                    shadow = beam_shadowed(
                        g.qx[near], g.qy[near], wi_dome, self.mirror.half_separation,
                        self.sample_radius, h_rim,
                    )  # fmt: skip
                    lit = lit.copy()
                    lit[near[shadow]] = 0
            runs = g.runs()
        if self._scene_fx:
            bg = self._scene_background(bg, kind, model, theta_i, g, rc, lit, gv, isq, kd0, ks0, k0)
        delta = None
        if model is not None and model.has_delta:
            wi_local, _, _ = self._frames(theta_i, phi_i)
            delta = self._delta_terms(model, wi_local, wi_dome, psi, band)
        return _Scene(bg, dark, exposure, k0, idx, rc, lit, gv, isq, kd0, ks0, delta, rays, runs)

    def _compose(
        self, sc: _Scene, f_number: float, kernel=True, digitise=False, lamp: float = 1.0
    ) -> NDArray:
        """Noise-free electrons of a scene at ``f_number`` (flat float64), or with
        ``digitise`` the flat uint16 image; ``lamp`` scales the beam's signal."""
        tk = sc.exposure / f_number**2
        k = sc.k0 * tk * lamp if lamp != 1.0 else sc.k0 * tk
        kdc, ksc = k * sc.kd0, k * sc.ks0
        sen = self.sensor
        n = self.lens.height * self.lens.width
        if kernel:
            from gonio.simulator import _kernels

            # candidates as runs (unique pixels), else the pixel index (supersampled repeats)
            runs = sc.runs is not None
            where = sc.runs if runs else (sc.idx,)
            head = (sc.bg, sc.dark, tk, sc.exposure, *where, sc.rc, sc.lit, sc.g, sc.isq, kdc, ksc)
            if digitise and sc.delta is None and sen.linear:
                img = np.empty(n, dtype=np.uint16)
                compose_u16 = _kernels.compose_u16_runs if runs else _kernels.compose_u16
                compose_u16(*head, *sen.linear_adc, img)
                return img
            out = np.empty(n)
            (_kernels.compose_float_runs if runs else _kernels.compose_float)(*head, out)
        else:
            out = sc.bg * tk + sc.dark * sc.exposure
            sig = sc.rc * sc.lit * (kdc + ksc * sc.g * sc.isq)
            if sc.rays == 1:
                out[sc.idx] += sig
            else:  # a pixel's sub-pixel rays add up
                np.add.at(out, sc.idx, sig)
        if sc.delta is not None:
            pix, val = sc.delta
            out[pix] += k * val
        if digitise:
            return sen.digitise(out)
        return out

    def _shoot(
        self, sc: _Scene, f_number: float, noise: bool, rng, binning, skip_noise_draws=True,
        frame: tuple[str, float | None] = ("", None),
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:  # fmt: skip
        """One frame of a scene: noise (or none), ADC, optional binning; ``frame`` = (a name
        of the frame for the per-frame effects' draws, its campaign time or None for
        :attr:`clock_s`), see :meth:`_frame_electrons`."""
        sen = self.sensor
        h, w = self.lens.height, self.lens.width
        if not sen.ideal_readout or sen.has_charge_effects:
            # a sensor with effects: charge effects, readout and ADC of the composed electrons
            e = self._frame_electrons(sc, f_number, *frame)
            dark_e = sc.dark * sc.exposure if sen.smear > 0.0 else None  # smear needs it
            return self._finish_effects(e, dark_e, noise, rng, binning)
        fused = not self._frame_fx and sc.delta is None
        if not noise and skip_noise_draws and binning is None and sen.linear and fused:
            # no random draws, ADC fused into the render pass
            return self._compose(sc, f_number, digitise=True).reshape(h, w), self.lens
        if noise and binning is None and sen.linear:
            # shot + read noise and the ADC in one compiled pass over the composed electrons
            from gonio.simulator import _kernels

            e = self._frame_electrons(sc, f_number, *frame)
            img = np.empty(h * w, dtype=np.uint16)
            _kernels.noise_u16(
                e, _kernels.seed_state(rng), sen.normal_threshold, sen.read_noise,
                *sen.linear_adc, img,
            )  # fmt: skip
            return img.reshape(h, w), self.lens
        e = self._frame_electrons(sc, f_number, *frame)
        if noise:
            # shot + read noise drawn in place
            from gonio.simulator import _kernels

            state = _kernels.seed_state(rng)
            _kernels.noise_float(e, state, sen.normal_threshold, sen.read_noise, e)
        elif not skip_noise_draws:
            # the "no random draws when noise is off" rule switched off (benchmark): draw the
            # shot and read noise as if noise were on and add them with zero amplitude
            gen = np.random.default_rng(0)
            drawn = sen.add_noise(e, gen) - e
            e = e + 0.0 * drawn
        return self._finish(e, False, None, binning)

    def _render(
        self, kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
        kernel=True, visible_only=True, digitise=False, rays=1,
    ) -> NDArray:  # fmt: skip
        """Noise-free electrons (flat float64), or with ``digitise`` the uint16 image."""
        sc = self._scene(
            kind, model, theta_i, phi_i, exposure, band, source_samples, kernel, visible_only,
            rays,
        )  # fmt: skip
        return self._compose(sc, f_number, kernel, digitise)

    def _electrons(
        self, kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
        kernel=True, visible_only=True, rays=1,
    ) -> NDArray:  # fmt: skip
        return self._render(
            kind, model, theta_i, phi_i, exposure, f_number, band, source_samples,
            kernel, visible_only, False, rays,
        )  # fmt: skip

    def _dark(self) -> NDArray:
        """Dark-current map, electrons per second (flat, cached)."""
        if getattr(self, "_dark_map", None) is None:
            g = self.geometry
            self._dark_map = self.sensor.dark_map(g.height, g.width).ravel()
        return self._dark_map

    # ------------------------------------------------------------------ capture
    def _finish(
        self, e: NDArray, noise: bool, rng: np.random.Generator, binning, kernel: bool = True,
        dark_e: NDArray | None = None,
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:  # fmt: skip
        """Noise, ADC and binning of expected electrons ``e`` (flat); ``dark_e``: their dark
        part (smear follows the rest; default: the instrument's dark map at no exposure)."""
        sen = self.sensor
        if not sen.ideal_readout or sen.has_charge_effects:
            return self._finish_effects(e, dark_e, noise, rng, binning)
        if noise:
            e = sen.add_noise(e, rng)
        if binning is None:
            if sen.linear and kernel:
                from gonio.simulator import _kernels

                img = np.empty(e.size, dtype=np.uint16)
                _kernels.digitise_linear(e.ravel(), *sen.linear_adc, img)
            else:
                img = sen.digitise(e)
            return img.reshape(self.lens.height, self.lens.width), self.lens
        return self._bin(e, binning, sen.full_well)

    def _finish_effects(
        self,
        e: NDArray,
        dark_e: NDArray | None,
        noise: bool,
        rng: np.random.Generator | None,
        binning,
    ) -> tuple[NDArray[np.uint16], FisheyeLens]:
        """:meth:`_finish` for a sensor with effects (:attr:`Sensor.ideal_readout` false or
        charge effects on): blooming and smear of the expected charge (``dark_e``: its dark
        part, which smear does not follow; None: no dark part), then
        :meth:`Sensor.readout` (noise, full-well clip, offsets) and the ADC with no further
        clip."""
        sen = self.sensor
        h, w = self.lens.height, self.lens.width
        e = sen.spread(np.asarray(e, dtype=np.float64).reshape(h, w), dark_e)
        if binning is None:
            return sen.readout_dn(e, rng, noise=noise), self.lens
        return self._bin(sen.readout(e, rng, noise=noise), binning, math.inf)

    def _bin(self, e: NDArray, binning, clip_e: float) -> tuple[NDArray[np.uint16], FisheyeLens]:
        """Area-average binning to ``binning = (width, height)`` of electrons ``e`` clipped at
        ``clip_e``, then black level, rounding and the ADC's range."""
        import cv2

        sen = self.sensor
        bw, bh = binning
        x = np.minimum(e, clip_e) * (1.0 / sen.gain)
        if not sen.linear:
            xm = sen._x_max
            x = xm * (np.clip(x, 0.0, xm) / xm) ** sen.response_gamma
        x = x.reshape(self.lens.height, self.lens.width) + sen.black_level
        small = cv2.resize(x, (bw, bh), interpolation=cv2.INTER_AREA)
        dn = np.clip(np.rint(small), 0, sen.max_dn).astype(np.uint16)
        return dn, self.lens.resized(bw, bh)

    def capture(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        band: int | None = None,
        source_samples: int | None = None,
        rays_per_pixel: int = 1,
        skip_noise_draws: bool = True,
        clock_s: float | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """One raw image of ``sample`` lit from (θ_i, φ_i).

        Parameters
        ----------
        sample : BRDF, callable, str or None
            A model, a plain callable ``f(wi, wo)``, a material preset name
            (:func:`gonio.materials.get`) or model name, ``"standard"`` (the diffuse
            standard of reflectance ``rho_standard``), or ``None`` (no sample: background).
        theta_i, phi_i : float
            Incidence in the sample frame (radians), ``0 <= theta_i < pi/2``. θ_i is set by
            the source arm, φ_i by rotating the sample holder to ``arm_azimuth - phi_i``.
        exposure : float
            Exposure time, seconds (> 0).
        f_number : float
            Lens f-number (image irradiance ∝ 1/N²).
        rng : int, Generator or None
            Noise seed. An int (or None, which draws a fresh seed) is recorded in the
            metadata so the capture can be reproduced; a Generator is used as is.
        noise : bool
            False: no shot or read noise and no random draws (fixed patterns remain).
        binning : (width, height), True or None
            Reduce the image by area averaging before quantisation; ``True`` means Ward's
            108 × 80.
        band : int, optional
            Band index of a spectral BRDF (default: the mean over bands, white light).
        source_samples : int, optional
            Directions averaged over the source cone; default 1 when the model's lobe is
            at least 5× the beam divergence (or the model declares no lobe width), else 19.
        rays_per_pixel : int
            Sub-pixel supersampling: an ``s × s`` grid of rays per pixel (1, 4, 9, ..., 64),
            each traced through the mirror to the sample; the pixel averages their BRDF
            values (the background stays per pixel). Recorded in the metadata when not 1.
        skip_noise_draws : bool
            Benchmark switch of the rule "no random draws when noise is off": False draws
            the shot and read noise anyway and adds them with zero amplitude (same image).
        clock_s : float, optional
            Campaign time of the capture (s) for the lamp's warm-up and drift; default
            :attr:`clock_s`.

        Returns
        -------
        image : ndarray of uint16, shape (height, width)
        metadata : dict
            JSON-ready; see :meth:`metadata` (also written as the image side-car).
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = self._check_args(theta_i, phi_i, exposure, f_number)
        binning = self._check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        sc = self._scene(kind, model, theta_i, phi_i, exposure, band, source_samples, rays=rays)
        key = _frame_key(kind, theta_i, phi_i, exposure, f_number, seed, 0)
        img, lens = self._shoot(sc, f_number, noise, gen, binning, skip_noise_draws, (key, clock_s))
        meta = self.metadata(
            kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise, binning,
            band, source_samples, lens, img, rays,
        )  # fmt: skip
        return img, meta

    def capture_series(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        settings: Sequence[Mapping[str, Any]],
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        band: int | None = None,
        source_samples: int | None = None,
        rays_per_pixel: int = 1,
        clock_s: float | None = None,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """Several raw images of one scene: ``capture(sample, theta_i, phi_i, **s)`` for each
        ``s`` of ``settings`` (keys ``exposure``, ``f_number``, ``rng``), the noise-free
        scene rendered once.

        The scene does not depend on the exposure or the f-number (:class:`_Scene`: both
        enter only when the frame is composed), so each frame equals the separate
        :meth:`capture` bit for bit (a test checks it); a calibration series such as the
        f-stop ladder (the standard at one incidence through every stop, repeated) then
        costs one BRDF evaluation instead of one per frame.
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, _, _ = self._check_args(theta_i, phi_i, 1.0, 1.0)
        binning = self._check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        bad = sorted({k for s in settings for k in s} - {"exposure", "f_number", "rng"})
        if bad:
            raise ValueError(f"settings have unknown keys {bad}; expected exposure, f_number, rng")
        sc0 = None
        out = []
        for s in settings:
            _, _, exposure, f_number = self._check_args(
                theta_i, phi_i, s.get("exposure", 0.01), s.get("f_number", 4.0)
            )
            gen, seed = _rng_and_seed(s.get("rng")) if noise else (None, None)
            if sc0 is None:
                sc0 = self._scene(kind, model, theta_i, phi_i, exposure, band, source_samples,
                                  rays=rays)  # fmt: skip
            sc = sc0 if exposure == sc0.exposure else replace(sc0, exposure=exposure)
            key = _frame_key(kind, theta_i, phi_i, exposure, f_number, seed, 0)
            img, lens = self._shoot(sc, f_number, noise, gen, binning, True, (key, clock_s))
            meta = self.metadata(
                kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise,
                binning, band, source_samples, lens, img, rays,
            )  # fmt: skip
            out.append((img, meta))
        return out

    @staticmethod
    def _check_binning(binning):
        if binning is None or binning is False:
            return None
        if binning is True:
            return WARD_BINNING
        try:
            bw, bh = (int(x) for x in binning)
        except (TypeError, ValueError):
            raise ValueError(
                f"binning must be (width, height), True or None, got {binning!r}"
            ) from None
        if bw < 1 or bh < 1:
            raise ValueError(f"binning must be positive (width, height), got {binning!r}")
        return (bw, bh)

    def metadata(
        self, kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise, binning,
        band, source_samples, lens, img, rays_per_pixel=1,
    ) -> dict[str, Any]:  # fmt: skip
        """The metadata dict of a capture (everything needed to reproduce it).

        ``rays_per_pixel`` is recorded (key ``"rays_per_pixel"``) only when it is not 1.
        """
        meta = self.to_dict()
        meta["full_lens"] = meta["lens"]
        meta["lens"] = lens.to_dict()
        brdf = None
        if model is not None:
            brdf = {"name": model.name, "params": _json_value(model.params)}
            if material:
                brdf["material"] = material
        meta.update(
            {
                "exposure_s": exposure,
                "f_number": f_number,
                "theta_i": theta_i,
                "phi_i": phi_i,
                "sample_rotation": self.source.arm_azimuth - phi_i,
                "sample": kind,
                "brdf": brdf,
                "seed": seed,
                "noise": bool(noise),
                "binning": list(binning) if binning else None,
                "band": band,
                "source_samples": source_samples,
                "shape": list(img.shape),
                "dtype": str(img.dtype),
                "units": "DN",
                "frame": "dome: origin sphere centre, z up, x right (phi 0); camera at (0,-D,0), "
                "sample at (0,D,0); camera frame = dome frame, image u = +x, v = +y",
            }
        )
        if rays_per_pixel != 1:
            meta["rays_per_pixel"] = int(rays_per_pixel)
        return meta

    # ------------------------------------------------------------------ calibration captures
    def capture_dark(
        self,
        *,
        exposure: float = 0.01,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """A shutter-closed dark frame: no light reaches the sensor, only the dark current
        (with its nonuniformity and hot pixels), the offsets and the read noise — the dark
        image a laboratory records for dark subtraction and the sensor's DSNU
        (EMVA 1288 R4.0, dark measurements of Sec. 6-8).

        The side-car has ``calibration = "dark"``, ``shutter = "closed"`` and
        ``photons_per_pixel = 0``.
        """
        return self._calibration_capture("dark", 0.0, exposure, rng, noise, binning)

    def capture_flat(
        self,
        photons_per_pixel: float,
        *,
        exposure: float = 0.01,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
    ) -> tuple[NDArray[np.uint16], dict[str, Any]]:
        """A flat field: the lens removed and the sensor lit by an integrating sphere with
        ``photons_per_pixel`` photons per pixel during the exposure (a uniform irradiance, as
        a calibrated sphere and radiometer give it), the EMVA 1288 set-up for gain, PRNU and
        the photon transfer curve (R4.0 Sec. 6.1, 6.5).

        The side-car has ``calibration = "flat_field"``, ``shutter = "open"`` and
        ``photons_per_pixel`` (what the laboratory's radiometer reports).
        """
        p = _check_positive(photons_per_pixel, "photons_per_pixel")
        return self._calibration_capture("flat_field", p, exposure, rng, noise, binning)

    def _calibration_capture(self, kind, photons, exposure, rng, noise, binning):
        exposure = _check_positive(exposure, "exposure")
        binning = self._check_binning(binning)
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        h, w = self.lens.height, self.lens.width
        dark_e = self._dark() * exposure
        e = dark_e
        if photons > 0.0:
            prnu, _ = self.sensor.maps(h, w)
            e = (self.sensor.qe * photons) * prnu.ravel() + dark_e
        img, lens = self._finish(e, noise, gen, binning, dark_e=dark_e)
        meta = self.to_dict()
        meta["full_lens"] = meta["lens"]
        meta["lens"] = lens.to_dict()
        meta.update(
            {
                "calibration": kind,
                "sample": kind,
                "shutter": "closed" if kind == "dark" else "open",
                "photons_per_pixel": float(photons),
                "exposure_s": exposure,
                "seed": seed,
                "noise": bool(noise),
                "binning": list(binning) if binning else None,
                "shape": list(img.shape),
                "dtype": str(img.dtype),
                "units": "DN",
            }
        )
        return img, meta

    # ------------------------------------------------------------------ bands
    def capture_bands(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        wavelengths_nm: Sequence[float] = (450.0, 550.0, 650.0),
        *,
        exposure: float = 0.01,
        f_number: float = 4.0,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        evaluate_once: bool = True,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """One capture per colour filter (flat source spectrum, equal filter efficiency).

        A spectral BRDF is evaluated at the band nearest each filter (within 5 nm); a grey
        BRDF is evaluated once and reused for every filter (``evaluate_once=False`` forces
        one evaluation per filter, for the benchmark). Noise streams are spawned per filter
        from ``rng``.
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, f_number = self._check_args(theta_i, phi_i, exposure, f_number)
        wl = [float(w) for w in wavelengths_nm]
        if not wl:
            raise ValueError("wavelengths_nm must name at least one filter")
        bands: list[int | None] = [None] * len(wl)
        if model is not None and model.n_bands:
            mw = np.asarray(model.wavelengths_nm)
            for i, w in enumerate(wl):
                j = int(np.argmin(np.abs(mw - w)))
                if abs(mw[j] - w) > 5.0:
                    raise ValueError(
                        f"filter {w} nm has no band of {model.name} within 5 nm "
                        f"(bands {mw.min():g}-{mw.max():g} nm)"
                    )
                bands[i] = j
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        gens = gen.spawn(len(wl)) if noise else [None] * len(wl)
        out = []
        shared = None
        for i, w in enumerate(wl):
            grey = bands[i] is None
            if grey and evaluate_once and shared is not None:
                e = shared.copy()
            else:
                e = self._electrons(kind, model, theta_i, phi_i, exposure, f_number, bands[i], None)
                if grey and evaluate_once:
                    shared = e.copy()
            img, lens = self._finish(e, noise, gens[i], None, dark_e=self._dark() * exposure)
            meta = self.metadata(
                kind, model, material, theta_i, phi_i, exposure, f_number, seed, noise, None,
                bands[i], None, lens, img,
            )  # fmt: skip
            meta["filter_nm"] = w
            meta["filter_index"] = i
            out.append((img, meta))
        return out

    # ------------------------------------------------------------------ bracketing
    def plan_bracket(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_stops: Sequence[float] = F_STOPS,
        min_signal_dn: float = 16.0,
        headroom: float = 0.9,
        skip_stops: bool = True,
    ) -> dict[str, Any]:
        """Choose the f-stops that cover the dynamic range of a sample's image.

        From the noise-free image: the first stop is the widest aperture at which the
        brightest lit pixel stays below ``headroom × saturation``; each wider stop is kept
        only if it brings at least one lit pixel into the usable range (unsaturated and at
        least ``min_signal_dn`` above the background) that no kept stop covered. Stops
        that add no such pixel are skipped. ``skip_stops=False`` switches the skip off
        (benchmark): every stop from the first one on is kept.

        The scene is rendered once at f/1 and every stop evaluated from it (one compiled
        pass over the lit pixels for all stops).

        Returns
        -------
        dict
            ``f_numbers`` (kept, darkest first), ``skipped`` (tried and not kept),
            ``covered_fraction`` of lit pixels, ``peak_saturated`` (even the darkest stop
            saturates the peak), ``n_lit``.
        """
        kind, model, _ = _resolve_sample(sample)
        theta_i, phi_i, exposure, _ = self._check_args(theta_i, phi_i, exposure, 1.0)
        sc = self._scene(kind, model, theta_i, phi_i, exposure, None, None)
        return self._plan(sc, f_stops, min_signal_dn, headroom, skip_stops)

    def _plan(
        self, sc: _Scene, f_stops, min_signal_dn, headroom, skip_stops=True
    ) -> dict[str, Any]:
        """:meth:`plan_bracket` on a rendered scene (electrons at f/1, rendered once)."""
        stops = sorted({_check_positive(f, "f_stops") for f in f_stops}, reverse=True)
        if not stops:
            raise ValueError("f_stops must not be empty")
        sen = self.sensor
        exposure = sc.exposure
        if len(stops) > 62:
            raise ValueError(f"f_stops: at most 62 stops, got {len(stops)}")
        from gonio.simulator import _kernels

        sat_e = headroom * sen.full_well
        min_e = min_signal_dn * sen.gain
        inv_n2 = np.array([1.0 / n**2 for n in stops], dtype=np.float64)
        lead = np.zeros(1, dtype=np.int64)
        # all signal lies on candidate pixels (and the mirror component's pixels)
        if sc.delta is None:
            masks = np.empty(sc.idx.size, dtype=np.int64)
            k = sc.k0 * exposure
            n_lit = _kernels.plan_scene(
                sc.bg, sc.dark, exposure, sc.idx, sc.rc, sc.lit, sc.g, sc.isq, k * sc.kd0,
                k * sc.ks0, inv_n2, sat_e, min_e, masks, lead,
            )  # fmt: skip
        else:
            cp = np.unique(np.concatenate([sc.idx, sc.delta[0]]))
            e1 = self._compose(sc, 1.0)[cp]  # electrons at f/1: sample + background + dark
            dk = self._dark()[cp] * exposure
            sig = e1 - (sc.bg[cp] * exposure + dk)  # signal at f/1 (dark is not scaled by N)
            lit = sig > 0.0
            a, d, sig = e1[lit] - dk[lit], dk[lit], sig[lit]
            n_lit = int(a.size)
            masks = np.empty(max(n_lit, 1), dtype=np.int64)
            _kernels.plan_masks(a, d, sig, inv_n2, sat_e, min_e, masks, lead)
        masks = masks[:n_lit]
        # distinct usability patterns and how many lit pixels have each
        if len(stops) <= 16:
            cnt = np.bincount(masks, minlength=1)
            pats = np.flatnonzero(cnt)
            cnt = cnt[pats]
        else:
            pats, cnt = np.unique(masks, return_counts=True)
        pats = [int(x) for x in pats]
        cnt = [int(x) for x in cnt]
        # the widest stop before the first that saturates a lit pixel
        first = int(lead[0]) - 1 if lead[0] > 0 else None
        peak_saturated = first is None
        start = 0 if first is None else first
        kept: list[float] = []
        skipped: list[float] = []
        kbits = 0  # bits of the kept stops: a pixel is covered when pattern & kbits != 0
        for i in range(start, len(stops)):
            bit = 1 << i
            new = any(p & bit and not p & kbits for p in pats)
            if new or not kept or not skip_stops:
                kept.append(stops[i])
                kbits |= bit
            else:
                skipped.append(stops[i])
            if skip_stops and n_lit and all(p & kbits for p in pats):
                break
        covered = sum(c for p, c in zip(pats, cnt) if p & kbits)
        return {
            "f_numbers": kept,
            "skipped": skipped,
            "covered_fraction": covered / n_lit if n_lit else 1.0,
            "peak_saturated": peak_saturated,
            "n_lit": n_lit,
            "exposure_s": exposure,
        }

    def bracket(
        self,
        sample: Any,
        theta_i: float,
        phi_i: float = 0.0,
        *,
        exposure: float = 0.01,
        f_stops: Sequence[float] = F_STOPS,
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
        binning: tuple[int, int] | bool | None = None,
        rays_per_pixel: int = 1,
        clock_s: float | None = None,
        **plan_kw: Any,
    ) -> list[tuple[NDArray[np.uint16], dict[str, Any]]]:
        """Capture the f-stops :meth:`plan_bracket` chooses; each metadata has ``bracket``.

        The noise-free scene is rendered once (at f/1); the plan and every stop are
        composed from it (signal and background scale with 1/N², dark current does not),
        so with noise off each frame equals ``capture(..., f_number=N)`` bit for bit.
        Noise streams are spawned per stop from ``rng``. ``plan_kw``: ``min_signal_dn``,
        ``headroom``, ``skip_stops`` (see :meth:`plan_bracket`). ``clock_s``: the campaign
        time of the bracket (lamp effects; default :attr:`clock_s`).
        """
        kind, model, material = _resolve_sample(sample)
        theta_i, phi_i, exposure, _ = self._check_args(theta_i, phi_i, exposure, 1.0)
        binning = self._check_binning(binning)
        rays = _check_rays(rays_per_pixel)
        unknown = set(plan_kw) - {"min_signal_dn", "headroom", "skip_stops"}
        if unknown:
            raise ValueError(
                f"bracket got unexpected arguments {sorted(unknown)}; plan options are "
                "min_signal_dn, headroom, skip_stops"
            )
        sc = self._scene(kind, model, theta_i, phi_i, exposure, None, None, rays=rays)
        plan = self._plan(
            sc, f_stops, plan_kw.get("min_signal_dn", 16.0), plan_kw.get("headroom", 0.9),
            plan_kw.get("skip_stops", True),
        )  # fmt: skip
        nf = len(plan["f_numbers"])
        gen, seed = _rng_and_seed(rng) if noise else (None, None)
        gens = gen.spawn(nf) if noise else [None] * nf
        out = []
        for i, n in enumerate(plan["f_numbers"]):
            n = self._check_args(theta_i, phi_i, exposure, n)[3]
            key = _frame_key(kind, theta_i, phi_i, exposure, n, seed, i)
            img, lens = self._shoot(sc, n, noise, gens[i], binning, frame=(key, clock_s))
            meta = self.metadata(
                kind, model, material, theta_i, phi_i, exposure, n, seed, noise, binning,
                None, None, lens, img, rays,
            )  # fmt: skip
            meta["bracket"] = {"index": i, **plan}
            out.append((img, meta))
        return out

    # ------------------------------------------------------------------ fake-device hook
    def camera_render(
        self,
        sample: Any,
        *,
        source_axis: str = "source",
        sample_axis: str = "sample",
        rng: int | np.random.Generator | None = None,
        noise: bool = True,
    ) -> Callable[[dict[str, float], float, float], tuple[NDArray[np.uint16], dict[str, Any]]]:
        """A ``camera_render(positions, exposure_s, f_number)`` callable for a simulated bench.

        ``positions`` maps stage names to degrees: ``positions[source_axis]`` is θ_i (source
        arm) and ``positions[sample_axis]`` the sample-holder rotation ψ, so that
        ``φ_i = arm_azimuth - ψ``; a negative arm angle means the arm swung through the
        zenith (``θ_i = |θ|``, ``φ_i + π``). Successive calls draw fresh noise from one generator.
        """
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

        def render(positions: dict[str, float], exposure_s: float, f_number: float):
            try:
                th = math.radians(float(positions[source_axis]))
                rot = math.radians(float(positions.get(sample_axis, 0.0)))
            except KeyError:
                raise ValueError(
                    f"positions {positions!r} lack the source axis {source_axis!r}"
                ) from None
            phi = self.source.arm_azimuth - rot
            if th < 0.0:  # the arm swung through the zenith: same as +|θ| on the far side
                th, phi = -th, phi + math.pi
            phi = math.pi - (math.pi - phi) % (2 * math.pi)  # in (-π, π]
            return self.capture(
                sample, th, phi, exposure=exposure_s, f_number=f_number, rng=gen, noise=noise
            )

        return render


# ---------------------------------------------------------------------------- module level
_DEFAULT: dict[str, LBLInstrument] = {}


def default_instrument() -> LBLInstrument:
    """The shared default instrument (ellipsoid, 640 × 480 equidistant fisheye)."""
    if "lbl" not in _DEFAULT:
        _DEFAULT["lbl"] = LBLInstrument()
    return _DEFAULT["lbl"]


def capture(
    sample: Any,
    theta_i: float,
    phi_i: float = 0.0,
    *,
    instrument: LBLInstrument | None = None,
    **kwargs: Any,
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """:meth:`LBLInstrument.capture` on ``instrument`` (default: :func:`default_instrument`)."""
    inst = instrument if instrument is not None else default_instrument()
    return inst.capture(sample, theta_i, phi_i, **kwargs)


def reproduce(
    meta: dict[str, Any], sample: Any = None
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Capture again from a capture's metadata (the BRDF is rebuilt from ``meta["brdf"]``
    unless ``sample`` is given; a plain callable cannot be rebuilt and must be passed)."""
    inst = LBLInstrument.from_metadata(meta)
    if meta.get("calibration") in ("dark", "flat_field"):
        if meta.get("seed") is None and meta.get("noise"):
            raise ValueError("the capture used a caller's Generator; its seed was not recorded")
        kw = {
            "exposure": meta["exposure_s"],
            "rng": meta.get("seed"),
            "noise": meta["noise"],
            "binning": tuple(meta["binning"]) if meta.get("binning") else None,
        }
        if meta["calibration"] == "dark":
            return inst.capture_dark(**kw)
        return inst.capture_flat(meta["photons_per_pixel"], **kw)
    if sample is None:
        if meta["sample"] == "standard":
            sample = STANDARD
        elif meta["sample"] == "brdf":
            from gonio import brdf

            b = meta["brdf"]
            if b["name"] in ("callable", "sum") or any(
                isinstance(v, dict) and "sha256" in v for v in b["params"].values()
            ):
                raise ValueError(
                    f"the capture imaged a {b['name']!r} BRDF that metadata cannot rebuild "
                    "(a callable, a sum or a large table); pass it as sample"
                )
            sample = brdf.create(b["name"], **b["params"])
    if meta.get("seed") is None and meta.get("noise"):
        raise ValueError("the capture used a caller's Generator; its seed was not recorded")
    return inst.capture(
        sample,
        meta["theta_i"],
        meta["phi_i"],
        exposure=meta["exposure_s"],
        f_number=meta["f_number"],
        rng=meta.get("seed"),
        noise=meta["noise"],
        binning=tuple(meta["binning"]) if meta.get("binning") else None,
        band=meta.get("band"),
        source_samples=meta.get("source_samples"),
        rays_per_pixel=meta.get("rays_per_pixel", 1),
    )
