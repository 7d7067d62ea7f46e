"""Configuration and metadata of the LBL instrument: the arguments a capture is asked with,
checked, and the side-car it writes.

This part knows names and numbers — a sample's name or model, the angles, exposure,
f-number, binning and seed of a capture, the instrument's description
(:meth:`~gonio.simulator.lbl.LBLInstrument.to_dict`) — and no physics.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from gonio.simulator.lenses import LENS_MODELS, FisheyeLens, make_lens
from gonio.simulator.lenses import _pos_finite as _check_positive
from gonio.simulator.optics import MIRRORS, Mirror

from gonio.brdf.base import BRDF, as_brdf

__all__ = ["STANDARD", "WARD_BINNING", "Request"]

#: the ``sample`` value that images the diffuse reflectance standard
STANDARD = "standard"
#: Ward's reduced image size (width, height)
WARD_BINNING = (108, 80)
#: the dome frame, as a capture's side-car states it
FRAME = (
    "dome: origin sphere centre, z up, x right (phi 0); camera at (0,-D,0), "
    "sample at (0,D,0); camera frame = dome frame, image u = +x, v = +y"
)


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


def make_mirror(
    mirror: str | Mirror, radius, half_separation, reflectance, transmittance
) -> Mirror:
    """The dome: ``mirror`` itself, or the named shape built from the other arguments."""
    if isinstance(mirror, Mirror):
        return mirror
    if mirror not in MIRRORS:
        raise ValueError(f"mirror {mirror!r} is unknown; expected one of {', '.join(MIRRORS)}")
    return Mirror(mirror, radius, half_separation, reflectance, transmittance)


def make_camera_lens(lens: str | FisheyeLens, width: int, height: int) -> FisheyeLens:
    """The lens: ``lens`` itself, or the named model for a ``width × height`` sensor."""
    if isinstance(lens, FisheyeLens):
        return lens
    if isinstance(lens, str):
        if lens not in LENS_MODELS:
            raise ValueError(f"lens {lens!r} is unknown; expected one of {', '.join(LENS_MODELS)}")
        return make_lens(lens, width, height)
    raise ValueError(f"lens must be a model name or a FisheyeLens, got {lens!r}")


def check_args(theta_i, phi_i, exposure, f_number) -> tuple[float, float, float, float]:
    """A capture's incidence, exposure and f-number, checked."""
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


def check_binning(binning) -> tuple[int, int] | None:
    """``binning`` as (width, height) or None (``True``: Ward's 108 × 80)."""
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


def capture_metadata(
    instrument: dict[str, Any], arm_azimuth: float, kind, model, material, theta_i, phi_i,
    exposure, f_number, seed, noise, binning, band, source_samples, lens, img,
    rays_per_pixel=1,
) -> dict[str, Any]:  # fmt: skip
    """The side-car of a capture by the instrument ``instrument`` describes (everything
    needed to reproduce it); ``rays_per_pixel`` is recorded only when it is not 1."""
    meta = _with_lens(instrument, lens)
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
            "sample_rotation": arm_azimuth - phi_i,
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
            "frame": FRAME,
        }
    )
    if rays_per_pixel != 1:
        meta["rays_per_pixel"] = int(rays_per_pixel)
    return meta


def calibration_metadata(
    instrument: dict[str, Any], kind, photons, exposure, seed, noise, binning, lens, img
) -> dict[str, Any]:
    """The side-car of a calibration capture (``kind``: "dark" or "flat_field")."""
    meta = _with_lens(instrument, lens)
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
    return meta


def _with_lens(instrument: dict[str, Any], lens: FisheyeLens) -> dict[str, Any]:
    """The instrument's description with the lens of the image (binned or not) as
    ``lens`` and the instrument's own as ``full_lens``."""
    meta = dict(instrument)
    meta["full_lens"] = meta["lens"]
    meta["lens"] = lens.to_dict()
    return meta


def effect_magnitudes(
    effects: Mapping[str, float] | None, seed: Any
) -> tuple[int, dict[str, float], dict[str, float]]:
    """``(instrument seed, every effect's magnitude, the non-zero ones)``, checked."""
    from gonio.simulator.effects import EFFECTS, check_magnitudes

    if not isinstance(seed, int | np.integer) or int(seed) < 0:
        raise ValueError(f"instrument_seed must be a non-negative integer, got {seed!r}")
    fx: dict[str, float] = {}
    if effects is not None:
        check_magnitudes(effects)
        fx = {k: float(v) for k, v in effects.items() if float(v) != 0.0}
    return int(seed), {name: fx.get(name, 0.0) for name in EFFECTS}, fx


@dataclass(frozen=True)
class Request:
    """What a capture was asked, checked: the sample (its kind, model and material name),
    the incidence, and how its frames are read out and described."""

    kind: str
    model: BRDF | None
    material: str | None
    theta_i: float
    phi_i: float
    noise: bool
    binning: tuple[int, int] | None
    band: int | None
    source_samples: int | None
    rays: int


def bench_incidence(
    positions: Mapping[str, float], source_axis: str, sample_axis: str, arm_azimuth: float
) -> tuple[float, float]:
    """``(θ_i, φ_i)`` of a simulated bench's stage ``positions`` (degrees):
    ``positions[source_axis]`` is θ_i (source arm) and ``positions[sample_axis]`` the
    sample-holder rotation ψ, so that ``φ_i = arm_azimuth - ψ``; a negative arm angle means
    the arm swung through the zenith (``θ_i = |θ|``, ``φ_i + π``); φ_i in (-π, π]."""
    try:
        th = math.radians(float(positions[source_axis]))
        rot = math.radians(float(positions.get(sample_axis, 0.0)))
    except KeyError:
        raise ValueError(f"positions {positions!r} lack the source axis {source_axis!r}") from None
    phi = arm_azimuth - rot
    if th < 0.0:  # the arm swung through the zenith: same as +|θ| on the far side
        th, phi = -th, phi + math.pi
    phi = math.pi - (math.pi - phi) % (2 * math.pi)  # in (-π, π]
    return th, phi


def filter_bands(model: BRDF | None, wl: list[float]) -> list[int | None]:
    """The band of a spectral ``model`` nearest each colour filter's wavelength ``wl``
    (within 5 nm), or None for each filter when the model is grey (or no sample)."""
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
    return bands


def check_sample(sample_radius, rho_standard, mirror: Mirror) -> tuple[float, float]:
    """The sample's radius (smaller than the dome's ``2D``, so it does not overlap the
    lens) and the diffuse standard's reflectance (in (0, 1]), checked."""
    sr = _check_positive(sample_radius, "sample_radius")
    if sr >= 2.0 * mirror.half_separation:
        raise ValueError(
            f"sample_radius = {sample_radius!r} must be smaller than 2D = "
            f"{2.0 * mirror.half_separation!r} (the sample would overlap the lens)"
        )
    rs = _check_positive(rho_standard, "rho_standard")
    if rs > 1.0:
        raise ValueError(f"rho_standard must be in (0, 1], got {rho_standard!r}")
    return sr, rs
