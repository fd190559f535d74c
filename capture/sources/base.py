"""The interface every stereo source implements, and the frame it yields.

A source yields :class:`StereoFrame` objects: a left and a right image taken at (nearly) the same
time, with timestamps in seconds on one monotonic clock. Sources count what they had to drop
(unpaired frames, sequence gaps) in :attr:`StereoSource.stats`, so the recorder's summary can say
how many frames were lost before they reached it.

Failures:
- a source that cannot start (no device, camera index not opening, missing file) raises
  :class:`SourceError` (an :class:`~staticdepth.errors.InputError`: one line, exit code 2);
- a source that stops delivering mid-run (device unplugged, camera lost) raises
  :class:`SourceLost` from its iterator; every frame yielded before that is valid.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import StereoRig


class SourceError(InputError):
    """The source cannot start: no device found, a camera does not open, an input is missing."""


class SourceLost(RuntimeError):
    """The source stopped delivering frames mid-run (device unplugged, camera lost)."""


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One synchronised pair.

    left, right: (H, W) uint8/uint16 grey or (H, W, 3) BGR images, same shape.
    timestamp_s: the pair's time in seconds (mean of both sides), monotonic clock of the source.
    left_timestamp_s, right_timestamp_s: each side's own capture time (seconds).
    sequence: the source's frame counter (device sequence number, or the pairer's count); gaps in it
        are frames lost before the host saw them.
    """

    left: np.ndarray
    right: np.ndarray
    timestamp_s: float
    left_timestamp_s: float
    right_timestamp_s: float
    sequence: int = -1

    @classmethod
    def at(cls, left: np.ndarray, right: np.ndarray, left_timestamp_s: float,
           right_timestamp_s: float, sequence: int = -1) -> "StereoFrame":
        return cls(left, right, 0.5 * (left_timestamp_s + right_timestamp_s), left_timestamp_s,
                   right_timestamp_s, sequence)


@dataclass
class SourceStats:
    """What a source lost before the recorder saw it (counted, never silent).

    Frames lost on a device (missing sequence numbers) are counted by the recorder from
    :attr:`StereoFrame.sequence`.
    """

    pairs: int = 0                 # pairs yielded
    unpaired_left: int = 0         # left frames with no right partner within the tolerance
    unpaired_right: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def dropped(self) -> int:
        return self.unpaired_left + self.unpaired_right

    def to_dict(self) -> dict[str, Any]:
        return {"pairs": self.pairs, "unpaired_left": self.unpaired_left,
                "unpaired_right": self.unpaired_right, "dropped": self.dropped, **self.extra}


class StereoSource(abc.ABC):
    """A stereo source: ``with source: for frame in source.frames(): ...``.

    Subclasses implement :meth:`open`, :meth:`frames` and :meth:`close`; :meth:`settings` describes
    the source for the recording's manifest and :attr:`rig` is the calibration when the source
    knows it (a DepthAI device's factory calibration, a rig file, a recording's rig).
    """

    kind: str = "source"

    def __init__(self) -> None:
        self.stats = SourceStats()
        self.rig: StereoRig | None = None
        self.nominal_fps: float | None = None

    @abc.abstractmethod
    def open(self) -> None:
        """Start the source; raises :class:`SourceError` when it cannot."""

    @abc.abstractmethod
    def frames(self) -> Iterator[StereoFrame]:
        """Yield pairs until the source ends (replay) or fails (:class:`SourceLost`)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release devices and threads; safe to call twice."""

    def settings(self) -> dict[str, Any]:
        """JSON-serialisable description for the manifest."""
        return {"kind": self.kind, "nominal_fps": self.nominal_fps}

    def __enter__(self) -> "StereoSource":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
