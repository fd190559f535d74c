"""Fail fast: everything ``adapt`` needs is checked before the first frame is predicted.

The configuration (built and validated by the dataclasses), the sequence (an adaptation split;
instances for ``detector gt``), the output paths (the sequence's folder for its prediction store
and stage files, the summary's and the saved model's folders), the model (it loads; for
fine-tuning it is a torch model whose layer group exists) and the detector (its weights load);
then, with the stage hashes, that the disk holds the outputs still to write (:func:`disk_space`).
"""
from __future__ import annotations

import os
import shutil

import numpy as np

from staticdepth.adaptation import agents
from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.config import AdaptConfig, is_builtin
from staticdepth.errors import InputError
from staticdepth.fileio import check_writable


def writable_folder(path: str, what: str, inside: bool = False) -> None:
    """A file can be created at ``path`` (``inside``: in the folder ``path`` when it exists): a
    probe file is created and removed (permissions alone say nothing for root or a read-only
    mount)."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InputError(f"the folder of the {what} does not exist", path)
    try:
        check_writable(os.path.join(path, "probe") if inside and os.path.isdir(path) else path)
    except InputError as e:
        raise InputError(f"cannot write the {what} there ({e.problem})", path) from None


def usable_agents(conf: AdaptConfig, ws: Workspace) -> None:
    """Tracking settings no agent of this sequence can pass (the ground plane would fail only
    after every frame is predicted; each setting's own range is TrackingConfig's)."""
    t, n_split = conf.tracking, len(ws.adapt_split)
    if t.min_height_px >= ws.height:
        raise InputError(f"tracking.min_height_px = {t.min_height_px} is not below the image "
                         f"height ({ws.height} px): no agent can be kept", ws.seq)
    if t.min_frames > n_split:
        raise InputError(f"tracking.min_frames = {t.min_frames} is more than the adaptation "
                         f"split's {n_split} frames: no track can be kept", ws.seq)


def prepare(conf: AdaptConfig, ws: Workspace, *, device=None, summary_path: str,
            save_model: str | None = None):
    """Check everything; returns (model on its device, detector or None, trained layer group)."""
    from staticdepth.adaptation.finetune import trainable_layers
    from staticdepth.models import TorchDepthModel, load_model

    if len(ws.adapt_split) == 0:
        raise InputError("the sequence has no adaptation split (adapt_frames = 0)", ws.seq)
    usable_agents(conf, ws)
    for p in (ws.dir, ws.seq + ".pred"):
        if os.path.exists(p) and not os.path.isdir(p):
            raise InputError("exists and is not a folder", p)
        writable_folder(p, "sequence's predictions and stage files", inside=True)
    writable_folder(summary_path, "summary")
    if save_model:
        if not is_builtin(conf.model):
            raise InputError("--save-model writes the built-in network only (model builtin:...)")
        if conf.finetune.epochs == 0:
            raise InputError("--save-model needs fine-tuning (--epochs > 0)")
        writable_folder(save_model, "saved model")
    detector = agents.make(conf, ws)
    model = load_model(conf.model)
    layers = conf.finetune.layers
    if conf.finetune.epochs > 0:
        if not isinstance(model, TorchDepthModel):
            raise InputError(f"model {conf.model!r} runs inference only (ONNX): fine-tuning needs "
                             "a torch model (builtin:, hf:, torch:) or --epochs 0")
        layers = trainable_layers(model, layers)
        pl = conf.pseudo_labels
        if conf.finetune.loss == "si" and (pl.source != "aligned" or pl.untrusted == "label"):
            raise InputError("finetune.loss=si (no shift) needs shift-free labels: "
                             "pseudo_labels.source=aligned with pseudo_labels.untrusted=base, "
                             "ignore or aligned (or finetune.loss=ssi)")
        if layers != conf.finetune.layers:
            ws.log(f"model {conf.model!r} names no layer groups: fine-tuning all its parameters")
    if device is not None and isinstance(model, TorchDepthModel):
        model.to(device)
    return model, detector, layers


def probe_model(conf: AdaptConfig, ws: Workspace, model, base_hash: str) -> bool:
    """Run the network on the first adaptation frame before any stage: a model whose output is
    not one map of the frame (a wrong output head, a segmentation export) or not finite fails
    in seconds, not after the agents' pass over the sequence. Not run (False) when the base
    prediction of these settings (``base_hash``, which holds the model's identity) is complete:
    this model has already made every map of the sequence."""
    if ws.pred_done("base", base_hash):
        return False
    i = int(ws.adapt_split[0])
    with ws.reader() as r:
        inv = np.asarray(model.predict(r.left(i)))
    if inv.shape != (ws.height, ws.width):
        raise InputError(f"model {conf.model!r} returned a map of shape {inv.shape} for a "
                         f"{ws.width}x{ws.height} frame; expected {(ws.height, ws.width)}")
    if not np.isfinite(inv).any():
        raise InputError(f"model {conf.model!r} returned no finite value on frame {i}")
    return True


# (output, stage hash it carries, bytes per pixel); "<name>" = the prediction store's file
PER_FRAME_FILES = (("<base>", "base", 4), ("<ft>", "ft", 4), ("<align>", "align", 4),
                   ("<ft-align>", "align", 4), ("<align-metric>", "scale", 4),
                   ("<ft-align-metric>", "scale", 4), ("inverse-base.h5", "base", 4),
                   ("agents.h5", "agents", 2), ("labels.h5", "pseudo_labels", 4))
MARGIN_BYTES = 1 << 20          # per file: HDF5 metadata, checksums, rows


def output_bytes(conf: AdaptConfig, ws: Workspace, hashes: dict[str, str], model=None
                 ) -> tuple[int, int]:
    """(bytes adapt may still write, number of per-frame maps in it): every per-frame file
    uncompressed (an upper bound: the files are compressed) for the frames not yet written with
    these settings (complete files are skipped, partial ones resumed), plus the fine-tuning
    checkpoint (the weights and Adam's two moments) while the fine-tuned prediction is not."""
    from staticdepth.dataset.framefile import frames_left
    from staticdepth.dataset.predictions import prediction_path

    total, maps, ft_left = 0, 0, 0
    px = ws.height * ws.width
    for name, stage, bpp in PER_FRAME_FILES:
        if name == "agents.h5" and conf.detector.name == "gt":
            continue
        n = len(ws.adapt_split) if name == "labels.h5" else ws.n
        path = prediction_path(ws.seq, name[1:-1]) if name[0] == "<" else ws.path(name)
        left = frames_left(path, ws.identity, hashes[stage], n)
        ft_left += left if name == "<ft>" else 0
        if left:
            total += left * (px * bpp + 4) + MARGIN_BYTES
            maps += left
    if ft_left and conf.finetune.epochs > 0 and hasattr(model, "net"):
        total += 3 * sum(p.numel() * p.element_size() for p in model.net.parameters())
    return total, maps


def disk_space(conf: AdaptConfig, ws: Workspace, hashes: dict[str, str], model=None) -> None:
    """Refuse to start when the sequence's folder (the prediction store and stage files go
    beside it) has less free space than :func:`output_bytes`."""
    need, maps = output_bytes(conf, ws, hashes, model)
    folder = os.path.dirname(os.path.abspath(ws.seq))
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(f"not enough free disk space for adapt's outputs: up to "
                         f"{need / 2**30:.2f} GiB ({maps} maps of {ws.width}x{ws.height}, "
                         f"uncompressed), {free / 2**30:.2f} GiB free", folder)
