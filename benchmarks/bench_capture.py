"""Can the recorder keep up with 2 x 1280x800 grey at 30 FPS? (issue 9)

Runs the synthetic source (camera-like texture with sensor noise) through the real recorder:
1. unpaced, per PNG preset: pairs written per second, as a ratio to the 30 FPS requirement;
2. paced at 30 FPS in real time: achieved FPS, writer queue depth, time the capture loop blocked.
Ratios > 1 mean headroom. All numbers come from this one run on this machine.

    python benchmarks/bench_capture.py [--seconds 10] [--presets fast,zlib1,compact]
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time

from staticdepth.capture.record import RECORD_PRESETS, record
from staticdepth.capture.sources.synthetic import SyntheticSource

REQUIRED_FPS = 30.0


def _du_mb(path: str) -> float:
    total = 0
    for d, _, files in os.walk(path):
        total += sum(os.path.getsize(os.path.join(d, f)) for f in files)
    return total / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of the paced run")
    ap.add_argument("--frames", type=int, default=150, help="pairs per unpaced run")
    ap.add_argument("--presets", default="fast,zlib1,compact")
    ap.add_argument("--size", default="1280x800")
    ap.add_argument("--dir", default=None, help="where to write (default: a temporary folder)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    base = tempfile.mkdtemp(prefix="bench_capture_", dir=args.dir)
    print(f"{w}x{h} grey pairs, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}, "
          f"writing to {base}")
    try:
        rates = {}
        for name in args.presets.split(","):
            src = SyntheticSource(w, h, REQUIRED_FPS, frames=args.frames)
            src.open()                                   # texture made outside the timing
            t0 = time.perf_counter()
            root, s = record(src, os.path.join(base, f"unpaced_{name}"), RECORD_PRESETS[name])
            dt = time.perf_counter() - t0
            rates[name] = s["frames_written"] / dt
            mb = _du_mb(str(root)) / (2 * s["frames_written"])
            ratio = rates[name] / REQUIRED_FPS
            print(f"unpaced {name:8s}: {rates[name]:6.1f} pairs/s = {ratio:.2f}"
                  f" x the required 30 FPS, {mb:.2f} MB per image, max queue "
                  f"{s['max_queue_depth']}")
            shutil.rmtree(root)
        first = args.presets.split(",")[0]
        for name, r in rates.items():
            print(f"throughput {name} / {first}: {r / rates[first]:.2f}")
        src = SyntheticSource(w, h, REQUIRED_FPS, realtime=True)
        root, s = record(src, os.path.join(base, "paced"), RECORD_PRESETS[first],
                         duration_s=args.seconds)
        print(f"paced 30 FPS ({first}, {args.seconds:.0f} s): {s['frames_written']} pairs, "
              f"achieved {s['achieved_fps']:.2f} FPS = {s['achieved_fps'] / REQUIRED_FPS:.3f} x "
              f"required, gaps {s['gaps']}, max interval {s['interval_max_s'] * 1000:.1f} ms, "
              f"writer queue max {s['max_queue_depth']} pairs, capture blocked "
              f"{s['capture_blocked_s']:.2f} s")
    finally:
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
