"""KITTI raw: calibration as a frozen record, LiDAR to camera-2 depth, and the sequence importer.

Layout read (KITTI raw, synced):
``<root>/<date>/calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``,
``<root>/<date>/<drive>_sync/image_02/data/NNNNNNNNNN.png`` (+ ``image_02/timestamps.txt``),
``velodyne_points/data/NNNNNNNNNN.bin`` (float32 x, y, z, reflectance), optional ``image_03``.
Depth (METHOD.md section 8): ``P = P_rect_02 . R_rect_00 (4x4) . [R|T]_cam0_from_velo``; keep points
with x_velo > 0 (and a positive camera depth); ``u, v = round(.) - 1``; in bounds; nearest point per
pixel; NaN = unknown. The official depth-completion maps (uint16 PNG / 256, 0 = unknown) replace the
projection when given (``depth_maps``: a root holding
``**/<drive>_sync/proj_depth/groundtruth/image_02``). Those maps leave out the first and last
``DEPTH_MAP_END_FRAMES`` frames of every drive: such frames are imported with unknown depth, counted
and listed (``frames_without_depth_map``); a map missing elsewhere is a bad frame, like a missing
scan or ``image_03`` image (an error naming the file; ``skip_bad`` skips and lists the frame).
"""
from __future__ import annotations

import glob
import os
import re
from dataclasses import dataclass
from typing import Any, Sequence

import cv2
import numpy as np

from staticdepth.dataset.h5 import SequenceMeta
from staticdepth.dataset.pack import (LoadedFrame, list_frames, name_from_output, read_image,
                                      read_left_right, read_rgb)
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig

KITTI_CAMERA_HEIGHT_M = 1.65
DEPTH_MAP_END_FRAMES = 5  # the official depth-completion maps omit this many at each drive end


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def read_calib_file(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """``key: v1 v2 ...`` lines into arrays; non-numeric values (``calib_time``) are skipped."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("calibration file not found", path)
    out: dict[str, np.ndarray] = {}
    with open(path) as f:
        for line in f:
            key, sep, value = line.partition(":")
            if not sep:
                continue
            try:
                out[key.strip()] = np.array([float(x) for x in value.split()])
            except ValueError:
                continue
    return out


def _need(d: dict[str, np.ndarray], key: str, size: int, path: str) -> np.ndarray:
    if key not in d:
        raise InputError(f"calibration has no {key!r}", path)
    if d[key].size != size:
        raise InputError(f"{key!r} has {d[key].size} values, expected {size}", path)
    return d[key]


@dataclass(frozen=True, eq=False)
class KittiCalib:
    """One recording day's calibration (pykitti's idea: frame-named, immutable).

    ``P_rect_02``/``P_rect_03``: 3x4 projections of the rectified colour cameras (from rectified
    camera 0 coordinates); ``R_rect_00``: 3x3 rectifying rotation of camera 0; ``cam0_from_velo``:
    4x4 pose of the LiDAR in (unrectified) camera 0; ``size_rect``: (width, height) of the
    rectified images.
    """

    P_rect_02: np.ndarray
    P_rect_03: np.ndarray
    R_rect_00: np.ndarray
    cam0_from_velo: np.ndarray
    size_rect: tuple[int, int]
    source: str = ""

    @classmethod
    def load(cls, date_dir: str | os.PathLike) -> "KittiCalib":
        date_dir = os.fspath(date_dir)
        p_cam = os.path.join(date_dir, "calib_cam_to_cam.txt")
        p_velo = os.path.join(date_dir, "calib_velo_to_cam.txt")
        cam, velo = read_calib_file(p_cam), read_calib_file(p_velo)
        T = np.eye(4)
        T[:3, :3] = _need(velo, "R", 9, p_velo).reshape(3, 3)
        T[:3, 3] = _need(velo, "T", 3, p_velo)
        size = _need(cam, "S_rect_02", 2, p_cam)
        return cls(P_rect_02=_readonly(_need(cam, "P_rect_02", 12, p_cam).reshape(3, 4)),
                   P_rect_03=_readonly(_need(cam, "P_rect_03", 12, p_cam).reshape(3, 4)),
                   R_rect_00=_readonly(_need(cam, "R_rect_00", 9, p_cam).reshape(3, 3)),
                   cam0_from_velo=_readonly(T), size_rect=(int(size[0]), int(size[1])),
                   source=date_dir)

    @property
    def img2_from_velo(self) -> np.ndarray:
        """3x4 projection of LiDAR points into rectified image 2 (third row: camera-2 depth)."""
        R4 = np.eye(4)
        R4[:3, :3] = self.R_rect_00
        return self.P_rect_02 @ R4 @ self.cam0_from_velo

    def camera(self, width: int | None = None, height: int | None = None) -> Camera:
        """Rectified camera 2 (intrinsics from ``P_rect_02``)."""
        w, h = self.size_rect
        return Camera(self.P_rect_02[:, :3], width or w, height or h)

    @property
    def baseline_m(self) -> float:
        """Distance between rectified cameras 2 and 3: ``(P02[0,3] - P03[0,3]) / fx``."""
        return float((self.P_rect_02[0, 3] - self.P_rect_03[0, 3]) / self.P_rect_02[0, 0])

    def rig(self, width: int | None = None, height: int | None = None) -> StereoRig:
        """The rectified colour pair (image_02 left, image_03 right)."""
        return StereoRig.rectified(self.camera(width, height), self.baseline_m,
                                   extra={"source": "KITTI P_rect_02/P_rect_03"})


def read_velodyne(path: str | os.PathLike) -> np.ndarray:
    """A scan as (N, 4) float32 (x, y, z, reflectance); a truncated file is an InputError."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("file not found", path)
    size = os.path.getsize(path)
    if size == 0 or size % 16:
        raise InputError(f"truncated scan: {size} bytes is not a whole number of 16-byte points",
                         path)
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)


def depth_from_lidar(points_velo: np.ndarray, img_from_velo: np.ndarray, width: int,
                     height: int) -> np.ndarray:
    """Sparse depth (height, width) float32 metres, NaN = no point, from LiDAR points (N, >=3).

    KITTI's convention: x_velo > 0, ``u, v = round(P X) - 1``, nearest point wins per pixel.
    """
    pts = np.asarray(points_velo, dtype=np.float64)
    pts = pts[pts[:, 0] > 0]
    X = np.c_[pts[:, :3], np.ones(len(pts))]
    p = X @ np.asarray(img_from_velo, dtype=np.float64).T
    z = p[:, 2]
    front = z > 0
    p, z = p[front], z[front]
    u = np.round(p[:, 0] / z).astype(np.int64) - 1
    v = np.round(p[:, 1] / z).astype(np.int64) - 1
    ok = (u >= 0) & (v >= 0) & (u < width) & (v < height)
    u, v, z = u[ok], v[ok], z[ok]
    lin = v * width + u
    order = np.lexsort((z, lin))  # by pixel, nearest first within a pixel
    lin, z = lin[order], z[order]
    first = np.ones(len(lin), bool)
    first[1:] = lin[1:] != lin[:-1]
    depth = np.full(height * width, np.nan, np.float32)
    depth[lin[first]] = z[first]
    return depth.reshape(height, width)


def read_depth_png(path: str | os.PathLike) -> np.ndarray:
    """KITTI depth-completion map (uint16 PNG, depth * 256, 0 = unknown) as float32 metres.

    Unknown pixels are NaN.
    """
    a = read_image(path, flags=cv2.IMREAD_ANYDEPTH)
    if a.dtype != np.uint16:
        raise InputError(f"expected a 16-bit depth PNG, got {a.dtype}", path)
    d = a.astype(np.float32) / 256.0
    d[a == 0] = np.nan
    return d


def read_timestamps(path: str | os.PathLike) -> np.ndarray:
    """KITTI ``timestamps.txt`` (``YYYY-MM-DD hh:mm:ss.fffffffff`` per line) as float64 seconds."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("timestamps file not found", path)
    out = []
    with open(path) as f:
        for k, line in enumerate(f, 1):
            s = line.strip()
            if not s:
                continue
            try:
                out.append(np.datetime64(s.replace(" ", "T"), "ns").astype(np.int64) / 1e9)
            except ValueError:
                raise InputError(f"line {k}: not a timestamp: {s!r}", path) from None
    return np.array(out, dtype=np.float64)


# -- drives and the importer ---------------------------------------------------------------------
@dataclass(frozen=True)
class KittiTask:
    """Everything needed to load one frame (picklable; the loader is a pure function of it).

    ``scan`` and ``depth_png`` both None: a frame at a drive's end that the depth-completion maps
    leave out (depth unknown)."""

    image: str
    scan: str | None
    depth_png: str | None
    right: str | None
    timestamp: float
    img2_from_velo: np.ndarray
    size: tuple[int, int]


def drive_dir(root: str | os.PathLike, drive: str) -> str:
    """``<root>/<date>/<drive>_sync`` for a drive named ``2011_09_28_drive_0016``.

    The ``_sync`` suffix of the name is optional.
    """
    name = drive if drive.endswith("_sync") else drive + "_sync"
    if not re.match(r"\d{4}_\d{2}_\d{2}_", name):
        raise InputError(f"drive {drive!r} does not start with its recording date (KITTI raw "
                         "drives are <root>/YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync)",
                         os.fspath(root))
    d = os.path.join(os.fspath(root), name[:10], name)
    if not os.path.isdir(d):
        raise InputError("drive folder not found", d)
    return d


def _depth_map_dir(depth_root: str, drive_folder: str) -> str:
    name = os.path.basename(drive_folder)
    hits = sorted(glob.glob(os.path.join(depth_root, "**", name, "proj_depth", "groundtruth",
                                         "image_02"), recursive=True))
    if not hits:
        raise InputError(f"no depth-completion maps for {name} "
                         f"(expected **/{name}/proj_depth/groundtruth/image_02)", depth_root)
    return hits[0]


def drive_tasks(root: str | os.PathLike, drive: str, *, right: bool = False,
                depth_maps: str | None = None, skip_bad: bool = False
                ) -> tuple[list[KittiTask], list[str], KittiCalib]:
    """Tasks and labels (``<drive>/<frame>``) for every frame of one drive, in frame order.

    The image size is the first frame's; with ``skip_bad`` the first readable frame's.
    """
    d = drive_dir(root, drive)
    calib = KittiCalib.load(os.path.dirname(d))
    left_dir = os.path.join(d, "image_02", "data")
    stems = [os.path.splitext(n)[0] for n in list_frames(left_dir)]
    if not stems:
        raise InputError("drive has no frames", d)
    # The left images are the frames. A frame's right image or scan missing makes it a bad frame
    # (loading it names the file; skip_bad skips it); one without a left image is refused.
    if right:  # image_03/data must exist
        _check_frame_files(d, os.path.join("image_03", "data"), ".png", "right image", stems,
                           list_frames(os.path.join(d, "image_03", "data")))
    if depth_maps is None:
        scan_dir = os.path.join(d, "velodyne_points", "data")
        _check_frame_files(d, os.path.join("velodyne_points", "data"), ".bin", "LiDAR scan", stems,
                           list_frames(scan_dir, ".bin") if os.path.isdir(scan_dir) else [])
    ts_path = os.path.join(d, "image_02", "timestamps.txt")
    ts_all = read_timestamps(ts_path)
    if len(ts_all) != len(stems):
        raise InputError(f"{len(ts_all)} timestamps for {len(stems)} images", ts_path)
    ts = dict(zip(stems, ts_all))
    dm = None if depth_maps is None else _depth_map_dir(depth_maps, d)
    maps = set() if dm is None else {os.path.splitext(n)[0] for n in list_frames(dm)}
    end = DEPTH_MAP_END_FRAMES
    no_map = {s for k, s in enumerate(stems) if dm is not None and s not in maps
              and not end <= k < len(stems) - end}
    # The image size comes from the first frame; every frame is checked against it when loaded.
    first = _sample_images([os.path.join(left_dir, s + ".png") for s in stems], 1, skip_bad)[0]
    size = (first.shape[1], first.shape[0])
    P = calib.img2_from_velo
    tasks = [KittiTask(image=os.path.join(d, "image_02", "data", s + ".png"),
                       scan=None if dm else os.path.join(d, "velodyne_points", "data", s + ".bin"),
                       depth_png=None if dm is None or s in no_map else
                       os.path.join(dm, s + ".png"),
                       right=os.path.join(d, "image_03", "data", s + ".png") if right else None,
                       timestamp=float(ts[s]), img2_from_velo=P, size=size) for s in stems]
    return tasks, [f"{os.path.basename(d)}/{s}" for s in stems], calib


def _check_frame_files(drive: str, sub: str, ext: str, what: str, stems: Sequence[str],
                       names: Sequence[str]) -> None:
    """Refuse a per-frame stream (``names`` in ``drive/sub``) that is empty or holds a file
    without a left image; a frame without its file is left to loading (a bad frame)."""
    if not names:
        raise InputError(f"drive has no {what}s ({sub}/*{ext})", drive)
    extra = sorted({os.path.splitext(n)[0] for n in names} - set(stems))
    if extra:
        raise InputError(f"mismatched frame counts: {os.path.join(drive, sub)} has {len(extra)} "
                         f"{what}(s) without a left image (e.g. {extra[0]!r})", drive)


def _sample_images(paths: Sequence[str], n: int, skip_bad: bool) -> list[np.ndarray]:
    """Up to ``n`` images spread over ``paths`` (the first always among them). With ``skip_bad``
    an unreadable one is replaced by another readable image (its frame is skipped when the frames
    are written); without, its error stops the import."""
    spread = np.unique(np.linspace(0, len(paths) - 1, min(n, len(paths))).astype(int)).tolist()
    rest = sorted(set(range(len(paths))) - set(spread))
    images = []
    for i in spread + rest:
        if len(images) == len(spread):
            break
        try:
            images.append(read_rgb(paths[i]))
        except InputError:
            if not skip_bad:
                raise
    if not images:
        raise InputError("no readable image among the drive's frames", os.path.dirname(paths[0]))
    return images


def load_frame(task: KittiTask) -> LoadedFrame:
    """Image(s) and ground-truth depth of one frame (a pure function of the task)."""
    w, h = task.size
    arrays = read_left_right(task.image, task.right, (w, h), "the drive's first is")
    if task.depth_png is not None:
        if not os.path.exists(task.depth_png):
            raise InputError("depth-completion map not found (the official maps leave out only "
                             f"the first and last {DEPTH_MAP_END_FRAMES} frames of a drive)",
                             task.depth_png)
        depth = read_depth_png(task.depth_png)
        if depth.shape != (h, w):
            raise InputError(f"depth map is {depth.shape[1]}x{depth.shape[0]}, image {w}x{h}",
                             task.depth_png)
    elif task.scan is not None:
        depth = depth_from_lidar(read_velodyne(task.scan), task.img2_from_velo, w, h)
    else:  # a drive's end, which the depth-completion maps leave out: depth unknown
        depth = np.full((h, w), np.nan, np.float32)
    arrays["depth"] = depth
    return LoadedFrame(arrays=arrays, timestamp=task.timestamp)


def pose_difference(images_a: Sequence[np.ndarray], images_b: Sequence[np.ndarray]
                    ) -> dict[str, Any]:
    """How far apart two drives' views are: median images' mean absolute difference (grey levels,
    0-255) and their shift (px) by phase correlation. Moving objects vanish in the medians."""
    def med(imgs):
        g = [cv2.cvtColor(np.asarray(i), cv2.COLOR_RGB2GRAY) for i in imgs]
        return np.median(np.stack(g), axis=0).astype(np.float32)

    a, b = med(images_a), med(images_b)
    if a.shape != b.shape:
        return {"mean_abs_diff": float("inf"), "shift_px": None, "same_size": False}
    (dx, dy), _ = cv2.phaseCorrelate(a.astype(np.float64), b.astype(np.float64))
    return {"mean_abs_diff": float(np.mean(np.abs(a - b))), "shift_px": [float(dx), float(dy)],
            "same_size": True}


def import_kitti(root: str | os.PathLike, drives: Sequence[str], out: str | os.PathLike, *,
                 name: str | None = None, adapt_frames: int = 0, right: bool = False,
                 depth_maps: str | None = None, camera_height_m: float = KITTI_CAMERA_HEIGHT_M,
                 skip_bad: bool = False, resume: bool = False, overwrite: bool = False,
                 max_diff: float = 12.0, max_shift_px: float = 2.0, executor=None,
                 warn=print, restart: bool = False):
    """Concatenate ``drives`` (in order) into one sequence file; returns the write report.

    Grouped drives must share one camera pose: their median images are compared and ``warn``
    receives the measured difference when it exceeds ``max_diff`` grey levels or ``max_shift_px``.
    """
    from staticdepth.dataset.pack import write_frames

    if not drives:
        raise InputError("--drives needs at least one drive")
    names = [dv[:-len("_sync")] if dv.endswith("_sync") else dv for dv in drives]
    twice = [dv for k, dv in enumerate(names) if dv in names[:k]]
    if twice:
        raise InputError(f"drive {twice[0]} is listed twice in --drives (its frames would be "
                         "imported twice)", os.fspath(root))
    tasks, labels, checks, calib, per_drive = [], [], [], None, {}
    samples = {}
    for dv in drives:
        t, lab, calib_d = drive_tasks(root, dv, right=right, depth_maps=depth_maps,
                                      skip_bad=skip_bad)
        if calib is not None and not np.allclose(calib_d.P_rect_02, calib.P_rect_02):
            raise InputError(f"drive {dv} has a different camera calibration from {drives[0]}",
                             calib_d.source)
        calib = calib or calib_d
        tasks += t
        labels += lab
        per_drive[dv] = len(t)
        samples[dv] = _sample_images([task.image for task in t], 5, skip_bad)
    for a, b in zip(drives[:-1], drives[1:]):
        diff = pose_difference(samples[a], samples[b])
        moved = (not diff["same_size"] or diff["mean_abs_diff"] > max_diff
                 or np.hypot(*diff["shift_px"]) > max_shift_px)
        checks.append({"drives": [a, b], **diff, "same_pose": not moved})
        if moved:
            warn(f"warning: drives {a} and {b} may not share one camera pose: median images differ "
                 f"by {diff['mean_abs_diff']:.1f} grey levels, shift {diff['shift_px']} px")
    w, h = tasks[0].size
    if any(t.size != (w, h) for t in tasks):
        raise InputError("drives have different image sizes", root)
    no_map = [lab for t, lab in zip(tasks, labels) if depth_maps and t.depth_png is None]
    if no_map:
        warn(f"note: {len(no_map)} of {len(tasks)} frames have no depth-completion map (the "
             f"official maps leave out the first and last {DEPTH_MAP_END_FRAMES} frames of each "
             "drive): their depth is unknown (NaN); listed as frames_without_depth_map")
    meta = SequenceMeta(
        name=name or name_from_output(out), camera=calib.camera(w, h),
        gt_kind="lidar", source=f"KITTI raw: {', '.join(drives)}", adapt_frames=adapt_frames,
        rig=calib.rig(w, h) if right else None, camera_height_m=camera_height_m,
        provenance={"dataset": "KITTI raw", "root": os.fspath(root), "drives": list(drives),
                    "frames_per_drive": per_drive,
                    "ground_truth": "depth-completion maps" if depth_maps else
                    "LiDAR projected into camera 2 (nearest point per pixel)",
                    "depth_maps": depth_maps, "pose_check": checks,
                    **({"frames_without_depth_map": {"count": len(no_map), "frames": no_map}}
                       if depth_maps else {}),
                    "licence": "CC BY-NC-SA 3.0 (KITTI)"})
    streams = ("left", "right", "depth") if right else ("left", "depth")
    return write_frames(out, meta, streams, tasks, load_frame, labels=labels, skip_bad=skip_bad,
                        resume=resume, overwrite=overwrite, executor=executor, desc="import-kitti",
                        restart=restart)
