"""Stage predict: the network's relative inverse depth D of every frame, in batches.

Writes the prediction ``base`` (or ``ft``): relative depth ``1 / max(D, eps)`` (METHOD.md), and
for ``base`` also D itself into ``<SEQ>.h5.adapt/inverse-base.h5`` (the pseudo labels live in the
network's inverse-depth space). Batches start at multiples of ``predict.batch_size``, also when
resuming, so an interrupted run gives the same maps as an uninterrupted one.
"""
from __future__ import annotations

import contextlib

import numpy as np

from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.geometry.alignment import depth_from_inverse
from staticdepth.progress import progress


def run(conf: AdaptConfig, ws: Workspace, model, config_hash: str, *, name: str = "base",
        keep_inverse: bool = True, attrs: dict | None = None) -> None:
    """Predict every frame into the prediction ``name`` (and ``inverse-<name>.h5``)."""
    B = conf.predict.batch_size
    meta = {"stage": "adapt", "metric": False, "model": conf.model, **(attrs or {})}
    writers = [ws.pred_writer(name, config_hash, meta, chunk=B)]
    if keep_inverse:
        writers.append(ws.frame_writer(f"inverse-{name}.h5", n=ws.n,
                                       shape=(ws.height, ws.width), dtype=np.float32,
                                       config_hash=config_hash, chunk=B))
    if all(w.done for w in writers):
        return ws.skip(name)
    with contextlib.ExitStack() as stack, ws.reader() as r:
        for w in writers:
            stack.enter_context(w)
        start = min(w.written for w in writers if not w.done) // B * B
        steps = range(start, ws.n, B)
        for b0 in progress(steps, total=len(steps), desc=name, unit="batch"):
            idx = range(b0, min(b0 + B, ws.n))
            inv = model.predict_many([r.left(i) for i in idx])  # one pass for torch models
            ws.count(name, len(idx))
            for i, D in zip(idx, inv):
                depth = depth_from_inverse(D, conf.predict.eps)
                for w, out in zip(writers, (depth, D)):
                    if not w.done and i >= w.written:
                        w.write(i, out)


def copy_base(conf: AdaptConfig, ws: Workspace, config_hash: str, name: str = "ft") -> None:
    """Without fine-tuning the fine-tuned prediction is the base prediction."""
    w = ws.pred_writer(name, config_hash, {"stage": "adapt", "metric": False,
                                           "copy_of": "base"}, chunk=16)
    if w.done:
        return ws.skip(name)
    with w, ws.reader() as r:
        for i in range(w.start, ws.n):
            w.write(i, r.prediction("base", i))
            ws.count(name)
