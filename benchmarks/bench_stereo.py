"""Stereo accuracy (Aloe, Middlebury Art, Midd1) and speed, against textbook SGBM in the same run.

    python benchmarks/bench_stereo.py [--data ../shared/data] [--frames 20]

Accuracy: bad-1/bad-2 (%) and density (%) in ground-truth mode (errors over the valid pixels) and
dense mode (errors over all ground-truth pixels, missing = bad), and the ratios to textbook SGBM.
Speed: the default per-frame path (rectify, match with 192 disparities, checks, filtering,
triangulate) at 800x400 versus one bare ``StereoSGBM.compute`` with the same range.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_stereo_real import PAIRS, load_pair, ours, textbook  # noqa: E402

from staticdepth.geometry.camera import Camera, StereoRig  # noqa: E402
from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline  # noqa: E402
from staticdepth.stereo.scores import disparity_scores  # noqa: E402


def accuracy(root: Path) -> None:
    print(f"{'pair':6} {'mode':6} {'method':9} {'bad-1':>6} {'bad-2':>6} {'density':>7} "
          f"{'bad-2 ratio':>11} {'density ratio':>13}")
    for name in sorted(PAIRS):
        left, right, gt, n = load_pair(root, name)
        ref = disparity_scores(textbook(left, right, n), gt)
        for mode, fill, b1, b2 in (("gt", False, "bad-1", "bad-2"),
                                   ("dense", True, "bad-1-all", "bad-2-all")):
            got = disparity_scores(ours(left, right, n, fill).disparity, gt)
            print(f"{name:6} {mode:6} {'textbook':9} {ref[b1]:6.2f} {ref[b2]:6.2f} "
                  f"{ref['density']:7.2f}")
            print(f"{name:6} {mode:6} {'ours':9} {got[b1]:6.2f} {got[b2]:6.2f} "
                  f"{got['density']:7.2f} {got[b2] / ref[b2]:11.3f} "
                  f"{got['density'] / ref['density']:13.3f}")


def speed(root: Path, frames: int) -> None:
    left, right, _, _ = load_pair(root, "aloe")
    left = cv2.resize(left, (800, 400), interpolation=cv2.INTER_AREA)
    right = cv2.resize(right, (800, 400), interpolation=cv2.INTER_AREA)
    cam = Camera.from_intrinsics(400, 400, 399.5, 199.5, 800, 400)
    # a calibrated-looking rig (small rotation) so that rectification really remaps
    rig = StereoRig(cam, cam, cv2.Rodrigues(np.array([0.0, 0.002, 0.0]))[0], [-0.27, 0, 0])
    pipe = StereoPipeline(rig, StereoConfig(num_disparities=192))
    bare = cv2.StereoSGBM_create(0, 192, 5, P1=8 * 3 * 25, P2=32 * 3 * 25,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    pipe.process(left, right), bare.compute(left, right)
    t_pipe, t_bare = [], []
    for _ in range(frames):   # interleaved so both see the same machine load
        t = time.perf_counter(); bare.compute(left, right); t_bare.append(time.perf_counter() - t)
        t = time.perf_counter(); pipe.process(left, right); t_pipe.append(time.perf_counter() - t)
    p, b = float(np.median(t_pipe)), float(np.median(t_bare))
    print(f"speed 800x400, 192 disparities, {cv2.getNumThreads()} OpenCV threads, median of "
          f"{frames}: pipeline {1000 * p:.1f} ms ({1 / p:.1f} frames/s), bare SGBM.compute "
          f"{1000 * b:.1f} ms; ratio {p / b:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get(
        "STATICDEPTH_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data")))
    ap.add_argument("--frames", type=int, default=20)
    a = ap.parse_args()
    accuracy(Path(a.data))
    speed(Path(a.data), a.frames)


if __name__ == "__main__":
    main()
