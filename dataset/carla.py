"""CARLA exports: decode CARLA's depth and instance encodings and import a folder of frames.

Layout (frames saved by the usual sensor callbacks, ``image.save_to_disk``):
``rgb/NNNNNN.png``; ``depth/NNNNNN.png`` (depth = (R + 256 G + 65536 B) / (256^3 - 1) * 1000 m);
``instance/NNNNNN.png`` (0.9.14+: semantic tag in R, instance id = G + 256 B); optional
``right/NNNNNN.png``; optional ``timestamps.csv`` (``frame,timestamp_s``); ``sensor.json`` with the
blueprint attributes ``image_size_x``, ``image_size_y``, ``fov`` (degrees), optional
``sensor_tick`` (s) or ``fps`` (timestamp = frame number x period; else the frame number) and
``baseline_m``, and ``transform.location.{x,y,z}`` (m, ground at z = 0),
``transform.rotation.{pitch,yaw,roll}`` (degrees, Unreal: negative pitch looks down).
The rgb images are the frames: a frame whose depth, instance or right image is missing is a bad
frame (an error naming the file; ``skip_bad`` skips and lists the frame).

Camera: f = W / (2 tan(fov/2)), principal point at the image centre. Mounting: height = location.z,
ground normal from Unreal's rotation matrix, equal to
``Mounting.from_pitch_roll(z, -pitch, -roll)``.
Depth at CARLA's far plane (sky, 1000 m) is stored as NaN.
"""
from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from typing import Any, Mapping

import cv2
import numpy as np

from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta
from staticdepth.dataset.pack import (AuxStream, LoadedFrame, list_frames, name_from_output,
                                      read_image, read_left_right, write_frames)
from staticdepth.errors import InputError
from staticdepth.geometry.camera import (Camera, Mounting, StereoRig, check_camera_height,
                                         read_json)

FAR_PLANE_M = 1000.0
_DEPTH_SCALE = FAR_PLANE_M / (256.0 ** 3 - 1.0)

# Semantic tag -> COCO class of the agent (a rider is stored as a person, riding).
AGENT_TAGS = {12: schema.COCO["person"], 13: schema.COCO["person"], 14: schema.COCO["car"],
              15: schema.COCO["truck"], 16: schema.COCO["bus"], 18: schema.COCO["motorcycle"],
              19: schema.COCO["bicycle"]}
AGENT_TAGS_LEGACY = {4: schema.COCO["person"], 10: schema.COCO["car"]}  # before 0.9.14
# Ground: Road, Sidewalk, Terrain, RoadLine, Ground (0.9.14+); RoadLine, Road, Sidewalk, Ground,
# Terrain in the older numbering.
GROUND_TAGS = frozenset({1, 2, 10, 24, 25})
GROUND_TAGS_LEGACY = frozenset({6, 7, 8, 14, 22})
TAG_CHECK_FRAMES = 20  # instance images sampled to check that --legacy-tags fits the data


# -- encodings (pure) ---------------------------------------------------------------------------
def depth_from_carla_rgb(rgb: np.ndarray) -> np.ndarray:
    """CARLA depth image (H, W, 3) RGB uint8 -> depth (H, W) float32 metres; far plane -> NaN."""
    c = np.asarray(rgb).astype(np.float64)
    depth = (c[..., 0] + 256.0 * c[..., 1] + 65536.0 * c[..., 2]) * _DEPTH_SCALE
    out = depth.astype(np.float32)
    out[depth >= FAR_PLANE_M * (1 - 1e-6)] = np.nan
    return out


def carla_rgb_from_depth(depth: np.ndarray) -> np.ndarray:
    """Inverse of :func:`depth_from_carla_rgb` (nearest code); NaN and >= 1000 m -> far plane."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=FAR_PLANE_M)
    code = np.clip(np.round(d / _DEPTH_SCALE), 0, 256 ** 3 - 1).astype(np.int64)
    return np.stack([code & 255, (code >> 8) & 255, code >> 16], axis=-1).astype(np.uint8)


def tags_ids_from_instance_rgb(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CARLA 0.9.14+ instance image (H, W, 3) RGB -> semantic tags uint8, instance ids uint16."""
    a = np.asarray(rgb)
    ids = a[..., 1].astype(np.uint16) + (a[..., 2].astype(np.uint16) << 8)
    return a[..., 0].copy(), ids


def instance_rgb_from_tags_ids(tags: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Inverse of :func:`tags_ids_from_instance_rgb`."""
    ids = np.asarray(ids, dtype=np.uint16)
    return np.stack([np.asarray(tags, np.uint8), (ids & 255).astype(np.uint8),
                     (ids >> 8).astype(np.uint8)], axis=-1)


def agents_from_masks(tags: np.ndarray, ids: np.ndarray, agent_tags: Mapping[int, int]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Instance map (agents only, 0 elsewhere) and AGENT_DTYPE rows measured on each mask.

    foot_v = lowest mask row, foot_u = median column of that row, top_v = highest row; the class is
    the most frequent agent tag under the mask; track_id = CARLA's instance (actor) id.
    """
    is_agent = np.isin(tags, list(agent_tags))
    inst = np.where(is_agent, ids, 0).astype(np.uint16)
    vs, us = np.nonzero(is_agent)
    found = np.unique(inst[vs, us])
    found = found[found > 0]
    rows = schema.empty_agents(len(found))
    for k, i in enumerate(found):
        sel = inst[vs, us] == i
        v, u = vs[sel], us[sel]
        t, n = np.unique(tags[v, u], return_counts=True)
        bottom = v.max()
        rows[k]["instance_id"] = i
        rows[k]["track_id"] = int(i)
        rows[k]["class_id"] = agent_tags[int(t[np.argmax(n)])]
        rows[k]["foot_v"] = bottom
        rows[k]["foot_u"] = np.median(u[v == bottom])
        rows[k]["top_v"] = v.min()
        rows[k]["top_u"] = np.median(u[v == v.min()])
    return inst, rows


def ue_rotation(pitch_deg: float, yaw_deg: float, roll_deg: float) -> np.ndarray:
    """Unreal's FRotationMatrix: rows are the actor's forward (X), right (Y), up (Z) world axes."""
    p, y, r = (math.radians(a) for a in (pitch_deg, yaw_deg, roll_deg))
    sp, cp, sy, cy = math.sin(p), math.cos(p), math.sin(y), math.cos(y)
    sr, cr = math.sin(r), math.cos(r)
    return np.array([[cp * cy, cp * sy, sp],
                     [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, -sr * cp],
                     [-(cr * sp * cy + sr * sy), cy * sr - cr * sp * sy, cr * cp]])


def mounting_from_transform(z_m: float, pitch_deg: float, yaw_deg: float, roll_deg: float
                            ) -> Mounting:
    """Ground plane (z = 0) in the OpenCV camera frame of a CARLA camera at height ``z_m``."""
    fwd, right, up = ue_rotation(pitch_deg, yaw_deg, roll_deg)
    down_w = np.array([0.0, 0.0, -1.0])
    n = np.array([right @ down_w, -up @ down_w, fwd @ down_w])  # OpenCV: x right, y down, z fwd
    return Mounting(float(z_m), n, source="CARLA transform")


# -- the importer -------------------------------------------------------------------------------
@dataclass(frozen=True)
class CarlaSensor:
    """``sensor.json``: camera, mounting and optional stereo baseline and capture period."""

    camera: Camera
    mounting: Mounting
    baseline_m: float | None
    sensor_tick_s: float | None
    raw: Mapping[str, Any]

    @classmethod
    def load(cls, path: str | os.PathLike) -> "CarlaSensor":
        d = read_json(path)
        try:
            w, h, fov = int(d["image_size_x"]), int(d["image_size_y"]), float(d["fov"])
            loc, rot = d["transform"]["location"], d["transform"]["rotation"]
            z, pitch = float(loc["z"]), float(rot["pitch"])
            yaw, roll = float(rot.get("yaw", 0.0)), float(rot.get("roll", 0.0))
        except KeyError as e:
            raise InputError(f"sensor.json is missing {e.args[0]!r}", path) from None
        except (TypeError, ValueError) as e:
            raise InputError(f"sensor.json is malformed: {e}", path) from None
        if not 0 < fov < 180:
            raise InputError(f"fov must be within (0, 180) degrees, got {fov}", path)
        check_camera_height(z, "the camera height transform.location.z", path)
        base = d.get("baseline_m")
        tick = d.get("sensor_tick")
        if tick in (None, "", 0, "0", "0.0") and d.get("fps"):
            tick = 1.0 / float(d["fps"])
        try:
            cam = Camera.from_fov(w, h, fov)
        except InputError as e:
            raise InputError(e.problem, path) from None
        return cls(cam, mounting_from_transform(z, pitch, yaw, roll),
                   None if base is None else float(base),
                   float(tick) if tick not in (None, "", 0, "0", "0.0") else None, d)


@dataclass(frozen=True)
class CarlaTask:
    rgb: str
    depth: str
    instance: str
    right: str | None
    timestamp: float
    size: tuple[int, int]
    legacy_tags: bool


def _read_coded(path: str, size: tuple[int, int]) -> np.ndarray:
    a = read_image(path, flags=cv2.IMREAD_COLOR)  # BGR, alpha dropped
    if a.dtype != np.uint8 or (a.shape[1], a.shape[0]) != size:
        raise InputError(f"expected a {size[0]}x{size[1]} 8-bit image (sensor.json), got "
                         f"{a.shape[1]}x{a.shape[0]} {a.dtype}", path)
    return a[..., ::-1]


def load_frame(task: CarlaTask) -> LoadedFrame:
    """Images, depth, instance map, agents and ground mask of one frame (pure in the task)."""
    arrays = read_left_right(task.rgb, task.right, task.size, "sensor.json says")
    arrays["depth"] = depth_from_carla_rgb(_read_coded(task.depth, task.size))
    tags, ids = tags_ids_from_instance_rgb(_read_coded(task.instance, task.size))
    agent_tags = AGENT_TAGS_LEGACY if task.legacy_tags else AGENT_TAGS
    inst, agents = agents_from_masks(tags, ids, agent_tags)
    arrays["instances"] = inst
    ground = np.isin(tags, list(GROUND_TAGS_LEGACY if task.legacy_tags else GROUND_TAGS))
    return LoadedFrame(arrays=arrays, timestamp=task.timestamp, agents=agents,
                       aux={"ground": ground})


def _timestamps(folder: str, stems: list[str], tick: float | None) -> list[float]:
    path = os.path.join(folder, "timestamps.csv")
    if os.path.exists(path):
        table: dict[str, float] = {}
        with open(path, newline="") as f:
            for k, row in enumerate(csv.reader(f), 1):
                if not row or (k == 1 and not row[0].strip().lstrip("-").isdigit()):
                    continue
                try:
                    table[str(int(row[0]))] = float(row[1])
                except (ValueError, IndexError):
                    raise InputError(f"line {k}: expected 'frame,timestamp_s', got {row}",
                                     path) from None
        missing = [s for s in stems if str(int(s)) not in table]
        if missing:
            raise InputError(f"no timestamp for frame {missing[0]} ({len(missing)} missing)", path)
        return [table[str(int(s))] for s in stems]
    return [int(s) * (tick or 1.0) for s in stems]


def carla_tasks(folder: str | os.PathLike, *, legacy_tags: bool = False
                ) -> tuple[list[CarlaTask], list[str], CarlaSensor]:
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise InputError("is a file, not a CARLA export folder (rgb/, depth/, instance/, "
                         "sensor.json)" if os.path.exists(folder) else "folder not found", folder)
    sensor = CarlaSensor.load(os.path.join(folder, "sensor.json"))
    has_right = os.path.isdir(os.path.join(folder, "right"))
    stems = [os.path.splitext(n)[0] for n in list_frames(os.path.join(folder, "rgb"))]
    if not stems:
        raise InputError("no frames in rgb/", folder)
    bad = [s for s in stems if not s.isdigit()]
    if bad:
        raise InputError(f"frame names must be numbers (NNNNNN.png), got {bad[0]!r}", folder)
    stems.sort(key=int)
    # The rgb images are the frames. A frame's depth, instance or right image missing makes it a
    # bad frame (loading it names the file; skip_bad skips it); one without an rgb image is refused.
    for sub in ("depth", "instance") + (("right",) if has_right else ()):
        others = {os.path.splitext(n)[0] for n in list_frames(os.path.join(folder, sub))}
        if not others:
            raise InputError(f"no frames in {sub}/", folder)
        extra = sorted(others - set(stems))
        if extra:
            raise InputError(f"mismatched frame counts: {sub}/ has {len(extra)} image(s) without "
                             f"an rgb image (e.g. {extra[0]!r})", folder)
    ts = _timestamps(folder, stems, sensor.sensor_tick_s)
    size = sensor.camera.size
    tasks = [CarlaTask(*(os.path.join(folder, n, s + ".png") for n in ("rgb", "depth", "instance")),
                       right=os.path.join(folder, "right", s + ".png") if has_right else None,
                       timestamp=t, size=size, legacy_tags=legacy_tags) for s, t in zip(stems, ts)]
    return tasks, stems, sensor


def legacy_tags_check(tasks: list[CarlaTask], n: int = TAG_CHECK_FRAMES) -> dict[str, int]:
    """Agents that the pre-0.9.14 and the 0.9.14+ tag numberings find in up to ``n`` instance
    images spread over the frames (unreadable ones are left to the import to report)."""
    picks = np.unique(np.linspace(0, len(tasks) - 1, min(n, len(tasks))).astype(int))
    out = {"sampled_frames": 0, "agents_legacy": 0, "agents_current": 0}
    for i in picks:
        try:
            tags, ids = tags_ids_from_instance_rgb(_read_coded(tasks[i].instance, tasks[i].size))
        except InputError:
            continue
        out["sampled_frames"] += 1
        out["agents_legacy"] += len(agents_from_masks(tags, ids, AGENT_TAGS_LEGACY)[1])
        out["agents_current"] += len(agents_from_masks(tags, ids, AGENT_TAGS)[1])
    return out


def import_carla(folder: str | os.PathLike, out: str | os.PathLike, *, name: str | None = None,
                 adapt_frames: int = 0, legacy_tags: bool = False, skip_bad: bool = False,
                 resume: bool = False, overwrite: bool = False, executor=None,
                 restart: bool = False, warn=print):
    """Import a CARLA export folder into one sequence file; returns the write report.

    With ``legacy_tags``, ``warn`` receives one line when sampled frames hold agents in the
    0.9.14+ numbering and none in the pre-0.9.14 one (data from a newer CARLA: 0 agents)."""
    tasks, labels, sensor = carla_tasks(folder, legacy_tags=legacy_tags)
    tag_check = legacy_tags_check(tasks) if legacy_tags else None
    if tag_check and tag_check["agents_legacy"] == 0 and tag_check["agents_current"]:
        warn(f"warning: {os.fspath(folder)}: --legacy-tags (pre-0.9.14: Pedestrian 4, Vehicle "
             f"10) finds no agents in {tag_check['sampled_frames']} sampled frames, the 0.9.14+ "
             f"numbering finds {tag_check['agents_current']}: data from CARLA 0.9.14 or later "
             "needs no --legacy-tags")
    has_right = tasks[0].right is not None
    if has_right and sensor.baseline_m is None:
        raise InputError("right/ exists but sensor.json has no baseline_m",
                         os.path.join(os.fspath(folder), "sensor.json"))
    rig = StereoRig.rectified(sensor.camera, sensor.baseline_m) if has_right else None
    meta = SequenceMeta(
        name=name or name_from_output(out), camera=sensor.camera,
        gt_kind="synthetic", source=f"CARLA export: {os.fspath(folder)}", adapt_frames=adapt_frames,
        rig=rig, mounting=sensor.mounting,
        provenance={"dataset": "CARLA", "sensor": dict(sensor.raw),
                    "tag_numbering": "pre-0.9.14" if legacy_tags else "0.9.14+",
                    **({"legacy_tags_check": tag_check} if tag_check else {}),
                    "ground_tags": sorted(GROUND_TAGS_LEGACY if legacy_tags else GROUND_TAGS),
                    "ground_mask": "aux/ground", "far_plane_m": f"{FAR_PLANE_M} -> NaN"})
    streams = (("left", "right", "depth", "instances") if has_right
               else ("left", "depth", "instances"))
    return write_frames(out, meta, streams, tasks, load_frame, labels=labels, skip_bad=skip_bad,
                        resume=resume, overwrite=overwrite, aux=(AuxStream("ground"),),
                        executor=executor, desc="import-carla", restart=restart)


def write_carla_frame(folder: str | os.PathLike, index: int, rgb: np.ndarray, depth: np.ndarray,
                      tags: np.ndarray, ids: np.ndarray, right: np.ndarray | None = None) -> None:
    """Save one frame in the CARLA export encodings (the inverse of :func:`load_frame`)."""
    folder = os.fspath(folder)
    name = f"{index:06d}.png"
    images = {"rgb": rgb, "depth": carla_rgb_from_depth(depth),
              "instance": instance_rgb_from_tags_ids(tags, ids)}
    if right is not None:
        images["right"] = right
    from staticdepth.fileio import write_image

    for sub, img in images.items():
        os.makedirs(os.path.join(folder, sub), exist_ok=True)
        write_image(os.path.join(folder, sub, name), img)
