"""Import a video, an image folder or a camera URL into a sequence file (``staticdepth import-video``).

The step before ``adapt`` for a deployed camera: frames are streamed one at a time (a video or
stream through ``cv2.VideoCapture``, a folder image by image), never loaded whole, into a
sequence file with ``gt_kind = "none"`` (no ground truth) and the ``left`` stream only.

Intrinsics come from a camera or rig JSON (:func:`staticdepth.geometry.camera.load_camera`; scaled
when the frames are a uniformly resized version of the calibrated size) or, without one, from a
stated horizontal field-of-view guess (square pixels, principal point at the image centre). Which
of the two was used is recorded in the file's provenance (``intrinsics``) and returned, so that the
command prints it. Timestamps: the video's own position (``CAP_PROP_POS_MSEC``), else frame index /
fps; for a URL the wall clock since the first frame.

``--resume`` continues an interrupted import through the sequence writer's own resume path
(:mod:`staticdepth.dataset.resume`): the settings fingerprint holds the source file's size and
modification time and every setting that changes the frames; for an image folder each image is an
input identity (its path, size and time). The frames already written are passed over without
conversion (a video's are grabbed, which decodes them, not retrieved). A camera/stream URL
cannot be resumed: its frames are live, not the ones the partial holds.
"""
from __future__ import annotations

import glob
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from staticdepth.errors import InputError
from staticdepth.fileio import IMAGE_EXTS, sorted_frames
DEFAULT_FOV_DEG = 60.0


@dataclass(frozen=True)
class VideoFrame:
    index: int            # index in the source (before --every)
    timestamp: float      # seconds
    rgb: np.ndarray       # (H, W, 3) uint8


MAX_WIDTH = 16384     # px: wider frames are a typo (a sequence chunk holds one frame)


def is_url(source: str) -> bool:
    return "://" in source


def _to_rgb(img: np.ndarray, where: str) -> np.ndarray:
    if img is None:
        raise InputError("corrupt or unreadable frame", where)
    if img.dtype != np.uint8:
        raise InputError(f"expected 8-bit frames, got {img.dtype}", where)
    import cv2

    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if img.ndim == 3 and img.shape[2] in (3, 4):    # BGR(A) -> RGB; 40x numpy's strided copy
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGB)
    return np.ascontiguousarray(img[..., 2::-1])


def image_files(folder: str) -> list[str]:
    files = sorted_frames(f for f in glob.glob(os.path.join(glob.escape(folder), "*"))
                          if f.lower().endswith(IMAGE_EXTS) and os.path.isfile(f))
    if not files:
        raise InputError(f"no images ({', '.join(IMAGE_EXTS)}) in the folder", folder)
    return files


#: A video file whose frames end more than this share short of its header's count is reported
#: (containers' counts are estimates, a frame or two off; a truncated file stops far short).
SHORT_SHARE = 0.02


def iter_frames(source: str, *, every: int = 1, max_frames: int | None = None,
                fps: float | None = None, skip: int = 0,
                ended: dict | None = None) -> Iterator[VideoFrame]:
    """Yield every ``every``-th frame of a video file, a camera/stream URL or an image folder, at
    most ``max_frames`` of them, one at a time. ``fps`` sets the frame rate of a folder (default
    10) or overrides a video's. The first ``skip`` of those frames are passed over undecoded
    (they count towards ``max_frames``). When a video file's frames end, ``ended`` (a dict, if
    given) gets ``read`` (frames decoded) and ``header`` (the container's frame count, 0 when
    unknown), so that a caller can tell a truncated file from a complete one."""
    import cv2

    from staticdepth.dataset.pack import read_rgb

    if every < 1:
        raise InputError(f"--every must be >= 1, got {every}")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {max_frames}")
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise InputError(f"--fps must be a positive number, got {fps}")
    n_out = 0
    if os.path.isdir(source):
        rate = fps or 10.0
        for i, path in enumerate(image_files(source)):
            if i % every:
                continue
            if n_out < skip:
                n_out += 1
                continue
            yield VideoFrame(i, i / rate, read_rgb(path))
            n_out += 1
            if max_frames is not None and n_out >= max_frames:
                return
        return
    url = is_url(source)
    if not url and not os.path.isfile(source):
        raise InputError("no such video file, image folder or URL", source)
    cap = cv2.VideoCapture(source)
    if not cap.isOpened():
        raise InputError("cv2.VideoCapture cannot open it", source)
    try:
        rate = fps or cap.get(cv2.CAP_PROP_FPS) or 0.0
        if not (rate > 0 and math.isfinite(rate)):
            rate = 0.0
        t0 = time.monotonic()
        i = -1
        while True:
            ok = cap.grab()
            if not ok:
                if i < 0:
                    raise InputError("no frame could be read", source)
                if ended is not None and not url:
                    ended.update(read=i + 1, header=int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0))
                return
            i += 1
            if i % every:
                continue
            if n_out < skip:
                n_out += 1
                continue
            ok, img = cap.retrieve()
            if not ok:
                raise InputError(f"frame {i} cannot be decoded", source)
            if url:
                t = time.monotonic() - t0
            elif rate:
                t = i / rate
            else:
                t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            yield VideoFrame(i, float(t), _to_rgb(img, f"{source} frame {i}"))
            n_out += 1
            if max_frames is not None and n_out >= max_frames:
                return
    finally:
        cap.release()


class VideoFrames(Sequence):
    """Frames ``start``, ``start + step``, ... of the video file at ``path`` (RGB uint8), at most
    ``max_frames`` (None: to the end), read one at a time by index, for ``observations`` and
    ``stereo`` on videos (detectors index their input: the median background samples up to 50
    frames, then every frame is read in order). The length is the number of the video stream's
    packets, counted by demuxing alone (FFmpeg's raw mode: no decoding; a backend without it
    decodes to count), never the container's header count, which can be wrong. Reads grab
    (decode) forward through one open capture, converting only the frames asked for, and reopen
    it from ``start`` only when an index goes back (the last frame read is kept, so asking for
    it again costs nothing): a long video costs one frame of memory, and a read in order one
    decoding pass. ``source_index(i)``: frame ``i``'s index in the video."""

    def __init__(self, path: str, start: int = 0, step: int = 1, max_frames: int | None = None):
        self._cap = None         # the open capture, positioned at raw offset _next from start
        self._next = 0
        self._last: tuple[int, np.ndarray] | None = None     # (raw offset, BGR) of the last read
        if start < 0 or step < 1 or (max_frames is not None and max_frames < 1):
            raise InputError(f"need start >= 0, step >= 1 and max_frames >= 1 (got {start}, "
                             f"{step}, {max_frames})")
        self.path, self.start, self.step, self.max_frames = path, int(start), int(step), max_frames
        self._n = self._count()

    def _capture(self):
        import cv2

        cap = cv2.VideoCapture(self.path)
        if not cap.isOpened():
            raise InputError("cannot open video", self.path)
        if self.start:
            cap.set(cv2.CAP_PROP_POS_FRAMES, self.start)
        return cap

    def _count(self) -> int:
        """Frames this view holds: the packets up to the last frame it can use, read without
        decoding (raw mode), or grabbed (decoded, not converted) where the backend has no raw
        mode."""
        import cv2

        limit = None if self.max_frames is None else (self.max_frames - 1) * self.step + 1
        cap = cv2.VideoCapture(self.path)
        if not cap.isOpened():
            raise InputError("cannot open video", self.path)
        try:
            if cap.set(cv2.CAP_PROP_FORMAT, -1):          # packets as they are: demuxing only
                end = None if limit is None else self.start + limit
                packets = 0
                while (end is None or packets < end) and cap.grab():
                    packets += 1
                raw = max(0, packets - self.start)
            else:
                cap.release()
                cap, raw = self._capture(), 0
                while (limit is None or raw < limit) and cap.grab():
                    raw += 1
        finally:
            cap.release()
        return (raw + self.step - 1) // self.step

    def source_index(self, i: int) -> int:
        return self.start + int(i) * self.step

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        i = int(i)
        if not -self._n <= i < self._n:
            raise IndexError(i)
        want = (i % self._n) * self.step
        where = f"{self.path} frame {self.source_index(i)}"
        if self._last is not None and self._last[0] == want:
            return _to_rgb(self._last[1], where)       # a fresh array, as a decoded one is
        if self._cap is None or want < self._next:
            self.close()
            self._cap, self._next = self._capture(), 0
        while self._next <= want:
            if not self._cap.grab():
                self.close()
                raise InputError(f"frame {self.source_index(i)} could not be decoded (the video "
                                 f"holds fewer frames than the {self._n} packets counted)",
                                 self.path)
            self._next += 1
        ok, img = self._cap.retrieve()
        rgb = _to_rgb(img if ok else None, where)
        self._last = (want, img)
        return rgb

    def close(self) -> None:
        self._last = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __del__(self):
        self.close()


def camera_for(width: int, height: int, camera_json: str | None, fov_deg: float | None,
               native: tuple[int, int] | None = None):
    """(Camera, provenance text): the calibrated camera (scaled to the frame size) or a FOV guess.
    ``native``: the source's own frame size (before ``--width``); a camera calibrated at another
    size is scaled, and the text says so."""
    from staticdepth.geometry.camera import Camera, load_camera

    if camera_json and fov_deg is not None:
        raise InputError("give either --camera or --fov-deg, not both")
    if camera_json:
        calibrated = load_camera(camera_json)
        cam = calibrated.fitted_to(width, height, "the frames", camera_json)
        how = f"camera JSON {os.path.abspath(camera_json)}"
        w0, h0 = native or (width, height)
        if abs(calibrated.width - w0) > 1 or abs(calibrated.height - h0) > 1:
            how += (f", calibrated at {calibrated.width}x{calibrated.height}, the source is "
                    f"{w0}x{h0}: scaled (right for a resize of that image, not for a crop of the "
                    "sensor)")
        return cam, how
    fov = DEFAULT_FOV_DEG if fov_deg is None else float(fov_deg)
    if not 1.0 <= fov <= 179.0:
        raise InputError(f"--fov-deg must lie in [1, 179], got {fov}")
    cam = Camera.from_fov(width, height, fov)
    how = "given" if fov_deg is not None else "default"
    return cam, (f"GUESS: horizontal field of view {fov:g} deg ({how}; square pixels, principal "
                 f"point at the centre; f = {cam.fx:.1f} px)")


def import_video(source: str, out: str, *, camera_json: str | None = None,
                 fov_deg: float | None = None, every: int = 1, max_frames: int | None = None,
                 adapt_frames: int | None = None, width: int | None = None,
                 fps: float | None = None, name: str | None = None,
                 overwrite: bool = False, resume: bool = False, restart: bool = False) -> dict:
    """Stream ``source`` into the sequence file ``out``; returns a report dict (frames, size,
    intrinsics, adapt_frames, path, resumed_from). ``width`` resizes frames (aspect kept;
    intrinsics follow); ``adapt_frames`` None = every frame is in the adaptation split (clipped
    to the frames read). ``resume``/``restart``: continue or discard ``out.partial``."""
    import cv2

    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
    from staticdepth.fileio import exclusive_lock
    from staticdepth.progress import progress

    from staticdepth.dataset.schema import check_adapt_frames, check_name

    check_name(name)
    check_adapt_frames(adapt_frames, "all of them")
    if width is not None and not 16 <= width <= MAX_WIDTH:
        raise InputError(f"--width must lie in [16, {MAX_WIDTH}], got {width}")
    if resume and restart:
        raise InputError("give --resume or --restart, not both")
    if resume and is_url(source):
        raise InputError("a camera/stream URL cannot be resumed (its frames are live, not the "
                         "ones already written): --restart starts over", source)
    ended: dict = {}
    frames = iter_frames(source, every=every, max_frames=max_frames, fps=fps, ended=ended)
    first = next(frames)
    h0, w0 = first.rgb.shape[:2]
    size = (w0, h0) if width is None else (int(width), int(round(h0 * width / w0)))
    cam, how = camera_for(size[0], size[1], camera_json, fov_deg, native=(w0, h0))
    label = name or os.path.splitext(os.path.basename(source.rstrip("/")))[0] or "video"
    meta = SequenceMeta(name=label, camera=cam, gt_kind="none", source="video", adapt_frames=0,
                        provenance={"input": source, "intrinsics": how, "every": every,
                                    "max_frames": max_frames, "resized_from": [w0, h0]})
    settings, inputs, labels = _identity(source, every, max_frames, width, fps)
    with exclusive_lock(out):
        w = SequenceWriter(out, meta, streams=("left",), overwrite=overwrite, resume=resume,
                           restart=restart, settings=settings, inputs=inputs, labels=labels)
        try:
            done = len(w)
            if done:                   # resumed: read on after the frames the partial holds
                frames.close()
                frames = iter_frames(source, every=every, max_frames=max_frames, fps=fps,
                                     skip=done, ended=ended)
            else:
                frames = _chain(first, frames)
            total = None if max_frames is None else max_frames - done
            for fr in progress(frames, total=total, desc="import", unit="frame"):
                img = fr.rgb
                if img.shape[:2] != (h0, w0):
                    raise InputError(f"frame {fr.index} is {img.shape[1]}x{img.shape[0]}, the "
                                     f"first was {w0}x{h0}", source)
                if (w0, h0) != size:
                    img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
                w.append(left=img, timestamp=fr.timestamp)
            n = len(w)
            k = n if adapt_frames is None else min(adapt_frames, n)
            w.set_attr("adapt_frames", int(k))
            short = short_read(ended)
            if short:
                w.set_attr("input_ended_early", short)      # kept in the file, for inspect
            path = w.close()
        except BaseException:
            w.abort()
            raise
    return {"path": path, "frames": n, "size": size, "intrinsics": how, "adapt_frames": k,
            "adapt_clipped": adapt_frames is not None and adapt_frames > n, "fx": cam.fx,
            "upscaled": size[0] / w0 if size[0] > w0 else None,
            "resumed_from": done, "ended_early": short}


def short_read(ended: dict) -> str | None:
    """The line for a video file whose frames ended well before its header's count (a
    truncated or damaged file), else None."""
    read, header = ended.get("read", 0), ended.get("header", 0)
    if header <= 0 or read >= header * (1 - SHORT_SHARE):
        return None
    return (f"the video's frames end at {read} of the {header} its header lists (a truncated or "
            "damaged file?); the frames before are imported")


def _identity(source: str, every: int, max_frames: int | None, width: int | None,
              fps: float | None) -> tuple[dict, list[str] | None, list[str] | None]:
    """The writer's resume fingerprint: (settings, per-frame input identities, their labels)."""
    from staticdepth.dataset.resume import file_identity, task_identity

    settings = {"every": every, "max_frames": max_frames, "width": width, "fps": fps}
    if os.path.isdir(source):
        files = image_files(source)[::every]
        if max_frames is not None:
            files = files[:max_frames]
        return settings, [task_identity(f) for f in files], [os.path.basename(f) for f in files]
    if not is_url(source):
        settings["source_file"] = file_identity(source)
    return settings, None, None


def _chain(first: VideoFrame, rest: Iterator[VideoFrame]) -> Iterator[VideoFrame]:
    yield first
    yield from rest


def register(sub) -> None:
    p = sub.add_parser("import-video",
                       help="import a video, an image folder or a camera URL (no ground truth)",
                       description="Stream frames into a sequence file (gt_kind none) for "
                                   "`staticdepth adapt`: intrinsics from a camera/rig JSON or a "
                                   "stated field-of-view guess, recorded in the file.")
    p.add_argument("source", help="video file, image folder, or a camera/stream URL (rtsp://...)")
    p.add_argument("--out", required=True, help="output sequence file (.h5)")
    p.add_argument("--camera", default=None, help="camera or rig JSON (intrinsics)")
    p.add_argument("--fov-deg", type=float, default=None,
                   help=f"horizontal field of view guess when no --camera (default {DEFAULT_FOV_DEG:g})")
    p.add_argument("--every", type=int, default=1, help="keep every K-th frame")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N kept frames")
    p.add_argument("--adapt-frames", type=int, default=None,
                   help="the first N >= 1 frames form the adaptation split (default: all; "
                        "clipped to the frames read)")
    p.add_argument("--width", type=int, default=None, help="resize frames to this width")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate of an image folder (default 10), or override a video's")
    p.add_argument("--name", default=None, help="sequence name (default: the input's name)")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted import (<out>.partial) of the same source and "
                        "settings (not for a URL)")
    p.add_argument("--restart", action="store_true",
                   help="discard an interrupted import's <out>.partial and start over")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from staticdepth.dataset.writer import check_sequence_output

    check_sequence_output(args.out)
    rep = import_video(args.source, args.out, camera_json=args.camera, fov_deg=args.fov_deg,
                       every=args.every, max_frames=args.max_frames,
                       adapt_frames=args.adapt_frames, width=args.width, fps=args.fps,
                       name=args.name, overwrite=args.overwrite, resume=args.resume,
                       restart=args.restart)
    print(f"intrinsics: {rep['intrinsics']}")
    if rep["resumed_from"]:
        print(f"resumed after the {rep['resumed_from']} frames of the earlier import")
    note = " (clipped to the frames read)" if rep["adapt_clipped"] else ""
    if rep["ended_early"]:
        print(f"warning: {args.source}: {rep['ended_early']}")
    if rep["upscaled"]:
        print(f"warning: --width {rep['size'][0]} enlarges the {args.source} frames "
              f"{rep['upscaled']:.1f}x: interpolated pixels add no detail, only size and time")
    print(f"wrote {rep['frames']} frames of {rep['size'][0]}x{rep['size'][1]} to {rep['path']}; "
          f"adaptation split: the first {rep['adapt_frames']}{note}")
    return 0
