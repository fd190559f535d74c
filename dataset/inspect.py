"""Summaries and pictures of a sequence file (used by ``staticdepth inspect``)."""
from __future__ import annotations

import os
from typing import Any

import cv2
import numpy as np

from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError


def colorize_depth(depth: np.ndarray, vmin: float | None = None, vmax: float | None = None,
                   inverse: bool = True) -> np.ndarray:
    """Turbo colour map of a depth map (RGB uint8); NaN pixels are black.

    With ``inverse`` the colours follow 1/depth (near = red), the usual way depth is shown.
    """
    d = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not ok.any():
        return out
    x = 1.0 / d if inverse else d
    lo = np.nanpercentile(x[ok], 2) if vmin is None else (1.0 / vmax if inverse and vmax else vmin)
    hi = np.nanpercentile(x[ok], 98) if vmax is None else (1.0 / vmin if inverse and vmin else vmax)
    if not hi > lo:
        hi = lo + 1e-6
    t = np.clip((np.where(ok, x, lo) - lo) / (hi - lo), 0, 1)
    bgr = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    out[ok] = bgr[..., ::-1][ok]
    return out


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write an RGB image atomically (temporary file, then rename)."""
    path = os.fspath(path)
    root, ext = os.path.splitext(path)
    tmp = f"{root}.tmp{os.getpid()}{ext or '.png'}"
    if not cv2.imwrite(tmp, np.ascontiguousarray(rgb[..., ::-1] if rgb.ndim == 3 else rgb)):
        raise InputError("cannot write image", path)
    os.replace(tmp, path)


def summarize(reader: SequenceReader, sample: int = 16) -> dict[str, Any]:
    """Frames, splits, streams, ground-truth density and depth range (over <= ``sample`` frames)."""
    m = reader.meta
    info: dict[str, Any] = {
        "path": reader.path, "name": m.name, "frames": len(reader),
        "size": f"{reader.width}x{reader.height}", "streams": reader.streams(),
        "gt_kind": m.gt_kind, "source": m.source,
        "splits": {"adapt": len(reader.split("adapt")), "eval": len(reader.split("eval"))},
        "camera": {k: round(v, 3) for k, v in m.camera.to_dict().items()
                   if k in ("fx", "fy", "cx", "cy")},
        "camera_height_m": m.camera_height_m,
        "baseline_m": None if m.rig is None else round(m.rig.baseline_m, 4),
        "predictions": reader.predictions(),
        "agents": int(len(reader.agents())),
    }
    if m.mounting is not None:
        info["pitch_deg"] = round(m.mounting.pitch_deg, 2)
        info["roll_deg"] = round(m.mounting.roll_deg, 2)
    if reader.has("depth"):
        idx = np.unique(np.linspace(0, len(reader) - 1, min(sample, len(reader))).astype(int))
        dens, lo, hi = [], np.inf, -np.inf
        for i in idx:
            d = reader.depth(int(i))
            ok = np.isfinite(d) & (d > 0)
            dens.append(ok.mean())
            if ok.any():
                lo, hi = min(lo, float(d[ok].min())), max(hi, float(d[ok].max()))
        info["gt_density"] = round(float(np.mean(dens)), 4)
        info["depth_range_m"] = [round(lo, 3), round(hi, 3)] if np.isfinite(lo) else None
    return info


def format_summary(info: dict[str, Any]) -> str:
    lines = [f"{info['path']}: sequence {info['name']!r}"]
    for k, v in info.items():
        if k not in ("path", "name"):
            lines.append(f"  {k:16s} {v}")
    return "\n".join(lines)


def thumbnail_sheet(reader: SequenceReader, n: int = 6, thumb_width: int = 240) -> np.ndarray:
    """A sheet of ``n`` evenly spaced frames: image over colourised depth (RGB uint8)."""
    idx = np.unique(np.linspace(0, len(reader) - 1, min(n, len(reader))).astype(int))
    s = thumb_width / reader.width
    th = max(1, round(reader.height * s))
    cols = []
    for i in idx:
        img = cv2.resize(reader.left(int(i)), (thumb_width, th), interpolation=cv2.INTER_AREA)
        tiles = [img]
        if reader.has("depth"):
            dep = colorize_depth(reader.depth(int(i)))
            tiles.append(cv2.resize(dep, (thumb_width, th), interpolation=cv2.INTER_NEAREST))
        cols.append(np.concatenate(tiles, axis=0))
    return np.concatenate(cols, axis=1)
