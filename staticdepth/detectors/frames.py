"""The frames a detector reads, one at a time: never a whole sequence or video in memory.

Detectors take their input as a ``Sequence`` of RGB images: the median background of the motion
and YOLOX detectors picks up to 50 frames spread over it (:func:`staticdepth.detectors.motion.
median_background`), then every frame is read in order. Both classes here read a frame only when
it is indexed and keep none:

- :class:`SequenceFrames`: the left images of an open sequence file (all of them, or a split's
  indices), for adapt's agents stage, ``locate``, ``deploy``'s ground region and ``observations``;
- :class:`VideoFrames`: every ``step``-th frame of a video from frame ``start``, at most
  ``max_frames``, for ``observations``. Its length comes from one pass that grabs the frames
  without converting them; reads grab forward through one open capture, converting only the
  frames asked for, and reopen it from ``start`` only when an index goes back (the background's
  samples, then the frames in order: three passes over the video in all), so a long video costs
  one frame of memory, not all of them.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from staticdepth.errors import InputError


class SequenceFrames(Sequence):
    """The left images of an open sequence reader, at ``indices`` (default: every frame)."""

    def __init__(self, reader, indices=None):
        self.reader = reader
        self.indices = None if indices is None else [int(i) for i in indices]

    def __len__(self) -> int:
        return len(self.reader) if self.indices is None else len(self.indices)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        i %= len(self)
        return self.reader.left(i if self.indices is None else self.indices[i])


class VideoFrames(Sequence):
    """Frames ``start``, ``start + step``, ... of the video at ``path`` (RGB uint8), at most
    ``max_frames`` (None: to the end). ``source_index(i)`` is frame ``i``'s index in the video."""

    def __init__(self, path: str, start: int = 0, step: int = 1, max_frames: int | None = None):
        self._cap = None         # the open capture, positioned at raw offset _next from start
        self._next = 0
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
        """Frames this view holds, by grabbing (demuxing and decoding, no colour conversion)
        up to the last one it can use."""
        limit = None if self.max_frames is None else (self.max_frames - 1) * self.step + 1
        cap, raw = self._capture(), 0
        try:
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
        if self._cap is None or want < self._next:
            self.close()
            self._cap, self._next = self._capture(), 0
        while self._next <= want:
            if not self._cap.grab():
                self.close()
                raise InputError(f"frame {self.source_index(i)} could not be read (the video "
                                 "holds fewer frames than its first pass counted)", self.path)
            self._next += 1
        ok, bgr = self._cap.retrieve()
        if not ok or bgr is None:
            raise InputError(f"frame {self.source_index(i)} cannot be decoded", self.path)
        return np.ascontiguousarray(bgr[..., ::-1])

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __del__(self):
        self.close()
