"""Agents from motion: background subtraction with a static camera (no weights; the default).

The background is the per-pixel median of frames sampled over the sequence (or OpenCV's MOG2,
``method="mog2"``); foreground = max channel difference above ``threshold``, cleaned by a
morphological opening and closing; each connected component above ``min_area`` pixels is one
agent. Motion cannot tell classes apart: upright blobs (taller than wide) are labelled person,
others car.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import cv2
import numpy as np

from staticdepth.dataset.schema import COCO
from staticdepth.detectors.base import Detector, rows_from_masks
from staticdepth.errors import InputError


def median_background(images: Sequence[np.ndarray], max_frames: int = 50) -> np.ndarray:
    """Per-pixel median of up to ``max_frames`` frames spread evenly over ``images``."""
    n = len(images)
    if n == 0:
        raise InputError("background model: no frame")
    idx = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int))
    return np.median(np.stack([np.asarray(images[i]) for i in idx]), axis=0).astype(np.uint8)


def foreground_mask(image: np.ndarray, background: np.ndarray, threshold: int = 30,
                    open_px: int = 3, close_px: int = 7) -> np.ndarray:
    diff = np.abs(image.astype(np.int16) - background.astype(np.int16)).max(axis=2)
    fg = (diff > threshold).astype(np.uint8)
    if open_px > 1:
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8))
    if close_px > 1:
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((close_px, close_px), np.uint8))
    return fg.astype(bool)


@dataclass
class MotionDetector(Detector):
    method: str = "median"      # "median" background or "mog2"
    threshold: int = 30         # grey-level difference that counts as motion
    min_area: int | None = None  # px; smaller components are noise (None: 3e-4 of the image, >= 12)
    open_px: int = 3
    close_px: int = 5
    name: str = "motion"

    def __post_init__(self):
        if self.method not in ("median", "mog2"):
            raise InputError(f"motion detector method must be median or mog2, got {self.method!r}")

    def components(self, frame: int, fg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=8)
        min_area = self.min_area if self.min_area is not None else max(12, 3e-4 * fg.size)
        masks, classes = [], []
        for k in range(1, n):
            if stats[k, cv2.CC_STAT_AREA] < min_area:
                continue
            w, h = stats[k, cv2.CC_STAT_WIDTH], stats[k, cv2.CC_STAT_HEIGHT]
            masks.append(labels == k)
            classes.append(COCO["person"] if h >= w else COCO["car"])
        return rows_from_masks(frame, masks, classes, [1.0] * len(masks), fg.shape)

    def detect_sequence(self, images: Iterable[np.ndarray]
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if self.method == "median":
            frames = images if isinstance(images, Sequence) else list(images)
            bg = median_background(frames)
            for i, im in enumerate(frames):
                yield self.components(i, foreground_mask(im, bg, self.threshold, self.open_px,
                                                         self.close_px))
            return
        sub = cv2.createBackgroundSubtractorMOG2(history=200, varThreshold=16, detectShadows=False)
        for i, im in enumerate(images):
            fg = sub.apply(np.ascontiguousarray(im[..., ::-1])) > 0
            if self.open_px > 1:
                fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN,
                                      np.ones((self.open_px, self.open_px), np.uint8))
            if self.close_px > 1:
                fg = cv2.morphologyEx(np.asarray(fg, np.uint8), cv2.MORPH_CLOSE,
                                      np.ones((self.close_px, self.close_px), np.uint8))
            yield self.components(i, np.asarray(fg, bool))
