"""A deterministic synthetic stereo source: tests, benchmarks and disk-speed checks without cameras.

Frame ``k`` is a smooth random texture (with a little pixel noise, so PNG sizes resemble camera
images) seen by two cameras ``disparity_px`` apart, panning one pixel per frame; its first pixels
carry the frame number. :meth:`SyntheticSource.make_pair` regenerates any frame exactly, so a test
can check that a recording is lossless.
"""
from __future__ import annotations

import time
from typing import Any, Iterator

import cv2
import numpy as np

from staticdepth.capture.sources.base import SourceLost, StereoFrame, StereoSource
from staticdepth.errors import InputError


class SyntheticSource(StereoSource):
    """``frames`` pairs (None: endless) of ``width`` x ``height`` grey (or BGR) images at ``fps``.

    realtime: pace frames at ``fps`` and stamp them with the monotonic clock; otherwise frames come
        as fast as they are consumed, stamped ``k / fps``.
    lost_after: raise :class:`SourceLost` after that many frames (a simulated unplugged device).
    """

    kind = "synthetic"
    PAN_PERIOD = 256

    def __init__(self, width: int = 1280, height: int = 800, fps: float = 30.0,
                 frames: int | None = None, *, color: bool = False, disparity_px: int = 16,
                 realtime: bool = False, lost_after: int | None = None, seed: int = 0):
        super().__init__()
        if width < 16 or height < 4 or fps <= 0:
            raise InputError(f"synthetic source needs width >= 16, height >= 4, fps > 0 "
                             f"(got {width}x{height} at {fps})")
        self.width, self.height, self.nominal_fps = int(width), int(height), float(fps)
        self.n_frames, self.color, self.disparity_px = frames, color, int(disparity_px)
        self.realtime, self.lost_after, self.seed = realtime, lost_after, seed
        self._texture: np.ndarray | None = None

    def _make_texture(self) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        w = self.width + self.disparity_px + self.PAN_PERIOD
        ch = 3 if self.color else 1
        coarse = rng.uniform(0, 255, (self.height // 8 + 2, w // 8 + 2, ch)).astype(np.float32)
        smooth = cv2.resize(coarse, (w, self.height), interpolation=cv2.INTER_CUBIC)
        smooth = smooth.reshape(self.height, w, ch)
        noise = rng.normal(0, 3, smooth.shape).astype(np.float32)
        tex = np.clip(smooth + noise, 0, 255).astype(np.uint8)
        return tex if self.color else tex[..., 0]

    def make_pair(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``k``'s (left, right) images, exactly as :meth:`frames` yields them."""
        if self._texture is None:
            self._texture = self._make_texture()
        s = k % self.PAN_PERIOD
        d = self.disparity_px
        # A point at left column x appears at right column x - d (right camera to the right).
        left = self._texture[:, s: s + self.width].copy()
        right = self._texture[:, s + d: s + d + self.width].copy()
        stamp = np.frombuffer(int(k).to_bytes(8, "little"), dtype=np.uint8)
        for img in (left, right):
            img.reshape(-1)[:8] = stamp
        return left, right

    def open(self) -> None:
        if self._texture is None:
            self._texture = self._make_texture()

    def frames(self) -> Iterator[StereoFrame]:
        t0 = time.monotonic()
        k = 0
        while self.n_frames is None or k < self.n_frames:
            if self.lost_after is not None and k >= self.lost_after:
                raise SourceLost(f"synthetic source lost after {k} frames")
            if self.realtime:
                t = t0 + k / self.nominal_fps
                delay = t - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                t = time.monotonic()
            else:
                t = k / self.nominal_fps
            left, right = self.make_pair(k)
            self.stats.pairs += 1
            yield StereoFrame(left, right, t, t, t, k)
            k += 1

    def close(self) -> None:
        pass

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "width": self.width, "height": self.height,
                "color": self.color, "disparity_px": self.disparity_px, "seed": self.seed,
                "realtime": self.realtime}
