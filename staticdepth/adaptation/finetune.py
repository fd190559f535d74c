"""Stage finetune: adapt the network on its pseudo labels, streaming the adaptation frames.

The adaptation frames and their labels are read from the files through a torch ``Dataset`` /
``DataLoader`` (a batch sampler gives each epoch's order and flips from
:func:`staticdepth.finetune.epoch_order`), so memory does not grow with the split. Each step is
:func:`staticdepth.finetune.train_step`; the checkpoint ``<SEQ>.h5.adapt/finetune.ckpt`` (atomic,
after every epoch, keyed by the stage hash) resumes an interrupted run and, once complete, is the
fine-tuned network of later runs.

Layers: ``finetune.layers`` names one of the network's layer groups; a network that names no
groups at all (e.g. a plain TorchScript file) trains all its parameters.
"""
from __future__ import annotations

import os
import time
from typing import Any

import numpy as np
import torch

from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.errors import InputError
from staticdepth.fileio import atomic_torch_save
from staticdepth.finetune import (CHECKPOINT_FORMAT, _load_trainable_state, _peak_memory_mb,
                                  _trainable_state, epoch_order, epoch_steps, train_step)
from staticdepth.progress import progress


def trainable_layers(model, layers: str) -> str:
    """The layer group that will be trained (checked now: it must exist and hold parameters)."""
    if layers != "all" and not model.layer_groups:
        layers = "all"
    model.parameters_for(layers)
    return layers


class AdaptationFrames(torch.utils.data.Dataset):
    """Item ``(k, flip)``: frame ``split[k]``'s image (H, W, 3) uint8, label and loss weights
    (0 where the label is not finite; ``agent_weight`` on the agents' pixels - those of the rows
    of ``classes`` in the instance maps of ``detector`` - and 1 elsewhere)."""

    def __init__(self, ws: Workspace, detector: str = "gt", agent_weight: float = 1.0,
                 classes=()):
        self.ws, self.split = ws, ws.adapt_split
        self.detector, self.agent_weight, self.classes = detector, agent_weight, list(classes)
        self._reader = self._labels = self._agents = None

    def __len__(self) -> int:
        return len(self.split)

    def __getitem__(self, item: tuple[int, bool]) -> dict[str, np.ndarray]:
        if self._reader is None:                 # opened lazily: once per worker process
            self._reader, self._labels = self.ws.reader(), self.ws.frame_file("labels.h5")
            if self.agent_weight != 1.0:
                from staticdepth.adaptation.common import Agents

                self._agents = Agents(self.ws, self.detector)
        k, flip = item
        i = self.split[k]
        image, target = self._reader.left(i), self._labels[k]
        weight = np.isfinite(target).astype(np.float32)
        if self._agents is not None:
            rows = self._agents.rows(i)
            ids = rows["instance_id"][np.isin(rows["class_id"], self.classes)]
            inst = np.asarray(self._agents.instances(i))
            weight[np.isin(inst, ids) & (inst > 0)] *= np.float32(self.agent_weight)
        if flip:
            image, target, weight = image[:, ::-1], target[:, ::-1], weight[:, ::-1]
        target = np.ascontiguousarray(target, dtype=np.float32)
        return {"image": np.ascontiguousarray(image), "target": target,
                "mask": np.ascontiguousarray(weight)}

    def close(self) -> None:
        for h in (self._reader, self._labels, self._agents):
            if h is not None:
                h.close()
        self._reader = self._labels = self._agents = None


def _batches(n: int, conf, epoch: int, steps: int) -> list[list[tuple[int, bool]]]:
    """The first ``steps`` batches of epoch ``epoch``'s order (a permutation of all ``n`` frames)."""
    order, flips = epoch_order(n, conf, epoch)
    return [[(int(k), bool(flips[k])) for k in order[s:s + conf.batch_size]]
            for s in range(0, n, conf.batch_size)][:steps]


def _load(path: str) -> dict[str, Any] | None:
    if not os.path.exists(path):
        return None
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception:            # damaged by an interruption: train again
        return None


def run(conf: AdaptConfig, ws: Workspace, model, config_hash: str,
        layers: str) -> list[dict[str, float]]:
    """Fine-tune ``model`` in place; returns one record per epoch run (steps, loss, seconds, peak
    memory): ``finetune.epochs`` over the adaptation split, cut at ``finetune.max_steps``."""
    fc = conf.finetune
    ckpt_path = ws.path("finetune.ckpt")
    os.makedirs(ws.dir, exist_ok=True)
    key = f"{config_hash}/{ws.identity}"         # these settings, on this sequence
    ck = _load(ckpt_path)
    if ck is not None and (ck.get("format") != CHECKPOINT_FORMAT or ck.get("key") != key):
        ck = None
    params = model.set_trainable(layers)
    optimizer = torch.optim.Adam(params, lr=fc.lr, weight_decay=fc.weight_decay)
    history, start = [], 0
    if ck is not None:
        _load_trainable_state(model, ck["state"])
        optimizer.load_state_dict(ck["optimizer"])
        history, start = list(ck["history"]), int(ck["epoch"])
    data = AdaptationFrames(ws, conf.detector.name, fc.agent_weight, conf.pseudo_labels.classes)
    plan = epoch_steps(len(data), fc)
    if start >= len(plan):
        ws.skip("finetune")
    torch.manual_seed(fc.seed)
    model.net.eval()
    device = model.device
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    try:
        for epoch in range(start, len(plan)):
            t0 = time.perf_counter()
            loader = torch.utils.data.DataLoader(
                data, batch_sampler=_batches(len(data), fc, epoch, plan[epoch]), num_workers=0)
            losses = []
            bar = progress(loader, total=len(loader), desc=f"fine-tune {epoch + 1}/{len(plan)}",
                           unit="batch")
            for batch in bar:
                batch = {"image": batch["image"].to(device).permute(0, 3, 1, 2).float() / 255,
                         "target": batch["target"].to(device), "mask": batch["mask"].to(device)}
                losses.append(train_step(model, batch, fc, optimizer))
                ws.count("finetune", len(batch["image"]))
            rec = {"epoch": epoch + 1, "steps": len(losses), "loss": float(np.mean(losses)),
                   "seconds": time.perf_counter() - t0, "peak_memory_mb": _peak_memory_mb(device)}
            history.append(rec)
            atomic_torch_save(ckpt_path, {"format": CHECKPOINT_FORMAT, "key": key,
                                          "epoch": epoch + 1, "state": _trainable_state(model),
                                          "optimizer": optimizer.state_dict(),
                                          "history": history})
            ws.log(f"  epoch {rec['epoch']}/{len(plan)}: {rec['steps']} steps, loss "
                   f"{rec['loss']:.5f} ({rec['seconds']:.1f} s, "
                   f"peak {rec['peak_memory_mb']:.0f} MiB)")
    finally:
        data.close()
    for p in model.net.parameters():
        p.requires_grad_(False)
    if not history and fc.epochs > 0:
        raise InputError("fine-tuning ran no epoch", ckpt_path)
    return history
