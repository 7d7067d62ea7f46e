"""Mirror geometry calibration: D/R and a small camera tilt from specular peaks.

A mirror-like sample illuminated at several known incidences reflects the beam into the
specular direction ``reflect(wi)``; the image point where that peak lands depends on the dome
geometry. :func:`fit_geometry` finds ``D`` (and the camera tilt) by least squares on the angle
between the exactly traced reflection direction at each observed peak pixel
(:func:`gonio.calibration.angles.trace`) and the known specular direction.

Angles alone fix only ``D/R`` (the whole dome can be scaled), so ``R`` is taken as known (a
ruler measurement) and ``D`` is reported in its units.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3.2, eq. 3 and Figure 3 (the geometry being calibrated).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gonio.calibration.angles import MirrorGeometry, to_sample_frame, trace
from numpy.typing import ArrayLike, NDArray

__all__ = ["fit_geometry", "peak_location"]


def peak_location(image: ArrayLike, *, window: int = 3) -> NDArray[np.float64]:
    """Sub-pixel ``(u, v)`` of the brightest spot: value-weighted centroid around the maximum."""
    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2 or not np.isfinite(a).all():
        raise ValueError(f"image must be a finite 2-D array, got shape {a.shape}")
    v0, u0 = np.unravel_index(int(np.argmax(a)), a.shape)
    sl = (slice(max(v0 - window, 0), v0 + window + 1), slice(max(u0 - window, 0), u0 + window + 1))
    w = a[sl] - np.min(a[sl])
    vv, uu = np.mgrid[sl]
    s = w.sum()
    if s <= 0:
        return np.array([float(u0), float(v0)])
    return np.array([(w * uu).sum() / s, (w * vv).sum() / s])


def fit_geometry(
    peaks_uv: ArrayLike,
    wi: ArrayLike,
    rotations: Sequence[float] | ArrayLike,
    lens: Any,
    nominal: MirrorGeometry,
    *,
    fit_tilt: bool = True,
) -> tuple[MirrorGeometry, dict[str, Any]]:
    """Least-squares dome geometry from observed specular peaks.

    Parameters
    ----------
    peaks_uv : array_like (K, 2)
        Peak pixel coordinates (:func:`peak_location`).
    wi : array_like (K, 3)
        Incident directions in the sample frame.
    rotations : array_like (K,)
        Sample rotations (radians) of the captures.
    lens : FisheyeLens
        The (calibrated) lens.
    nominal : MirrorGeometry
        Kind and radius (held fixed) and the starting ``D``.
    fit_tilt : bool
        Also fit the camera tilt (two small angles).

    Returns
    -------
    geometry : MirrorGeometry
    info : dict
        ``rms_rad`` of the angular residuals, ``n_peaks``, ``success``.
    """
    from scipy.optimize import least_squares

    uv = np.asarray(peaks_uv, dtype=np.float64).reshape(-1, 2)
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    rot = np.asarray(rotations, dtype=np.float64).ravel()
    if not (uv.shape[0] == wi.shape[0] == rot.shape[0]):
        raise ValueError("peaks_uv, wi and rotations must have the same length")
    need = 3 if fit_tilt else 1
    if uv.shape[0] < need:
        raise ValueError(f"need at least {need} peaks, got {uv.shape[0]}")
    cam = lens.unproject(uv)
    spec = wi * np.array([-1.0, -1.0, 1.0])  # mirror direction about the normal
    R = nominal.radius

    def geom(p: NDArray) -> MirrorGeometry:
        d = float(np.clip(p[0], 0.0, 0.99)) * R
        tilt = (p[1], p[2]) if fit_tilt else (0.0, 0.0)
        return nominal.with_(half_separation=d, tilt=tilt)

    def resid(p: NDArray) -> NDArray:
        wo, _, _ = trace(cam, geom(p))
        ws = np.stack([to_sample_frame(wo[k], rot[k]) for k in range(len(rot))])
        return (ws - spec).ravel()

    p0 = np.array([nominal.d_over_r, *nominal.tilt]) if fit_tilt else np.array([nominal.d_over_r])
    res = least_squares(resid, p0, x_scale=0.01)
    g = geom(res.x)
    r = resid(res.x).reshape(-1, 3)
    return g, {
        "rms_rad": float(np.sqrt(np.mean(np.sum(r * r, axis=1)))),
        "n_peaks": int(uv.shape[0]),
        "success": bool(res.success),
        "d_over_r": g.d_over_r,
        "tilt": list(g.tilt),
    }
