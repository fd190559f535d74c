"""Write a synthetic sequence in the layout of a CARLA recording (for the CARLA importer's tests).

Layout of ``out_dir``::

    rgb/NNNNNN.png        left image
    right/NNNNNN.png      right image (optional)
    depth/NNNNNN.png      CARLA depth: depth_m = (R + 256 G + 65536 B) / (256^3 - 1) * 1000
    instance/NNNNNN.png   CARLA 0.9.14+ instance segmentation: R = semantic tag, id = G + 256 B
    sensor.json           blueprint attributes image_size_x, image_size_y, fov (horizontal, deg),
                          transform {location {x, y, z} m, rotation {pitch, yaw, roll} deg}

The transform is Unreal's: ground at z = 0, camera at z = camera height, negative pitch looks
down. Roll: ``rotation.roll = -roll_deg`` where the toolkit's positive roll raises the camera's
right side (``normal_from_pitch_roll``); the exact normal is also stored under ``staticdepth``.
PNG channels are written as CARLA has them (R really is red: OpenCV's BGR is reversed here).
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, Mounting

CARLA_MAX_DEPTH_M = 1000.0
_SCALE = 256 ** 3 - 1


def carla_depth_from_meters(depth_m: np.ndarray) -> np.ndarray:
    """Depth (H, W) metres, NaN/inf = sky -> CARLA's depth encoding (H, W, 3) uint8, RGB order."""
    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=CARLA_MAX_DEPTH_M,
                      posinf=CARLA_MAX_DEPTH_M)
    code = np.round(np.clip(d / CARLA_MAX_DEPTH_M, 0.0, 1.0) * _SCALE).astype(np.int64)
    return np.stack([code & 255, (code >> 8) & 255, (code >> 16) & 255], -1).astype(np.uint8)


def meters_from_carla_depth(rgb: np.ndarray) -> np.ndarray:
    """Inverse of :func:`carla_depth_from_meters` (RGB order in), float32 metres."""
    c = rgb.astype(np.float64)
    return ((c[..., 0] + 256.0 * c[..., 1] + 65536.0 * c[..., 2]) / _SCALE
            * CARLA_MAX_DEPTH_M).astype(np.float32)


def carla_instance_image(semantic: np.ndarray, instances: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB: R = semantic tag, G = id & 255, B = id >> 8."""
    ids = instances.astype(np.uint32)
    return np.stack([semantic.astype(np.uint8), (ids & 255).astype(np.uint8),
                     (ids >> 8).astype(np.uint8)], -1)


def _write_rgb(path: Path, rgb: np.ndarray) -> None:
    from staticdepth.fileio import write_image

    write_image(path, rgb)


def sensor_json(camera: Camera, mounting: Mounting, baseline_m: float | None,
                fps: float | None = None) -> dict[str, Any]:
    hfov = math.degrees(2.0 * math.atan(camera.width / (2.0 * camera.fx)))
    d: dict[str, Any] = {
        "image_size_x": camera.width, "image_size_y": camera.height, "fov": hfov,
        "transform": {"location": {"x": 0.0, "y": 0.0, "z": mounting.height_m},
                      "rotation": {"pitch": -mounting.pitch_deg, "yaw": 0.0,
                                   "roll": -mounting.roll_deg}},
        "staticdepth": {"camera": camera.to_dict(), "mounting": mounting.to_dict()},
    }
    if baseline_m is not None:
        d["baseline_m"] = float(baseline_m)
    if fps is not None:
        d["fps"] = float(fps)
    return d


def write_carla_export(scene_or_frames, out_dir: str | os.PathLike, n_frames: int | None = None,
                       start: int = 0, *, camera: Camera | None = None,
                       mounting: Mounting | None = None, baseline_m: float | None = None,
                       right: bool = True, overwrite: bool = False) -> Path:
    """Write frames of a :class:`SyntheticScene` (``n_frames`` from ``start``) or an iterable of
    frame dicts (``left``, ``depth``, ``instances``, ``semantic``, optional ``right``; then
    ``camera`` and ``mounting`` are required) as a CARLA-style folder. Returns ``out_dir``."""
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise InputError("output folder exists and is not empty (pass overwrite=True)", out)
    fps = None
    if hasattr(scene_or_frames, "render"):
        scene = scene_or_frames
        if n_frames is None or n_frames <= 0:
            raise InputError(f"n_frames must be positive, got {n_frames}")
        camera, mounting = scene.camera, scene.mounting
        baseline_m, fps = scene.rig.baseline_m, scene.config.fps
        frames: Iterable[Mapping[str, Any]] = scene.frames(n_frames, start)
    else:
        if camera is None or mounting is None:
            raise InputError("exporting frame dicts needs camera= and mounting=")
        frames = scene_or_frames
    dirs = ["rgb", "depth", "instance"] + (["right"] if right else [])
    for d in dirs:
        (out / d).mkdir(parents=True, exist_ok=True)
    count = 0
    for k, fr in enumerate(frames):
        if n_frames is not None and k >= n_frames:
            break
        if "semantic" not in fr:
            raise InputError(f"frame {k} has no 'semantic' tags; CARLA instance images need them")
        name = f"{int(fr.get('index', start + k)):06d}.png"
        _write_rgb(out / "rgb" / name, fr["left"])
        _write_rgb(out / "depth" / name, carla_depth_from_meters(fr["depth"]))
        _write_rgb(out / "instance" / name, carla_instance_image(fr["semantic"], fr["instances"]))
        if right and fr.get("right") is not None:
            _write_rgb(out / "right" / name, fr["right"])
        count += 1
    meta = sensor_json(camera, mounting, baseline_m, fps)
    meta["n_frames"] = count
    from staticdepth.fileio import atomic_write_json

    atomic_write_json(out / "sensor.json", meta)
    return out
