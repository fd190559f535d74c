"""Rectification: a calibrated rig's maps, applied per frame, and a check that a pair is rectified.

A rig that is already rectified (identity rotation, pure x baseline, equal undistorted cameras)
needs no maps. Otherwise the rig's stored ``stereoRectify`` outputs are used (or computed here with
``alpha``), the rectified left camera is P1's intrinsics and the rectified baseline is
``-P2[0, 3] / P2[0, 0]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig


def stereo_rectify(rig: StereoRig, alpha: float = 0.0) -> dict[str, np.ndarray]:
    """OpenCV ``stereoRectify`` for ``rig``: R1, R2, P1, P2, Q (rectified frame = rotated left)."""
    size = rig.left.size
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        rig.left.K, rig.left.dist, rig.right.K, rig.right.dist, size, rig.R, rig.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha, newImageSize=size)
    return {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q}


# focal (px) x baseline (m) below which a rig measures nothing: 1 px of disparity at 1 mm depth
MIN_SHIFT_PX_M = 1e-3


class Rectifier:
    """Undistort-and-rectify maps for a rig, built once; :meth:`rectify` per frame.

    A rig that cannot be rectified side by side (cameras of different sizes, one camera above the
    other, no baseline) is an :class:`InputError` naming ``source`` (the rig's file).
    """

    def __init__(self, rig: StereoRig, alpha: float = 0.0, source: str | None = None):
        self.rig = rig
        self.size = rig.left.size
        if rig.right.size != rig.left.size:
            raise InputError(f"rig cameras differ in image size ({rig.left.width}x{rig.left.height}"
                             f" vs {rig.right.width}x{rig.right.height})", source)
        if rig.is_rectified():
            self.maps = None
            self.camera = rig.left
            self.baseline_m = rig.baseline_m
            return
        rect = rig.rectification if rig.rectification is not None else stereo_rectify(rig, alpha)
        P1, P2 = np.asarray(rect["P1"]), np.asarray(rect["P2"])
        if abs(P2[0, 3]) < MIN_SHIFT_PX_M and abs(P2[1, 3]) < MIN_SHIFT_PX_M:
            raise InputError(f"rig has no baseline (its rectified cameras are "
                             f"{np.hypot(P2[0, 3], P2[1, 3]) / P2[0, 0]:.2g} m apart): calibrated "
                             f"from the same images for both views? Calibrate it again", source)
        if abs(P2[1, 3]) > abs(P2[0, 3]):
            raise InputError("rig is rectified vertically (one camera above the other); "
                             "only side-by-side rigs are supported", source)
        self.camera = Camera(P1[:3, :3], *self.size)
        self.baseline_m = float(abs(P2[0, 3] / P2[0, 0]))
        self.maps = []
        for cam, R, P in ((rig.left, rect["R1"], P1), (rig.right, rect["R2"], P2)):
            self.maps.append(cv2.initUndistortRectifyMap(cam.K, cam.dist, np.asarray(R), P,
                                                         self.size, cv2.CV_16SC2))

    def rectify(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pair -> rectified pair (same size, uint8)."""
        if self.maps is None:
            return left_rgb, right_rgb
        out = []
        for img, (m1, m2) in zip((left_rgb, right_rgb), self.maps):
            out.append(cv2.remap(img, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        return out[0], out[1]

    def rectify_points(self, uv: np.ndarray, which: str = "left") -> np.ndarray:
        """Raw pixel positions (N, 2) -> their rectified positions (N, 2)."""
        rig = self.rig
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        if self.maps is None:
            return uv.reshape(-1, 2)
        rect = rig.rectification if rig.rectification is not None else stereo_rectify(rig)
        cam, R, P = ((rig.left, rect["R1"], rect["P1"]) if which == "left"
                     else (rig.right, rect["R2"], rect["P2"]))
        return cv2.undistortPoints(uv, cam.K, cam.dist, R=np.asarray(R),
                                   P=np.asarray(P)).reshape(-1, 2)


def _ratio_matches(left_rgb: np.ndarray, right_rgb: np.ndarray, n_features: int, ratio: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Matched ORB positions (N, 2) left and right: Lowe's ratio test both ways, mutual best."""
    orb = cv2.ORB_create(n_features)
    kl, dl = orb.detectAndCompute(cv2.cvtColor(left_rgb, cv2.COLOR_RGB2GRAY), None)
    kr, dr = orb.detectAndCompute(cv2.cvtColor(right_rgb, cv2.COLOR_RGB2GRAY), None)
    if dl is None or dr is None or len(dl) < 2 or len(dr) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)

    def distinct(a, b):
        return {mn[0].queryIdx: mn[0].trainIdx for mn in bf.knnMatch(a, b, k=2)
                if len(mn) == 2 and mn[0].distance < ratio * mn[1].distance}

    fwd, back = distinct(dl, dr), distinct(dr, dl)
    pairs = [(i, j) for i, j in fwd.items() if back.get(j) == i]
    return (np.array([kl[i].pt for i, _ in pairs], np.float64).reshape(-1, 2),
            np.array([kr[j].pt for _, j in pairs], np.float64).reshape(-1, 2))


@dataclass(frozen=True)
class RectificationCheck:
    """Vertical misalignment of a pair: ``dy = v_right - v_left ~ a + b u + c v`` (RANSAC)."""

    matches: int        # distinct mutual ORB matches (ratio test)
    inliers: int        # matches the fitted row-offset model explains within the tolerance
    offset_px: float    # median |dy| of the inliers (about 0 for a rectified pair)
    disparities: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)
    # u_left - u_right of the inliers: positive for a left/right pair in the right order

    @property
    def conclusive(self) -> bool:
        return self.inliers >= 20 and self.inliers >= 0.25 * self.matches


def measure_rectification(left_rgb: np.ndarray, right_rgb: np.ndarray, *, n_features: int = 4000,
                          ratio: float = 0.8, tol_px: float = 1.5, iterations: int = 500,
                          seed: int = 0) -> RectificationCheck:
    """Fit the vertical offset of matched features as an affine function of the position.

    Repetitive texture (tiles, facades, a chessboard) yields confident but wrong matches; the
    ratio test drops ambiguous ones and RANSAC keeps the largest consistent set, so the offset is
    measured on true correspondences. A rectified pair gives ``offset_px`` near 0; a vertical
    shift, rotation or scale error between the views gives its size in pixels.
    """
    pl, pr = _ratio_matches(left_rgb, right_rgb, n_features, ratio)
    n = len(pl)
    if n < 3:
        return RectificationCheck(n, 0, float("nan"))
    dy = pr[:, 1] - pl[:, 1]
    A = np.column_stack([np.ones(n), pl])
    rng = np.random.default_rng(seed)
    best = np.zeros(n, bool)
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        try:
            coef = np.linalg.solve(A[idx], dy[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(A @ coef - dy) <= tol_px
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 3:
        return RectificationCheck(n, int(best.sum()), float("nan"))
    return RectificationCheck(n, int(best.sum()), float(np.median(np.abs(dy[best]))),
                              pl[best, 0] - pr[best, 0])


def check_rectified(left_rgb: np.ndarray, right_rgb: np.ndarray, max_offset_px: float = 2.0,
                    source: str | None = None, warn=print) -> RectificationCheck:
    """Raise :class:`InputError` if matched features sit on different rows (pair not rectified).

    The one rectification check (``stereo``, ``pack``). Too few consistent matches to tell
    (textureless images) gives a warning, not an error. Callers offer
    ``--skip-rectification-check`` instead of calling it.
    """
    res = measure_rectification(left_rgb, right_rgb)
    if not res.conclusive:
        warn(f"warning: cannot check that the pair is rectified ({res.inliers} consistent of "
             f"{res.matches} distinct feature matches)" + (f": {source}" if source else ""))
    elif res.offset_px > max_offset_px:
        raise InputError(f"images are not rectified: matched features are {res.offset_px:.1f} px "
                         f"apart vertically ({res.inliers} of {res.matches} distinct ORB matches "
                         f"agree, at most {max_offset_px} px allowed); calibrate the rig and pass "
                         f"--rig, or pass --skip-rectification-check", source)
    return res
