"""The colour foot's walks per frame (issue 19, fourteenth round): every frame of a static camera
reads the same median image, so ``alignment_vertical.static_colour_feet`` walks every pixel once
and each frame's ``colour_foot`` gathers its candidates' feet, where it walked them per frame.

Usage: python benchmarks/bench_colour_feet.py [--size 800x400] [--share 0.3] [--repeats 5]
On the bench_align.py camera (5 m, 30 deg) with a textured image (blocks of random grey, each
pixel's noise under the run's threshold), ``--share`` of the pixels as one frame's candidates:
ms for walking them (``colour_feet``, the former per-frame cost), for walking every pixel once
(the kept walk's first frame) and for a frame that finds them kept (hashing the image and the
vertical, then a gather), and the ratios of the last two to the first, measured in one run.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align import best_ms, frame  # noqa: E402
from staticdepth.geometry import alignment_vertical as av  # noqa: E402
from staticdepth.geometry.alignment_upright import FOOT_DIFF  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", default="800x400")
    ap.add_argument("--share", type=float, default=0.3)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    K, n, _, _ = frame(w, h, f=w / 2.0)
    du = av.down_step(K, n, w, h)
    rng = np.random.default_rng(0)
    blocks = rng.uniform(0, 1, (h // 8 + 1, w // 8 + 1, 3))
    img = np.repeat(np.repeat(blocks, 8, 0), 8, 1)[:h, :w]
    img = np.clip(img + rng.uniform(-0.05, 0.05, img.shape), 0, 1)
    pix = np.flatnonzero(rng.random(h * w) < a.share)

    walk = best_ms(lambda: av.colour_feet(img, du, pix, FOOT_DIFF), a.repeats)
    t0 = time.perf_counter()
    first = av.static_colour_feet(img, du, FOOT_DIFF)
    once = 1e3 * (time.perf_counter() - t0)
    kept = best_ms(lambda: av.static_colour_feet(img, du, FOOT_DIFF)[pix], a.repeats)
    assert np.array_equal(first[pix], av.colour_feet(img, du, pix, FOOT_DIFF))
    print(f"{w}x{h}, {len(pix)} candidate pixels ({a.share:.0%}):")
    print(f"  walked per frame        {walk:8.1f} ms  1.00x")
    print(f"  every pixel, once       {once:8.1f} ms  {once / walk:.2f}x")
    print(f"  a frame, kept walks     {kept:8.1f} ms  {kept / walk:.2f}x")


if __name__ == "__main__":
    main()
