"""Replay recordings, image folders and video files as stereo sources.

So that everything downstream of capture runs on recorded data:
- :class:`RecordingSource`: a folder written by ``staticdepth capture`` (timestamps and rig kept);
- :class:`FolderSource`: two image folders or glob patterns (``left/``, ``right/``, or
  ``DIR/left*.png`` and ``DIR/right*.png``), paired in frame order, stamped ``k / fps``;
- :class:`VideoSource`: two video files, or one side-by-side video (left half, right half).
Use lossless inputs for stereo matching; a lossy video replays, but its artefacts reach matching.
:func:`open_replay` picks the right one for a path.
"""
from __future__ import annotations

import glob
import math
import os
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from staticdepth import fileio
from staticdepth.capture import layout
from staticdepth.capture.sources.base import SourceError, StereoFrame, StereoSource
from staticdepth.errors import InputError
from staticdepth.geometry.camera import StereoRig

IMAGE_EXTENSIONS = fileio.IMAGE_EXTS   # the toolkit's one list of image suffixes
DEFAULT_FPS = 30.0


def _check_fps(fps: float | None, path: str) -> float | None:
    """``fps`` unchanged when it is None or a positive finite rate, else a :class:`SourceError`
    (a rate of 0 or below would stamp frames at one time or backwards)."""
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise SourceError(f"the replay rate must be a positive number of frames per second, "
                          f"got {fps}", path)
    return fps


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Decode an image unchanged (grey stays grey, 16-bit stays 16-bit) through the toolkit's one
    reader; a file that cannot be decoded is a :class:`SourceError` naming it."""
    try:
        return fileio.read_image(path)
    except InputError as e:
        raise SourceError(e.problem, e.path) from None


class RecordingSource(StereoSource):
    """A recording folder, frame by frame, with its original timestamps and rig."""

    kind = "recording"

    def __init__(self, path: str | os.PathLike):
        super().__init__()
        self.path = Path(path)
        self.recording: layout.Recording | None = None

    def open(self) -> None:
        self.recording = layout.read_recording(self.path)
        self.rig = self.recording.rig
        self.nominal_fps = self.recording.nominal_fps

    def frames(self) -> Iterator[StereoFrame]:
        assert self.recording is not None, "open() first"
        for f in self.recording.frames:
            left, right = read_image(f.left_path), read_image(f.right_path)
            self.stats.pairs += 1
            yield StereoFrame(left, right, f.timestamp_s, f.left_timestamp_s, f.right_timestamp_s,
                              f.sequence)

    def close(self) -> None:
        pass

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "path": os.fspath(self.path),
                "recorded_source": (self.recording.manifest.get("source")
                                    if self.recording else None)}


def _list_images(spec: str | os.PathLike) -> list[str]:
    spec = os.fspath(spec)
    if os.path.isdir(spec):
        files = [os.path.join(spec, n) for n in os.listdir(spec)
                 if n.lower().endswith(IMAGE_EXTENSIONS)]
    else:
        files = [f for f in glob.glob(spec) if f.lower().endswith(IMAGE_EXTENSIONS)]
    return fileio.sorted_frames(files)   # 2.png before 10.png


class FolderSource(StereoSource):
    """Two image folders (or glob patterns), paired in frame order (numbers in names by value:
    ``2.png`` before ``10.png``), stamped ``k / fps``."""

    kind = "folder"

    def __init__(self, left: str | os.PathLike, right: str | os.PathLike, fps: float = DEFAULT_FPS,
                 rig: StereoRig | None = None):
        super().__init__()
        self.left_spec, self.right_spec = os.fspath(left), os.fspath(right)
        self.nominal_fps, self.rig = float(_check_fps(fps, self.left_spec)), rig
        self.pairs: list[tuple[str, str]] = []

    def open(self) -> None:
        left, right = _list_images(self.left_spec), _list_images(self.right_spec)
        if not left:
            raise SourceError("no images found", self.left_spec)
        if len(left) != len(right):
            raise SourceError(f"{len(left)} left images but {len(right)} right images in "
                              f"{self.right_spec}; cannot pair them", self.left_spec)
        self.pairs = list(zip(left, right))

    def frames(self) -> Iterator[StereoFrame]:
        for k, (lp, rp) in enumerate(self.pairs):
            left, right = read_image(lp), read_image(rp)
            if left.shape != right.shape:
                raise SourceError(f"left image {left.shape} and right image {right.shape} differ "
                                  f"in size ({rp})", lp)
            t = k / self.nominal_fps
            self.stats.pairs += 1
            yield StereoFrame(left, right, t, t, t, k)

    def close(self) -> None:
        pass

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "left": self.left_spec, "right": self.right_spec,
                "pairs": len(self.pairs)}


class VideoSource(StereoSource):
    """Two video files, or one side-by-side video (``right=None``: left half | right half)."""

    kind = "video"

    def __init__(self, left: str | os.PathLike, right: str | os.PathLike | None = None,
                 fps: float | None = None, rig: StereoRig | None = None):
        super().__init__()
        self.left_path = os.fspath(left)
        self.right_path = None if right is None else os.fspath(right)
        self.fps_override, self.rig = _check_fps(fps, self.left_path), rig
        self._caps: list[cv2.VideoCapture] = []

    def open(self) -> None:
        for path in filter(None, (self.left_path, self.right_path)):
            if not os.path.isfile(path):
                raise SourceError("video file not found", path)
            cap = cv2.VideoCapture(path)
            if not cap.isOpened():
                raise SourceError("cannot open as a video", path)
            self._caps.append(cap)
        fps = self.fps_override
        if fps is None:
            fps = self._caps[0].get(cv2.CAP_PROP_FPS)   # 0 or NaN when the file does not say
            fps = fps if math.isfinite(fps) and fps > 0 else DEFAULT_FPS
        self.nominal_fps = float(fps)

    def frames(self) -> Iterator[StereoFrame]:
        k = 0
        while True:
            images = []
            for cap in self._caps:
                ok, img = cap.read()
                if not ok:
                    return
                images.append(img)
            if len(images) == 1:
                img = images[0]
                if img.shape[1] % 2:
                    raise SourceError(f"side-by-side video has an odd width {img.shape[1]}",
                                      self.left_path)
                half = img.shape[1] // 2
                images = [img[:, :half], img[:, half:]]
            t = k / self.nominal_fps
            self.stats.pairs += 1
            yield StereoFrame(images[0], images[1], t, t, t, k)
            k += 1

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "left": self.left_path, "right": self.right_path,
                "side_by_side": self.right_path is None}


def open_replay(path: str | os.PathLike, right: str | os.PathLike | None = None,
                fps: float | None = None, rig: StereoRig | None = None, *,
                side_by_side: bool = False) -> StereoSource:
    """The replay source for ``path``: a recording folder (has ``manifest.json``), a folder with
    ``left/`` and ``right/``, two image folders/patterns, two videos, or one video that holds
    both views side by side (only when ``side_by_side`` says so: a lone video is more often a
    monocular one, which is not a stereo pair). ``fps`` stamps image folders and overrides a
    video's rate (default: the video's, else 30); a recording keeps its own timestamps."""
    p = os.fspath(path)
    _check_fps(fps, p)
    rate = DEFAULT_FPS if fps is None else fps
    if right is None and os.path.isdir(p):
        if os.path.isfile(os.path.join(p, layout.MANIFEST)):
            if fps is not None:
                raise SourceError("a recording keeps its own timestamps: drop the replay rate "
                                  "(--fps)", p)
            return RecordingSource(p)
        if os.path.isdir(os.path.join(p, "left")) and os.path.isdir(os.path.join(p, "right")):
            return FolderSource(os.path.join(p, "left"), os.path.join(p, "right"), rate, rig)
        raise SourceError("folder is neither a recording (manifest.json) nor has left/ and "
                          "right/ image folders", p)
    if right is not None and (os.path.isdir(p) or any(c in p for c in "*?[")
                              or p.lower().endswith(IMAGE_EXTENSIONS)):
        return FolderSource(p, right, rate, rig)
    if not os.path.exists(p):
        raise SourceError("replay input not found", p)
    if right is None and not side_by_side:
        raise SourceError("one video without --right: if it holds both views side by side, add "
                          "--side-by-side; a monocular video is imported with `staticdepth "
                          "import-video`", p)
    return VideoSource(p, right, fps, rig)
