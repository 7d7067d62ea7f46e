"""Fisheye lens calibration with a ChArUco board and OpenCV's ``cv2.fisheye`` model.

Ward (1992, §3.2) leaves the first step of angle recovery — "the mapping from
image point locations to the lens incident direction" — to a measurement. This module makes that
measurement the way a lab would today:

* :func:`render_board_view` renders a ChArUco board seen through a lens model at a given pose
  (for each output pixel: unproject through the lens, intersect the board plane, sample the
  board's image; anti-aliased by supersampling). The lens inverse is evaluated through a dense
  1-D table of the radial map, so a view costs a few array operations per sub-pixel;
* :func:`detect_charuco` finds the board's inner corners (``cv2.aruco.CharucoDetector``,
  refined by ``cv2.cornerSubPix``);
* :func:`calibrate_fisheye` fits the Kannala-Brandt model (``cv2.fisheye.calibrate``: focal
  lengths, principal point, k1..k4) and returns a :class:`~gonio.simulator.lenses.FisheyeLens`
  with the reprojection RMS; :func:`write_lens_calibration` / reduction's ``lens=`` read and
  use it.

OpenCV 5 notes: flags are ``cv2.CALIB_*``; per-view points are float64 arrays of shape
``(1, N, 3)`` and ``(1, N, 2)``; an intrinsic guess is required.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3.2 (lens mapping "easily measured"). J. Kannala, S. Brandt, "A generic
camera model and calibration method for conventional, wide-angle, and fish-eye lenses", IEEE
PAMI 28(8), 2006 (OpenCV's fisheye model).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "LensCalibration",
    "board_poses",
    "calibrate_fisheye",
    "detect_charuco",
    "detect_views",
    "make_board",
    "read_lens_calibration",
    "render_board_view",
    "render_board_views",
    "write_lens_calibration",
]


def make_board(
    squares_x: int = 9,
    squares_y: int = 7,
    square_length: float = 0.04,
    marker_length: float = 0.02,
    dictionary: int | None = None,
):
    """A ``cv2.aruco.CharucoBoard`` (default 9 × 7 squares of 40 mm, 20 mm 4×4 markers).

    Markers of half the square size leave a white margin around each chessboard corner wide
    enough for ``cornerSubPix`` (with 3/4-size markers the refinement window sees marker bits
    and the corners are biased by ~0.1 px).
    """
    import cv2

    for name, v in (("squares_x", squares_x), ("squares_y", squares_y)):
        if not (isinstance(v, int) and v >= 3):
            raise ValueError(f"{name} must be an integer ≥ 3, got {v!r}")
    if not (0 < marker_length < square_length):
        raise ValueError(
            f"marker_length must be in (0, square_length = {square_length}), got {marker_length}"
        )
    d = cv2.aruco.getPredefinedDictionary(
        cv2.aruco.DICT_4X4_250 if dictionary is None else dictionary
    )
    # a ChArUco board carries a distinct marker in every other square; a board needing more
    # markers than the dictionary holds cannot be made (and OpenCV would first allocate it)
    n_markers = (squares_x * squares_y) // 2
    if n_markers > d.bytesList.shape[0]:
        raise ValueError(
            f"squares {squares_x} x {squares_y} need {n_markers} ArUco markers, more than the "
            f"{d.bytesList.shape[0]} of the board's dictionary"
        )
    return cv2.aruco.CharucoBoard((squares_x, squares_y), square_length, marker_length, d)


def _board_texture(board, px_per_square: int) -> tuple[NDArray[np.uint8], float]:
    sx, sy = board.getChessboardSize()
    img = board.generateImage((sx * px_per_square, sy * px_per_square), marginSize=0)
    return np.ascontiguousarray(img), px_per_square / board.getSquareLength()


def _radial_table(lens, n: int = 200001) -> tuple[NDArray, NDArray]:
    """Normalised radius r → field angle θ, tabulated densely (for fast unprojection)."""
    r_max = lens.r_max * 1.02
    r = np.linspace(0.0, r_max, n)
    uv = np.stack([lens.cx + lens.fx * r, np.full_like(r, lens.cy)], -1)
    return r, lens.field_angle(uv)


def render_board_view(
    lens: Any,
    board: Any,
    rvec: ArrayLike,
    tvec: ArrayLike,
    *,
    supersample: int = 4,
    px_per_square: int = 120,
    background: int = 255,
    chunk_rows: int = 64,
) -> NDArray[np.uint8]:
    """Render a ChArUco board through a fisheye lens.

    Parameters
    ----------
    lens : FisheyeLens
        The camera (image size, intrinsics, radial model).
    board : cv2.aruco.CharucoBoard
    rvec, tvec : array_like (3,)
        Board pose in the camera frame (OpenCV: ``X_cam = R(rvec) X_board + tvec``, metres).
    supersample : int
        Sub-pixels per pixel side (box-filter anti-aliasing).
    px_per_square : int
        Resolution of the board texture.
    background : int
        Grey level where a ray misses the board.

    Returns
    -------
    ndarray (H, W) uint8
    """
    return render_board_views(
        lens, board, [(rvec, tvec)], supersample=supersample, px_per_square=px_per_square,
        background=background, chunk_rows=chunk_rows,
    )[0]  # fmt: skip


def render_board_views(
    lens: Any,
    board: Any,
    poses: Sequence[tuple[ArrayLike, ArrayLike]],
    *,
    supersample: int = 4,
    px_per_square: int = 120,
    background: int = 255,
    chunk_rows: int = 64,
) -> list[NDArray[np.uint8]]:
    """:func:`render_board_view` at each ``(rvec, tvec)`` of ``poses``, the same images: the
    pixels' rays through the lens (which do not depend on the pose, and are half of a view's
    work) are computed once for all views."""
    import cv2

    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample must be ≥ 1, got {supersample!r}")
    posed = []
    for rvec, tvec in poses:
        R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        posed.append((R, t, R[:, 2], float(R[:, 2] @ t)))
    tex, scale = _board_texture(board, int(px_per_square))
    texf = tex.astype(np.float32)
    rt, tt = _radial_table(lens)
    W, H = lens.width, lens.height
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    outs = [np.empty((H, W), np.float32) for _ in posed]
    u = np.arange(W, dtype=np.float64)
    for r0 in range(0, H, chunk_rows):
        rows = np.arange(r0, min(H, r0 + chunk_rows), dtype=np.float64)
        accs = [np.zeros((rows.size, W), np.float32) for _ in posed]
        for dv in offs:
            for du in offs:
                vv = (rows + dv)[:, None]
                uu = (u + du)[None, :]
                yd = (vv - lens.cy) / lens.fy
                xd = (uu - lens.cx) / lens.fx - lens.skew * yd
                rr = np.hypot(xd, yd)
                theta = np.interp(rr, rt, tt)
                st = np.sin(theta)
                safe = rr > 0
                inv = np.where(safe, st / np.where(safe, rr, 1.0), 1.0)
                ray = (xd * inv, yd * inv, np.cos(theta), rr <= lens.r_max)
                for acc, pose in zip(accs, posed):
                    acc += _board_hit(ray, pose, texf, scale, float(background))
        for out, acc in zip(outs, accs):
            out[r0 : r0 + rows.size] = acc / (ss * ss)
    return [np.clip(np.rint(out), 0, 255).astype(np.uint8) for out in outs]


def _board_hit(ray: tuple, pose: tuple, texf: NDArray, scale: float, background: float) -> NDArray:
    """The board texture's grey level along the rays ``(dx, dy, dz, in_circle)`` from the
    camera, for the board at ``pose`` ``(R, t, normal, normal · t)``; ``background`` where
    a ray misses it."""
    dx, dy, dz, in_circle = ray
    R, t, n, nt = pose
    th, tw = texf.shape
    den = n[0] * dx + n[1] * dy + n[2] * dz
    ok = (np.abs(den) > 1e-12) & in_circle
    s = np.where(ok, nt / np.where(ok, den, 1.0), -1.0)
    ok &= s > 0
    px = s * dx - t[0]
    py = s * dy - t[1]
    pz = s * dz - t[2]
    bx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
    by = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
    ix = np.floor(bx * scale).astype(np.int64)
    iy = np.floor(by * scale).astype(np.int64)
    inb = ok & (ix >= 0) & (ix < tw) & (iy >= 0) & (iy < th)
    val = np.full(dx.shape, background, np.float32)
    val[inb] = texf[iy[inb], ix[inb]]
    return val


def board_poses(
    lens: Any,
    board: Any,
    n_views: int = 16,
    *,
    max_field_angle: float = math.radians(70.0),
    distance: float | None = None,
    rng: int | np.random.Generator | None = 0,
) -> list[tuple[NDArray, NDArray]]:
    """Board poses that cover the field of view: centres at field angles from 0 to
    ``max_field_angle`` spread in azimuth, the board roughly facing the camera with a random
    tilt of up to 35°.

    Returns a list of ``(rvec, tvec)``.
    """
    import cv2

    rng = np.random.default_rng(rng)
    sx, sy = board.getChessboardSize()
    L = board.getSquareLength()
    bw, bh = sx * L, sy * L
    if distance is None:
        distance = 0.9 * max(bw, bh)
    centre_b = np.array([bw / 2, bh / 2, 0.0])
    poses = []
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for k in range(int(n_views)):
        frac = k / max(n_views - 1, 1)
        alpha = max_field_angle * math.sqrt(frac)
        az = k * golden
        c = distance * np.array(
            [math.sin(alpha) * math.cos(az), math.sin(alpha) * math.sin(az), math.cos(alpha)]
        )
        # board normal facing the camera (board z towards −c), plus a random tilt
        zb = c / np.linalg.norm(c)
        tilt = rng.uniform(-0.6, 0.6, 2)
        zb = zb + 0.6 * np.array([tilt[0], tilt[1], 0.0]) * 0.5
        zb /= np.linalg.norm(zb)
        roll = rng.uniform(-math.pi, math.pi)
        a = np.array([math.cos(roll), math.sin(roll), 0.0])
        xb = a - (a @ zb) * zb
        xb /= np.linalg.norm(xb)
        yb = np.cross(zb, xb)
        R = np.stack([xb, yb, zb], axis=1)
        t = c - R @ centre_b
        rvec, _ = cv2.Rodrigues(R)
        poses.append((rvec.ravel(), t))
    return poses


def detect_charuco(image: ArrayLike, board: Any, *, refine: bool = True):
    """Detect ChArUco corners: returns ``(corners (N, 2) float64, ids (N,) int)`` (maybe empty)."""
    import cv2

    img = np.asarray(image)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ValueError(f"image must be a 2-D uint8 array, got {img.dtype} {img.shape}")
    det = cv2.aruco.CharucoDetector(board)
    corners, ids, _, _ = det.detectBoard(img)
    if corners is None or ids is None or len(ids) == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    c = np.asarray(corners, np.float32).reshape(-1, 1, 2)
    if refine and len(c):
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
        c = cv2.cornerSubPix(img, c, (5, 5), (-1, -1), crit)
    return c.reshape(-1, 2).astype(np.float64), np.asarray(ids).ravel().astype(np.int64)


@dataclass
class LensCalibration:
    """Result of :func:`calibrate_fisheye`.

    Attributes
    ----------
    lens : FisheyeLens
        Kannala-Brandt lens with the fitted intrinsics.
    rms : float
        Reprojection RMS over all corners (pixels), as returned by OpenCV.
    per_view_rms : list of float
    n_views, n_points : int
    rvecs, tvecs : list of arrays
        Estimated board poses.
    """

    lens: Any
    rms: float
    per_view_rms: list[float]
    n_views: int
    n_points: int
    rvecs: list[NDArray] = field(default_factory=list)
    tvecs: list[NDArray] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content of a lens-calibration file."""
        return {
            "kind": "gonio.lens_calibration",
            "lens": self.lens.to_dict(),
            "rms_px": float(self.rms),
            "per_view_rms_px": [float(x) for x in self.per_view_rms],
            "n_views": int(self.n_views),
            "n_points": int(self.n_points),
            **self.info,
        }


#: Two views whose common ChArUco corners all lie within this many pixels show the board at
#: one pose (detection repeats to ~0.05 px on a still board): the second adds no constraint.
SAME_POSE_PX = 0.5


def _same_pose(corners: Any, ids: Any, seen: list[tuple[NDArray, NDArray]]) -> int | None:
    """Index in ``seen`` of an earlier view at the same pose as ``(corners, ids)``, or None."""
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    i = np.ravel(ids)
    for k, (c0, i0) in enumerate(seen):
        common, a, b = np.intersect1d(i, i0, return_indices=True)
        if len(common) < max(4, len(i) // 2):
            continue
        if float(np.max(np.linalg.norm(c[a] - c0[b], axis=1))) <= SAME_POSE_PX:
            return k
    return None


def calibrate_fisheye(
    images: Sequence[ArrayLike],
    board: Any,
    *,
    initial: Any = None,
    theta_max: float = math.pi / 2,
    min_corners: int = 8,
    fix_skew: bool = True,
    detections: Sequence[tuple[NDArray, NDArray]] | None = None,
) -> LensCalibration:
    """Fit the Kannala-Brandt fisheye model to ChArUco views with ``cv2.fisheye.calibrate``.

    Parameters
    ----------
    images : sequence of (H, W) uint8 arrays
        Board views.
    board : cv2.aruco.CharucoBoard
    initial : FisheyeLens, optional
        Intrinsic guess; default an equidistant lens whose 180° image circle fills 0.95 of
        the shorter image side, centred.
    theta_max : float
        Field of view recorded in the returned lens.
    min_corners : int
        Views with fewer detected corners are skipped, and so are views repeating an earlier
        view's pose (every common corner within :data:`SAME_POSE_PX`; listed in
        ``info["views_repeated"]``). Fewer than 3 distinct views raise ``ValueError``: the
        same view three times gave fx −3.4 % and a wrong distortion with rms 0.048 px.
    detections : sequence of (corners, ids), optional
        The views' corners as :func:`detect_views` found them (one per image): several
        calibrations from the same views (a split-half uncertainty) detect each view once.

    Returns
    -------
    LensCalibration
    """
    import cv2
    from gonio.simulator.lenses import FisheyeLens, make_lens

    t0 = time.perf_counter()
    imgs = [np.asarray(a) for a in images]
    if not imgs:
        raise ValueError("images must hold at least one board view")
    h, w = imgs[0].shape[:2]
    if detections is None:
        detections = detect_views(imgs, board)
    elif len(detections) != len(imgs):
        raise ValueError(f"detections has {len(detections)} entries for {len(imgs)} images")
    objp, imgp, used, duplicates = _board_views(detections, board, min_corners)
    if len(objp) < 3:
        same = "".join(f"; view {a} repeats view {b}" for a, b in duplicates)
        raise ValueError(
            f"only {len(objp)} of {len(imgs)} views show the board at distinct poses with "
            f"≥ {min_corners} ChArUco corners; need at least 3 (a view whose corners all lie "
            f"within {SAME_POSE_PX} px of an earlier view's adds no constraint){same}"
        )
    if initial is None:
        initial = make_lens("equidistant", w, h, fill=0.95)
    K = initial.camera_matrix().astype(np.float64)
    D = np.asarray(initial.k, np.float64).reshape(4, 1)
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_RECOMPUTE_EXTRINSIC
    if fix_skew:
        flags |= cv2.CALIB_FIX_SKEW
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
        objp, imgp, (w, h), K, D, flags=flags, criteria=crit
    )
    per_view, rms_px = _reprojection_rms(objp, imgp, rvecs, tvecs, K, D)
    lens = FisheyeLens(
        "kannala_brandt",
        fx=float(K[0, 0]),
        fy=float(K[1, 1]),
        cx=float(K[0, 2]),
        cy=float(K[1, 2]),
        width=int(w),
        height=int(h),
        k=tuple(float(x) for x in np.ravel(D)),
        skew=float(K[0, 1] / K[0, 0]),
        theta_max=_safe_theta_max(np.ravel(D), theta_max),
    )
    return LensCalibration(
        lens=lens,
        rms=rms_px,
        per_view_rms=per_view,
        n_views=len(objp),
        n_points=int(sum(o.shape[1] for o in objp)),
        rvecs=[np.ravel(r) for r in rvecs],
        tvecs=[np.ravel(t) for t in tvecs],
        info={
            "opencv_rms_px": float(rms),
            "views_used": used,
            "views_repeated": [a for a, _ in duplicates],
            "seconds": time.perf_counter() - t0,
        },
    )


def detect_views(images: Sequence[ArrayLike], board: Any) -> list[tuple[NDArray, NDArray]]:
    """:func:`detect_charuco` on each image, all of one shape: ``[(corners, ids), ...]``."""
    imgs = [np.asarray(a) for a in images]
    out = []
    for k, img in enumerate(imgs):
        if img.shape[:2] != imgs[0].shape[:2]:
            raise ValueError(f"images[{k}] has shape {img.shape}, expected {imgs[0].shape[:2]}")
        out.append(detect_charuco(img, board))
    return out


def _board_views(
    detections: Sequence[tuple[NDArray, NDArray]], board: Any, min_corners: int
) -> tuple[list[NDArray], list[NDArray], list[int], list[tuple[int, int]]]:
    """The views :func:`calibrate_fisheye` uses: board points, image points, view indices,
    and (view, earlier view) pairs skipped as repeating a pose.

    Views with fewer than ``min_corners`` ChArUco corners are skipped.
    """
    obj_all = np.asarray(board.getChessboardCorners(), np.float64)
    objp, imgp, used = [], [], []
    seen: list[tuple[NDArray, NDArray]] = []
    duplicates: list[tuple[int, int]] = []
    for k, (c, ids) in enumerate(detections):
        if len(ids) < min_corners:
            continue
        dup = _same_pose(c, ids, seen)
        if dup is not None:
            duplicates.append((k, used[dup]))
            continue
        seen.append((np.asarray(c, np.float64).reshape(-1, 2), np.ravel(ids)))
        objp.append(obj_all[ids].reshape(1, -1, 3))
        imgp.append(c.reshape(1, -1, 2))
        used.append(k)
    return objp, imgp, used, duplicates


def _reprojection_rms(
    objp: list[NDArray], imgp: list[NDArray], rvecs: Any, tvecs: Any, K: NDArray, D: NDArray
) -> tuple[list[float], float]:
    """Each view's rms reprojection error and that of all points together (pixels)."""
    import cv2

    per_view = []
    for o, p, rv, tv in zip(objp, imgp, rvecs, tvecs):
        proj, _ = cv2.fisheye.projectPoints(o, rv, tv, K, D)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj - p) ** 2, axis=-1)))))
    all_res = np.concatenate(
        [
            (cv2.fisheye.projectPoints(o, rv, tv, K, D)[0] - p).reshape(-1, 2)
            for o, p, rv, tv in zip(objp, imgp, rvecs, tvecs)
        ]
    )
    return per_view, float(np.sqrt(np.mean(np.sum(all_res**2, axis=1))))


def _safe_theta_max(k: NDArray, theta_max: float) -> float:
    """Largest θ ≤ theta_max where the fitted KB map is still increasing."""
    t = np.linspace(0.0, theta_max, 4097)
    t2 = t * t
    dg = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    bad = np.nonzero(dg <= 0)[0]
    return float(theta_max if bad.size == 0 else t[max(bad[0] - 1, 1)])


def write_lens_calibration(cal: LensCalibration, path: str | os.PathLike) -> Path:
    """Write a lens-calibration JSON file atomically."""
    import json

    from gonio.io.atomic import atomic_write_bytes

    return atomic_write_bytes(path, (json.dumps(cal.to_dict(), indent=2) + "\n").encode())


def read_lens_calibration(path: str | os.PathLike):
    """Read a lens-calibration file: returns the :class:`FisheyeLens`."""
    from gonio.calibration.reduce import load_lens

    return load_lens(path)
