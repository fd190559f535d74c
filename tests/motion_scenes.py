"""Long synthetic sequences for the motion detector's shape test, and its exact reference.

:class:`LongScene` renders frames of a static textured background crossed by upright rectangles
whose width changes over time (two single walkers, aspect 0.17-0.5, and a side-by-side pair,
aspect 0.62-0.96), each in its own band of rows so that they never touch: every region is one
connected blob and the upright ones' aspect ratios drift slowly, so the running median moves and
regions fall on both sides of the shape test's thresholds. A frame is rendered when it is indexed
(nothing is held: thousands of frames cost no memory), seeded.

:class:`ExactMedian` keeps every value and takes ``np.median`` of all of them on each query (the
detector's former rule: memory and time grow with the frame count); :class:`ExactMotion` is the
motion detector with it, the reference the histogram median is compared against.
"""
from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from staticdepth.detectors.motion import MotionDetector

H, W = 96, 128
# (top row, height, mean width, width swing, period in frames, speed px/frame, colour): two
# walkers and a side-by-side pair, each in its own band of rows
AGENTS = ((4, 22, 7, 3, 97, 1.3, (230, 40, 40)),
          (34, 24, 8, 4, 131, 0.9, (40, 230, 40)),
          (66, 24, 19, 4, 173, 1.1, (230, 230, 40)))


def _background(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(60, 120, (H, W, 3)).astype(np.uint8), (5, 5), 0)


def _column(t: int, speed: float, width: int, phase: int) -> int:
    """Left column bouncing 3 px inside the image edges (a triangle wave; nearer, the
    foreground's closing reaches the border and widens the box)."""
    span = W - width - 6
    x = (phase + speed * t) % (2 * span)
    return 3 + int(x if x < span else 2 * span - x)


class LongScene(Sequence):
    """``n`` frames (H, W, 3) uint8, each rendered when indexed (nothing is held)."""

    def __init__(self, n: int, seed: int = 0):
        self.n = n
        self.background = _background(seed)
        self.phases = np.random.default_rng(seed + 1).integers(0, W, len(AGENTS))

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, t):
        if isinstance(t, slice):
            return [self[k] for k in range(*t.indices(self.n))]
        if not -self.n <= t < self.n:
            raise IndexError(t)
        t = t % self.n
        im = self.background.copy()
        for (top, h, w0, swing, period, speed, colour), phase in zip(AGENTS, self.phases):
            w = int(round(w0 + swing * np.sin(2 * np.pi * t / period)))
            u = _column(t, speed, w, int(phase))
            im[top:top + h, u:u + w] = colour
        return im


def box_sizes() -> set[tuple[int, int]]:
    """Every (width, height) an agent of the scene can take."""
    return {(w, h) for _, h, w0, swing, _, _, _ in AGENTS
            for w in range(w0 - swing, w0 + swing + 1)}


class ExactMedian:
    """Every value kept; the median of all of them (the reference; O(values) per query)."""

    def __init__(self):
        self.values: list[np.ndarray] = []
        self.medians: list[float] = []      # what each query returned, in order

    def add(self, values: np.ndarray) -> None:
        self.values.append(np.asarray(values, np.float64).ravel())

    def median(self) -> float:
        v = np.concatenate(self.values) if self.values else np.zeros(0)
        m = float(np.median(v)) if len(v) else float("nan")
        self.medians.append(m)
        return m


class ExactMotion(MotionDetector):
    """The motion detector with the exact median; ``stats`` is the last sequence's."""

    def aspect_statistic(self) -> ExactMedian:
        self.stats = ExactMedian()
        return self.stats
