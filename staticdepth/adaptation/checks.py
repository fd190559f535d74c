"""Fail fast: everything ``adapt`` needs is checked before the first frame is predicted.

The configuration (built and validated by the dataclasses), the sequence (an adaptation split;
instances for ``detector gt``), the output paths (the sequence's folder for its prediction store
and stage files, the summary's and the saved model's folders), the model (it loads; for
fine-tuning it is a torch model whose layer group exists) and the detector (its weights load).
"""
from __future__ import annotations

import os

from staticdepth.adaptation import agents
from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.config import AdaptConfig, is_builtin
from staticdepth.errors import InputError


def writable_folder(path: str, what: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InputError(f"the folder of the {what} does not exist", path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"cannot write the {what} there (permission denied)", folder)


def prepare(conf: AdaptConfig, ws: Workspace, *, device=None, summary_path: str,
            save_model: str | None = None):
    """Check everything; returns (model on its device, detector or None, trained layer group)."""
    from staticdepth.adaptation.finetune import trainable_layers
    from staticdepth.models import TorchDepthModel, load_model

    if len(ws.adapt_split) == 0:
        raise InputError("the sequence has no adaptation split (adapt_frames = 0)", ws.seq)
    writable_folder(ws.seq, "sequence's predictions")
    for p in (ws.dir, ws.seq + ".pred"):
        if os.path.exists(p) and not os.path.isdir(p):
            raise InputError("exists and is not a folder", p)
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
        if layers != conf.finetune.layers:
            ws.log(f"model {conf.model!r} names no layer groups: fine-tuning all its parameters")
    if device is not None and isinstance(model, TorchDepthModel):
        model.to(device)
    return model, detector, layers
