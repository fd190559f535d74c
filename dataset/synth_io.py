"""Render a synthetic scene into a sequence file (the ``synth`` command and the demo)."""
from __future__ import annotations

import os
import shutil
import time
from typing import Any, Mapping

from staticdepth.config import check_seed
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.errors import InputError
from staticdepth.fileio import check_writable
from staticdepth.progress import progress

MAX_FRAMES = 1_000_000
# Bytes per pixel of a synth frame, uncompressed: left and right RGB (uint8), depth (float32),
# instances (uint16).
RAW_BYTES_PER_PIXEL = 3 + 3 + 4 + 2
# The smallest compressed/raw ratio measured on real synth outputs (10 frames each): demo 0.42,
# c1 0.43, street 0.32, c2 0.36, r2 0.42, c1 without agents, props, buildings and texture 0.14.
# The disk check uses this lower bound, so it refuses only outputs that surely do not fit.
MIN_COMPRESSED_FRACTION = 0.1


def check_disk_space(out: str | os.PathLike, n_frames: int, width: int, height: int, *,
                     resume: bool = False) -> None:
    """Refuse when ``n_frames`` of ``width`` x ``height`` cannot fit in the free space of
    ``out``'s folder, by a lower estimate (:data:`MIN_COMPRESSED_FRACTION` of the raw size; a
    resumed run's ``.partial`` file already holds its part)."""
    raw = n_frames * width * height * RAW_BYTES_PER_PIXEL
    need = int(raw * MIN_COMPRESSED_FRACTION)
    partial = os.fspath(out) + ".partial"
    if resume and os.path.isfile(partial):
        need -= os.path.getsize(partial)
    folder = os.path.dirname(os.path.abspath(out))
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(f"not enough free disk space for {n_frames} frames of {width}x{height}: "
                         f"at least {_size(need)} compressed ({_size(raw)} raw), {_size(free)} "
                         "free; render fewer --frames", folder)


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.2f} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:.1f} MiB"


def render_to_file(out: str | os.PathLike, *, preset_name: str = "demo", n_frames: int = 60,
                   adapt_frames: int | None = None, seed: int = 0,
                   overrides: Mapping[str, Any] | None = None, overwrite: bool = False,
                   resume: bool = False, restart: bool = False) -> dict[str, Any]:
    """Render ``n_frames`` of a preset scene to ``out``; returns a small summary dict."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    check_seed(seed)
    if not 0 < n_frames <= MAX_FRAMES:
        raise InputError(f"--frames must be in 1..{MAX_FRAMES:,}, got {n_frames}")
    if adapt_frames is None:
        adapt_frames = int(round(0.4 * n_frames))
    if not 0 <= adapt_frames <= n_frames:
        raise InputError(f"--adapt-frames must be within 0..{n_frames}, got {adapt_frames}")
    t0 = time.perf_counter()
    config = preset(preset_name, seed=seed, **dict(overrides or {}))
    check_writable(out)     # a read-only folder is said as such, before its free space
    check_disk_space(out, n_frames, config.width, config.height, resume=resume)
    scene = SyntheticScene(config)
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
