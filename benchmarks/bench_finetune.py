"""Fine-tuning speed of the built-in model: 300 frames at 384x192, the default 30 epochs.

Renders the adaptation frames of the synthetic ``c1`` scene at 384x192, labels them with the
built-in model's own prediction and the ground-truth agent masks (pseudo labels, METHOD.md 1),
then fine-tunes with the ``builtin`` preset (decoder, Adam 1e-3, batch 4, flips, the step budget
``max_steps``). Prints the time per epoch, the total against the 10-minute budget (ratio < 1
passes), the peak memory, and the per-epoch time as a ratio to one inference pass over the same
frames (measured in the same run).

``--adapt-frames 200,800``: ``staticdepth adapt`` itself (tiny network, ``--detector gt``, the
default 30 epochs and step budget) on c1 sequences whose adaptation split holds that many frames;
prints the training seconds (the epochs' records), the steps and epochs it ran, what 30 full epochs
would cost at the same seconds per step (``--max-steps 0`` measures them instead), the stage's
lap (training + predicting every frame with the fine-tuned network) and adapt's total.

    .venv/bin/python benchmarks/bench_finetune.py [--frames 300] [--epochs 30] [--model PATH.pt]
    .venv/bin/python benchmarks/bench_finetune.py --adapt-frames 200,800 --size 192x96
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
    ap.add_argument("--max-steps", type=int, default=None, help="finetune.max_steps (default: "
                    "the config's; 0 = no budget)")
    ap.add_argument("--adapt-frames", default="", help="comma-separated adaptation split lengths: "
                    "time adapt's fine-tuning stage on each instead")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.adapt_frames:
        return adapt_budget(args)

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
    if args.max_steps is not None:
        conf = dataclasses.replace(conf, max_steps=args.max_steps)
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
          f"{hist[-1]['loss']:.4f}; {sum(r['steps'] for r in hist)} steps in {len(hist)} epochs")


def adapt_budget(args) -> None:
    """adapt's fine-tuning seconds against the adaptation split's length (see the module doc)."""
    import os
    import tempfile

    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config
    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.finetune import epoch_steps
    from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin
    from staticdepth.train_builtin import parse_size

    w, h = parse_size(args.size)
    sets = {"detector.name": "gt", "finetune.epochs": args.epochs, "tracking.min_height_px": 6,
            "plane.bootstrap": 0}
    if args.max_steps is not None:
        sets["finetune.max_steps"] = args.max_steps
    print(f"adapt at {w}x{h}, tiny network, {args.threads} threads, settings {sets}")
    print(f"{'adapt frames':>12} {'steps':>6} {'epochs':>6} {'train s':>8} {'s/step':>7} "
          f"{'30-epoch steps':>14} {'30-epoch s (est.)':>17} {'stage s':>8} {'adapt s':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        torch.manual_seed(0)
        model = os.path.join(tmp, "tiny.pt")
        save_builtin(model, builtin_model(TinyDepthNet(enc_channels=(4, 8, 8, 16, 16),
                                                       dec_channels=(16, 8, 8, 4)),
                                          input_height=h, input_width=w))
        for n in (int(x) for x in args.adapt_frames.split(",")):
            seq = os.path.join(tmp, f"c1_{n}.h5")
            render_to_file(seq, preset_name="c1", n_frames=n + 4, adapt_frames=n, seed=1,
                           overrides={"width": w, "height": h})
            conf = build_config({"model": f"builtin:{model}", **sets})
            t0 = time.perf_counter()
            s = adapt(seq, conf, device="cpu", log=lambda m: None)
            total = time.perf_counter() - t0
            steps = sum(r["steps"] for r in s["finetune"])
            sec = sum(r["seconds"] for r in s["finetune"])
            full = sum(epoch_steps(n, dataclasses.replace(conf.finetune, epochs=30, max_steps=0)))
            print(f"{n:>12} {steps:>6} {len(s['finetune']):>6} {sec:>8.1f} {sec / steps:>7.3f} "
                  f"{full:>14} {full * sec / steps:>17.0f} {s['timings_s']['finetune']:>8.1f} "
                  f"{total:>8.1f}", flush=True)


if __name__ == "__main__":
    main()
