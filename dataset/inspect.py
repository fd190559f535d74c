"""Summaries and pictures of a sequence file (used by ``staticdepth inspect``)."""
from __future__ import annotations

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


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    """``text`` in white on a dark band over the tile's top-left corner (RGB uint8)."""
    out = tile.copy()
    scale = 0.4
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    out[:h + base + 4, :w + 6] //= 3
    cv2.putText(out, text, (3, h + 2), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def thumbnail_sheet(reader: SequenceReader, n: int = 6, thumb_width: int = 240,
                    preds: tuple[str, ...] | list[str] = ()) -> np.ndarray:
    """A sheet of ``n`` evenly spaced frames (columns): the image, the colourised ground-truth
    depth when the sequence has it, and each named prediction (rows, labelled; near = red).

    Predictions are coloured per frame by their own percentiles (relative predictions have no
    metric scale), so a sequence without ground truth can still be looked at.
    """
    missing = [p for p in preds if p not in reader.predictions()]
    if missing:
        raise InputError(f"no prediction {', '.join(map(repr, missing))} in the sequence "
                         f"(it has: {', '.join(reader.predictions()) or 'none'})", reader.path)
    idx = np.unique(np.linspace(0, len(reader) - 1, min(n, len(reader))).astype(int))
    s = thumb_width / reader.width
    th = max(1, round(reader.height * s))
    labelled = bool(preds)
    cols = []
    for i in idx:
        img = cv2.resize(reader.left(int(i)), (thumb_width, th), interpolation=cv2.INTER_AREA)
        tiles = [_label(img, f"frame {int(i)}") if labelled else img]
        rows = [("ground truth", reader.depth(int(i)))] if reader.has("depth") else []
        rows += [(f"pred {p}", reader.prediction(p, int(i))) for p in preds]
        for name, dep in rows:
            tile = cv2.resize(colorize_depth(dep), (thumb_width, th),
                              interpolation=cv2.INTER_NEAREST)
            tiles.append(_label(tile, name) if labelled else tile)
        cols.append(np.concatenate(tiles, axis=0))
    return np.concatenate(cols, axis=1)
