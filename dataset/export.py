"""Export a sequence file to KITTI-style folders for other tools.

Layout written (one file per frame, in frame order, numbered ``0000000000``):
``image_02/data/*.png`` (left, RGB PNG), ``image_03/data/*.png`` (right, when stored),
``proj_depth/groundtruth/image_02/*.png`` (uint16 = round(depth * 256), 0 = unknown, as KITTI's
depth benchmark; depth beyond 255.996 m becomes 0 too, counted in ``calib.json``
``depth_beyond_range_px``), ``instances/*.png`` (uint16 instance ids, when stored),
``timestamps.txt`` (seconds, one per line, with the same number of decimals on every line: see
:func:`timestamp_lines`), ``calib_cam_to_cam.txt`` (``S_rect_02``,
``P_rect_02``, ``R_rect_00`` and, with a rig, ``P_rect_03``), ``calib.json`` (camera, rig,
mounting, camera height) and ``splits/{adapt,eval}.txt`` (frame numbers) and
``.staticdepth-export.json`` (marks the folder as ours). The folder appears atomically (built
beside it, then renamed); ``--overwrite`` replaces only a folder holding that marker, and only
once the new export is complete.
"""
from __future__ import annotations

import json
import os
import shutil
from typing import Any, Callable

import numpy as np

from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError
from staticdepth.fileio import write_image
from staticdepth.progress import progress

EXPORT_FORMAT = "staticdepth.kitti-export/1"
DEPTH_SCALE = 256.0
MAX_DEPTH_M = 65535 / DEPTH_SCALE


def kitti_png_from_depth(depth: np.ndarray) -> tuple[np.ndarray, int]:
    """Depth (H, W) metres, NaN unknown -> uint16 ``round(d * 256)``, 0 unknown; also returns how
    many pixels were beyond the format's 255.996 m and were therefore written as unknown."""
    d = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    code = np.zeros(d.shape, np.float64)
    code[ok] = np.round(d[ok] * DEPTH_SCALE)
    code[ok & (code == 0)] = 1  # a tiny positive depth stays known
    far = code > 65535
    code[far] = 0
    return code.astype(np.uint16), int(np.count_nonzero(far))


def beyond_range_note(pixels: int) -> str:
    """What the export lost, in words (``pixels`` from :func:`kitti_png_from_depth`)."""
    return (f"{pixels} depth pixel(s) beyond {MAX_DEPTH_M:.3f} m (the limit of KITTI's uint16 "
            f"PNG, depth x {DEPTH_SCALE:g}) are stored as 0 (unknown)")


def timestamp_decimals(times: np.ndarray) -> int:
    """Decimals that every one of ``times`` (float64 seconds) holds: 9 (nanoseconds), fewer
    where the largest time leaves float64 coarser steps (epoch seconds, as KITTI's, step 2.4e-7:
    6, microseconds), so that no digit written is float noise."""
    t = np.abs(np.asarray(times, np.float64))
    t = t[np.isfinite(t)]
    step = float(np.spacing(t.max())) if t.size else 0.0
    return 9 if step == 0 else int(np.clip(np.floor(-np.log10(2 * step)), 0, 9))


def timestamp_lines(times: np.ndarray) -> list[str]:
    """``times`` as the lines of ``timestamps.txt``: fixed point, :func:`timestamp_decimals`
    decimals on every line (KITTI's 13:02:25.964389445, stored as 1317042145.9643893 epoch
    seconds, is ``1317042145.964389``, not ``.964389324``; 0.3 s at 10 fps is ``0.300000000``)."""
    d = timestamp_decimals(times)
    return [f"{float(t):.{d}f}\n" for t in times]


MARKER = ".staticdepth-export.json"  # written into every export: what --overwrite may replace


def is_export(path: str) -> bool:
    """A KITTI-style export written by this toolkit (it holds our marker file)."""
    try:
        with open(os.path.join(path, MARKER)) as f:
            return json.load(f).get("format") == EXPORT_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def check_replaceable(out: str, overwrite: bool, ours: Callable[[str], bool], what: str) -> None:
    """Refuse (one line, ``out`` untouched) unless ``out`` is absent, or ``overwrite`` is given and
    ``out`` is a folder of our own kind (``ours``)."""
    if not os.path.lexists(out):
        return
    if not overwrite:
        raise InputError("exists already; pass --overwrite to replace it", out)
    if os.path.islink(out) or not os.path.isdir(out) or not ours(out):
        raise InputError(f"exists and is not {what}; --overwrite replaces only that, so it is "
                         "left untouched (move it away yourself)", out)


def replace_dir(tmp: str, out: str, overwrite: bool, ours: Callable[[str], bool] = is_export,
                what: str = "a staticdepth export") -> None:
    """Move the finished folder ``tmp`` onto ``out`` (replacing ``out`` only with ``overwrite``
    and only when it is of our own kind)."""
    from staticdepth.fileio import os_error, temporary_path

    check_replaceable(out, overwrite, ours, what)
    try:
        if os.path.lexists(out):
            old = temporary_path(out, "old")
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except OSError as e:
        raise os_error(e, out) from None


def _calib_txt(reader: SequenceReader) -> str:
    cam = reader.camera
    P2 = np.c_[cam.K, np.zeros(3)]
    lines = [f"S_rect_02: {cam.width:e} {cam.height:e}",
             "R_rect_00: " + " ".join(f"{x:e}" for x in np.eye(3).ravel()),
             "P_rect_02: " + " ".join(f"{x:e}" for x in P2.ravel())]
    rig = reader.meta.rig
    if rig is not None:
        P3 = P2.copy()
        P3[0, 3] = -cam.fx * rig.baseline_m
        lines.append("P_rect_03: " + " ".join(f"{x:e}" for x in P3.ravel()))
    return "\n".join(lines) + "\n"


def export_kitti(seq: str | os.PathLike, out: str | os.PathLike, *, overwrite: bool = False
                 ) -> dict[str, Any]:
    """Write ``seq`` as KITTI-style folders under ``out``; returns a summary dict."""
    from staticdepth.fileio import exclusive_lock

    out = os.fspath(out)
    check_replaceable(out, overwrite, is_export, "a staticdepth export")
    with exclusive_lock(out, what="writing"):
        return _export(seq, out, overwrite)


def _export(seq, out: str, overwrite: bool) -> dict[str, Any]:
    from staticdepth.fileio import os_error, remove_stale_temporaries, temporary_path

    remove_stale_temporaries(out)
    tmp = temporary_path(out, "export")
    far_total = 0
    try:
        with SequenceReader(seq) as r:
            dirs = {"left": "image_02/data", "right": "image_03/data",
                    "depth": "proj_depth/groundtruth/image_02", "instances": "instances"}
            streams = [s for s in dirs if r.has(s)]
            for s in streams:
                os.makedirs(os.path.join(tmp, dirs[s]))
            for i in progress(range(len(r)), total=len(r), desc="export", unit="frame"):
                name = f"{i:010d}.png"
                for s in streams:
                    a = r.read(s, i)
                    if s == "depth":
                        a, far = kitti_png_from_depth(a)
                        far_total += far
                    # inside the export's temporary folder, renamed (and synced) as a whole
                    write_image(os.path.join(tmp, dirs[s], name), a, fsync=False)
            times = r.timestamps()
            with open(os.path.join(tmp, "timestamps.txt"), "w") as f:
                f.writelines(timestamp_lines(times))
            with open(os.path.join(tmp, "calib_cam_to_cam.txt"), "w") as f:
                f.write(_calib_txt(r))
            m = r.meta
            calib = {"name": m.name, "camera": m.camera.to_dict(),
                     "rig": None if m.rig is None else m.rig.to_dict(),
                     "mounting": None if m.mounting is None else m.mounting.to_dict(),
                     "camera_height_m": m.camera_height_m, "depth_png_scale": DEPTH_SCALE,
                     "frames": len(r), "adapt_frames": m.adapt_frames, "gt_kind": m.gt_kind,
                     "source_file": os.path.basename(os.fspath(seq)),
                     "depth_beyond_range_px": far_total,
                     "timestamp_decimals": timestamp_decimals(times)}
            with open(os.path.join(tmp, "calib.json"), "w") as f:
                json.dump(calib, f, indent=2)
            os.makedirs(os.path.join(tmp, "splits"))
            for split in ("adapt", "eval"):
                with open(os.path.join(tmp, "splits", f"{split}.txt"), "w") as f:
                    f.writelines(f"{i:010d}\n" for i in r.split(split))
            n = len(r)
            with open(os.path.join(tmp, MARKER), "w") as f:
                json.dump({"format": EXPORT_FORMAT, "source_file": calib["source_file"]}, f)
        replace_dir(tmp, out, overwrite)
    except OSError as e:
        raise os_error(e, out) from None
    finally:
        if os.path.exists(tmp):
            shutil.rmtree(tmp)
    return {"path": out, "frames": n, "streams": streams, "depth_beyond_range_px": far_total}
