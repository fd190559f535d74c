"""Agents from motion: background subtraction with a static camera (no weights; the default).

The background is the per-pixel median of frames sampled over the sequence (or OpenCV's MOG2,
``method="mog2"``). Foreground, with hysteresis: pixels whose max channel difference exceeds
``threshold``, opened by ``open_px`` to drop speckles, are seeds; every connected region of
pixels above ``low_threshold`` that holds a seed is kept whole, then closed by ``close_px``. The
opening alone erased the thin extremes the ground plane needs (a head 2-3 px wide, the tip of a
foot) and the single threshold cut feet and heads whose colour is near the background's: on the
independent scenes (benchmarks/bench_motion_plane.py) the top row came 3-4 px low and the foot
row 1-3 px high in most detections, which put the plane 5-10 degrees off.

Each kept region above ``min_area`` pixels is one agent; upright ones (taller than wide) are
labelled person, others car. A region that holds several agents whose silhouettes touch
(:mod:`staticdepth.detectors.merges`: two regions flowing into it, or it splitting later, within
``lookahead`` frames), or an upright region whose width / height is outside ``aspect_band`` x the
median of the upright regions seen so far (two people side by side are wider, one behind the other
taller, a car seen end-on from above wider than a person) gets the score ``merged_score`` (below
the tracker's ``min_score``, so the ground plane does not use it: its foot is one agent's and its
top another's, or its class is a guess). That median is exact and counted in a histogram of the
distinct ratios (:class:`RunningMedian`): memory and time per frame do not grow over thousands of
frames (keeping every ratio and taking their median for each frame did, quadratically). It lives
in one call of :meth:`MotionDetector.detect_sequence`: nothing carries over to the next sequence.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import cv2
import numpy as np

from staticdepth.dataset.schema import COCO
from staticdepth.detectors.base import Detector, rows_from_masks
from staticdepth.detectors.merges import backward_counts, overlap_matrix, propagate
from staticdepth.errors import InputError


def median_background(images: Sequence[np.ndarray], max_frames: int = 50) -> np.ndarray:
    """Per-pixel median of up to ``max_frames`` frames spread evenly over ``images`` (taken in
    strips of rows: np.median's working copy stays small beside the frames themselves)."""
    n = len(images)
    if n == 0:
        raise InputError("background model: no frame")
    idx = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int))
    stack = np.stack([np.asarray(images[i]) for i in idx])
    out = np.empty(stack.shape[1:], np.uint8)
    rows = max(1, (1 << 22) // max(1, stack[:, :1].size))      # about 4 M samples per strip
    for r in range(0, stack.shape[1], rows):
        out[r:r + rows] = np.median(stack[:, r:r + rows], axis=0).astype(np.uint8)
    return out


def clean_foreground(strong: np.ndarray, weak: np.ndarray | None = None, open_px: int = 3,
                     close_px: int = 5, reconstruct: bool = True) -> np.ndarray:
    """Seeds = ``strong`` opened by ``open_px``; the connected regions of ``weak | seeds``
    (8-connected) holding a seed, closed by ``close_px``. ``weak`` None: ``strong``;
    ``reconstruct`` False: the seeds alone, closed (a plain opening and closing)."""
    strong = np.asarray(strong, np.uint8)
    seeds = strong
    if open_px > 1:
        seeds = cv2.morphologyEx(strong, cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8))
    if not reconstruct:
        weak = seeds
    region = (strong if weak is None else np.asarray(weak, np.uint8)) | seeds
    n, labels = cv2.connectedComponents(region, connectivity=8)
    keep = np.zeros(n, bool)
    keep[np.unique(labels[seeds > 0])] = True
    keep[0] = False
    fg = keep[labels].astype(np.uint8)
    if close_px > 1:
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((close_px, close_px), np.uint8))
    return fg.astype(bool)


def foreground_mask(image: np.ndarray, background: np.ndarray, threshold: int = 30,
                    open_px: int = 3, close_px: int = 5, low_threshold: int | None = 20,
                    reconstruct: bool = True) -> np.ndarray:
    """The hysteresis foreground of one frame (see the module doc; ``low_threshold`` None:
    ``threshold``, no hysteresis; ``reconstruct`` False: opened and closed only, as YOLOX's
    masks use it)."""
    diff = np.abs(image.astype(np.int16) - background.astype(np.int16)).max(axis=2)
    low = threshold if low_threshold is None else min(low_threshold, threshold)
    return clean_foreground(diff > threshold, diff > low, open_px, close_px, reconstruct)


class RunningMedian:
    """Exact running median from a histogram whose bins are the distinct values added.

    Memory and the cost of :meth:`add` and :meth:`median` grow with the number of distinct
    values, not with how many were added: the aspect ratios w / h of integer pixel boxes with
    h <= the image height take at most H^2 / 2 values, and a scene's few agent sizes far fewer
    (tens to a few thousand), so a sequence of thousands of frames costs the same per frame as a
    short one. :meth:`median` equals ``np.median`` of every value added (the mean of the two
    middle values for an even count).
    """

    def __init__(self):
        self.values = np.zeros(0, np.float64)     # distinct values, sorted
        self.counts = np.zeros(0, np.int64)
        self.n = 0

    def add(self, values: np.ndarray) -> None:
        v = np.asarray(values, np.float64).ravel()
        v = v[np.isfinite(v)]
        if len(v) == 0:
            return
        u, c = np.unique(v, return_counts=True)
        k = np.searchsorted(self.values, u)
        old = k < len(self.values)
        old[old] = self.values[k[old]] == u[old]
        self.counts[k[old]] += c[old]
        if not old.all():
            self.values = np.insert(self.values, k[~old], u[~old])
            self.counts = np.insert(self.counts, k[~old], c[~old])
        self.n += len(v)

    def median(self) -> float:
        """The median of every value added (NaN when none)."""
        if self.n == 0:
            return float("nan")
        k = np.searchsorted(np.cumsum(self.counts), [(self.n - 1) // 2, self.n // 2],
                            side="right")       # bins of the two middle order statistics
        return float((self.values[k[0]] + self.values[k[1]]) / 2)


@dataclass
class MotionDetector(Detector):
    method: str = "median"      # "median" background or "mog2"
    threshold: int = 30         # grey-level difference that seeds motion
    low_threshold: int | None = 20   # difference that extends a seeded region (None: threshold)
    min_area: int | None = None  # px; smaller components are noise (None: 3e-4 of the image, >= 12)
    open_px: int = 3
    close_px: int = 3
    lookahead: int = 30         # frames searched forward for a region splitting (merge test)
    merged_score: float = 0.2   # score of a region holding several agents (0 < it < 1)
    aspect_band: tuple[float, float] = (0.5, 1.5)   # upright regions whose width/height is
    #                                  outside this band x the median of those seen are doubtful
    name: str = "motion"

    def __post_init__(self):
        if self.method not in ("median", "mog2"):
            raise InputError(f"motion detector method must be median or mog2, got {self.method!r}")
        lo, hi = self.aspect_band
        if not 0 <= lo <= 1 <= hi:
            raise InputError(f"motion detector: aspect_band must be (lo <= 1, hi >= 1), got "
                             f"{self.aspect_band}")
        if self.lookahead < 1 or not 0 <= self.merged_score <= 1:
            raise InputError(f"motion detector: need lookahead >= 1 and 0 <= merged_score <= 1 "
                             f"(got {self.lookahead}, {self.merged_score})")

    def regions(self, fg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                               np.ndarray]:
        """(labels (H, W) int32 of the kept regions 1..n, class ids, areas, pixel heights,
        widths)."""
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=8)
        min_area = self.min_area if self.min_area is not None else max(12, 3e-4 * fg.size)
        kept = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
        relabel = np.zeros(n, np.int32)
        relabel[kept] = np.arange(1, len(kept) + 1)
        w, h = stats[kept, cv2.CC_STAT_WIDTH], stats[kept, cv2.CC_STAT_HEIGHT]
        cls = np.where(h >= w, COCO["person"], COCO["car"])
        return (relabel[labels], cls, stats[kept, cv2.CC_STAT_AREA].astype(np.float64),
                h.astype(np.float64), w.astype(np.float64))

    def components(self, frame: int, fg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One frame's agents without the merge test (every score 1)."""
        labels, cls, _, _, _ = self.regions(fg)
        masks = [labels == k for k in range(1, len(cls) + 1)]
        return rows_from_masks(frame, masks, cls, [1.0] * len(masks), fg.shape)

    def foregrounds(self, images: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
        if self.method == "median":
            frames = images if isinstance(images, Sequence) else list(images)
            bg = median_background(frames)
            for im in frames:
                yield foreground_mask(im, bg, self.threshold, self.open_px, self.close_px,
                                      self.low_threshold)
            return
        sub = cv2.createBackgroundSubtractorMOG2(history=200, varThreshold=16, detectShadows=False)
        for im in images:
            yield clean_foreground(sub.apply(np.ascontiguousarray(im[..., ::-1])) > 0, None,
                                   self.open_px, self.close_px)

    def detect_sequence(self, images: Iterable[np.ndarray]
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        buf: deque = deque()      # (labels, classes, areas, heights, widths, forward counts)
        links: deque = deque()        # overlap matrices between consecutive buffered frames
        aspects = self.aspect_statistic()     # width / height of the upright regions seen
        done = 0
        for fg in self.foregrounds(images):
            labels, cls, area, height, width = self.regions(fg)
            aspects.add((width / height)[width < height])
            if buf:
                p = buf[-1]
                links.append(overlap_matrix(p[0], labels, len(p[1]), len(cls)))
                fwd = propagate(p[5], links[-1], p[2], p[3], height)
            else:
                fwd = np.ones(len(cls))
            buf.append((labels, cls, area, height, width, fwd))
            if len(buf) > self.lookahead:
                yield self._emit(done, buf, links, aspects.median())
                done += 1
        while buf:
            yield self._emit(done, buf, links, aspects.median())
            done += 1

    def aspect_statistic(self) -> RunningMedian:
        """A fresh running median of the upright regions' width / height (one per sequence)."""
        return RunningMedian()

    def _emit(self, frame: int, buf: deque, links: deque, med: float
              ) -> tuple[np.ndarray, np.ndarray]:
        """The oldest buffered frame's agents, scored by the merge and shape tests; pops it."""
        bwd = backward_counts(list(links), [b[2] for b in buf], [b[3] for b in buf])
        labels, cls, _, height, width, fwd = buf.popleft()
        if links:
            links.popleft()
        med = med if np.isfinite(med) else 0.0     # no upright region seen: none is odd
        ar = width / height
        odd = (ar < 1) & ((ar < self.aspect_band[0] * med) | (ar > self.aspect_band[1] * med))
        several = (np.maximum(fwd, bwd) >= 1.5) | odd
        scores = np.where(several, self.merged_score, 1.0)
        masks = [labels == k for k in range(1, len(cls) + 1)]
        return rows_from_masks(frame, masks, cls, scores, labels.shape)
