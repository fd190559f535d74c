"""Stereo rigs from other tools' calibration files: DepthAI (OAK) JSON, Middlebury, KITTI.

Every importer returns a :class:`~staticdepth.geometry.camera.StereoRig` (``P_right = R P_left + T``
in metres) that the stereo pipeline can use directly:

- DepthAI: ``CalibrationHandler.eepromToJson()`` / ``eepromToJsonFile()``. ``cameraData`` is a list
  of ``[socket, {width, height, intrinsicMatrix, distortionCoeff, extrinsics: {rotationMatrix,
  translation {x, y, z} in cm, specTranslation, toCameraSocket}, ...}]``; a camera's extrinsics map
  its points into the ``toCameraSocket`` camera. The pair is ``stereoRectificationData``'s
  ``leftCameraSocket``/``rightCameraSocket``; ``R``/``T`` follow the extrinsics chain from left to
  right (the calibrated translation, not the design ``specTranslation``); the stored
  ``rectifiedRotationLeft/Right`` become R1/R2, with the left camera's intrinsics as the rectified
  camera.
- Middlebury (2014/2021 ``calib.txt``: ``cam0``, ``cam1``, ``doffs``, ``baseline`` in mm, ``width``,
  ``height``, ``ndisp``, ...): the views are rectified but their principal points differ by
  ``doffs = cx1 - cx0``, so the dataset's disparities satisfy ``Z = f B / (d + doffs)``. The rig
  keeps both cameras and a rectification whose right map shifts the right image by ``doffs``;
  after the pipeline's rectification the disparity is ``d + doffs`` and depth is ``f B / d``
  as everywhere else. ``doffs`` and ``ndisp`` are kept in ``rig.extra``.
- KITTI ``calib_cam_to_cam.txt``: the rectified pair (cameras 2 and 3 by default, 0 and 1 with
  ``camera=0``) from ``P_rect_0x``; baseline ``(P_left[0, 3] - P_right[0, 3]) / f``; image size
  ``S_rect_0x``.
"""
from __future__ import annotations

import os
import re
from typing import Any, Callable

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig, read_json

# DepthAI board sockets: JSON stores them as numbers; names accepted too.
SOCKETS = {"AUTO": -1, "CAM_A": 0, "RGB": 0, "CENTER": 0, "CAM_B": 1, "LEFT": 1, "CAM_C": 2,
           "RIGHT": 2, "CAM_D": 3, "CAM_E": 4, "CAM_F": 5, "CAM_G": 6, "CAM_H": 7}


def _socket(value: Any, path: str) -> int:
    if isinstance(value, str):
        if value.upper() not in SOCKETS:
            raise InputError(f"unknown camera socket {value!r}", path)
        return SOCKETS[value.upper()]
    return int(value)


def _xyz(d: Any, key: str, path: str) -> np.ndarray:
    try:
        return np.array([float(d[key][k]) for k in "xyz"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"extrinsics {key!r} must be {{x, y, z}}", path) from None


def rectification_for(K: np.ndarray, R1: np.ndarray, R2: np.ndarray, T: np.ndarray,
                      source: str | None = None) -> dict[str, np.ndarray]:
    """OpenCV-style R1, R2, P1, P2, Q for given rectifying rotations and rectified camera ``K``.

    In the rectified frames the right camera sits at ``R2 T``; that must be (nearly) a pure x
    translation, else the rotations do not rectify this rig (:class:`InputError`).
    """
    t = np.asarray(R2, float) @ np.asarray(T, float)
    if abs(t[0]) <= 0 or np.hypot(t[1], t[2]) > 0.02 * abs(t[0]):
        raise InputError(f"the rectifying rotations do not align the baseline with x (rectified "
                         f"right camera at {np.round(t, 5).tolist()} m)", source)
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = P1.copy()
    P2[0, 3] = f * t[0]
    Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1 / t[0], 0]])
    return {"R1": np.asarray(R1, float), "R2": np.asarray(R2, float), "P1": P1, "P2": P2, "Q": Q}


# -- DepthAI ------------------------------------------------------------------------------------

def rig_from_depthai(path: str | os.PathLike) -> StereoRig:
    """The stereo pair of a DepthAI calibration JSON (see the module docstring)."""
    path = os.fspath(path)
    d = read_json(path)
    try:
        pairs = [(s, info) for s, info in d["cameraData"]]
        rect = d["stereoRectificationData"]
        left_s = _socket(rect["leftCameraSocket"], path)
        right_s = _socket(rect["rightCameraSocket"], path)
        R1 = np.asarray(rect["rectifiedRotationLeft"], float)
        R2 = np.asarray(rect["rectifiedRotationRight"], float)
    except KeyError as e:
        raise InputError(f"DepthAI calibration is missing the key {e.args[0]!r}", path) from None
    except (TypeError, ValueError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError("DepthAI 'cameraData' must be a list of [socket, camera] pairs", path) \
            from None
    cams = {_socket(s, path): info for s, info in pairs}
    for s in (left_s, right_s):
        if s not in cams:
            raise InputError(f"stereo socket {s} is not in cameraData (sockets: {sorted(cams)})",
                             path)

    def camera(s: int) -> Camera:
        c = cams[s]
        try:
            if int(c.get("cameraType", 0)) == 1:
                raise InputError(f"camera on socket {s} is a fisheye model (not supported)", path)
            return Camera(np.asarray(c["intrinsicMatrix"], float), int(c["width"]),
                          int(c["height"]), np.asarray(c.get("distortionCoeff", []), float))
        except KeyError as e:
            raise InputError(f"camera on socket {s} is missing {e.args[0]!r}", path) from None
        except InputError as e:
            raise InputError(f"camera on socket {s}: {e.problem}", path) from None

    def step(s: int) -> tuple[int, np.ndarray, np.ndarray] | None:
        ext = cams[s].get("extrinsics") or {}
        to = _socket(ext.get("toCameraSocket", -1), path)
        if to < 0 or to not in cams:
            return None
        R = np.asarray(ext["rotationMatrix"], float).reshape(3, 3)
        return to, R, _xyz(ext, "translation", path) / 100.0      # cm -> m

    def chain(src: int, dst: int) -> tuple[np.ndarray, np.ndarray] | None:
        R, T, s, seen = np.eye(3), np.zeros(3), src, {src}
        while s != dst:
            nxt = step(s)
            if nxt is None or nxt[0] in seen:
                return None
            s, Rs, ts = nxt
            R, T = Rs @ R, Rs @ T + ts
            seen.add(s)
        return R, T

    found = chain(left_s, right_s)
    if found is None:
        back = chain(right_s, left_s)
        if back is None:
            raise InputError(f"no extrinsics chain links socket {left_s} to socket {right_s}", path)
        found = (back[0].T, -back[0].T @ back[1])
    R, T = found
    left, right = camera(left_s), camera(right_s)
    K = left.K
    rectification = rectification_for(K, R1, R2, T, path)
    return StereoRig(left, right, R, T, rectification, extra={
        "source": f"DepthAI calibration {os.path.basename(path)}", "importer": "depthai",
        "sockets": [left_s, right_s], "board": d.get("boardName", "")})


# -- Middlebury ---------------------------------------------------------------------------------

def _middlebury_fields(path: str) -> dict[str, str]:
    if not os.path.isfile(path):
        raise InputError("calibration file not found", path)
    out = {}
    with open(path) as f:
        for line in f:
            key, sep, value = line.partition("=")
            if sep:
                out[key.strip()] = value.strip()
    return out


def _matrix3(text: str, key: str, path: str) -> np.ndarray:
    rows = text.strip().strip("[]").split(";")
    try:
        K = np.array([[float(x) for x in r.split()] for r in rows])
    except ValueError:
        raise InputError(f"{key} is not a matrix: {text!r}", path) from None
    if K.shape != (3, 3):
        raise InputError(f"{key} must be 3x3, got {K.shape}", path)
    return K


def rig_from_middlebury(path: str | os.PathLike) -> StereoRig:
    """The rig of a Middlebury ``calib.txt`` (see the module docstring)."""
    path = os.fspath(path)
    f = _middlebury_fields(path)
    missing = [k for k in ("cam0", "cam1", "baseline", "width", "height") if k not in f]
    if missing:
        raise InputError(f"Middlebury calibration is missing {missing}", path)
    K0, K1 = _matrix3(f["cam0"], "cam0", path), _matrix3(f["cam1"], "cam1", path)
    try:
        baseline_m = float(f["baseline"]) / 1000.0
        width, height = int(f["width"]), int(f["height"])
        doffs = float(f.get("doffs", K1[0, 2] - K0[0, 2]))
        extra: dict[str, Any] = {k: float(f[k]) for k in ("ndisp", "vmin", "vmax", "dyavg", "dymax")
                                 if k in f}
    except ValueError as e:
        raise InputError(f"Middlebury calibration has a malformed number ({e})", path) from None
    if not abs(doffs - (K1[0, 2] - K0[0, 2])) < 1e-3 * max(1.0, abs(doffs)):
        raise InputError(f"doffs {doffs} differs from cx1 - cx0 = {K1[0, 2] - K0[0, 2]}", path)
    left, right = Camera(K0, width, height), Camera(K1, width, height)
    T = np.array([-baseline_m, 0.0, 0.0])
    rect = None if left == right else rectification_for(K0, np.eye(3), np.eye(3), T, path)
    extra.update(source=f"Middlebury {os.path.basename(path)}", importer="middlebury",
                 doffs_px=doffs, depth="Z = f B / (d + doffs) for the raw views' disparity d")
    return StereoRig(left, right, np.eye(3), T, rect, extra=extra)


# -- KITTI --------------------------------------------------------------------------------------

def rig_from_kitti(path: str | os.PathLike, camera: int = 2) -> StereoRig:
    """The rectified pair (``camera``, ``camera + 1``) of a KITTI ``calib_cam_to_cam.txt``."""
    from staticdepth.dataset.kitti import read_calib_file

    path = os.fspath(path)
    if camera not in (0, 2):
        raise InputError(f"KITTI stereo pairs are cameras 0+1 (grey) and 2+3 (colour); "
                         f"--camera must be 0 or 2, got {camera}")
    cal = read_calib_file(path)

    def need(key: str, size: int) -> np.ndarray:
        if key not in cal:
            raise InputError(f"calibration has no {key!r}", path)
        if cal[key].size != size:
            raise InputError(f"{key!r} has {cal[key].size} values, expected {size}", path)
        return cal[key]

    P_l = need(f"P_rect_0{camera}", 12).reshape(3, 4)
    P_r = need(f"P_rect_0{camera + 1}", 12).reshape(3, 4)
    w, h = need(f"S_rect_0{camera}", 2)
    if not np.allclose(P_l[:, :3], P_r[:, :3]):
        raise InputError(f"P_rect_0{camera} and P_rect_0{camera + 1} have different intrinsics",
                         path)
    baseline_m = float((P_l[0, 3] - P_r[0, 3]) / P_l[0, 0])
    if not baseline_m > 0:
        raise InputError(f"camera {camera + 1} is not to the right of camera {camera} "
                         f"(baseline {baseline_m:.4f} m)", path)
    return StereoRig.rectified(Camera(P_l[:, :3], int(w), int(h)), baseline_m, extra={
        "source": f"KITTI {os.path.basename(path)} P_rect_0{camera}/P_rect_0{camera + 1}",
        "importer": "kitti", "cameras": [camera, camera + 1]})


IMPORTERS: dict[str, Callable[..., StereoRig]] = {
    "depthai": rig_from_depthai, "middlebury": rig_from_middlebury, "kitti": rig_from_kitti}


def import_rig(kind: str, path: str | os.PathLike, *, camera: int | None = None,
               size: tuple[int, int] | None = None) -> StereoRig:
    """A rig from the calibration file ``path`` of format ``kind``, optionally for resized images.

    ``size`` = (width, height) of the images the rig will see when they are a resized version of
    the calibrated ones (e.g. a DepthAI calibrated at 1280x800, recorded at 640x400).
    """
    if kind not in IMPORTERS:
        raise InputError(f"unknown rig format {kind!r} (known: {', '.join(sorted(IMPORTERS))})")
    if camera is not None and kind != "kitti":
        raise InputError(f"--camera applies to KITTI only, not {kind}")
    rig = IMPORTERS[kind](path, camera) if kind == "kitti" and camera is not None \
        else IMPORTERS[kind](path)
    return rig if size is None else scaled_rig(rig, *size)


def scaled_rig(rig: StereoRig, width: int, height: int) -> StereoRig:
    """The rig for images resized from the calibrated size to ``width`` x ``height``."""
    sx, sy = width / rig.left.width, height / rig.left.height
    if (width, height) == rig.left.size:
        return rig
    if not abs(sx / sy - 1) < 0.02:
        raise InputError(f"resizing {rig.left.width}x{rig.left.height} to {width}x{height} "
                         f"changes the aspect ratio")
    left, right = rig.left.scaled(sx, sy), rig.right.scaled(sx, sy)
    rect = None
    if rig.rectification is not None:
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
        rect = dict(rig.rectification)
        rect["P1"], rect["P2"] = S @ rect["P1"], S @ rect["P2"]
        f, cx, cy = rect["P1"][0, 0], rect["P1"][0, 2], rect["P1"][1, 2]
        tx = rect["P2"][0, 3] / rect["P2"][0, 0]
        rect["Q"] = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1 / tx, 0]])
    extra = dict(rig.extra, calibrated_size=list(rig.left.size))
    for key in ("doffs_px",):
        if key in extra:
            extra[key] = float(extra[key]) * sx
    return StereoRig(left, right, rig.R, rig.T, rect, rig.mounting, rig.rms_reprojection_px, extra)


def parse_size(text: str) -> tuple[int, int]:
    """``"640x400"`` -> (640, 400)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text or "")
    if not m or int(m.group(1)) <= 0 or int(m.group(2)) <= 0:
        raise InputError(f"size must be WIDTHxHEIGHT, e.g. 640x400, got {text!r}")
    return int(m.group(1)), int(m.group(2))
