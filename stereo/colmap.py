"""Cameras in COLMAP's text format (``cameras.txt``).

COLMAP puts the top-left pixel's centre at (0.5, 0.5), OpenCV (and this toolkit) at (0, 0):
``cx_colmap = cx_opencv + 0.5`` (same for cy). Models read: SIMPLE_PINHOLE, PINHOLE,
SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV; written: PINHOLE (no distortion), OPENCV (k1 k2 p1 p2)
or FULL_OPENCV (OpenCV's rational model k1 k2 p1 p2 k3 k4 k5 k6: every rig ``calibrate`` writes has
a k3). Thin-prism or tilt terms (OpenCV's 12/14-coefficient models) have no COLMAP model.
"""
from __future__ import annotations

import os

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera

# model name -> number of parameters
MODELS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
          "FULL_OPENCV": 12}


def camera_to_colmap(camera: Camera) -> tuple[str, list[float]]:
    """(model, params) of a camera in COLMAP's pixel convention."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5
    dist = np.asarray(camera.dist, np.float64).ravel()
    if dist.size > 8 and np.any(dist[8:] != 0):
        raise InputError("COLMAP has no camera model with OpenCV's thin-prism/tilt distortion "
                         "terms (this camera has more than k1 k2 p1 p2 k3 k4 k5 k6)")
    d = np.zeros(8)
    d[:min(8, dist.size)] = dist[:8]
    if not np.any(d):
        return "PINHOLE", [fx, fy, cx, cy]
    if not np.any(d[4:]):
        return "OPENCV", [fx, fy, cx, cy, *d[:4]]
    return "FULL_OPENCV", [fx, fy, cx, cy, *d]


def camera_from_colmap(model: str, width: int, height: int, params, source: str | None = None
                       ) -> Camera:
    """A camera from COLMAP's (model, width, height, params)."""
    if model not in MODELS:
        raise InputError(f"unsupported COLMAP camera model {model!r} "
                         f"(supported: {', '.join(MODELS)})", source)
    p = [float(x) for x in params]
    if len(p) != MODELS[model]:
        raise InputError(f"COLMAP model {model} needs {MODELS[model]} parameters, got {len(p)}",
                         source)
    dist = np.zeros(5)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        if model != "SIMPLE_PINHOLE":
            dist[0] = p[3]
        if model == "RADIAL":
            dist[1] = p[4]
    else:
        fx, fy, cx, cy = p[:4]
        if model == "OPENCV":
            dist[:4] = p[4:8]
        elif model == "FULL_OPENCV":  # k1 k2 p1 p2 k3 k4 k5 k6 -> OpenCV's rational model
            dist = np.array([p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11]])
    return Camera.from_intrinsics(fx, fy, cx - 0.5, cy - 0.5, width, height, dist)


def write_cameras_txt(path: str | os.PathLike, cameras: dict[int, Camera]) -> None:
    """Write ``{camera_id: Camera}`` as COLMAP ``cameras.txt``."""
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(cameras)}"]
    for cid, cam in sorted(cameras.items()):
        model, params = camera_to_colmap(cam)
        lines.append(" ".join([str(cid), model, str(cam.width), str(cam.height)]
                              + [repr(float(x)) for x in params]))
    from staticdepth.fileio import atomic_write_text

    atomic_write_text(path, "\n".join(lines) + "\n")


def read_cameras_txt(path: str | os.PathLike) -> dict[int, Camera]:
    """Read COLMAP ``cameras.txt`` into ``{camera_id: Camera}`` (OpenCV pixel convention)."""
    path = os.fspath(path)
    try:
        with open(path) as f:
            text = f.read()
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    cams: dict[int, Camera] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            cid, model, w, h = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
        except (IndexError, ValueError):
            raise InputError(f"line {n}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...",
                             path) from None
        cams[cid] = camera_from_colmap(model, w, h, parts[4:], f"{path}:{n}")
    if not cams:
        raise InputError("no cameras in file", path)
    return cams
