"""Camera height and ground plane from views of a calibration board lying flat on the ground.

Per view: detect the board in the raw left image, estimate the board's pose (pycolmap's LO-RANSAC
absolute pose with non-linear refinement when pycolmap is installed, OpenCV ``solvePnP`` (IPPE +
Levenberg-Marquardt) otherwise, and always as a cross-check), and read the ground plane off it:
the board's z axis is the plane normal and its origin lies on the plane (plus the board's
thickness). Planes are expressed in the *rectified* left camera's frame (the frame of the stereo
depth maps): ``n_rect = R1 n_raw``.

Views are combined as one plane: the normal is the mean of the views' normals and the plane passes
through the mean of their (thickness-shifted) board origins along it, so height and normal belong
to the same plane. Views that disagree (normals more than ``max_normal_spread_deg`` apart, heights
spread over more than ``max_height_spread`` of the height) are refused: the board moved off the
ground plane or the camera moved between views.
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

MAX_THICKNESS_M = 0.5            # a board on the ground, not on a table
MAX_NORMAL_SPREAD_DEG = 2.0      # largest angle between two views' ground normals
MAX_HEIGHT_SPREAD = 0.05         # largest (max - min) of the views' heights / the height

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
                     thickness_m: float = 0.0,
                     max_normal_spread_deg: float = MAX_NORMAL_SPREAD_DEG,
                     max_height_spread: float = MAX_HEIGHT_SPREAD,
                     source: str | None = None) -> MountEstimate:
    """Estimate the mounting from raw left images of ``board`` lying on the ground.

    Raises :class:`InputError` (naming ``source``, the images' folder or pattern) for a thickness
    outside [0, ``MAX_THICKNESS_M``), no view with the board, or views that disagree beyond the
    tolerances (see the module's docstring).
    """
    if not (np.isfinite(thickness_m) and 0 <= thickness_m < MAX_THICKNESS_M):
        raise InputError(f"board thickness must be in [0, {MAX_THICKNESS_M:g}) m, "
                         f"got {thickness_m}")
    camera = rig.left
    if rig.rectification is not None:
        R1 = np.asarray(rig.rectification["R1"])
    else:
        R1 = np.eye(3) if rig.is_rectified() else stereo_rectify(rig)["R1"]
    normals, origins, heights, used, skipped = [], [], [], [], []
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
        n_cv, _ = ground_from_pose(R_cv, t_cv, thickness_m)
        pose = pose_colmap(obj, uv, camera)
        if pose is not None:
            n, d = ground_from_pose(*pose, thickness_m)
            t = pose[1]
            crosscheck = max(crosscheck, angle_between_deg(n, n_cv))
        else:
            n, d, t = n_cv, float(n_cv @ t_cv) + thickness_m, t_cv
            method = "opencv"
        normals.append(R1 @ n), origins.append(R1 @ t), heights.append(d), used.append(f)
    if not used:
        raise InputError(f"board ({board.pattern} {board.cols}x{board.rows}) not found in any of "
                         f"the {len(files)} images: {', '.join(map(os.path.basename, files))}",
                         source)
    n_mean = np.mean(normals, axis=0)
    n_mean /= np.linalg.norm(n_mean)
    # the plane with the mean normal through the views' board origins, lowered by the thickness
    height = float(np.mean(np.asarray(origins) @ n_mean)) + thickness_m
    _check_agreement(used, normals, heights, height, max_normal_spread_deg, max_height_spread,
                     source)
    per_view = {f: (h, angle_between_deg(n, n_mean)) for f, h, n in zip(used, heights, normals)}
    mounting = Mounting(height, n_mean, source=f"board on the ground ({len(used)} views, {method})")
    return MountEstimate(mounting, per_view, method, crosscheck, skipped)


def _check_agreement(files: list[str], normals: list[np.ndarray], heights: list[float],
                     height: float, max_deg: float, max_spread: float, source: str | None) -> None:
    """Raise :class:`InputError` when the views' ground planes disagree beyond the tolerances."""
    worst, pair = 0.0, (files[0], files[0])
    for i in range(len(files)):
        for j in range(i + 1, len(files)):
            a = angle_between_deg(normals[i], normals[j])
            if a > worst:
                worst, pair = a, (files[i], files[j])
    spread = (max(heights) - min(heights)) / height if height > 0 else float("inf")
    if worst <= max_deg and spread <= max_spread:
        return
    names = [os.path.basename(f) for f in files]
    lo, hi = names[int(np.argmin(heights))], names[int(np.argmax(heights))]
    raise InputError(f"the {len(files)} views disagree on the ground: normals up to "
                     f"{worst:.1f} deg apart ({os.path.basename(pair[0])}, "
                     f"{os.path.basename(pair[1])}; at most {max_deg:g}), heights "
                     f"{min(heights):.3f} m ({lo}) to {max(heights):.3f} m "
                     f"({hi}), {100 * spread:.0f}% of {height:.3f} m (at most "
                     f"{100 * max_spread:g}%); the board must lie flat on one ground plane and the "
                     f"camera stay still: drop the views that differ, or raise --max-normal-spread "
                     f"/ --max-height-spread", source)
