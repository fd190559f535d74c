"""Crash safety and cost of the sequence writer.

1. Throughput: the writer (v1.8 superblock, a flush and an undo record per frame, file object
   driver) against a reference measured in the same run: the same datasets written the old way
   (sec2 driver, ``libver="latest"``, no flush until the end). Prints frames/s and the ratio.
   Then the undo journal's own share of the writer's time (its records and commits timed inside
   one run) and the bytes it journals per frame.
2. Kill trials: a writer subprocess is killed with SIGKILL at a random moment; then the partial is
   resumed with ``SequenceWriter(resume=True)``. Counts how many partials reopened, how many
   frames were kept, how many were rolled back by the CRC check, and whether the finished file
   verifies. The same trials with the old settings count how many partials reopen at all.

    python benchmarks/bench_crash_resume.py [--frames 60] [--trials 20] [--size 800x400]
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np

WRITER = r"""
import sys, numpy as np, h5py
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, _compression
from staticdepth.geometry import Camera
w_, h_, mode, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
rng = np.random.default_rng(0)
left = rng.integers(0, 255, (h_, w_, 3), dtype=np.uint8)
depth = rng.uniform(1, 80, (h_, w_)).astype(np.float32)
if mode == "new":
    w = SequenceWriter(out, SequenceMeta("b", Camera.from_fov(w_, h_, 90)),
                       streams=("left", "depth"), restart=True)
    for i in range(10**6):
        w.append(left=np.roll(left, i, axis=1), depth=depth + i)
else:  # the old settings: latest superblock, no flush
    f = h5py.File(out + ".partial", "w", libver="latest")
    dl = f.create_dataset("left", shape=(0, h_, w_, 3), maxshape=(None, h_, w_, 3),
                          chunks=(1, h_, w_, 3), dtype=np.uint8, **_compression("int"))
    dd = f.create_dataset("depth", shape=(0, h_, w_), maxshape=(None, h_, w_),
                          chunks=(1, h_, w_), dtype=np.float32, **_compression("float"))
    for i in range(10**6):
        dl.resize(i + 1, axis=0); dl[i] = np.roll(left, i, axis=1)
        dd.resize(i + 1, axis=0); dd[i] = depth + i
        f.attrs["n_written"] = i + 1
"""


def throughput(w: int, h: int, frames: int, folder: str) -> tuple[float, float]:
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, _compression
    from staticdepth.geometry import Camera

    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(1, 80, (h, w)).astype(np.float32)
    t0 = time.perf_counter()
    meta = SequenceMeta("b", Camera.from_fov(w, h, 90))
    with SequenceWriter(os.path.join(folder, "new.h5"), meta, streams=("left", "depth")) as sw:
        for i in range(frames):
            sw.append(left=np.roll(left, i, axis=1), depth=depth + i)
    new = frames / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    with h5py.File(os.path.join(folder, "old.h5"), "w", libver="latest") as f:
        dl = f.create_dataset("left", shape=(0, h, w, 3), maxshape=(None, h, w, 3),
                              chunks=(1, h, w, 3), dtype=np.uint8, **_compression("int"))
        dd = f.create_dataset("depth", shape=(0, h, w), maxshape=(None, h, w),
                              chunks=(1, h, w), dtype=np.float32, **_compression("float"))
        crc = f.create_dataset("crc", shape=(0,), maxshape=(None,), dtype=np.uint32,
                               chunks=(4096,))
        from staticdepth.dataset.integrity import checksum

        for i in range(frames):
            a, d = np.roll(left, i, axis=1), depth + i
            dl.resize(i + 1, axis=0)
            dl[i] = a
            dd.resize(i + 1, axis=0)
            dd[i] = d
            crc.resize(2 * i + 2, axis=0)
            crc[2 * i:] = [checksum(a), checksum(d)]
            f.attrs["n_written"] = i + 1
    old = frames / (time.perf_counter() - t0)
    return new, old


def journal_share(w: int, h: int, frames: int, folder: str) -> tuple[float, float]:
    """(the share of the writer's time spent journaling, kB journaled per frame)."""
    from staticdepth.dataset import resume as rs
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
    from staticdepth.geometry import Camera

    acc = {"t": 0.0, "bytes": 0}
    keep, reset = rs.UndoableFile._keep, rs.UndoableFile._reset_journal

    def timed_keep(self, off, end):
        t, pos = time.perf_counter(), self._jpos
        keep(self, off, end)
        acc["t"] += time.perf_counter() - t
        acc["bytes"] += self._jpos - pos

    def timed_reset(self):
        t = time.perf_counter()
        reset(self)
        acc["t"] += time.perf_counter() - t

    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(1, 80, (h, w)).astype(np.float32)
    rs.UndoableFile._keep, rs.UndoableFile._reset_journal = timed_keep, timed_reset
    try:
        t0 = time.perf_counter()
        with SequenceWriter(os.path.join(folder, "j.h5"), SequenceMeta("b", Camera.from_fov(
                w, h, 90)), streams=("left", "depth")) as sw:
            for i in range(frames):
                sw.append(left=np.roll(left, i, axis=1), depth=depth + i)
        total = time.perf_counter() - t0
    finally:
        rs.UndoableFile._keep, rs.UndoableFile._reset_journal = keep, reset
    return acc["t"] / total, acc["bytes"] / frames / 1024


def kill_trials(w: int, h: int, trials: int, mode: str, folder: str) -> dict:
    from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter
    from staticdepth.geometry import Camera

    stats = {"reopened": 0, "renamed_aside": 0, "kept": [], "rolled_back": [], "verified": 0}
    rnd = random.Random(1)
    for t in range(trials):
        out = os.path.join(folder, f"{mode}{t}.h5")
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(w), str(h), mode, out],
                                stderr=subprocess.DEVNULL)
        while not os.path.exists(out + ".partial"):
            time.sleep(0.01)
        time.sleep(rnd.uniform(0.2, 2.0))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        if mode == "old":
            try:
                with h5py.File(out + ".partial", "a", locking=False):
                    stats["reopened"] += 1
            except OSError:
                pass
            continue
        try:
            with h5py.File(out + ".partial", "r", locking=False) as f:
                written = int(f.attrs["n_written"])
        except OSError:
            written = None
        warned = []
        sw = SequenceWriter(out, SequenceMeta("b", Camera.from_fov(w, h, 90)),
                            streams=("left", "depth"), resume=True, warn=warned.append)
        if warned:
            stats["renamed_aside"] += 1
        else:
            stats["reopened"] += 1
            stats["kept"].append(len(sw))
            stats["rolled_back"].append((written or 0) - len(sw))
        rng = np.random.default_rng(0)
        left = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        depth = rng.uniform(1, 80, (h, w)).astype(np.float32)
        i = len(sw)
        sw.append(left=np.roll(left, i, axis=1), depth=depth + i)
        sw.close()
        with SequenceReader(out) as r:
            ok = not r.checksum_errors() and all(
                np.array_equal(r.left(j), np.roll(left, j, axis=1)) for j in range(len(r)))
        stats["verified"] += int(ok)
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--size", default="800x400")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    with tempfile.TemporaryDirectory() as d:
        new, old = throughput(w, h, a.frames, d)
        print(f"throughput {w}x{h} left+depth, {a.frames} frames: writer {new:.1f} frames/s, "
              f"old settings (no flush) {old:.1f} frames/s, ratio {new / old:.2f}")
        share, kb = journal_share(w, h, a.frames, d)
        print(f"undo journal: {100 * share:.1f}% of the writer's time, {kb:.1f} kB per frame")
        s = kill_trials(w, h, a.trials, "new", d)
        kept = s["kept"] or [0]
        print(f"SIGKILL x{a.trials}, writer: reopened {s['reopened']}, renamed aside "
              f"{s['renamed_aside']}, frames kept median {int(np.median(kept))} "
              f"(min {min(kept)}, max {max(kept)}), frames rolled back by the CRC check "
              f"{sum(s['rolled_back'])}, resumed files verified {s['verified']}/{a.trials}")
        o = kill_trials(w, h, a.trials, "old", d)
        print(f"SIGKILL x{a.trials}, old settings: partials that reopen {o['reopened']}/{a.trials}")


if __name__ == "__main__":
    main()
