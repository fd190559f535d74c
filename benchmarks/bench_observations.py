"""Peak memory and seconds per frame of ``staticdepth observations`` on a video against its length.

The command reads its frames one at a time (``staticdepth.dataset.video.VideoFrames``); before,
it read every frame of the run into a list and kept every instance map the detector made, so its memory
grew with ``--max-frames`` (vtest.avi, 768x576: 1.9 GB at 800 frames). Each run is a child
process (peak RSS from its own ``rusage``); ratios are against the shortest run of the same
command, measured in this run.

    .venv/bin/python benchmarks/bench_observations.py [--video PATH] [--frames 100,400,800]
        [--detector motion|yolox] [--detector-model yolox_nano.onnx]

Default video: ``$STATICDEPTH_DATA/video/vtest.avi`` (``../shared/data``).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("STATICDEPTH_DATA", os.path.join(HERE, "..", "..", "shared", "data"))


def run(video: str, frames: int, detector: str, model: str | None, out: str) -> dict:
    cmd = [sys.executable, "-c", "import sys; from staticdepth.cli import main; "
           "sys.exit(main(sys.argv[1:]))", "observations", video, "--max-frames", str(frames),
           "--detector", detector, "--out", out, "--overwrite"]
    if model:
        cmd += ["--detector-model", model]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, ru = os.wait4(p.pid, 0)       # reaps the child and gives its own rusage
    wall = time.perf_counter() - t0
    stdout, stderr = p.stdout.read(), p.stderr.read()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"observations failed: {stderr[-2000:]}")
    return {"peak_mb": ru.ru_maxrss / 1024.0, "wall_s": wall, "line": stdout.strip()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--video", default=os.path.join(DATA, "video", "vtest.avi"))
    ap.add_argument("--frames", default="100,400,800")
    ap.add_argument("--detector", default="motion", choices=("motion", "yolox"))
    ap.add_argument("--detector-model",
                    default=os.path.join(DATA, "models", "yolox_nano", "yolox_nano.onnx"))
    a = ap.parse_args()
    if not os.path.isfile(a.video):
        raise SystemExit(f"{a.video}: no such video (set STATICDEPTH_DATA or --video)")
    model = a.detector_model if a.detector == "yolox" else None
    counts = [int(n) for n in a.frames.split(",")]
    print(f"{'frames':>7} {'peak MiB':>9} {'x ref':>6} {'s/frame':>8}  output  ({a.detector})")
    ref = None
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            r = run(a.video, n, a.detector, model, os.path.join(tmp, "obs.csv"))
            ref = ref or r["peak_mb"]
            print(f"{n:7d} {r['peak_mb']:9.0f} {r['peak_mb'] / ref:6.2f} {r['wall_s'] / n:8.4f}  "
                  f"{r['line'].split(' -> ')[0]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
