"""Camera height and ground plane from views of a calibration board lying flat on the ground.

Per view: detect the board in the raw left image, estimate the board's pose (pycolmap's LO-RANSAC
absolute pose with non-linear refinement when pycolmap is installed, OpenCV ``solvePnP`` (IPPE +
Levenberg-Marquardt) otherwise, and always as a cross-check), and read the ground plane off it:
the board's z axis is the plane normal and its origin lies on the plane (plus the board's
thickness). Planes are expressed in the *rectified* left camera's frame (the frame of the stereo
depth maps): ``n_rect = R1 n_raw``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, Mounting, StereoRig
from staticdepth.geometry.plane import angle_between_deg
from staticdepth.stereo.calibrate import Board, detect_corners
from staticdepth.stereo.colmap import camera_to_colmap
from staticdepth.stereo.io import read_rgb
from staticdepth.stereo.rectify import stereo_rectify

try:
    import pycolmap
except ImportError:  # optional
    pycolmap = None


def pose_opencv(obj: np.ndarray, uv: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """``cam_from_board`` (R (3, 3), t (3,)) of a planar board with OpenCV (IPPE, then LM)."""
    ok, rvec, tvec = cv2.solvePnP(obj, uv, camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise InputError("solvePnP failed")
    rvec, tvec = cv2.solvePnPRefineLM(obj, uv, camera.K, camera.dist, rvec, tvec)
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def pose_colmap(obj: np.ndarray, uv: np.ndarray, camera: Camera
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """``cam_from_board`` with pycolmap (robust + refined), or None when it is unavailable/fails."""
    if pycolmap is None:
        return None
    try:
        model, params = camera_to_colmap(camera)
    except InputError:      # distortion terms COLMAP has no model for: OpenCV alone
        return None
    cam = pycolmap.Camera(model=model, width=camera.width, height=camera.height, params=params)
    res = pycolmap.estimate_and_refine_absolute_pose(
        np.asarray(uv, np.float64) + 0.5, np.asarray(obj, np.float64), cam)
    if res is None:
        return None
    pose = res["cam_from_world"]
    return np.asarray(pose.rotation.matrix()), np.asarray(pose.translation).ravel()


def ground_from_pose(R: np.ndarray, t: np.ndarray, thickness_m: float = 0.0
                     ) -> tuple[np.ndarray, float]:
    """Ground plane ``n . P = d`` (camera frame, d > 0) under a board at pose ``cam_from_board``."""
    n = R[:, 2].copy()
    d = float(n @ t)
    if d < 0:
        n, d = -n, -d
    return n, d + thickness_m


@dataclass(frozen=True)
class MountEstimate:
    mounting: Mounting
    per_view: dict[str, tuple[float, float]]    # file -> (height_m, angle to the mean normal, deg)
    method: str                                 # "pycolmap" or "opencv"
    crosscheck_deg: float                       # largest normal difference pycolmap vs OpenCV
    skipped: list[str]


def mount_from_board(rig: StereoRig, files: list[str], board: Board, *,
                     thickness_m: float = 0.0) -> MountEstimate:
    """Estimate the mounting from raw left images of ``board`` lying on the ground."""
    camera = rig.left
    if rig.rectification is not None:
        R1 = np.asarray(rig.rectification["R1"])
    else:
        R1 = np.eye(3) if rig.is_rectified() else stereo_rectify(rig)["R1"]
    normals, heights, used, skipped = [], [], [], []
    crosscheck, method = 0.0, "pycolmap" if pycolmap is not None else "opencv"
    for f in files:
        img = read_rgb(f)
        if (img.shape[1], img.shape[0]) != camera.size:
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]}, the rig's left camera is "
                             f"{camera.width}x{camera.height}", f)
        det = detect_corners(board, img)
        if det is None:
            skipped.append(f)
            continue
        ids, uv = det
        obj = board.object_points()[ids]
        R_cv, t_cv = pose_opencv(obj, uv, camera)
        n_cv, d_cv = ground_from_pose(R_cv, t_cv, thickness_m)
        pose = pose_colmap(obj, uv, camera)
        if pose is not None:
            n, d = ground_from_pose(*pose, thickness_m)
            crosscheck = max(crosscheck, angle_between_deg(n, n_cv))
        else:
            n, d = n_cv, d_cv
            method = "opencv"
        normals.append(R1 @ n), heights.append(d), used.append(f)
    if not used:
        raise InputError(f"board ({board.pattern} {board.cols}x{board.rows}) not found in any of "
                         f"the {len(files)} images: {', '.join(map(os.path.basename, files))}")
    n_mean = np.mean(normals, axis=0)
    n_mean /= np.linalg.norm(n_mean)
    height = float(np.median(heights))
    per_view = {f: (h, angle_between_deg(n, n_mean)) for f, h, n in zip(used, heights, normals)}
    mounting = Mounting(height, n_mean, source=f"board on the ground ({len(used)} views, {method})")
    return MountEstimate(mounting, per_view, method, crosscheck, skipped)
