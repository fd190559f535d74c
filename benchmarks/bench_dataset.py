"""Sequence-file speed and size at 800x400 (issue 4 targets), measured in one run.

Packing with depth already computed (target >= 100 frames/s), random single-frame reads of left +
depth (>= 500 frames/s; the reader checks each frame's CRC-32, printed against raw h5py reads
of the same frames) and the compressed size against the raw arrays (<= 60 %). Frames are
synthetic renders of the c1 preset (textured ground, buildings, agents, exact depth), cycled.

    .venv/bin/python benchmarks/bench_dataset.py [--frames 200] [--unique 6]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter
from staticdepth.dataset.pack import LoadedFrame, write_frames
from staticdepth.dataset.synth import SyntheticScene, preset


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--unique", type=int, default=6, help="distinct rendered frames, cycled")
    ap.add_argument("--reads", type=int, default=1000)
    args = ap.parse_args()
    scene = SyntheticScene(preset("c1", seed=0))
    t0 = time.perf_counter()
    frames = [scene.render(i * 7) for i in range(args.unique)]
    print(f"rendered {args.unique} frames of {scene.camera.width}x{scene.camera.height} "
          f"in {time.perf_counter() - t0:.1f} s")
    meta = SequenceMeta(name="bench", camera=scene.camera, gt_kind="synthetic", adapt_frames=0)
    with tempfile.TemporaryDirectory() as d:
        for streams in (("left", "depth"), ("left", "right", "depth")):
            path = os.path.join(d, "_".join(streams) + ".h5")
            tasks = list(range(args.frames))

            def load(k: int, streams=streams) -> LoadedFrame:
                fr = frames[k % len(frames)]
                return LoadedFrame({s: fr[s] for s in streams}, timestamp=k / 10)

            t0 = time.perf_counter()
            write_frames(path, meta, streams, tasks, load)
            t_pack = time.perf_counter() - t0
            raw = sum(frames[0][s].nbytes for s in streams) * args.frames
            size = os.path.getsize(path)
            rng = np.random.default_rng(0)
            idx = rng.integers(0, args.frames, args.reads)
            with SequenceReader(path) as r:
                # the reader's reads, and the same reads straight from h5py without the reader's
                # per-frame checksum, alternated (the best of two each: the page cache warms)
                left, depth = r._f["left"], r._f["depth"]
                checked = (lambda i: (r.left(i), r.depth(i)))
                unchecked = (lambda i: (left[i], depth[i]))
                times: dict = {checked: [], unchecked: []}
                for _ in range(2):
                    for how in (unchecked, checked):
                        t0 = time.perf_counter()
                        for i in idx:
                            how(int(i))
                        times[how].append(time.perf_counter() - t0)
                t_read, t_raw = min(times[checked]), min(times[unchecked])
            print(f"streams {'+'.join(streams):18s} pack {args.frames / t_pack:7.1f} frames/s "
                  f"(target >= 100, ratio {args.frames / t_pack / 100:.2f}) | random read "
                  f"left+depth {args.reads / t_read:7.1f} frames/s (target >= 500, ratio "
                  f"{args.reads / t_read / 500:.2f}; checked reads take {t_read / t_raw:.2f}x "
                  f"the raw h5py reads) | size {size / raw:.1%} of raw "
                  f"({size / 2**20:.1f} MiB for {raw / 2**20:.1f} MiB; target <= 60%)")


if __name__ == "__main__":
    main()
