"""Decoding passes and time per frame of the video-reading paths against a plain
``cv2.VideoCapture`` read loop over the same frames, measured in the same run (ratios).

Paths: ``stereo`` (``VideoFrames``: its length, then every frame in order), ``observations``
(``VideoFrames`` with the motion detector's access pattern: frame 0, the median background's 50
samples over the run, then every frame in order; the detection itself is left out) and
``import-video`` (``import_video`` into a temporary sequence file, writing included). Decoding
passes = frames decoded (``grab``/``read`` outside FFmpeg's raw packet mode) / frames of the run;
before, ``VideoFrames`` decoded every frame once more to count them (stereo 2, observations 3).

    .venv/bin/python benchmarks/bench_video_frames.py [--video PATH] [--frames N] [--repeat R]

Default video: ``$STATICDEPTH_DATA/video/vtest.avi`` (``../shared/data``), all its frames.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import cv2

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("STATICDEPTH_DATA", os.path.join(HERE, "..", "..", "shared", "data"))
_VideoCapture = cv2.VideoCapture


class Counted:
    """cv2.VideoCapture that counts the frames it decodes (outside raw packet mode)."""

    decoded = 0

    def __init__(self, *args):
        self.cap, self.raw = _VideoCapture(*args), False

    def __getattr__(self, name):
        return getattr(self.cap, name)

    def set(self, prop, value):
        ok = self.cap.set(prop, value)
        if prop == cv2.CAP_PROP_FORMAT and value == -1:
            self.raw = bool(ok)
        return ok

    def grab(self):
        ok = self.cap.grab()
        Counted.decoded += bool(ok and not self.raw)
        return ok

    def read(self, *args):
        ok, img = self.cap.read(*args)
        Counted.decoded += bool(ok and not self.raw)
        return ok, img


def raw_loop(video: str, n: int) -> int:
    cap, k = cv2.VideoCapture(video), 0
    while k < n:
        ok, _ = cap.read()
        if not ok:
            break
        k += 1
    cap.release()
    return k


def stereo(video: str, n: int) -> int:
    from staticdepth.dataset.video import VideoFrames

    frames = VideoFrames(video, max_frames=n)
    k = sum(1 for _ in (frames[i] for i in range(len(frames))))
    frames.close()
    return k


def observations(video: str, n: int) -> int:
    import numpy as np

    from staticdepth.dataset.video import VideoFrames

    frames = VideoFrames(video, max_frames=n)
    frames[0]                                                   # from_video: the frame size
    for i in np.unique(np.linspace(0, len(frames) - 1, min(len(frames), 50)).round()):
        frames[int(i)]                                          # median_background's samples
    k = sum(1 for _ in frames)                                  # then every frame in order
    frames.close()
    return k


def import_video(video: str, n: int) -> int:
    from staticdepth.dataset.video import import_video as run

    with tempfile.TemporaryDirectory() as tmp:
        return run(video, os.path.join(tmp, "v.h5"), max_frames=n)["frames"]


def measure(fn, video: str, n: int, repeat: int) -> tuple[float, float]:
    """(decoding passes, best seconds per frame) of ``fn``."""
    best = float("inf")
    for _ in range(repeat):
        Counted.decoded = 0
        t0 = time.perf_counter()
        k = fn(video, n)
        best = min(best, (time.perf_counter() - t0) / k)
    return Counted.decoded / k, best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--video", default=os.path.join(DATA, "video", "vtest.avi"))
    ap.add_argument("--frames", type=int, default=None, help="frames of the run (default: all)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per path; the fastest counts")
    a = ap.parse_args()
    if not os.path.isfile(a.video):
        raise SystemExit(f"{a.video}: no such video (set STATICDEPTH_DATA or --video)")
    cv2.VideoCapture = Counted
    n = a.frames or int(_VideoCapture(a.video).get(cv2.CAP_PROP_FRAME_COUNT)) or 10 ** 9
    cap = _VideoCapture(a.video)
    size = f"{int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))}x{int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))}"
    cap.release()
    _, ref = measure(raw_loop, a.video, n, a.repeat)
    print(f"{os.path.basename(a.video)} {size}, {n} frames; ratios against the raw cv2 read loop")
    print(f"{'path':<13} {'passes':>6} {'ms/frame':>9} {'x raw loop':>10}")
    for name, fn in (("raw loop", raw_loop), ("stereo", stereo),
                     ("observations", observations), ("import-video", import_video)):
        passes, t = measure(fn, a.video, n, a.repeat)
        ref = min(ref, t) if fn is raw_loop else ref      # the best of both raw-loop runs
        print(f"{name:<13} {passes:6.2f} {1e3 * t:9.2f} {t / ref:10.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
