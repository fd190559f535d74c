"""``staticdepth observations``: the agents' observation table (``obs.csv``) that ``ground-plane``
reads, from a sequence file or a video.

Agents come from a detector: ``gt`` (a sequence's own instance maps and agent rows, the default
when it has them), ``motion`` (background subtraction, no weights, the default otherwise) or
``yolox`` (``--detector-model yolox_nano.onnx``). Detections are tracked and filtered by
:mod:`staticdepth.tracking` (the same functions ``adapt`` uses), so the CSV holds what the
ground-plane fit would see: per kept detection ``frame, track, class_id, foot_u, foot_v,
height_px, score, top_u, feet`` in pixels (OpenCV convention; foot = lowest silhouette point,
height = foot row - top row, both half a pixel beyond the extreme mask rows), then the images'
``image_width, image_height``.
"""
from __future__ import annotations

import argparse
import io
import os

import numpy as np

from staticdepth.errors import InputError

COLUMNS = ("frame", "track", "class_id", "foot_u", "foot_v", "height_px", "score", "top_u",
           "feet")
#: the size of the images the pixels were measured on, on every row: ``ground-plane`` fits the
#: intrinsics to it (scaled for a uniform resize, refused otherwise)
SIZE_COLUMNS = ("image_width", "image_height")
SPLITS = ("adapt", "eval", "all")


def observations_csv(obs: np.ndarray, size: tuple[int, int]) -> str:
    """The observation table (:data:`staticdepth.tracking.OBS_DTYPE`) as CSV text with a header,
    each row ending with the ``(width, height)`` of the images it was measured on."""
    buf = io.StringIO()
    buf.write(",".join(COLUMNS + SIZE_COLUMNS) + "\n")
    tail = f"{int(size[0])},{int(size[1])}"
    for r in obs:
        vals = []
        for c in COLUMNS:
            v = r[c]
            vals.append(str(int(v)) if c in ("frame", "track", "class_id", "feet")
                        else ("" if not np.isfinite(v) else f"{float(v):.3f}"))
        buf.write(",".join(vals) + "," + tail + "\n")
    return buf.getvalue()


def _tracked(frames, indices, model: str, min_height_px: float | None) -> np.ndarray:
    """Track the per-frame ``(instance map, rows)`` pairs of ``frames`` (an iterable, consumed
    one frame at a time) and number them with ``indices``, the input's frame numbers."""
    from staticdepth import tracking

    extra = {} if min_height_px is None else {"min_height_px": min_height_px}
    conf = tracking.TrackingConfig.for_model(model, **extra)
    obs = tracking.observations_from_instances(frames, conf)
    obs["frame"] = np.asarray(indices)[obs["frame"]]       # back to the input's frame numbers
    return obs


def _detect(detector: str, images, model: str | None):
    """The detector's ``(instance map, rows)`` per frame of ``images`` (a lazy ``Sequence``:
    :class:`staticdepth.detectors.frames.SequenceFrames`,
    :class:`staticdepth.dataset.video.VideoFrames`), yielded one frame at a time, with a
    progress bar."""
    from staticdepth.detectors import make_detector
    from staticdepth.progress import progress

    if detector == "yolox" and not model:
        raise InputError("--detector yolox needs --detector-model yolox_nano.onnx")
    opts = {"model": model} if detector in ("yolox", "mask2former") else {}
    return progress(make_detector(detector, **opts).detect_sequence(images), total=len(images),
                    desc=detector, unit="frame")


def from_sequence(path: str, *, detector: str | None = None, split: str = "adapt",
                  detector_model: str | None = None, model: str = "exact",
                  min_height_px: float | None = None) -> tuple[np.ndarray, dict]:
    """(observations, camera dict) of a sequence file's ``split`` frames, read one at a time."""
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.detectors.frames import SequenceFrames

    with SequenceReader(path) as r:
        indices = list(range(len(r))) if split == "all" else list(r.split(split))
        if not indices:
            raise InputError(f"the {split!r} split is empty", path)
        detector = detector or ("gt" if r.has("instances") else "motion")
        if detector == "gt":
            if not r.has("instances"):
                raise InputError("--detector gt needs the sequence's 'instances' stream; use "
                                 "--detector motion or yolox", path)
            frames = ((r.instances(i), r.agents(i)) for i in indices)
        else:
            frames = _detect(detector, SequenceFrames(r, indices), detector_model)
        obs = _tracked(frames, indices, model, min_height_px)
        camera = r.meta.camera.to_dict()
    return obs, {"detector": detector, **camera}


def from_video(path: str, *, detector: str = "motion", detector_model: str | None = None,
               start: int = 0, max_frames: int = 300, step: int = 1, model: str = "exact",
               min_height_px: float | None = None) -> tuple[np.ndarray, dict]:
    """(observations, info) of up to ``max_frames`` frames of a video, every ``step``-th, read one
    at a time (:class:`staticdepth.dataset.video.VideoFrames`)."""
    from staticdepth.dataset.video import VideoFrames

    if detector == "gt":
        raise InputError("a video has no ground-truth instances: use --detector motion or yolox",
                         path)
    if max_frames < 3 or step < 1 or start < 0:
        raise InputError("--max-frames must be >= 3, --step >= 1 and --start >= 0")
    images = VideoFrames(path, start, step, max_frames)
    try:
        if len(images) < 3:
            raise InputError(f"only {len(images)} frames read from the video", path)
        h, w = images[0].shape[:2]
        indices = [images.source_index(i) for i in range(len(images))]
        obs = _tracked(_detect(detector, images, detector_model), indices, model, min_height_px)
    finally:
        images.close()
    return obs, {"detector": detector, "width": w, "height": h}


def register(sub) -> None:
    from staticdepth.cli import add_overwrite_argument

    p = sub.add_parser("observations", help="agents' foot points and heights (obs.csv) for "
                                            "ground-plane",
                       description="Detect and track the agents of a sequence file or a video and "
                                   "write the observation CSV that `staticdepth ground-plane` "
                                   "reads (frame, track, class_id, foot_u, foot_v, height_px, "
                                   "score, top_u, feet; pixels; image_width, image_height: the "
                                   "size of the images they were measured on).")
    p.add_argument("input", help="sequence file (.h5) or video (.avi, .mp4, ...)")
    p.add_argument("--out", required=True, help="observation CSV to write")
    p.add_argument("--detector", choices=("gt", "motion", "yolox", "mask2former"),
                   help="agent detector (default: gt for a sequence with instance maps, else "
                        "motion)")
    p.add_argument("--detector-model", help="detector weights (yolox: an ONNX file)")
    p.add_argument("--split", choices=SPLITS, default="adapt",
                   help="sequence frames to use (the paper fits the plane on the adapt split)")
    p.add_argument("--start", type=int, help="video: first frame (default 0)")
    p.add_argument("--max-frames", type=int, help="video: most frames to read (default 300)")
    p.add_argument("--step", type=int, help="video: use every N-th frame (default 1)")
    p.add_argument("--model", choices=("exact", "paper", "affine"), default="exact",
                   help="the ground-plane model the tracks are filtered for (paper/affine drop "
                        "straight walkers)")
    p.add_argument("--min-height-px", type=float,
                   help="drop agents shorter than this many pixels (default: tracking's 20)")
    p.add_argument("--camera-out", help="sequence: also write its camera (fx, fy, cx, cy) as "
                                        "JSON for ground-plane --intrinsics")
    add_overwrite_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from staticdepth.cli import refuse_existing
    from staticdepth.config import check_ranges
    from staticdepth.fileio import IMAGE_EXTS, VIDEO_EXTS, atomic_write_text
    from staticdepth.stereo.io import is_video

    refuse_existing(args.out, args.camera_out, overwrite=args.overwrite)
    check_ranges(args, "", {"min_height_px": ">=0"}, options=True)
    video_only = [o for o, v in (("--start", args.start), ("--max-frames", args.max_frames),
                                 ("--step", args.step)) if v is not None]
    common = {"detector_model": args.detector_model, "model": args.model,
              "min_height_px": args.min_height_px}
    if is_video(args.input):
        if args.camera_out:
            raise InputError("--camera-out needs a sequence file (a video has no intrinsics)")
        obs, info = from_video(args.input, detector=args.detector or "motion",
                               start=0 if args.start is None else args.start,
                               max_frames=300 if args.max_frames is None else args.max_frames,
                               step=1 if args.step is None else args.step, **common)
    elif os.path.isfile(args.input):
        if args.input.lower().endswith(IMAGE_EXTS):
            raise InputError("an image: observations reads a sequence file (.h5) or a video "
                             f"({', '.join(VIDEO_EXTS)}); import a folder of frames with "
                             "import-video first", args.input)
        if video_only:
            raise InputError(f"{', '.join(video_only)}: for a video only (a sequence's frames "
                             f"are chosen with --split)", args.input)
        obs, info = from_sequence(args.input, detector=args.detector, split=args.split, **common)
        if args.camera_out:
            cam = {k: info[k] for k in ("width", "height", "fx", "fy", "cx", "cy")}
            atomic_write_text(args.camera_out, json.dumps(cam, indent=2))
    else:
        raise InputError("file not found (expected a sequence file or a video)", args.input)
    if len(obs) == 0:
        raise InputError(f"no agent was tracked ({info['detector']} detector): nothing to write",
                         args.input)
    atomic_write_text(args.out, observations_csv(obs, (info["width"], info["height"])))
    print(f"{len(obs)} observations of {len(np.unique(obs['track']))} tracks "
          f"({info['detector']} detector) -> {args.out}")
    return 0
