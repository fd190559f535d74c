"""Synthetic scene rendering speed: stereo frames/s, against the naive full-frame reference.

    python benchmarks/bench_synth.py [--preset c1] [--frames 40] [--naive-frames 4]

The fast path renders the static scene once and traces each agent only inside the screen
rectangle of its 3-D bounding box; the reference intersects every object (static ones included)
with every ray of both views, every frame. Both are timed in this run, and their outputs compared.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from staticdepth.dataset.synth import SyntheticScene, preset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="c1")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--naive-frames", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    scene = SyntheticScene(preset(args.preset, seed=args.seed))
    t0 = time.perf_counter()
    scene.static_canvases()
    t_static = time.perf_counter() - t0
    step = 7  # spread the frames over the sequence so agent counts vary
    t0, c0 = time.perf_counter(), time.process_time()
    n_rows = 0
    for k in range(args.frames):
        n_rows += len(scene.render(k * step)["agents"])
    fast = args.frames / (time.perf_counter() - t0)
    fast_cpu = args.frames / (time.process_time() - c0)
    t0 = time.perf_counter()
    worst = 0.0
    for k in range(args.naive_frames):
        ref = scene.render(k * step, full_frame=True)
        fr = scene.render(k * step)
        same = np.array_equal(ref["instances"], fr["instances"]) and np.array_equal(
            ref["left"], fr["left"])
        worst = max(worst, float(np.nanmax(np.abs(ref["depth"] - fr["depth"]))))
        if not same:
            print(f"warning: frame {k * step} differs between the fast and the naive path")
    naive = args.naive_frames / (time.perf_counter() - t0 - args.naive_frames / fast)
    c = scene.camera
    print(f"preset {args.preset} {c.width}x{c.height}, {n_rows / args.frames:.1f} visible agent "
          f"instances per frame; static scene (both views) rendered once in {t_static:.2f} s")
    print(f"fast:  {fast:.1f} stereo frames/s wall clock, {fast_cpu:.1f} per CPU-second "
          f"({args.frames} frames; the CPU figure is what an unshared core gives)")
    print(f"naive: {naive:.2f} stereo frames/s ({args.naive_frames} frames, full-frame ray casting "
          f"of every object)")
    print(f"speed-up: {fast / naive:.1f}x; max |depth difference| {worst:.2e} m")


if __name__ == "__main__":
    main()
