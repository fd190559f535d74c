"""Stereo ground truth of a sequence file that already holds rectified left/right streams.

``staticdepth stereo --sequence SEQ.h5 --out-name NAME [--temporal] [--fill]`` matches every frame
(per frame, or fused over time by :mod:`staticdepth.stereo.temporal`) and stores two predictions
through :func:`staticdepth.dataset.h5.add_prediction`, so ``staticdepth evaluate`` scores the
stereo ground truth against the sequence's own depth:

- ``NAME``: depth in metres (float32, NaN = hole), attribute ``metric`` (evaluated unscaled);
- ``NAME-confidence``: the per-pixel confidence in [0, 1] (0 on holes), attribute
  ``kind = "confidence"``; ``evaluate`` reports NAME's accuracy per confidence band with it.

An existing prediction of that name is replaced only with ``--overwrite``; a run stopped before
finishing leaves ``NAME.h5.partial`` (and so on), which ``--resume`` continues (the same settings
only) and ``--restart`` deletes; without either flag it is refused, never deleted unasked.

The temporal background model is cached beside the sequence (``SEQ.h5.NAME.background.npz``,
keyed by the settings and the sequence), so a killed run does not rebuild it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.projection import depth_from_disparity
from staticdepth.stereo.fill import fill_from_background
from staticdepth.stereo.match import create_matcher, num_disparities_for
from staticdepth.stereo.pipeline import DEFAULT_NUM_DISPARITIES, StereoConfig, _median_rows
from staticdepth.stereo.temporal import (BackgroundModel, TemporalConfig, build_background,
                                         config_key, depth_precision, fuse_frame,
                                         match_confidence, sample_indices)

CONFIDENCE_SUFFIX = "-confidence"


@dataclass(frozen=True)
class SequenceStereoResult:
    name: str
    frames: int
    num_disparities: int
    density: float             # share of pixels with a depth, over all frames
    background_reused: bool


def frame_confidence(left_rgb: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """A single frame's confidence in its depth: match reliability x depth precision (see
    :func:`~staticdepth.stereo.temporal.depth_precision`)."""
    return match_confidence(left_rgb, disparity) * depth_precision(disparity)


def _num_disparities(config: StereoConfig, focal_px: float, baseline_m: float, width: int,
                     camera_height_m: float | None) -> int:
    """The configured range, else f B / Z_min with Z_min = half the camera height, else 192;
    always below the image width."""
    if config.num_disparities:
        n = config.num_disparities
    elif config.min_depth_m or camera_height_m:
        n = num_disparities_for(focal_px, baseline_m, config.min_depth_m or 0.5 * camera_height_m)
    else:
        n = DEFAULT_NUM_DISPARITIES
    cap = 16 * ((width - 1) // 16)
    if cap < 16:
        raise InputError(f"images {width} px wide are too narrow for stereo matching")
    return int(min(n, cap))


def _background(reader, path: str, name: str, match, match_scaled, temporal: TemporalConfig,
                key: str) -> tuple[BackgroundModel, bool]:
    from staticdepth.fileio import atomic_write_bytes

    cache = f"{path}.{name}.background.npz"
    if os.path.exists(cache):
        try:
            with open(cache, "rb") as f:
                model, stored = BackgroundModel.from_bytes(f.read())
            if stored == key:
                return model, True
        except (OSError, ValueError, KeyError):
            pass                                  # damaged or old: build it again
    picks = sample_indices(len(reader), temporal.samples)
    model = build_background(((reader.left(i), reader.right(i)) for i in picks), match,
                             match_scaled, temporal)
    atomic_write_bytes(cache, model.to_bytes(key))
    return model, False


def check_name(name: str) -> str:
    """A stereo prediction's name: a prediction name (``dataset.predictions.check_name``) that
    leaves room for its ``NAME-confidence``."""
    from staticdepth.dataset.predictions import check_name as check_prediction_name

    if not name or name.endswith(CONFIDENCE_SUFFIX):
        raise InputError(f"prediction name {name!r} must be non-empty and not end in "
                         f"{CONFIDENCE_SUFFIX!r}")
    check_prediction_name(name)
    check_prediction_name(name + CONFIDENCE_SUFFIX)
    return name


def partial_paths(path: str | os.PathLike, name: str) -> list[str]:
    """The ``.partial`` files an interrupted ``stereo --sequence`` of ``name`` left (if any)."""
    from staticdepth.dataset.predictions import PARTIAL, prediction_path

    return [p + PARTIAL for p in (prediction_path(path, name),
                                  prediction_path(path, name + CONFIDENCE_SUFFIX))
            if os.path.exists(p + PARTIAL)]


def _check_outputs(path: str, name: str, identity: str, chash: str, *, overwrite: bool,
                   resume: bool, restart: bool) -> None:
    """The project's output rules for ``NAME`` and ``NAME-confidence``, before any work: an
    existing prediction is replaced only with ``overwrite`` (a ``resume`` of this very run may
    finish one it wrote with the same settings); a leftover ``.partial`` is never resumed or
    deleted unasked: ``resume`` continues it (same settings and sequence only), ``restart``
    deletes it."""
    import h5py

    from staticdepth.dataset import resume as rs
    from staticdepth.dataset.framefile import PARTIAL, is_complete
    from staticdepth.dataset.predictions import prediction_path
    from staticdepth.fileio import exclusive_lock

    if resume and restart:
        raise InputError("give --resume or --restart, not both")
    outs = [prediction_path(path, n) for n in (name, name + CONFIDENCE_SUFFIX)]
    for out in outs:
        if os.path.lexists(out) and not overwrite and not (resume and is_complete(out, identity,
                                                                                  chash)):
            raise InputError("exists already; pass --overwrite to replace it", out)
    for out in outs:
        partial = out + PARTIAL
        if not os.path.exists(partial):
            continue
        if restart:
            with exclusive_lock(out):
                os.remove(partial)
                rs.remove_journal(partial)
        elif not resume:
            raise rs.leftover(partial)
        elif not rs.journal_pending(partial):   # killed in a flush: its writer puts it back
            try:
                with h5py.File(partial, "r") as f:
                    same = (f.attrs.get("config_hash") == chash
                            and f.attrs.get("sequence_id") == identity)
            except OSError:
                same = False
            if not same:
                raise InputError("cannot resume: the partial file was written with other "
                                 "settings or of another sequence; --restart starts over",
                                 partial)


def stereo_sequence(path: str | os.PathLike, name: str, config: StereoConfig | None = None,
                    temporal: TemporalConfig | None = None, *, overwrite: bool = False,
                    resume: bool = False, restart: bool = False) -> SequenceStereoResult:
    """Match the left/right streams of ``path`` into predictions ``name`` and its confidence.

    ``temporal=None`` matches each frame alone; otherwise the frames are fused over time.
    ``config.fill`` fills every remaining hole (100% density; depth capped at ``max_depth_m``).
    An existing prediction ``name`` (or its confidence) is refused unless ``overwrite``; a
    ``.partial`` left by an interrupted run is refused unless ``resume`` (continue it: same
    settings only) or ``restart`` (delete it): see :func:`_check_outputs`.
    """
    from staticdepth.config import config_hash
    from staticdepth.dataset.h5 import SequenceReader, add_prediction
    from staticdepth.fileio import temporary_path
    from staticdepth.progress import progress

    path = os.fspath(path)
    c = config or StereoConfig()
    check_name(name)
    with SequenceReader(path) as r:
        if not r.has("right"):
            raise InputError("sequence has no right stream to match (KITTI: import with --right; "
                             "CARLA: record the right camera)", path)
        if r.meta.rig is None:
            raise InputError("sequence has right images but no stereo rig (baseline)", path)
        f_px, baseline = float(r.camera.fx), float(r.meta.rig.baseline_m)
        w, h, n_frames = r.width, r.height, len(r)
        n_disp = _num_disparities(c, f_px, baseline, w, r.meta.camera_height_m)
        attrs: dict[str, Any] = {
            "kind": "depth", "source": "stereo", "metric": 1, "matcher": c.matcher,
            "num_disparities": n_disp, "fill": int(c.fill), "stereo": c.to_dict(),
            "temporal": temporal.to_dict() if temporal else "", "confidence": name
            + CONFIDENCE_SUFFIX, "focal_px": f_px, "baseline_m": baseline}
        sid = r.sequence_id()
        chash = config_hash(attrs, 16)       # what a --resume must find unchanged
        attrs["config_hash"] = chash
        _check_outputs(path, name, sid, chash, overwrite=overwrite, resume=resume,
                       restart=restart)
        dense_match = c.fill and temporal is None
        matcher = create_matcher(c.matcher, num_disparities=n_disp, image_size=(w, h),
                                 dense=dense_match, options=c.options)
        match = lambda a, b: matcher.match(a, b).disparity  # noqa: E731
        model, reused = None, False
        if temporal is not None:
            s = temporal.plate_scale
            scaled = create_matcher(c.matcher, num_disparities=n_disp * s,
                                    image_size=(w * s, h * s), options=c.options) if s > 1 \
                else matcher
            matching = {k: v for k, v in c.to_dict().items() if k != "fill"}
            key = config_key(matching, temporal.to_dict(), {
                "n": n_frames, "size": [w, h], "name": r.meta.name,
                "created": str(r.attrs.get("created", "")), "num_disparities": n_disp})
            model, reused = _background(r, path, name, match,
                                        lambda a, b: scaled.match(a, b).disparity, temporal, key)
        d_min = np.float32(f_px * baseline / c.max_depth_m)
        conf_tmp = temporary_path(path, f"{name}-confidence.npy")
        # the confidence waits on disk (1/255 steps) until the depth is stored: memory stays
        # one frame, whatever the length
        confidence = np.lib.format.open_memmap(conf_tmp, mode="w+", dtype=np.uint8,
                                               shape=(n_frames, h, w))
        counted = [0]

        def depth_maps() -> Iterator[np.ndarray]:
            for i in progress(range(n_frames), desc=f"stereo {name}", unit="frame"):
                L, R = r.left(i), r.right(i)
                d = match(L, R)
                if model is not None:
                    fused = fuse_frame(model, L, d)
                    d, conf = fused.disparity, fused.confidence
                else:
                    conf = frame_confidence(L, d)
                if c.fill:
                    d = fill_from_background(d, median_rows=_median_rows(h))
                    d = np.maximum(d, d_min)      # every pixel a depth, at most max_depth_m
                z = depth_from_disparity(d, f_px, baseline, None if c.fill else c.max_depth_m)
                conf = np.where(np.isfinite(z), np.clip(conf, 0, 1), 0)   # 0: no depth
                confidence[i] = np.round(conf * 255)
                counted[0] += int(np.isfinite(z).sum())
                yield z

        try:
            add_prediction(path, name, depth_maps(), attrs)
        except BaseException:
            del confidence
            os.remove(conf_tmp)
            raise
    try:
        confidence.flush()
        add_prediction(path, name + CONFIDENCE_SUFFIX,
                       (confidence[i] * np.float32(1 / 255) for i in range(n_frames)),
                       {"kind": "confidence", "of": name, "config_hash": chash})
    finally:
        del confidence
        if os.path.exists(conf_tmp):
            os.remove(conf_tmp)
    return SequenceStereoResult(name, n_frames, n_disp, counted[0] / (n_frames * w * h), reused)
