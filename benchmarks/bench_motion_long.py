"""Seconds per frame of the motion detector against the frame count: the running median of the
shape test (staticdepth.detectors.motion.RunningMedian) against the former rule (every aspect
ratio kept, their median taken for each frame: tests/motion_scenes.ExactMedian), on the same
rendered long scene (tests/motion_scenes.LongScene, 128x96, three agents). For each, the mean
time per frame over the first and the last ``--window`` frames, and their ratio (1.0: the cost
per frame does not grow); the two give the same decisions (tests/test_motion_shape.py).

    .venv/bin/python benchmarks/bench_motion_long.py [--frames 3000] [--window 500]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

from motion_scenes import ExactMotion, LongScene  # noqa: E402

from staticdepth.detectors.motion import MotionDetector  # noqa: E402


def per_frame_times(detector, frames) -> list[float]:
    """Seconds each frame took to come out of ``detect_sequence`` (the first one includes the
    background model)."""
    out, t = [], time.perf_counter()
    for _ in detector.detect_sequence(frames):
        now = time.perf_counter()
        out.append(now - t)
        t = now
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--window", type=int, default=500)
    args = ap.parse_args()
    frames = LongScene(args.frames)
    k = args.window
    print(f"{'median':>8} {'first ms/frame':>15} {'last ms/frame':>14} {'last/first':>11}"
          f"   ({args.frames} frames, windows of {k})")
    for name, det in (("running", MotionDetector()), ("exact", ExactMotion())):
        t = per_frame_times(det, frames)
        first, last = sum(t[1:k + 1]) / k, sum(t[-k:]) / k
        print(f"{name:>8} {1e3 * first:>15.3f} {1e3 * last:>14.3f} {last / first:>11.2f}",
              flush=True)


if __name__ == "__main__":
    main()
