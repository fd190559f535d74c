"""Stereo accuracy (Aloe, Middlebury Art, Midd1) and speed, against textbook SGBM in the same run.

    python benchmarks/bench_stereo.py [--data ../shared/data] [--frames 20]

Accuracy: bad-1/bad-2 (%) and density (%) in ground-truth mode (errors over the valid pixels) and
dense mode (errors over all ground-truth pixels, missing = bad), and the ratios to textbook SGBM.
Speed: the default per-frame path (rectify, match with 192 disparities, checks, filtering,
triangulate) at 800x400 versus one bare ``StereoSGBM.compute`` with the same range, for the
default half-resolution left border and the full-resolution padding.
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
    pipes = {b: StereoPipeline(rig, StereoConfig(num_disparities=192, options={"border": b}))
             for b in ("half", "full")}
    bare = cv2.StereoSGBM_create(0, 192, 5, P1=8 * 3 * 25, P2=32 * 3 * 25,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    times: dict[str, list[float]] = {"bare": [], "half": [], "full": []}
    runs = {"bare": lambda: bare.compute(left, right),
            **{b: (lambda p=p: p.process(left, right)) for b, p in pipes.items()}}
    for f in runs.values():
        f()
    for _ in range(frames):   # interleaved so all see the same machine load
        for k, f in runs.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    b = med["bare"]
    print(f"speed 800x400, 192 disparities, {cv2.getNumThreads()} OpenCV threads, median of "
          f"{frames}, load average {open('/proc/loadavg').read().split()[0]}: bare "
          f"SGBM.compute {1000 * b:.1f} ms")
    for k in ("half", "full"):
        p = med[k]
        print(f"  pipeline, border={k}{' (default)' if k == 'half' else ''}: {1000 * p:.1f} ms "
              f"({1 / p:.1f} frames/s), ratio to bare {p / b:.2f}")


def border_accuracy(root: Path) -> None:
    """bad-2 and density in the first num_disparities columns (where bare SGBM has nothing)."""
    print("left border columns, ground-truth mode:")
    for name in sorted(PAIRS):
        left, right, gt, n = load_pair(root, name)
        h, w = left.shape[:2]
        rig = StereoRig.rectified(Camera.from_intrinsics(1000, 1000, w / 2, h / 2, w, h), 0.1)
        row = []
        for b in ("half", "full"):
            conf = StereoConfig(num_disparities=n, max_depth_m=1e9, options={"border": b})
            d = StereoPipeline(rig, conf).process(left, right).disparity
            s = disparity_scores(d[:, :n], gt[:, :n])
            row.append(f"border={b}: bad-2 {s['bad-2']:5.2f} density {s['density']:5.1f}")
        print(f"  {name:6} " + " | ".join(row))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get(
        "STATICDEPTH_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data")))
    ap.add_argument("--frames", type=int, default=20)
    a = ap.parse_args()
    accuracy(Path(a.data))
    border_accuracy(Path(a.data))
    speed(Path(a.data), a.frames)


if __name__ == "__main__":
    main()
