"""Peak memory and seconds per frame per stage of ``staticdepth adapt`` against the frame count.

For each run (default: 100, 400 and 1600 frames at 800x400, 300 frames at 1280x720) a sequence
is written by cycling through a short rendered clip of the synthetic ``c1`` scene (its first
``--adapt`` frames are the adaptation split, so fine-tuning and the plane see the same data at
every length; ``--split N``: the first N frames of every sequence instead, cycling too), and ``staticdepth adapt`` runs in a child process with a tiny built-in network
(input 96x192), ``--detector gt`` (or ``--detector motion``: the background-subtraction detector
on the frames themselves) and one fine-tuning epoch. Peak RSS comes from the child's own
``rusage`` (``os.wait4``); the outputs' size on disk (prediction store and stage files); stage
timings from the summary, in seconds per frame of the sequence
(pseudo_labels, finetune's training and ground_plane work on the adaptation split only, so their
share falls with the length; base, agents, align and scale should stay flat). Ratios are against
the first run of the same size (the reference measured in this run); the goal is a 400-frame
peak <= 1.3 x the 100-frame peak and <= 3 GiB at 800x400.

    .venv/bin/python benchmarks/bench_adapt_scale.py [--runs 800x400:100,800x400:400,...]
        [--detector gt|motion] [--split N] [--threads 1] [--time-box 1800]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

STAGES = ("base", "agents", "pseudo_labels", "finetune", "ground_plane", "align", "scale")
RUN = ("import sys, torch; torch.set_num_threads(int(sys.argv[1]))\n"
       "from staticdepth.cli import main\n"
       "sys.exit(main(sys.argv[2:]))\n")


def write_sequence(clip: str, path: str, n: int, split: int | None = None) -> None:
    """``n`` frames cycling through the clip; the first ``split`` are the adaptation split
    (default: the clip's)."""
    from dataclasses import replace

    from staticdepth.dataset.h5 import SequenceReader, SequenceWriter

    with SequenceReader(clip) as r:
        frames = [r.frame(i) for i in range(len(r))]
        meta = r.meta if split is None else replace(r.meta, adapt_frames=min(split, n))
    with SequenceWriter(path, meta, streams=("left", "instances")) as w:
        for i in range(n):
            f = frames[i % len(frames)]
            w.append(left=f["left"], instances=f["instances"], agents=f["agents"],
                     timestamp=float(i))


def run_one(seq: str, model: str, threads: int, timeout: float, detector: str = "gt") -> dict:
    cmd = [sys.executable, "-c", RUN, str(threads), "adapt", seq, "--model", f"builtin:{model}",
           "--detector", detector, "--epochs", "1", "--device", "cpu",
           "--set", "tracking.min_height_px=8", "--set", "plane.bootstrap=0",
           # the tiny untrained network does not see the ground: under align.min_ground_r2 its
           # outputs would be the plane alone (0.03 s a frame), not the alignment measured here
           "--set", "align.min_ground_r2=0"]
    t0 = time.perf_counter()
    err = tempfile.TemporaryFile("w+")
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, text=True)
    while True:                  # os.wait4 reaps the child and gives its own rusage
        pid, status, ru = os.wait4(p.pid, os.WNOHANG)
        if pid:
            break
        if time.perf_counter() > t0 + timeout:
            p.kill()
            os.wait4(p.pid, 0)
            return {"timed_out": True}
        time.sleep(0.2)
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        err.seek(0)
        raise RuntimeError(f"adapt failed: {err.read()[-2000:]}")
    summary = json.load(open(seq.replace(".h5", ".adapt.json")))
    disk = sum(os.path.getsize(os.path.join(d, f)) for folder in (seq + ".pred", seq + ".adapt")
               for d, _, fs in os.walk(folder) for f in fs)
    return {"peak_rss_mb": ru.ru_maxrss / 1024.0, "wall_s": time.perf_counter() - t0,
            "timings_s": summary["timings_s"], "frames": summary["frames"], "disk_gib": disk / 2**30}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="800x400:100,800x400:400,800x400:1600,1280x720:300")
    ap.add_argument("--adapt", type=int, default=40, help="adaptation frames (the clip's length)")
    ap.add_argument("--detector", default="gt", choices=("gt", "motion"))
    ap.add_argument("--split", type=int, default=None,
                    help="adaptation split of the long sequences (default: the clip, --adapt)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--time-box", type=float, default=1800.0, help="seconds for all runs")
    args = ap.parse_args()

    import torch

    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin

    runs = [(tuple(int(v) for v in r.split(":")[0].split("x")), int(r.split(":")[1]))
            for r in args.runs.split(",")]
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        torch.manual_seed(0)
        model = os.path.join(tmp, "tiny.pt")
        save_builtin(model, builtin_model(TinyDepthNet(enc_channels=(4, 8, 8, 16, 16),
                                                       dec_channels=(16, 8, 8, 4)),
                                          input_height=96, input_width=192))
        clips: dict[tuple[int, int], str] = {}
        ref: dict[tuple[int, int], dict] = {}
        print(f"{'size':>9} {'frames':>6} {'peak MiB':>9} {'x ref':>6} "
              + " ".join(f"{s[:8]:>8}" for s in STAGES) + f" {'wall s':>7} {'out GiB':>7}   (s/frame; "
              f"detector {args.detector})")
        for (w, h), n in runs:
            left = args.time_box - (time.perf_counter() - t_start)
            if left < 30:
                print(f"{w}x{h} {n}: skipped (time box)")
                continue
            if (w, h) not in clips:
                clips[(w, h)] = os.path.join(tmp, f"clip{w}.h5")
                render_to_file(clips[(w, h)], preset_name="c1", n_frames=args.adapt,
                               adapt_frames=args.adapt, seed=1,
                               overrides={"width": w, "height": h})
            seq = os.path.join(tmp, f"s{w}x{h}_{n}.h5")
            write_sequence(clips[(w, h)], seq, n, args.split)
            res = run_one(seq, model, args.threads, left, args.detector)
            if res.get("timed_out"):
                print(f"{w}x{h} {n}: stopped at the time box")
                continue
            ref.setdefault((w, h), res)
            ratio = res["peak_rss_mb"] / ref[(w, h)]["peak_rss_mb"]
            per = [res["timings_s"].get(s, float("nan")) / n for s in STAGES]
            print(f"{w}x{h:<4} {n:>6} {res['peak_rss_mb']:>9.0f} {ratio:>6.2f} "
                  + " ".join(f"{p:>8.4f}" for p in per)
                  + f" {res['wall_s']:>7.0f} {res['disk_gib']:>7.2f}", flush=True)
    print("goal: peak(400) <= 1.3 x peak(100) and <= 3072 MiB at 800x400")


if __name__ == "__main__":
    main()
