"""``staticdepth predict``: stream a video, an image folder, a URL or a sequence through a model to
(metric) depth, written as 16-bit PNG, NPY or a colour-mapped MP4, with frames per second.

Metric with an exported model (:class:`staticdepth.deploy.MetricOnnx`) or with a model SPEC plus
the adapt summary and sequence (:func:`staticdepth.deploy.metric_depth_reference`, the numpy
pipeline); otherwise relative depth ``1/D``, said so.
"""
from __future__ import annotations

import os
import time
from typing import Any, Iterator

import numpy as np

from staticdepth.deploy import (MetricOnnx, camera_frame, deployment_constants,
                                metric_depth_reference)
from staticdepth.errors import InputError


def _frames(source: str, every: int = 1, max_frames: int | None = None) -> Iterator[np.ndarray]:
    if source.endswith(".h5") and os.path.isfile(source):
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(source) as r:
            idx = range(0, len(r), every)
            for k, i in enumerate(idx):
                if max_frames is not None and k >= max_frames:
                    return
                yield r.left(i)
        return
    from staticdepth.dataset.video import iter_frames

    for fr in iter_frames(source, every=every, max_frames=max_frames):
        yield fr.rgb


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


def predict(model: str, source: str, out_dir: str, fmt: str = "png16", *,
            summary: str | None = None, sequence: str | None = None, every: int = 1,
            max_frames: int | None = None, device: str = "auto", log=print) -> dict[str, Any]:
    """Stream frames through a model into ``out_dir``; returns frames, fps and the kind."""
    import cv2

    from staticdepth.fileio import atomic_path, atomic_write_bytes, write_image
    from staticdepth.progress import progress

    if fmt not in ("png16", "npy", "mp4"):
        raise InputError(f"--format must be png16, npy or mp4, got {fmt!r}")
    fn, kind, desc = make_predictor(model, summary, sequence, log=log, device=device)
    log(f"model: {desc}")
    os.makedirs(out_dir, exist_ok=True)
    writer, tmp_ctx, rng = None, None, None
    n, t_model, t0 = 0, 0.0, time.perf_counter()
    try:
        for img in progress(_frames(source, every, max_frames), desc="predict", unit="frame"):
            t = time.perf_counter()
            depth = np.asarray(fn(img), dtype=np.float32)
            t_model += time.perf_counter() - t
            if fmt == "npy":
                import io

                buf = io.BytesIO()
                np.save(buf, depth)
                atomic_write_bytes(os.path.join(out_dir, f"{n:06d}.npy"), buf.getvalue())
            elif fmt == "png16":
                q = np.where(np.isfinite(depth), np.clip(np.round(depth * 256), 0, 65535), 0)
                write_image(os.path.join(out_dir, f"{n:06d}.png"), q.astype(np.uint16))
            else:
                if writer is None:
                    # the temporary ends in .mp4 (OpenCV picks the container by it) and is the
                    # one atomic_path removes when the run stops early
                    tmp_ctx = atomic_path(os.path.join(out_dir, "depth.mp4"), "part.mp4")
                    tmp = tmp_ctx.__enter__()
                    writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), 10.0,
                                             (depth.shape[1], depth.shape[0]))
                    fin = np.log(depth[np.isfinite(depth) & (depth > 0)])
                    rng = np.percentile(fin, [2, 98]) if len(fin) else (0.0, 1.0)
                with np.errstate(invalid="ignore", divide="ignore"):
                    x = (np.log(depth) - rng[0]) / max(rng[1] - rng[0], 1e-6)
                g = (255 * (1 - np.clip(np.nan_to_num(x, nan=1.0), 0, 1))).astype(np.uint8)
                writer.write(cv2.applyColorMap(g, cv2.COLORMAP_TURBO))
            n += 1
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
    wall = time.perf_counter() - t0
    return {"frames": n, "fps_model": n / t_model, "fps_total": n / wall, "kind": kind,
            "out": out_dir}
