"""Time of aligning one 800x400 frame (METHOD.md section 4), against np.median over the frame.

Usage: python benchmarks/bench_align.py [--repeats N]
Prints ms per frame for the alignment (plane fit included) and its ratio to one plain
``np.median`` over the same float32 frame, both measured in this run.
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from staticdepth.geometry.alignment import align_depth, depth_from_inverse


def frame(w: int = 800, h: int = 400, f: float = 400.0, pitch_deg: float = 30.0,
          height_m: float = 5.0):
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    t = math.radians(pitch_deg)
    n = np.array([0.0, math.cos(t), math.sin(t)])
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    nr = ((u - K[0, 2]) / f) * n[0] + ((v - K[1, 2]) / f) * n[1] + n[2]
    depth = np.where(nr > 1e-3, height_m / np.maximum(nr, 1e-3), 200.0).clip(max=200.0)
    ground = (nr > 0.05)
    D = (3.0 / depth + 0.08).astype(np.float32)
    return K, n, depth_from_inverse(D), ground


def best_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    K, n, Z, ground = frame()
    align = best_ms(lambda: align_depth(Z, K, n, 5.0, ground), args.repeats)
    median = best_ms(lambda: np.median(Z), args.repeats)
    print(f"align 800x400: {align:.2f} ms/frame (best of {args.repeats})")
    print(f"np.median over the frame: {median:.2f} ms")
    print(f"ratio align / median: {align / median:.2f}")


if __name__ == "__main__":
    main()
