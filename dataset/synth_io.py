"""Render a synthetic scene into a sequence file (the ``synth`` command and the demo)."""
from __future__ import annotations

import os
import time
from typing import Any, Mapping

from staticdepth.config import check_seed
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.errors import InputError
from staticdepth.progress import progress


def render_to_file(out: str | os.PathLike, *, preset_name: str = "demo", n_frames: int = 60,
                   adapt_frames: int | None = None, seed: int = 0,
                   overrides: Mapping[str, Any] | None = None, overwrite: bool = False,
                   resume: bool = False, restart: bool = False) -> dict[str, Any]:
    """Render ``n_frames`` of a preset scene to ``out``; returns a small summary dict."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    check_seed(seed)
    if n_frames <= 0:
        raise InputError(f"--frames must be positive, got {n_frames}")
    if adapt_frames is None:
        adapt_frames = int(round(0.4 * n_frames))
    if not 0 <= adapt_frames <= n_frames:
        raise InputError(f"--adapt-frames must be within 0..{n_frames}, got {adapt_frames}")
    t0 = time.perf_counter()
    scene = SyntheticScene(preset(preset_name, seed=seed, **dict(overrides or {})))
    meta = SequenceMeta(name=f"synth-{preset_name}-s{seed}", camera=scene.camera,
                        gt_kind="synthetic", source=f"staticdepth.dataset.synth:{preset_name}",
                        adapt_frames=adapt_frames, rig=scene.rig, mounting=scene.mounting,
                        provenance={"preset": preset_name, "seed": seed,
                                    "overrides": dict(overrides or {}),
                                    "config": scene.config_dict()})
    with SequenceWriter(out, meta, streams=("left", "right", "depth", "instances"),
                        overwrite=overwrite, resume=resume, restart=restart,
                        settings={"frames": n_frames}) as w:
        if w.resumed_from:
            print(f"resuming after frame {w.resumed_from}")
        for i in progress(range(len(w), n_frames), total=n_frames - len(w), desc="render",
                          unit="frame"):
            fr = scene.render(i)
            w.append(left=fr["left"], right=fr["right"], depth=fr["depth"],
                     instances=fr["instances"], agents=fr["agents"], timestamp=fr["timestamp"])
    return {"frames": n_frames, "adapt_frames": adapt_frames,
            "size": f"{scene.camera.width}x{scene.camera.height}",
            "seconds": time.perf_counter() - t0, "scene": scene}
