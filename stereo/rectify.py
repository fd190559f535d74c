"""Rectification: a calibrated rig's maps, applied per frame, and a check that a pair is rectified.

A rig that is already rectified (identity rotation, pure x baseline, equal undistorted cameras)
needs no maps. Otherwise the rig's stored ``stereoRectify`` outputs are used (or computed here with
``alpha``), the rectified left camera is P1's intrinsics and the rectified baseline is
``-P2[0, 3] / P2[0, 0]``.
"""
from __future__ import annotations

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


class Rectifier:
    """Undistort-and-rectify maps for a rig, built once; :meth:`rectify` per frame."""

    def __init__(self, rig: StereoRig, alpha: float = 0.0):
        self.rig = rig
        self.size = rig.left.size
        if rig.right.size != rig.left.size:
            raise InputError(f"rig cameras differ in image size ({rig.left.width}x{rig.left.height}"
                             f" vs {rig.right.width}x{rig.right.height})")
        if rig.is_rectified():
            self.maps = None
            self.camera = rig.left
            self.baseline_m = rig.baseline_m
            return
        rect = rig.rectification if rig.rectification is not None else stereo_rectify(rig, alpha)
        P1, P2 = np.asarray(rect["P1"]), np.asarray(rect["P2"])
        if abs(P2[1, 3]) > abs(P2[0, 3]):
            raise InputError("rig is rectified vertically (one camera above the other); "
                             "only side-by-side rigs are supported")
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


def vertical_offsets(left_rgb: np.ndarray, right_rgb: np.ndarray, n_features: int = 2000
                     ) -> np.ndarray:
    """Vertical offsets ``v_right - v_left`` (px) of cross-checked ORB matches between the views."""
    orb = cv2.ORB_create(n_features)
    gl = cv2.cvtColor(left_rgb, cv2.COLOR_RGB2GRAY)
    gr = cv2.cvtColor(right_rgb, cv2.COLOR_RGB2GRAY)
    kl, dl = orb.detectAndCompute(gl, None)
    kr, dr = orb.detectAndCompute(gr, None)
    if dl is None or dr is None:
        return np.zeros(0)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    good = [m for m in matches if m.distance < 40]
    return np.array([kr[m.trainIdx].pt[1] - kl[m.queryIdx].pt[1] for m in good])


def check_rectified(left_rgb: np.ndarray, right_rgb: np.ndarray, max_offset_px: float = 2.0,
                    min_matches: int = 20, source: str | None = None) -> float | None:
    """Raise :class:`InputError` if matched features sit on different rows (pair not rectified).

    Returns the median absolute vertical offset (px), or None when too few features matched to
    tell (textureless images).
    """
    dy = vertical_offsets(left_rgb, right_rgb)
    if len(dy) < min_matches:
        return None
    med = float(np.median(np.abs(dy)))
    if med > max_offset_px:
        raise InputError(f"images are not rectified: matched features are {med:.1f} px apart "
                         f"vertically (median of {len(dy)} ORB matches, at most {max_offset_px} "
                         f"allowed); calibrate the rig and pass --rig", source)
    return med
