"""Side-car consistency rules of a reduction: what the three captures' files must agree on.

Eq. 2 of the reduction (Ward 1992, §3.2) divides the sample's signal by the standard's after
subtracting the background's; it is only the BRDF if the three captures were taken at the same
incidence, by the same camera, and their side-cars describe the images they sit beside. A
mismatch does not raise anywhere downstream: it gives plausible-looking, wrong numbers (a
standard at θi 20° for a 40° image scales every value by cos 40°/cos 20° = 0.815; an 8-bit
image read with a 12-bit side-car gives 99 % negative values). :func:`check_captures` states
the rules once, before any arithmetic, and names the file and the field that break one.

Rules (every frame of the measured, standard and background captures):

* **ADC range and dtype**: the image's integer dtype holds the side-car's ADC range
  (``2**adc_bits - 1``, or ``max_dn``); no pixel exceeds that code; every frame of the three
  captures comes from one camera (the same ``adc_bits`` and dtype).
* **Signal**: some pixel is above the side-car's black level (an all-zero frame is no reading).
* **Exposure and f-number**: every side-car records its exposure time and f-number (the
  exposure scale ``t/N²`` of each frame enters eq. 2; a missing f-number is not 1).
* **Incidence**: the standard's and the background's ``theta_i`` (the source arm's angle)
  equals the measurement's (to :data:`ANGLE_TOLERANCE_RAD`). ``phi_i`` is the sample's own
  rotation (one standard serves every rotation of the sample), so it is not compared.
* **Typed side-cars**: every field the reduction reads has a type and a range
  (:data:`gonio.io.images.SIDECAR_SCHEMA`: a boolean is not a number, ``response`` names a
  known response model).
* **Distinct frames**: no frame is given twice in a bracket (the same file, or the same
  exposure and stop with the same pixels): it would count one reading twice and shrink σ.
* **Distinct captures**: no standard or background frame is pixel-for-pixel a measured frame
  (two real exposures never agree in every pixel), and a side-car's ``sample`` label, where it
  has one, names the capture's role (``"standard"`` / ``"none"`` for the background).

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. *Computer Graphics
(SIGGRAPH '92 Proceedings)* 26(2), 265-272. doi:10.1145/142920.134078, §3.2 (eq. 2).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from gonio.calibration.radiometry import _meta_get
from numpy.typing import NDArray

__all__ = ["ANGLE_TOLERANCE_RAD", "check_captures", "check_frame", "sidecar_angle"]

#: Largest accepted difference of the incidence angles of the three captures (rad); a
#: goniometer's encoders are read to ~1e-5 rad, side-cars store float64 radians.
ANGLE_TOLERANCE_RAD = 1e-6

#: A capture's role -> the side-car ``sample`` labels a frame of that role may carry.
_ROLE_LABELS: dict[str, tuple[str, ...] | None] = {
    "standard": ("standard",),
    "background": ("none", "background"),
}


def _number(v: Any, cast: Callable[[Any], Any], key: str, src: str, what: str = "a number") -> Any:
    """``cast(v)`` of the side-car field ``key``; ``ValueError`` naming ``src`` and the field."""
    try:
        return cast(v)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{src}: side-car field {key!r} must be {what}, got {v!r}") from None


def _field(meta: Mapping[str, Any], keys: tuple[str, ...], src: str, what: str) -> float:
    v = _meta_get(meta, keys)
    if v is None:
        raise ValueError(f"{src}: side-car field {keys[0]!r} ({what}) is missing")
    f = _number(v, float, keys[0], src)
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"{src}: side-car field {keys[0]!r} must be finite and > 0, got {v!r}")
    return f


def _adc_max(meta: Mapping[str, Any], src: str) -> int:
    top = _meta_get(meta, ("max_dn",))
    if top is None:
        bits = _meta_get(meta, ("adc_bits", "bit_depth"), 16)
        b = _number(bits, int, "adc_bits", src, "an integer")
        if not 1 <= b <= 32 or b != bits:
            raise ValueError(f"{src}: side-car field 'adc_bits' = {bits!r} is not in [1, 32]")
        return 2**b - 1
    t = _number(top, int, "max_dn", src, "an integer")
    if t < 1 or t != top:
        raise ValueError(f"{src}: side-car field 'max_dn' must be an integer >= 1, got {top!r}")
    return t


def check_frame(image: NDArray, meta: Mapping[str, Any], src: str) -> dict[str, Any]:
    """Check one raw frame against its side-car; return the camera fields the triple shares.

    Raises
    ------
    ValueError
        Naming ``src`` (the file) and the side-car field a rule fails on (module docstring).
    """
    from gonio.io.images import check_sidecar

    check_sidecar(meta, src)
    img = np.asarray(image)
    if img.dtype.kind not in "ui":
        raise ValueError(f"{src}: raw image must hold integer DN, got dtype {img.dtype}")
    if img.size == 0:
        raise ValueError(f"{src}: raw image is empty (shape {img.shape})")
    top = _adc_max(meta, src)
    hold = int(np.iinfo(img.dtype).max)
    if top > hold:
        raise ValueError(
            f"{src}: the side-car's ADC range (max_dn {top}) does not fit the image's dtype "
            f"{img.dtype} (max {hold}): the image is not the camera's raw output"
        )
    hi = int(img.max())
    if hi > top:
        n = int(np.count_nonzero(img > top))
        raise ValueError(
            f"{src}: {n} pixel(s) up to {hi} DN exceed the side-car's ADC range "
            f"(max_dn {top}, adc_bits {_meta_get(meta, ('adc_bits', 'bit_depth'))})"
        )
    black = _meta_get(meta, ("black_level_dn", "black_level_adu", "black_level", "bias_adu"), 0.0)
    black = _number(black, float, "black_level_dn", src)
    if hi <= black and hi == int(img.min()):
        raise ValueError(
            f"{src}: every pixel is {hi} DN, not above the side-car's black level "
            f"(black_level_dn {black:g}): the frame holds no reading"
        )
    _field(meta, ("exposure_s", "exposure_time_s", "exposure_time", "exposure"), src, "seconds")
    _field(meta, ("f_number", "fnumber"), src, "the lens stop; the exposure scale is t/N²")
    return {"max_dn": top, "dtype": img.dtype.name}


def sidecar_angle(
    meta: Mapping[str, Any], key: str, src: str, default: float | None = None
) -> float:
    """The side-car angle ``key`` (radians) as a finite float; ``ValueError`` naming ``src``."""
    v = meta.get(key, default)
    if v is None:
        raise ValueError(f"{src}: side-car field {key!r} (radians) is missing")
    f = _number(v, float, key, src, "a number (radians)")
    if not math.isfinite(f):
        raise ValueError(f"{src}: side-car field {key!r} must be finite, got {v!r}")
    return f


def check_captures(captures: Mapping[str, Any]) -> None:
    """Check the measured, standard and background captures of one reduction together.

    Parameters
    ----------
    captures : mapping
        ``{"measured": Capture, "standard": Capture, "background": Capture}``; each
        :class:`~gonio.calibration.reduce.Capture` names its frames' files in ``sources``.

    Raises
    ------
    ValueError
        The first rule of the module docstring that a frame breaks, naming the file and the
        side-car field.
    """
    ref_meta = captures["measured"].meta
    ref_src = _sources(captures["measured"], "measured")[0]
    theta = sidecar_angle(ref_meta, "theta_i", ref_src, None)
    camera: tuple[str, dict[str, Any]] | None = None
    measured = [np.asarray(a) for a in captures["measured"].images]
    for role, cap in captures.items():
        _check_distinct_frames(cap, role)
        for img, meta, src in zip(cap.images, cap.metas, _sources(cap, role)):
            cam = check_frame(img, meta, src)
            if camera is None:
                camera = (src, cam)
            for k, v in cam.items():
                if v != camera[1][k]:
                    raise ValueError(
                        f"{src}: {k} {v} differs from {camera[0]}'s {camera[1][k]}: the three "
                        "captures of a reduction must come from one camera"
                    )
            if role == "measured":
                continue
            a = sidecar_angle(meta, "theta_i", src)
            if abs(a - theta) > ANGLE_TOLERANCE_RAD:
                raise ValueError(
                    f"{src}: side-car field 'theta_i' = {math.degrees(a):.6g} deg differs from "
                    f"the measurement's {math.degrees(theta):.6g} deg ({ref_src}): the {role} "
                    "must be taken at the measurement's incidence"
                )
            _check_role(role, meta, src)
            a = np.asarray(img)
            for m, m_src in zip(measured, _sources(captures["measured"], "measured")):
                if m.shape == a.shape and np.array_equal(m, a):
                    raise ValueError(
                        f"{src}: the {role} frame is pixel-for-pixel the measured frame "
                        f"{m_src}: pass the {role}'s own capture"
                    )


def _check_distinct_frames(cap: Any, role: str) -> None:
    """Refuse a frame given twice in one bracket: the same file, or the same exposure and
    stop with pixel-for-pixel the same image (two real exposures never agree in every pixel)."""
    import os

    srcs = _sources(cap, role)
    seen: dict[tuple[str, str], list[int]] = {}
    for k, (img, meta) in enumerate(cap.frames):
        for j in range(k):
            a, b = srcs[j], srcs[k]
            try:
                same = os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)
            except OSError:
                same = False
            if same:
                raise ValueError(f"{b}: the {role} bracket holds this file twice ({a})")
        stop = (repr(_meta_get(meta, ("exposure_s", "exposure_time_s", "exposure_time"))),
                repr(_meta_get(meta, ("f_number", "fnumber"))))  # fmt: skip
        for j in seen.get(stop, []):
            other = cap.frames[j][0]
            if other.shape == img.shape and np.array_equal(other, img):
                raise ValueError(
                    f"{srcs[k]}: the {role} bracket holds the same frame twice ({srcs[j]}: same "
                    "exposure, stop and pixels); it would count one reading twice"
                )
        seen.setdefault(stop, []).append(k)


def _check_role(role: str, meta: Mapping[str, Any], src: str) -> None:
    labels = _ROLE_LABELS.get(role)
    label = meta.get("sample")
    if labels is None or label is None:
        return
    if str(label) not in labels:
        raise ValueError(
            f"{src}: side-car field 'sample' = {label!r}, but this frame is passed as the "
            f"{role} (expected {' or '.join(map(repr, labels))})"
        )


def _sources(capture: Any, role: str) -> Sequence[str]:
    src = getattr(capture, "sources", None)
    n = len(capture.frames)
    return list(src) if src else [f"{role} frame {k}" for k in range(n)]
