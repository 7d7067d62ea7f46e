"""Fisheye lens models: direction → pixel (forward) and pixel → direction (inverse).

Camera frame: right-handed, ``z`` along the optical axis (forward), ``x`` towards increasing
pixel column ``u`` and ``y`` towards increasing pixel row ``v`` (OpenCV's convention). In the
LBL dome the camera looks up the dome axis, so the camera frame coincides with the dome frame
(``x`` = "right", Ward's φ_c = 0). Pixel centres sit at integer coordinates (OpenCV), so the
centre of a ``W × H`` image is ``((W - 1)/2, (H - 1)/2)``.

All models share the form::

    r = g(θ),  u = fx (r cos ψ + skew · r sin ψ) + cx,  v = fy r sin ψ + cy

where θ is the angle from the optical axis, ψ = atan2(y, x) the azimuth and ``g`` the radial
mapping (focal length 1):

==================  ====================================================
``equidistant``     g = θ
``equisolid``       g = 2 sin(θ/2)
``stereographic``   g = 2 tan(θ/2)
``orthographic``    g = sin θ          (θ ≤ 90°)
``kannala_brandt``  g = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)  (OpenCV ``cv2.fisheye``)
==================  ====================================================

For ``kannala_brandt`` the forward projection is exactly ``cv2.fisheye.projectPoints`` with
``K = [[fx, skew·fx, cx], [0, fy, cy], [0, 0, 1]]`` and ``D = (k1, k2, k3, k4)`` (OpenCV writes
θ = atan(r) for points in front of the camera, which equals the angle used here), and the
inverse solves ``g(θ) = r`` by safeguarded Newton iteration.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3: "The first step is to determine the mapping from image point
locations to the lens incident direction. This is a function of the particular fisheye lens
used" — the paper leaves the lens model open; these are the standard fisheye projections and
the Kannala-Brandt model (J. Kannala, S. Brandt, IEEE PAMI 28(8), 2006) that OpenCV implements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import check_scalar

#: arrays of at least this many radii are inverted by the compiled Kannala-Brandt inverse
#: (:mod:`gonio.simulator._lens_kernels`, the same result bit for bit); smaller ones by
#: numpy, which needs no compiled code loaded
_COMPILED_MIN = 4096

__all__ = ["LENS_MODELS", "FisheyeLens", "make_lens"]

#: valid values of :attr:`FisheyeLens.model`
LENS_MODELS: tuple[str, ...] = (
    "equidistant",
    "equisolid",
    "stereographic",
    "orthographic",
    "kannala_brandt",
)


def _check_model(model: Any) -> str:
    if model not in LENS_MODELS:
        raise ValueError(
            f"lens model {model!r} is unknown; expected one of {', '.join(LENS_MODELS)}"
        )
    return model


def _pos_finite(value: Any, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


@dataclass(frozen=True)
class FisheyeLens:
    """A fisheye lens + camera intrinsics.

    Parameters
    ----------
    model : str
        One of :data:`LENS_MODELS`.
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point in pixels (pixel centres at integers).
    k : tuple of 4 floats
        Kannala-Brandt distortion ``k1..k4`` (must be zeros for the other models).
    skew : float
        OpenCV's fisheye ``alpha`` (skew coefficient); 0 for most lenses.
    width, height : int
        Image size in pixels (used by :meth:`pixel_grid` and for metadata).
    theta_max : float
        Largest field angle the lens images (radians, ≤ π/2 for ``orthographic``); pixels
        beyond it are outside the image circle.

    Examples
    --------
    >>> lens = make_lens("equidistant", 640, 480)
    >>> uv = lens.project([0.0, 0.0, 1.0])
    >>> [float(x) for x in uv]
    [319.5, 239.5]
    """

    model: str
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    skew: float = 0.0
    theta_max: float = math.pi / 2

    def __post_init__(self) -> None:
        _check_model(self.model)
        for name in ("fx", "fy"):
            object.__setattr__(self, name, _pos_finite(getattr(self, name), name))
        for name in ("cx", "cy", "skew"):
            object.__setattr__(self, name, check_scalar(getattr(self, name), name))
        for name in ("width", "height"):
            v = getattr(self, name)
            if not (isinstance(v, int | np.integer) and int(v) > 0):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        k = tuple(float(x) for x in np.asarray(self.k, dtype=np.float64).ravel())
        if len(k) != 4 or not all(math.isfinite(x) for x in k):
            raise ValueError(f"k must be 4 finite numbers (k1..k4), got {self.k!r}")
        if self.model != "kannala_brandt" and any(k):
            raise ValueError(f"k must be zeros for the {self.model!r} model, got {k}")
        object.__setattr__(self, "k", k)
        tm = _pos_finite(self.theta_max, "theta_max")
        limit = math.pi / 2 if self.model == "orthographic" else math.pi - 1e-6
        if self.model == "stereographic":
            limit = math.pi - 1e-3
        if tm > limit + 1e-15:
            raise ValueError(
                f"theta_max = {tm!r} exceeds what the {self.model!r} model can image"
                f" (≤ {limit:.6g})"
            )
        if self.model == "kannala_brandt":
            # g must be increasing on [0, theta_max] for the inverse to exist
            t = np.linspace(0.0, tm, 2049)
            if np.any(np.diff(self._g(t)) <= 0.0):
                raise ValueError(
                    f"k = {k} makes the Kannala-Brandt mapping non-monotonic below "
                    f"theta_max = {tm:.6g} rad; expected an increasing θ_d(θ)"
                )
        object.__setattr__(self, "theta_max", tm)

    # ------------------------------------------------------------------ radial map
    def _g(self, t: NDArray) -> NDArray:
        m = self.model
        if m == "equidistant":
            return t.copy()
        if m == "equisolid":
            return 2.0 * np.sin(0.5 * t)
        if m == "stereographic":
            return 2.0 * np.tan(0.5 * t)
        if m == "orthographic":
            return np.sin(t)
        k1, k2, k3, k4 = self.k
        t2 = t * t
        return t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _dg(self, t: NDArray) -> NDArray:
        k1, k2, k3, k4 = self.k
        t2 = t * t
        return 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))

    def _g_inv(self, r: NDArray) -> NDArray:
        m = self.model
        if m == "equidistant":
            return r.copy()
        if m == "equisolid":
            return 2.0 * np.arcsin(np.clip(0.5 * r, 0.0, 1.0))
        if m == "stereographic":
            return 2.0 * np.arctan(0.5 * r)
        if m == "orthographic":
            return np.arcsin(np.clip(r, 0.0, 1.0))
        # Kannala-Brandt: safeguarded Newton on g(t) = r, t in [0, theta_max * 1.5]
        hi_t = min(self.theta_max * 1.5, math.pi)
        r = np.asarray(r, dtype=np.float64)
        if r.size >= _COMPILED_MIN:  # the same iteration compiled, bit for bit
            from gonio.simulator._lens_kernels import kb_inverse

            out = np.empty(r.size)
            kb_inverse(np.ascontiguousarray(r).ravel(), *map(float, self.k), hi_t, out)
            return out.reshape(r.shape)
        return self._g_inv_numpy(r, hi_t)

    def _g_inv_numpy(self, r: NDArray, hi_t: float) -> NDArray:
        """The Kannala-Brandt inverse in numpy (the reference of
        :func:`gonio.simulator._lens_kernels.kb_inverse`)."""
        t = np.clip(r, 0.0, hi_t)
        lo = np.zeros_like(r)
        hi = np.full_like(r, hi_t)
        for _ in range(60):
            f = self._g(t) - r
            lo = np.where(f < 0.0, t, lo)
            hi = np.where(f > 0.0, t, hi)
            d = self._dg(t)
            step = np.where(d > 0.0, f / np.where(d > 0.0, d, 1.0), 0.0)
            tn = t - step
            bad = (tn <= lo) | (tn >= hi) | (d <= 0.0)
            tn = np.where(bad, 0.5 * (lo + hi), tn)
            if np.all(np.abs(tn - t) <= 1e-15 * np.maximum(1.0, np.abs(t))):
                t = tn
                break
            t = tn
        return t

    @property
    def r_max(self) -> float:
        """Normalised radius of the image circle (``g(theta_max)``)."""
        return float(self._g(np.array(self.theta_max)))

    # ------------------------------------------------------------------ public API
    def project(self, dirs: ArrayLike) -> NDArray[np.float64]:
        """Pixel coordinates ``(..., 2)`` = ``(u, v)`` of camera-frame directions ``(..., 3)``.

        Directions need not be unit length. Directions beyond :attr:`theta_max` are still
        projected with the same formula (callers mask them with :meth:`in_field`).
        """
        d = np.asarray(dirs, dtype=np.float64)
        if d.shape[-1:] != (3,):
            raise ValueError(f"dirs must have shape (..., 3), got {d.shape}")
        x, y, z = d[..., 0], d[..., 1], d[..., 2]
        rho = np.hypot(x, y)
        theta = np.arctan2(rho, z)
        g = self._g(theta)
        safe = rho > 0.0
        s = np.where(safe, g / np.where(safe, rho, 1.0), 0.0)
        xd, yd = s * x, s * y
        u = self.fx * (xd + self.skew * yd) + self.cx
        v = self.fy * yd + self.cy
        return np.stack([u, v], axis=-1)

    def unproject(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Unit camera-frame directions ``(..., 3)`` of pixel coordinates ``(..., 2)``."""
        return self.unproject_with_angle(uv)[0]

    def unproject_with_angle(
        self, uv: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`unproject` and :meth:`field_angle` of the same pixels, from one inverse of
        the radial map (the costly part of either): ``(directions (..., 3), θ (...))``."""
        p = np.asarray(uv, dtype=np.float64)
        if p.shape[-1:] != (2,):
            raise ValueError(f"uv must have shape (..., 2), got {p.shape}")
        yd = (p[..., 1] - self.cy) / self.fy
        xd = (p[..., 0] - self.cx) / self.fx - self.skew * yd
        r = np.hypot(xd, yd)
        theta = self._g_inv(r)
        safe = r > 0.0
        c = np.where(safe, xd / np.where(safe, r, 1.0), 1.0)
        s = np.where(safe, yd / np.where(safe, r, 1.0), 0.0)
        st = np.sin(theta)
        return np.stack([st * c, st * s, np.cos(theta)], axis=-1), theta

    def field_angle(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Angle θ from the optical axis of pixel coordinates ``(..., 2)``."""
        p = np.asarray(uv, dtype=np.float64)
        yd = (p[..., 1] - self.cy) / self.fy
        xd = (p[..., 0] - self.cx) / self.fx - self.skew * yd
        return self._g_inv(np.hypot(xd, yd))

    def in_field(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """True where pixel coordinates lie inside the image circle (θ ≤ theta_max)."""
        p = np.asarray(uv, dtype=np.float64)
        yd = (p[..., 1] - self.cy) / self.fy
        xd = (p[..., 0] - self.cx) / self.fx - self.skew * yd
        return np.hypot(xd, yd) <= self.r_max

    def pixel_grid(self) -> NDArray[np.float64]:
        """Pixel-centre coordinates ``(height, width, 2)``."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return np.stack([u, v], axis=-1)

    def camera_matrix(self) -> NDArray[np.float64]:
        """OpenCV ``K`` (3 × 3)."""
        return np.array(
            [[self.fx, self.skew * self.fx, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (inverse of :meth:`from_dict`)."""
        return {
            "model": self.model,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
            "k": list(self.k),
            "skew": self.skew,
            "theta_max": self.theta_max,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FisheyeLens:
        """Rebuild a lens from :meth:`to_dict` output."""
        if not isinstance(d, dict):
            raise ValueError(f"lens description must be a dict, got {type(d).__name__}")
        known = {"model", "fx", "fy", "cx", "cy", "width", "height", "k", "skew", "theta_max"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown lens field(s) {unknown}; expected {sorted(known)}")
        args = dict(d)
        if "k" in args:
            args["k"] = tuple(args["k"])
        try:
            return cls(**args)
        except TypeError as exc:
            raise ValueError(f"bad lens description {d!r}: {exc}") from None

    def resized(self, width: int, height: int) -> FisheyeLens:
        """The same lens imaged on a ``width × height`` sensor covering the same area.

        Used for binning: the pixel scale changes by ``width / self.width`` (and likewise in
        ``v``); pixel-centre coordinates are mapped so that image edges coincide.
        """
        sx = width / self.width
        sy = height / self.height
        return FisheyeLens(
            model=self.model,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=int(width),
            height=int(height),
            k=self.k,
            skew=self.skew,
            theta_max=self.theta_max,
        )


def make_lens(
    model: str,
    width: int,
    height: int,
    *,
    theta_max: float = math.pi / 2,
    fill: float = 0.98,
    k: ArrayLike = (0.0, 0.0, 0.0, 0.0),
    aspect: float = 1.0,
    skew: float = 0.0,
) -> FisheyeLens:
    """A lens whose image circle (θ = ``theta_max``) spans ``fill`` of the shorter image side.

    Parameters
    ----------
    model : str
        One of :data:`LENS_MODELS`.
    width, height : int
        Image size in pixels; the principal point is the image centre.
    theta_max : float
        Half field of view in radians (π/2 for a 180° fisheye).
    fill : float
        Image-circle diameter as a fraction of ``min(width, height)``, in (0, 1].
    k : array_like
        Kannala-Brandt ``k1..k4`` (``kannala_brandt`` only).
    aspect : float
        ``fy / fx`` (non-square pixels).
    skew : float
        OpenCV fisheye ``alpha``.
    """
    _check_model(model)
    fill = _pos_finite(fill, "fill")
    if fill > 1.0:
        raise ValueError(f"fill must be in (0, 1], got {fill!r}")
    aspect = _pos_finite(aspect, "aspect")
    probe = FisheyeLens(
        model, 1.0, 1.0, 0.0, 0.0, int(width), int(height), tuple(np.ravel(k)), 0.0, theta_max
    )
    f = fill * 0.5 * min(int(width), int(height)) / probe.r_max
    if aspect > 1.0:
        f = f / aspect
    return FisheyeLens(
        model=model,
        fx=f,
        fy=f * aspect,
        cx=(int(width) - 1) / 2.0,
        cy=(int(height) - 1) / 2.0,
        width=int(width),
        height=int(height),
        k=probe.k,
        skew=skew,
        theta_max=theta_max,
    )
