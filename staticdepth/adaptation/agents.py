"""Stage agents: per-frame instance maps (uint16) and agent rows from a detector.

Written to ``<SEQ>.h5.adapt/agents.h5`` (dataset ``instances``, table ``rows``) frame by frame.
With ``detector.name = gt`` the sequence's own ``instances`` stream and rows are used and nothing
is written. The detector sees the frames lazily (a ``Sequence`` read one frame at a time: the
motion detector's background samples at most 50 of them). On resume the detector runs from the
first frame again (a tracker's or background model's state depends on the frames before) and
frames already written are not written again.
"""
from __future__ import annotations

import os

import numpy as np

from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.dataset.schema import AGENT_DTYPE
from staticdepth.detectors.frames import SequenceFrames
from staticdepth.errors import InputError
from staticdepth.progress import progress


def make(conf: AdaptConfig, ws: Workspace):
    """The detector, built (weights loaded) before any frame is predicted; None for ``gt``."""
    d = conf.detector
    if d.name == "gt":
        if not ws.has_instances:
            raise InputError("--detector gt needs the sequence's 'instances' stream", ws.seq)
        return None
    from staticdepth.detectors import make_detector

    if d.name in ("yolox", "mask2former"):
        if not d.model or not os.path.exists(d.model):
            raise InputError(f"the {d.name} detector's weights were not found (give --set "
                             f"detector.model=PATH)", d.model or None)
        return make_detector(d.name, model=d.model)
    return make_detector(d.name)


def run(conf: AdaptConfig, ws: Workspace, detector, config_hash: str) -> None:
    if detector is None:      # a first run said 'up to date' of a stage it never ran
        return ws.skip("agents", "the sequence's own instance maps are the agents (detector gt)")
    w = ws.frame_writer("agents.h5", n=ws.n, shape=(ws.height, ws.width), dtype=np.uint16,
                        config_hash=config_hash, rows_dtype=AGENT_DTYPE, chunk=16,
                        attrs={"detector": conf.detector.name})
    if w.done:
        return ws.skip("agents")
    with w, ws.reader() as r:
        out = detector.detect_sequence(SequenceFrames(r))
        for i, (inst, rows) in enumerate(progress(out, total=ws.n, desc="agents")):
            if i >= w.written:
                w.write(i, inst, rows)
                ws.count("agents")
