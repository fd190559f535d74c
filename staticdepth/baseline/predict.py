"""Stage ``baseline predict``: metric depth for every frame, stored beside the sequence as
``<SEQ>.h5.pred/<name>.h5`` (:mod:`staticdepth.dataset.predictions`).

The network sees the left view resized to its input size; its scale-0 inverse depth
(``1/max + (1/min - 1/max) sigmoid``) is upsampled bilinearly to the sequence's size and
inverted (MonoDepth2's evaluation). The warp used the real baseline, so no rescaling follows.
"""
from __future__ import annotations

import json
import os
from typing import Any, Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from staticdepth.baseline.config import BaselineConfig
from staticdepth.baseline.data import resize_rgb, to_float
from staticdepth.baseline.layers import disp_to_depth
from staticdepth.baseline.network import DepthNet, build_model
from staticdepth.baseline.train import load_checkpoint
from staticdepth.errors import InputError
from staticdepth.progress import progress

DEFAULT_NAME = "stereo-baseline"


def load_model(checkpoint_path: str | os.PathLike) -> tuple[DepthNet, dict[str, Any]]:
    """The trained network (CPU, eval mode) and its checkpoint's state (config, geometry)."""
    state = load_checkpoint(checkpoint_path)
    model = build_model(state["config"], load_weights=False)
    model.load_state_dict(state["model"])
    return model.eval(), state


@torch.no_grad()
def predict_depth(model: DepthNet, images: np.ndarray, conf: BaselineConfig) -> np.ndarray:
    """(B, H, W, 3) uint8 RGB -> (B, H, W) float32 metric depth, on the model's device."""
    device = next(model.parameters()).device
    h, w = images.shape[1:3]
    x = np.stack([resize_rgb(im, conf.width, conf.height) for im in images])
    disp = model(to_float(torch.from_numpy(x)).to(device))[0]
    inv = disp_to_depth(disp, conf.min_depth, conf.max_depth)[0]
    inv = F.interpolate(inv, (h, w), mode="bilinear", align_corners=False)
    return (1.0 / inv[:, 0]).float().cpu().numpy()


def _depth_maps(sequence_path: str, model: DepthNet, conf: BaselineConfig, batch_size: int
                ) -> Iterator[np.ndarray]:
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(sequence_path) as r:
        n = len(r)
        for start in progress(range(0, n, batch_size), total=-(-n // batch_size),
                              desc="baseline predict", unit="batch"):
            idx = range(start, min(n, start + batch_size))
            yield from predict_depth(model, np.stack([r.left(i) for i in idx]), conf)


def predict_sequence(sequence_path: str | os.PathLike, checkpoint_path: str | os.PathLike,
                     device: torch.device | str = "cpu", *, name: str = DEFAULT_NAME,
                     batch_size: int = 4, overwrite: bool = False, any_sequence: bool = False,
                     log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Predict every frame of the sequence and store it with ``add_prediction`` as
    ``<SEQ>.h5.pred/<name>.h5``; an existing prediction ``name`` is refused before any work
    unless ``overwrite``.

    The sequence must have the camera the network was trained with (same focal length at the
    network's width), else its metric scale would not hold. A checkpoint trained on another
    sequence (another identity: a stale ``SEQ.baseline.pt`` of a file since replaced, or another
    scene's) is refused unless ``any_sequence``; one that records no identity (written before it
    was stored) is used with a ``log`` warning. The prediction records ``trained_on_id``.
    """
    from staticdepth.dataset.h5 import SequenceReader, add_prediction
    from staticdepth.dataset.predictions import prediction_path

    log = log or (lambda s: None)
    seq = os.fspath(sequence_path)
    if batch_size < 1:
        raise InputError(f"batch size must be >= 1, got {batch_size}")
    out = prediction_path(seq, name)
    if os.path.lexists(out) and not overwrite:
        raise InputError("exists already; pass --overwrite to replace it", out)
    model, state = load_model(checkpoint_path)
    conf: BaselineConfig = state["config"]
    with SequenceReader(seq) as r:
        focal = r.camera.fx * conf.width / r.camera.width
        n, seq_id = len(r), r.sequence_id()
    _check_trained_on(state, os.fspath(checkpoint_path), seq, seq_id, any_sequence, log)
    if abs(focal - state["focal_px"]) > 1e-3 * state["focal_px"]:
        raise InputError(f"the network was trained with focal {state['focal_px']:.2f} px at "
                         f"width {conf.width}, this sequence has {focal:.2f} px: its metric "
                         "depth would be wrong (train on this sequence)", seq)
    model.to(torch.device(device))
    with SequenceReader(seq) as r:          # refuse a collapsed model before storing anything
        from staticdepth.baseline.scene_fit import check_not_collapsed
        probe = [r.left(i) for i in np.linspace(0, n - 1, min(4, n)).astype(int)]
    check_not_collapsed(predict_depth(model, np.stack(probe), conf), conf,
                        f" ({os.fspath(checkpoint_path)})")
    attrs = {"method": "stereo self-supervised baseline (MonoDepth2 S)", "metric": 1,
             "checkpoint": os.path.abspath(os.fspath(checkpoint_path)),
             "baseline_m": float(state["baseline_m"]), "trained_on": str(state["sequence"]),
             "trained_on_id": str(state.get("sequence_id") or "unknown"),
             "config": json.dumps(conf.to_dict())}
    add_prediction(seq, name, _depth_maps(seq, model, conf, batch_size), attrs,
                   overwrite=overwrite)
    return {"name": name, "frames": n}


def _check_trained_on(state: dict[str, Any], ckpt: str, seq: str, seq_id: str, any_sequence: bool,
                      log: Callable[[str], None]) -> None:
    trained_on = state.get("sequence_id")
    if trained_on is None:
        log(f"warning: {ckpt} does not record which sequence it was trained on (an older "
            f"checkpoint); predicting {seq} with it")
    elif trained_on != seq_id and not any_sequence:
        raise InputError(f"the network was trained on another sequence ({state['sequence']!r}, "
                         f"id {trained_on}) than {seq} (id {seq_id}); train on this sequence, or "
                         "pass --any-sequence to predict with it anyway", ckpt)
