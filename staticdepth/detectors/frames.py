"""The frames of a sequence file a detector reads, one at a time: never the whole sequence.

Detectors take their input as a ``Sequence`` of RGB images: the median background of the motion
and YOLOX detectors picks up to 50 frames spread over it (:func:`staticdepth.detectors.motion.
median_background`), then every frame is read in order. :class:`SequenceFrames` reads a frame
only when it is indexed and keeps none (adapt's agents stage, ``locate``, ``deploy``'s ground
region, ``observations``); a video's counterpart is :class:`staticdepth.dataset.video.VideoFrames`.
"""
from __future__ import annotations

from collections.abc import Sequence


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
