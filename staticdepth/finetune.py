"""Light fine-tuning of a torch depth model on (pseudo) labels in its own inverse-depth space.

``train_step(model, batch, conf, optimizer)`` is the pure step (forward, loss, backward, update);
:func:`finetune` is the loop that owns data order, flips, the checkpoint (atomic, resumable), the
progress bar with the loss, and per-epoch time and peak memory. The network runs in eval mode
(dropout off, normalisation statistics frozen): only the chosen layers change.

Defaults follow METHOD.md section 1: scale-and-shift-invariant loss + 0.5 x gradient matching,
Adam 1e-5, batch 4, horizontal flips, 30 epochs, decoder layers, and a budget of 60 optimiser
steps (``max_steps``): the paper adapts on the first 200-800 frames of a sequence, where 30 epochs
would be 1500-6000 steps; the cap keeps the cost bounded whatever the split's length. 60 was
chosen on the independent scenes (``bench_gains.py``, i1 and i3, 27 adaptation frames, aligned
labels, Adam 1e-3): against 21 steps (3 epochs) the built-in network's agents 0.155 -> 0.144 and
0.134 -> 0.131, ft-align 0.199 -> 0.196 and 0.208 -> 0.208; the U-Net's agents 0.325 -> 0.375 and
0.438 -> 0.460 (still below base 0.396 / 0.500), ft-align 0.286 -> 0.289 and 0.285 -> 0.277. The ``builtin`` preset uses Adam
3e-4: the built-in network is ~100x smaller than DPT and trained at 1e-3. Chosen on the
independent scenes i1-i4 (``benchmarks/bench_gains.py``, 27 adaptation frames, 60 steps, both
networks, ``finetune.seed`` 0 / 1 / 2) from 1e-4, 2e-4, 3e-4, 5e-4 and 1e-3: ft-align averaged
over scenes, seeds and the two networks 0.1377 / 0.1357 / 0.1326 / 0.1336 / 0.1371 (the U-Net
0.130 / 0.128 / 0.125 / 0.131 / 0.135, the built-in 0.145 / 0.143 / 0.141 / 0.136 / 0.139); on
the held-out h1-h3 the same means as 1e-3 or lower (0.1465 / 0.1465 built-in, 0.166 / 0.171 U-Net)
with seeds within 0.005 where 1e-3's differed by up to 0.058 (docs/gains.md, eighteenth round).
The ``builtin`` preset's loss is ``si`` (scale only, no
shift): adapt's labels (``pseudo_labels.untrusted=base``) are shift-free inverse depth, and a
shift-invariant loss let the fine-tuned network keep any shift, which median-scaled depth
``1 / prediction`` cannot undo (the U-Net's i2 structures: 0.186 base, 0.418 ft with ``ssi`` and
every pixel labelled; 0.128 with trusted labels and ``si`` at 60 steps; docs/gains.md, fine-tuning).
"""
from __future__ import annotations

import dataclasses
import math
import os
import resource
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch

from staticdepth.config import check_ranges, check_seed, config_hash
from staticdepth.errors import InputError
from staticdepth.losses import LOSSES, masked_l1
from staticdepth.models.base import TorchDepthModel
from staticdepth.progress import progress

CHECKPOINT_FORMAT = "staticdepth.finetune/1"


@dataclass(frozen=True)
class FinetuneConfig:
    epochs: int = 30
    lr: float = 1e-5
    batch_size: int = 4
    seed: int = 0
    flip: bool = True
    loss: str = "ssi"             # "ssi", "ssi_mae", "si" (scale only; all three + gradient
    #                               matching) or "l1"
    grad_weight: float = 0.5
    layers: str = "decoder"       # "head", "decoder" or "all"
    weight_decay: float = 0.0
    agent_weight: float = 1.0     # loss weight of the agents' pixels (the relabelled ones) against
    #                               every other pixel's 1 (adapt: the agents of the instance maps)
    max_steps: int = 60           # budget of optimiser steps (0 = none): training stops after
    #                               min(epochs x batches per epoch, max_steps) steps, so its cost
    #                               does not grow with the adaptation split; every epoch is a
    #                               random order of the whole split, so a cut epoch still draws
    #                               its frames from all of it

    def __post_init__(self):
        check_seed(self.seed, "finetune.seed")
        check_ranges(self, "finetune.", {"grad_weight": ">=0", "weight_decay": ">=0"})
        if not (np.isfinite(self.agent_weight) and self.agent_weight > 0):
            raise InputError(f"finetune.agent_weight must be > 0, got {self.agent_weight}")
        if self.loss not in LOSSES:
            raise InputError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if self.max_steps < 0:
            raise InputError(f"finetune.max_steps must be >= 0 (0 = no budget), got {self.max_steps}")
        check_ranges(self, "finetune.", {"epochs": ">=0", "batch_size": ">=1", "lr": ">0"})


# builtin: Adam 3e-4 and the scale-only loss on adapt's shift-free trusted labels
# (pseudo_labels.untrusted): see the module docstring
PRESETS = {"paper": FinetuneConfig(), "builtin": FinetuneConfig(lr=3e-4, loss="si")}


class DivergedError(InputError):
    """The loss became NaN or inf (``loss``): the learning rate is too high for the data.
    ``train-builtin`` says it with its own option (--lr)."""

    def __init__(self, loss: float):
        self.loss = loss
        super().__init__(f"fine-tuning diverged (loss {loss}); lower the learning rate "
                         "(finetune.lr)")


def compute_loss(pred: torch.Tensor, batch: dict[str, torch.Tensor], conf: FinetuneConfig
                 ) -> torch.Tensor:
    if conf.loss == "l1":
        return masked_l1(pred, batch["target"], batch["mask"])
    return LOSSES[conf.loss](pred, batch["target"], batch["mask"], grad_weight=conf.grad_weight)


def train_step(model: TorchDepthModel, batch: dict[str, torch.Tensor], conf: FinetuneConfig,
               optimizer: torch.optim.Optimizer) -> float:
    """One update. batch: image (B, 3, H, W) in [0, 1], target (B, H, W), mask (B, H, W) bool."""
    optimizer.zero_grad(set_to_none=True)
    pred = model.forward(batch["image"])
    loss = compute_loss(pred, batch, conf)
    value = float(loss.detach())    # float(loss) itself warns: the loss requires grad
    if not math.isfinite(value):
        raise DivergedError(value)
    loss.backward()
    optimizer.step()
    return value


def make_batch(images: np.ndarray, targets: np.ndarray, masks: np.ndarray, idx: np.ndarray,
               flip: np.ndarray, device) -> dict[str, torch.Tensor]:
    """Stack frames ``idx`` (flipping those with ``flip``) into tensors on ``device``."""
    im = images[idx].copy()
    tg = targets[idx].copy()
    mk = masks[idx].copy()
    im[flip] = im[flip][:, :, ::-1]
    tg[flip] = tg[flip][:, :, ::-1]
    mk[flip] = mk[flip][:, :, ::-1]
    return {"image": torch.from_numpy(np.ascontiguousarray(im)).to(device).permute(0, 3, 1, 2).float() / 255,
            "target": torch.from_numpy(np.ascontiguousarray(tg, dtype=np.float32)).to(device),
            "mask": torch.from_numpy(np.ascontiguousarray(mk)).to(device)}


def epoch_order(n: int, conf: FinetuneConfig, epoch: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame order and flips of one epoch: a function of (seed, epoch) only, so resuming repeats it."""
    rng = np.random.default_rng([conf.seed, epoch])
    order = rng.permutation(n)
    flips = rng.random(n) < 0.5 if conf.flip else np.zeros(n, bool)
    return order, flips


def epoch_steps(n: int, conf: FinetuneConfig) -> list[int]:
    """Batches run in each epoch for ``n`` frames: ``ceil(n / batch_size)`` per epoch, the total
    cut at ``conf.max_steps`` (when > 0), so the last epoch may be shorter and later ones absent."""
    per = -(-n // conf.batch_size)
    total = conf.epochs * per
    if conf.max_steps > 0:
        total = min(total, conf.max_steps)
    return [min(per, total - e * per) for e in range(-(-total // per))] if per else []


def _peak_memory_mb(device) -> float:
    if getattr(device, "type", "cpu") == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2 ** 20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # Linux: KiB


def _trainable_state(model: TorchDepthModel) -> dict[str, torch.Tensor]:
    names = {id(p): n for n, p in model.net.named_parameters()}
    state = {names[id(p)]: p.detach().cpu().clone() for p in model.net.parameters() if p.requires_grad}
    state.update({f"buffer:{n}": b.detach().cpu().clone() for n, b in model.net.named_buffers()})
    return state


def _load_trainable_state(model: TorchDepthModel, state: dict[str, torch.Tensor]) -> None:
    params = dict(model.net.named_parameters())
    buffers = dict(model.net.named_buffers())
    with torch.no_grad():
        for k, v in state.items():
            if k.startswith("buffer:"):
                buffers[k[7:]].copy_(v)
            else:
                params[k].copy_(v)


def save_checkpoint(path: str, payload: dict[str, Any]) -> None:
    """``torch.save`` atomically."""
    from staticdepth.fileio import atomic_torch_save

    atomic_torch_save(path, payload, "ckpt")


def data_fingerprint(images: np.ndarray, targets: np.ndarray) -> str:
    return config_hash({"shape": list(images.shape), "img": float(images[:, ::7, ::7].astype(np.float64).sum()),
                        "tgt": float(np.nansum(targets[:, ::7, ::7], dtype=np.float64))})


def finetune(model: TorchDepthModel, images: np.ndarray, targets: np.ndarray,
             masks: np.ndarray | None = None, conf: FinetuneConfig = PRESETS["paper"], *,
             checkpoint: str | os.PathLike | None = None,
             on_epoch: Callable[[dict[str, float]], None] | None = None) -> list[dict[str, float]]:
    """Fine-tune ``model`` in place; returns one record per epoch run (steps, loss, seconds,
    peak_memory_mb): ``conf.epochs`` over the frames, cut at ``conf.max_steps`` (:func:`epoch_steps`).

    Args:
        images: (N, H, W, 3) uint8 RGB at the training size.
        targets: (N, H, W) float32 labels in the model's inverse-depth space (NaN = ignore).
        masks: (N, H, W) bool pixels used by the loss (default: finite targets).
        checkpoint: written atomically after every epoch; when it exists (same config and data)
            training resumes after its last epoch.
    """
    if images.ndim != 4 or images.shape[:3] != targets.shape:
        raise InputError(f"images {images.shape} and targets {targets.shape} do not match")
    n = len(images)
    if n == 0:
        raise InputError("nothing to fine-tune on: no frame")
    masks = np.isfinite(targets) if masks is None else (np.asarray(masks, bool) & np.isfinite(targets))
    device = model.device
    torch.manual_seed(conf.seed)
    params = model.set_trainable(conf.layers)
    optimizer = torch.optim.Adam(params, lr=conf.lr, weight_decay=conf.weight_decay)
    key = {"config": config_hash(conf), "data": data_fingerprint(images, targets)}
    history: list[dict[str, float]] = []
    start = 0
    ckpt_path = None if checkpoint is None else os.fspath(checkpoint)
    if ckpt_path and os.path.exists(ckpt_path):
        try:
            ck = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        except Exception as e:
            raise InputError(f"unreadable fine-tuning checkpoint ({type(e).__name__}); delete it "
                             "to start again", ckpt_path) from None
        if ck.get("format") != CHECKPOINT_FORMAT or ck.get("key") != key:
            raise InputError("checkpoint belongs to another configuration or data; delete it or "
                             "choose another path", ckpt_path)
        _load_trainable_state(model, ck["state"])
        optimizer.load_state_dict(ck["optimizer"])
        history, start = list(ck["history"]), int(ck["epoch"])
    model.net.eval()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    plan = epoch_steps(n, conf)
    for epoch in range(start, len(plan)):
        t0 = time.perf_counter()
        order, flips = epoch_order(n, conf, epoch)
        losses = []
        steps = range(0, plan[epoch] * conf.batch_size, conf.batch_size)
        bar = progress(steps, total=len(steps), desc=f"fine-tune {epoch + 1}/{len(plan)}", unit="batch")
        for s in bar:
            idx = order[s:s + conf.batch_size]
            batch = make_batch(images, targets, masks, idx, flips[idx], device)
            losses.append(train_step(model, batch, conf, optimizer))
            if hasattr(bar, "set_postfix"):
                bar.set_postfix(loss=f"{np.mean(losses):.4g}")
        rec = {"epoch": epoch + 1, "steps": len(losses), "loss": float(np.mean(losses)),
               "seconds": time.perf_counter() - t0, "peak_memory_mb": _peak_memory_mb(device)}
        history.append(rec)
        if ckpt_path:
            save_checkpoint(ckpt_path, {"format": CHECKPOINT_FORMAT, "key": key,
                                        "config": dataclasses.asdict(conf), "epoch": epoch + 1,
                                        "state": _trainable_state(model),
                                        "optimizer": optimizer.state_dict(), "history": history})
        if on_epoch:
            on_epoch(rec)
    for p in model.net.parameters():
        p.requires_grad_(False)
    return history
