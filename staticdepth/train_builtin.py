"""Train the built-in depth network on synthetic street-level scenes (``staticdepth train-builtin``).

Frames come from the ``street`` preset (a level camera 1.6 m up, the view off-the-shelf networks
are trained on), over several seeds (layouts) and times (agents); each layout's camera pitch and
height vary a little around street level (-3..12 deg, 1.2..2.2 m), so that the network learns
perspective cues rather than "the horizon is the middle row". Targets are inverse depth 1/Z,
0 for the sky; the loss is MiDaS's median/MAD-normalised scale-and-shift-invariant L1 with
gradient matching (the least-squares variant stalls from a random start), all layers, Adam 1e-3, flips. Weights go to ``--out`` atomically with their training
settings; nothing is downloaded.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import time
from dataclasses import dataclass

import numpy as np

from staticdepth.config import check_ranges, check_seed
from staticdepth.errors import InputError

FRAMES_PER_LAYOUT = 8      # frames rendered per scene seed (10 frames = 1 s apart)
MAX_LR = 1.0               # Adam steps move every weight by about lr: above 1 nothing trains


@dataclass(frozen=True)
class TrainBuiltinConfig:
    frames: int = 400
    epochs: int = 15
    width: int = 384
    height: int = 192
    lr: float = 1e-3
    batch_size: int = 8
    seed: int = 0
    max_steps: int = 0            # optimiser steps at most (0 = every epoch's; adapt's fine-tuning
    #                               has a budget of its own, finetune.max_steps)
    preset: str = "street"
    arch: str = "tiny"            # "tiny" (TinyDepthNet) or "unet" (models/unet.py)
    # street-level poses vary a little (cars, tripods, hand-held): one pitch and height per layout
    pitch_range_deg: tuple[float, float] = (-3.0, 12.0)
    height_range_m: tuple[float, float] = (1.2, 2.2)

    def __post_init__(self):
        check_seed(self.seed)
        check_ranges(self, "", {"frames": ">=1", "epochs": ">=1", "width": ">=1",
                                "height": ">=1", "lr": ">0", "batch_size": ">=1",
                                "max_steps": ">=0"}, options=True)
        if self.lr > MAX_LR:
            raise InputError(f"--lr must be in (0, {MAX_LR:g}], got {self.lr:g} (Adam's "
                             f"default is 1e-3)")


def parse_size(text: str) -> tuple[int, int]:
    """``"384x192"`` -> (384, 192), both multiples of 32."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"size must look like 384x192, got {text!r}") from None
    if w < 32 or h < 32 or w % 32 or h % 32:
        raise InputError(f"size sides must be multiples of 32 and >= 32, got {text!r}")
    return w, h


def render_training_set(conf: TrainBuiltinConfig) -> tuple[np.ndarray, np.ndarray]:
    """(frames, H, W, 3) uint8 images and (frames, H, W) float32 inverse-depth targets."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    images = np.empty((conf.frames, conf.height, conf.width, 3), np.uint8)
    targets = np.empty((conf.frames, conf.height, conf.width), np.float32)
    k = 0
    layout = 0
    while k < conf.frames:
        seed = conf.seed * 1000 + layout
        rng = np.random.default_rng([seed, 7])
        scene = SyntheticScene(preset(conf.preset, seed=seed, width=conf.width, height=conf.height,
                                      pitch_deg=float(rng.uniform(*conf.pitch_range_deg)),
                                      camera_height_m=float(rng.uniform(*conf.height_range_m))))
        for j in range(min(FRAMES_PER_LAYOUT, conf.frames - k)):
            f = scene.render(10 * j)
            images[k] = f["left"]
            with np.errstate(divide="ignore"):
                targets[k] = np.where(np.isfinite(f["depth"]), 1.0 / f["depth"], 0.0)
            k += 1
        layout += 1
    return images, targets


def train_builtin(conf: TrainBuiltinConfig, *, out: str | os.PathLike, device=None,
                  checkpoint: str | None = None, log=print):
    """Render, train, save; returns (model, history)."""
    import torch

    from staticdepth.finetune import DivergedError, FinetuneConfig, finetune
    from staticdepth.models.tiny import builtin_model, save_builtin

    from staticdepth.fileio import check_writable

    out = os.fspath(out)
    check_writable(out)  # a folder, a missing or read-only folder: refused before training
    t0 = time.perf_counter()
    images, targets = render_training_set(conf)
    log(f"rendered {len(images)} {conf.preset} frames {conf.width}x{conf.height} "
        f"in {time.perf_counter() - t0:.1f} s")
    torch.manual_seed(conf.seed)
    if conf.arch not in ("tiny", "unet"):
        raise InputError(f"arch must be tiny or unet, got {conf.arch!r}")
    net = None
    if conf.arch == "unet":
        from staticdepth.models.unet import TinyUNet
        net = TinyUNet()
    model = builtin_model(net, input_height=conf.height, input_width=conf.width)
    if device is not None:
        model.to(device)
    # every epoch asked for (FinetuneConfig's default budget of 60 steps is adapt's: it cut
    # the README's 125-step network at 60 without a word), or --max-steps
    ft = FinetuneConfig(epochs=conf.epochs, lr=conf.lr, batch_size=conf.batch_size,
                        seed=conf.seed, layers="all", flip=True, loss="ssi_mae",
                        max_steps=conf.max_steps)
    try:
        history = finetune(model, images, targets, conf=ft, checkpoint=checkpoint,
                           on_epoch=lambda r: log(f"epoch {r['epoch']}: loss {r['loss']:.4f} "
                                                  f"({r['seconds']:.1f} s)"))
    except DivergedError as e:
        raise InputError(f"training diverged (loss {e.loss}); lower --lr (it was "
                         f"{conf.lr:g})") from None
    model.to("cpu")
    # the weights depend on torch's thread count too (its reductions' order), not on the seed
    # alone: written down so that a run can be reproduced (docs/gains.md, thirteenth round)
    save_builtin(out, model, info={"train": dataclasses.asdict(conf),
                                   "final_loss": history[-1]["loss"] if history else None,
                                   "torch": str(torch.__version__),
                                   "torch_threads": torch.get_num_threads()})
    if checkpoint and os.path.exists(checkpoint):
        os.remove(checkpoint)
    return model, history


def register(sub) -> None:
    p = sub.add_parser("train-builtin", help="train the built-in small depth network",
                       description="Train the toolkit's small depth network on synthetic "
                                   "street-level scenes (level camera, 1.6 m up). No download.")
    p.add_argument("--out", required=True, help="weights file to write (e.g. builtin.pt)")
    p.add_argument("--frames", type=int, default=TrainBuiltinConfig.frames,
                   help="street-level training frames to render")
    p.add_argument("--epochs", type=int, default=TrainBuiltinConfig.epochs,
                   help="passes over the training frames")
    p.add_argument("--size", default="384x192", help="training size WxH, multiples of 32")
    p.add_argument("--lr", type=float, default=TrainBuiltinConfig.lr, help="Adam learning rate")
    p.add_argument("--batch-size", type=int, default=TrainBuiltinConfig.batch_size,
                   help="frames per optimisation step")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the scenes and the training (the weights also depend on "
                        "torch's thread count, written into the file)")
    p.add_argument("--max-steps", type=int, default=0,
                   help="stop after this many optimiser steps (0: train every epoch)")
    p.add_argument("--arch", choices=("tiny", "unet"), default="tiny",
                   help="network: tiny (the default encoder-decoder) or unet (a second one)")
    from staticdepth.cli import add_device_argument, add_overwrite_argument
    add_device_argument(p)
    add_overwrite_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing, resolve_device
    from staticdepth.fileio import check_writable

    check_writable(args.out)       # a folder, a missing or read-only folder: said first
    refuse_existing(args.out, overwrite=args.overwrite)
    w, h = parse_size(args.size)
    conf = TrainBuiltinConfig(frames=args.frames, epochs=args.epochs, width=w, height=h,
                              lr=args.lr, batch_size=args.batch_size, seed=args.seed,
                              arch=args.arch, max_steps=args.max_steps)
    device = resolve_device(args.device)
    _, hist = train_builtin(conf, out=args.out, device=device, checkpoint=args.out + ".ckpt")
    import torch        # loaded by the training already

    threads = f"{torch.get_num_threads()} torch threads"
    print(f"wrote {args.out} (final loss {hist[-1]['loss']:.4f}, {threads})" if hist
          else f"wrote {args.out} ({threads})")
    return 0
