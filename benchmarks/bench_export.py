"""Exported ONNX (image -> metric depth) vs the torch/numpy pipeline it replaces: speed and agreement.

Usage: python benchmarks/bench_export.py [--model builtin:PATH.pt] [--frames 20] [--size 400x200]
       [--threads N] [--mode eq2|ground|upright|all] [--train-frames 48 --train-epochs 4]

A synthetic scene (``demo`` preset) with its true plane stands for an adapted camera; the model is
the given built-in network, else the user cache's, else one trained here by ``train_builtin``
(``--train-frames`` street frames, ``--train-epochs``, 128x64, seed 0: a small run, so that the
alignment fits a network's real output rather than a random one's). For each alignment mode the
export bakes (``align.mode`` of the summary, adapt's other align defaults: in ``upright`` the
colour foot on the rendered frames' median image), both paths run on the CPU with the same number
of threads over the same frames; printed: frames per second of each, their ratio (goal >= 2), the
median / 99th-percentile relative difference of the metric depth (goal <= 0.5%), and the AbsRel
against the scene's true depth of both (metric protocol).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--size", default="400x200")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--mode", default="all", choices=("eq2", "ground", "upright", "all"))
    ap.add_argument("--train-frames", type=int, default=48)
    ap.add_argument("--train-epochs", type=int, default=4)
    args = ap.parse_args()
    import torch
    from dataclasses import asdict

    from staticdepth.adaptation.config import AlignConfig

    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.deploy import (MetricOnnx, deployment_constants, export_model,
                                    metric_depth_reference)
    from staticdepth.models import load_model
    from staticdepth.models.registry import default_builtin_path
    from staticdepth.metrics import evaluate
    from staticdepth.train_builtin import TrainBuiltinConfig, train_builtin

    torch.set_num_threads(args.threads)
    w, h = (int(x) for x in args.size.split("x"))
    tmp = tempfile.mkdtemp(prefix="bench_export_")
    seq = os.path.join(tmp, "s.h5")
    render_to_file(seq, preset_name="demo", n_frames=args.frames, adapt_frames=args.frames,
                   seed=0, overrides={"width": w, "height": h})
    spec = args.model
    if spec is None and os.path.isfile(default_builtin_path()):
        spec = "builtin"
    if spec is None:
        path = os.path.join(tmp, "m.pt")
        t0 = time.perf_counter()
        train_builtin(TrainBuiltinConfig(frames=args.train_frames, epochs=args.train_epochs,
                                         width=128, height=64, seed=0), out=path,
                      log=lambda s: None)
        print(f"trained a built-in network: {args.train_frames} frames, {args.train_epochs} "
              f"epochs, 128x64 ({time.perf_counter() - t0:.0f} s)")
        spec = f"builtin:{path}"
    with SequenceReader(seq) as r:
        m = r.meta.mounting
        frames = [r.left(i) for i in range(len(r))]
        gts = [r.depth(i) for i in range(len(r))]
    model = load_model(spec)
    print(f"model {spec}, {w}x{h}, {len(frames)} frames, {args.threads} threads")
    for mode in (("eq2", "ground", "upright") if args.mode == "all" else (args.mode,)):
        summary = os.path.join(tmp, f"{mode}.adapt.json")
        with open(summary, "w") as f:
            json.dump({"plane": {"normal": m.normal.tolist()}, "camera_height_m": m.height_m,
                       "scale": {"ft-align": m.height_m},
                       "config": {"detector": {"name": "gt"},
                                  "align": {**asdict(AlignConfig()), "mode": mode}}}, f)
        out = os.path.join(tmp, f"{mode}.onnx")
        info = export_model(spec, summary, seq, out, check_frames=3, log=lambda s: None)
        c = deployment_constants(summary, seq, log=lambda s: None)
        onnx = MetricOnnx(out, threads=args.threads)

        def run(fn):
            fn(frames[0])                                   # warm-up
            t0 = time.perf_counter()
            outs = [fn(im) for im in frames]
            return len(frames) / (time.perf_counter() - t0), outs

        fps_ref, ref = run(lambda im: metric_depth_reference(model, im, c))
        fps_onnx, got = run(onnx.predict)
        rel = np.concatenate([np.abs(g - r_)[np.isfinite(r_)] / r_[np.isfinite(r_)]
                              for g, r_ in zip(got, ref)])
        absrel = [float(np.mean([evaluate(p, gt, "metric")["abs_rel"] for p, gt in zip(x, gts)]))
                  for x in (ref, got)]
        print(f"-- align.mode {mode} (colour foot: {onnx.metadata['staticdepth.colour_foot']})")
        print(f"torch/numpy pipeline: {fps_ref:.2f} frames/s")
        print(f"exported ONNX:        {fps_onnx:.2f} frames/s")
        print(f"ratio ONNX / pipeline: {fps_onnx / fps_ref:.2f}x (goal >= 2)")
        print(f"metric depth difference: median {100 * np.median(rel):.4f}%, p99 "
              f"{100 * np.percentile(rel, 99):.3f}% (goal: median <= 0.5%); export's own check "
              f"{100 * info['median_rel_diff']:.4f}%")
        print(f"AbsRel vs the true depth (metric): pipeline {absrel[0]:.4f}, ONNX {absrel[1]:.4f}")


if __name__ == "__main__":
    main()
