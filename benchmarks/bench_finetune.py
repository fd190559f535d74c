"""Fine-tuning speed of the built-in model: 300 frames at 384x192, the default 30 epochs.

Renders the adaptation frames of the synthetic ``c1`` scene at 384x192, labels them with the
built-in model's own prediction and the ground-truth agent masks (pseudo labels, METHOD.md 1),
then fine-tunes with the ``builtin`` preset (decoder, Adam 1e-4, batch 4, flips). Prints the time
per epoch, the total against the 10-minute budget (ratio < 1 passes), the peak memory, and the
per-epoch time as a ratio to one inference pass over the same frames (measured in the same run).

    .venv/bin/python benchmarks/bench_finetune.py [--frames 300] [--epochs 30] [--model PATH.pt]
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import torch

BUDGET_S = 600.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--size", default="384x192")
    ap.add_argument("--model", default="", help="built-in weights (default: random init)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from staticdepth.dataset.synth import SyntheticScene, preset
    from staticdepth.finetune import PRESETS, finetune
    from staticdepth.models.tiny import builtin_model, load_builtin
    from staticdepth.pseudo_labels import pseudo_label
    from staticdepth.train_builtin import parse_size

    w, h = parse_size(args.size)
    torch.manual_seed(0)
    model = load_builtin(args.model) if args.model else builtin_model(input_height=h, input_width=w)
    scene = SyntheticScene(preset("c1", seed=0, width=w, height=h))
    t0 = time.perf_counter()
    frames = [scene.render(i) for i in range(args.frames)]
    images = np.stack([f["left"] for f in frames])
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    preds = [model.predict(im) for im in images]
    t_infer = time.perf_counter() - t0
    labels = np.stack([pseudo_label(p, f["instances"], f["agents"])[0] for p, f in zip(preds, frames)])
    conf = dataclasses.replace(PRESETS["builtin"], epochs=args.epochs)
    t0 = time.perf_counter()
    hist = finetune(model, images, labels, conf=conf)
    total = time.perf_counter() - t0
    per_epoch = [r["seconds"] for r in hist]
    print(f"frames {args.frames} at {w}x{h}, epochs {args.epochs}, threads {args.threads}, "
          f"config {conf}")
    print(f"render {t_render:.1f} s; one inference pass {t_infer:.2f} s")
    print(f"epoch time: median {np.median(per_epoch):.2f} s, min {min(per_epoch):.2f} s, "
          f"max {max(per_epoch):.2f} s")
    print(f"ratio epoch / inference pass: {np.median(per_epoch) / t_infer:.2f}")
    print(f"total fine-tuning {total:.1f} s; ratio to the {BUDGET_S:.0f} s budget: "
          f"{total / BUDGET_S:.3f} ({'PASS' if total < BUDGET_S else 'FAIL'})")
    print(f"peak memory {hist[-1]['peak_memory_mb']:.0f} MiB; loss {hist[0]['loss']:.4f} -> "
          f"{hist[-1]['loss']:.4f}")


if __name__ == "__main__":
    main()
