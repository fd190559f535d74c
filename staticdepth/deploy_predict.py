"""``staticdepth predict``: stream a video, an image folder, a URL or a sequence through a model to
(metric) depth, written as 16-bit PNG, NPY or a colour-mapped MP4, with frames per second.

Metric with an exported model (:class:`staticdepth.deploy.MetricOnnx`) or with a model SPEC plus
the adapt summary and sequence (:func:`staticdepth.deploy.metric_depth_reference`, the numpy
pipeline); otherwise relative depth ``1/D``, said so.

Outputs are named by the frame's index in the source (``--every 5``: ``000000``, ``000005``, ...).
A 16-bit PNG holds ``depth * scale`` rounded (0 = unknown), the scale in its ``tEXt`` chunk
``staticdepth.depth_scale`` (:func:`depth_from_png16`): 256 for metres (1/256 m steps up to
256 m), for relative depth ``65535 / the frame's largest depth`` (the full 16-bit range). The MP4
plays at the source's rate / ``every`` (:func:`source_fps`) with a colour bar under each frame.
"""
from __future__ import annotations

import io
import math
import os
import re
import time
from typing import Any, Iterator

import numpy as np

from staticdepth.deploy import (MetricOnnx, camera_frame, deployment_constants,
                                metric_depth_reference)
from staticdepth.errors import InputError

#: Frame rate assumed for an image folder, a URL or a sequence file without timestamps.
DEFAULT_FPS = 10.0
#: PNG units per metre of a metric prediction (KITTI's convention).
METRIC_PNG_SCALE = 256.0
PNG_SCALE_KEY = "staticdepth.depth_scale"
PNG_UNIT_KEY = "staticdepth.depth_unit"


def _frames(source: str, every: int = 1, max_frames: int | None = None
            ) -> Iterator[tuple[int, np.ndarray]]:
    """(index in the source, RGB image) of every ``every``-th frame, at most ``max_frames``."""
    if source.endswith(".h5") and os.path.isfile(source):
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(source) as r:
            idx = range(0, len(r), every)
            for k, i in enumerate(idx):
                if max_frames is not None and k >= max_frames:
                    return
                yield i, r.left(i)
        return
    from staticdepth.dataset.video import iter_frames

    for fr in iter_frames(source, every=every, max_frames=max_frames):
        yield fr.index, fr.rgb


def source_fps(source: str) -> tuple[float, bool]:
    """(frames per second of ``source``, whether the source says so): a video file's own rate, a
    sequence file's from its timestamps (median step); an image folder, a URL (not opened twice)
    or a source without a usable rate: :data:`DEFAULT_FPS`, False."""
    if os.path.isfile(source) and source.endswith(".h5"):
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(source) as r:
            steps = np.diff(np.asarray(r.timestamps(), np.float64))
        steps = steps[np.isfinite(steps) & (steps > 0)]
        rate = 1.0 / float(np.median(steps)) if len(steps) else 0.0
    elif os.path.isfile(source):
        import cv2

        cap = cv2.VideoCapture(source)
        try:
            rate = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) if cap.isOpened() else 0.0
        finally:
            cap.release()
    else:
        rate = 0.0
    if math.isfinite(rate) and 0 < rate <= 1000:
        return rate, True
    return DEFAULT_FPS, False


def png16_from_depth(depth: np.ndarray, metric: bool) -> tuple[np.ndarray, float]:
    """(uint16 image, scale) with ``depth ~= image / scale``, 0 = unknown (NaN, inf, <= 0).

    Metric: scale 256 (clipped at 65535, i.e. 256 m). Relative: ``65535 / max depth`` of the
    frame, so the largest depth is 65535 and the error is at most ``0.5 / scale`` everywhere. A
    known pixel is at least 1, never read back as unknown."""
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d) & (d > 0)
    if metric:
        scale = METRIC_PNG_SCALE
    else:
        scale = 65535.0 / float(d[ok].max()) if ok.any() else 1.0
    q = np.zeros(d.shape, np.uint16)
    q[ok] = np.clip(np.round(d[ok] * scale), 1, 65535)
    return q, scale


def write_png16(path: str, q: np.ndarray, scale: float, unit: str) -> None:
    """``q`` as a 16-bit PNG holding its scale and unit in ``tEXt`` chunks, written atomically."""
    from PIL import Image, PngImagePlugin

    from staticdepth.fileio import atomic_write_bytes

    info = PngImagePlugin.PngInfo()
    info.add_text(PNG_SCALE_KEY, repr(float(scale)))
    info.add_text(PNG_UNIT_KEY, unit)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(q, np.uint16)).save(buf, format="PNG", pnginfo=info)
    atomic_write_bytes(path, buf.getvalue())


def depth_from_png16(path: str) -> tuple[np.ndarray, str]:
    """(float32 depth, unit 'm' | 'relative') of a ``predict --format png16`` file; unknown =
    NaN. A PNG without the scale chunk is read as metres x256."""
    from PIL import Image

    with Image.open(path) as im:
        q = np.asarray(im).astype(np.float64)
        text = dict(getattr(im, "text", {}) or {})
    try:
        scale = float(text.get(PNG_SCALE_KEY, METRIC_PNG_SCALE))
    except ValueError:
        raise InputError(f"unreadable {PNG_SCALE_KEY} {text[PNG_SCALE_KEY]!r}", path) from None
    if q.ndim != 2 or not scale > 0:
        raise InputError("not a predict png16 depth file (one channel, positive scale)", path)
    return np.where(q > 0, q / scale, np.nan).astype(np.float32), text.get(PNG_UNIT_KEY, "m")


def mp4_frame(depth: np.ndarray, rng: tuple[float, float], bar: np.ndarray) -> np.ndarray:
    """The depth in colour over ``rng`` (:func:`colorize_depth`: inverse depth, near = red,
    unknown black) with ``bar`` under it (RGB uint8)."""
    from staticdepth.dataset.inspect import colorize_depth

    return np.concatenate([colorize_depth(depth, *rng), bar], axis=0)


def make_predictor(model: str, summary: str | None, sequence: str | None,
                   ground_mask_png: str | None = None, log=print, device: str = "auto"):
    """(callable image -> depth, 'metric' | 'relative', description)."""
    path = model[5:] if model.startswith("onnx:") else model
    if path.endswith(".onnx"):
        try:                       # an exported metric model, else a relative one (onnx:)
            m = MetricOnnx(path, ["CUDAExecutionProvider", "CPUExecutionProvider"]
                           if device.startswith("cuda") else None)
            return m.predict, "metric", f"exported metric model {path}"
        except InputError as e:
            if "not an exported metric model" not in str(e):
                raise
    from staticdepth.geometry.alignment import depth_from_inverse
    from staticdepth.models import TorchDepthModel, load_model

    net = load_model(model if ":" in model or model == "builtin" else f"onnx:{model}")
    if isinstance(net, TorchDepthModel):
        from staticdepth.cli import resolve_device

        net.to(resolve_device(device))
    if summary:
        if not sequence:
            raise InputError("--summary needs --sequence (the camera and its ground region)")
        c = deployment_constants(summary, sequence, ground_mask_png, log)
        size = (c["width"], c["height"], sequence)
        return (lambda im: metric_depth_reference(net, camera_frame(im, *size), c)), "metric", \
            f"{model} + alignment + scale x{c['scale']:.3f} (numpy pipeline)"
    return (lambda im: depth_from_inverse(net.predict(im))), "relative", \
        f"{model} (relative depth 1/D: give --summary and --sequence for metres)"


_OUTPUT_NAME = re.compile(r"^(\d{6,})\.(png|npy)$")


def stale_outputs(out_dir: str, written: set[str]) -> list[str]:
    """The files in ``out_dir`` named as ``predict`` names its outputs (``NNNNNN.png``,
    ``NNNNNN.npy``, ``depth.mp4``) that the run just finished did not write (``written``): an
    earlier run's (another ``--every``, ``--format`` or source), which would otherwise be taken
    for this one's. Other files are never touched."""
    return [name for name in sorted(os.listdir(out_dir))
            if (name == "depth.mp4" or _OUTPUT_NAME.match(name)) and name not in written]


def predict(model: str, source: str, out_dir: str, fmt: str = "png16", *,
            summary: str | None = None, sequence: str | None = None, every: int = 1,
            max_frames: int | None = None, device: str = "auto", log=print) -> dict[str, Any]:
    """Stream every ``every``-th frame of ``source`` (at most ``max_frames``) through a model into
    ``out_dir``, files named by the frame's index in the source; returns frames, their first and
    last source index, fps (model, overall; ``video_fps`` for mp4) and the kind. ``out_dir``
    is made once the source has given a frame; a failed run removes the folders it made and
    left empty."""
    if fmt not in ("png16", "npy", "mp4"):
        raise InputError(f"--format must be png16, npy or mp4, got {fmt!r}")
    if every < 1:
        raise InputError(f"--every must be >= 1, got {every}")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {max_frames}")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise InputError("is a file, not a folder (give the output folder)", out_dir)
    fn, kind, desc = make_predictor(model, summary, sequence, log=log, device=device)
    log(f"model: {desc}")
    made = _missing_folders(out_dir)
    try:
        return _predict_into(fn, kind, source, out_dir, fmt, every, max_frames, log)
    except BaseException:
        for d in made:              # the folders this run made, left empty: removed
            if os.path.isdir(d) and not os.listdir(d):
                os.rmdir(d)
        raise


def _missing_folders(path: str) -> list[str]:
    """``path`` and those of its parents that do not exist yet, deepest first."""
    out, p = [], os.path.abspath(path)
    while not os.path.exists(p) and os.path.dirname(p) != p:
        out.append(p)
        p = os.path.dirname(p)
    return out


def _predict_into(fn, kind: str, source: str, out_dir: str, fmt: str, every: int,
                  max_frames: int | None, log) -> dict[str, Any]:
    """:func:`predict`'s loop; ``out_dir`` is made once the source has given its first frame and
    the model its first depth."""
    import cv2

    from staticdepth.fileio import atomic_path, atomic_write_bytes
    from staticdepth.progress import progress

    unit = "m" if kind == "metric" else "relative"
    writer, tmp_ctx, rng, bar, video_fps = None, None, None, None, None
    n, first, last, t_model, t0 = 0, None, None, 0.0, time.perf_counter()
    written = {"depth.mp4"} if fmt == "mp4" else set()
    try:
        for i, img in progress(_frames(source, every, max_frames), desc="predict", unit="frame"):
            t = time.perf_counter()
            depth = np.asarray(fn(img), dtype=np.float32)
            t_model += time.perf_counter() - t
            if n == 0:
                os.makedirs(out_dir, exist_ok=True)   # the input opened and gave a depth
            if fmt == "npy":
                buf = io.BytesIO()
                np.save(buf, depth)
                atomic_write_bytes(os.path.join(out_dir, f"{i:06d}.npy"), buf.getvalue())
                written.add(f"{i:06d}.npy")
            elif fmt == "png16":
                q, scale = png16_from_depth(depth, kind == "metric")
                write_png16(os.path.join(out_dir, f"{i:06d}.png"), q, scale, unit)
                written.add(f"{i:06d}.png")
            else:
                if writer is None:
                    from staticdepth.report_figures import depth_colour_bar, depth_range

                    rate, known = source_fps(source)
                    video_fps = rate / every
                    if not known:
                        log(f"note: the input gives no frame rate; the video plays at "
                            f"{DEFAULT_FPS:g} / {every} = {video_fps:g} frames/s")
                    # one colour range for the whole video (the first frame's 2nd-98th
                    # percentile), so that colours compare between frames
                    rng = depth_range(depth) or (1.0, 2.0)
                    bar = depth_colour_bar(depth.shape[1], *rng,
                                           caption="depth m" if kind == "metric" else "relative")
                    # the temporary ends in .mp4 (OpenCV picks the container by it) and is the
                    # one atomic_path removes when the run stops early
                    tmp_ctx = atomic_path(os.path.join(out_dir, "depth.mp4"), "part.mp4")
                    tmp = tmp_ctx.__enter__()
                    size = depth.shape
                    writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), video_fps,
                                             (depth.shape[1], depth.shape[0] + bar.shape[0]))
                if depth.shape != size:
                    raise InputError(f"frame {i}: depth {depth.shape[1]}x{depth.shape[0]}, the "
                                     f"video's is {size[1]}x{size[0]}", source)
                writer.write(np.ascontiguousarray(mp4_frame(depth, rng, bar)[..., ::-1]))
            first = i if first is None else first
            last, n = i, n + 1
        if writer is not None:
            writer.release()
            tmp_ctx.__exit__(None, None, None)
    except BaseException as e:
        if tmp_ctx is not None:
            if writer is not None:
                writer.release()
            tmp_ctx.__exit__(type(e), e, e.__traceback__)
        raise
    if n == 0:
        raise InputError("no frame was read", source)
    stale = stale_outputs(out_dir, written)
    for name in stale:      # an earlier run's frames (another --every, --format or source)
        os.remove(os.path.join(out_dir, name))
    if stale:
        log(f"removed {len(stale)} file(s) of an earlier run from {out_dir}")
    wall = time.perf_counter() - t0
    return {"frames": n, "first_index": first, "last_index": last, "every": every,
            "fps_model": n / t_model, "fps_total": n / wall, "kind": kind, "out": out_dir,
            "video_fps": video_fps}
