"""Pictures of ``staticdepth locate``'s positions (OpenCV drawing, no plotting library).

- :func:`bev_image`: the tracks on a metric grid seen from above (x right, y forward, the camera's
  foot point at the origin), grid lines and labelled axes in metres.
- :func:`annotate_frame`: a frame with each agent's box, track and distance to the camera; pairs
  of people closer than the threshold joined by a red line labelled with their distance.
- :func:`write_annotated`: a few annotated frames as an animated GIF (Pillow) or an MP4 (OpenCV),
  and a PNG sheet of them beside it.
"""
from __future__ import annotations

import math
import os

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.fileio import write_image

RED = (220, 30, 30)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def track_colour(track: int) -> tuple[int, int, int]:
    """A stable, saturated RGB colour per track id (never pure red: red marks close pairs)."""
    hue = int((track * 47) % 150) + 15                    # OpenCV hue 0-179, skipping red
    c = cv2.cvtColor(np.array([[[hue, 220, 230]]], np.uint8), cv2.COLOR_HSV2RGB)[0, 0]
    return int(c[0]), int(c[1]), int(c[2])


def _nice_step(span: float, target: int = 8) -> float:
    raw = span / max(target, 1)
    mag = 10 ** math.floor(math.log10(max(raw, 1e-9)))
    for m in (1, 2, 5, 10):
        if m * mag >= raw:
            return m * mag
    return 10 * mag


def bev_image(pos: np.ndarray, size_px: int = 800, margin_px: int = 60,
              close: list | None = None) -> np.ndarray:
    """(size, size, 3) uint8 RGB bird's-eye view of the positions' ground coordinates."""
    ok = np.isfinite(pos["ground_x"]) & np.isfinite(pos["ground_y"])
    x, y = pos["ground_x"][ok], pos["ground_y"][ok]
    if len(x):
        lo_x, hi_x = np.percentile(x, [1, 99])
        lo_y, hi_y = np.percentile(y, [1, 99])
    else:
        lo_x, hi_x, lo_y, hi_y = -5.0, 5.0, 0.0, 10.0
    lo_x, hi_x = min(lo_x, 0.0), max(hi_x, 0.0)     # the camera's foot point stays in view
    lo_y, hi_y = min(lo_y, 0.0), max(hi_y, 0.0)
    span = max(hi_x - lo_x, hi_y - lo_y, 2.0) * 1.08
    cx, cy = (lo_x + hi_x) / 2, (lo_y + hi_y) / 2
    inner = size_px - 2 * margin_px
    s = inner / span                                    # px per metre

    def to_px(gx, gy):
        return (margin_px + (np.asarray(gx) - (cx - span / 2)) * s,
                margin_px + ((cy + span / 2) - np.asarray(gy)) * s)

    img = np.full((size_px, size_px, 3), 255, np.uint8)
    step = _nice_step(span)
    for k in range(int(math.floor((cx - span / 2) / step)),
                   int(math.ceil((cx + span / 2) / step)) + 1):
        px, _ = to_px(k * step, 0)
        if margin_px <= px <= size_px - margin_px:
            cv2.line(img, (int(px), margin_px), (int(px), size_px - margin_px), (225, 225, 225), 1)
            cv2.putText(img, f"{k * step:g}", (int(px) - 10, size_px - margin_px + 18), FONT, 0.4,
                        (60, 60, 60), 1, cv2.LINE_AA)
    for k in range(int(math.floor((cy - span / 2) / step)),
                   int(math.ceil((cy + span / 2) / step)) + 1):
        _, py = to_px(0, k * step)
        if margin_px <= py <= size_px - margin_px:
            cv2.line(img, (margin_px, int(py)), (size_px - margin_px, int(py)), (225, 225, 225), 1)
            cv2.putText(img, f"{k * step:g}", (8, int(py) + 4), FONT, 0.4, (60, 60, 60), 1,
                        cv2.LINE_AA)
    cv2.rectangle(img, (margin_px, margin_px), (size_px - margin_px, size_px - margin_px),
                  (120, 120, 120), 1)
    cv2.putText(img, "x (m, right)", (size_px // 2 - 40, size_px - 12), FONT, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)
    cv2.putText(img, "y (m, forward)", (8, margin_px - 12), FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"bird's-eye view, grid {step:g} m", (size_px // 2 - 90, 22), FONT, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)
    sub = 8
    for t in np.unique(pos["track"][ok]):
        sel = ok & (pos["track"] == t)
        px, py = to_px(pos["ground_x"][sel], pos["ground_y"][sel])
        pts = np.round(np.stack([px, py], 1) * sub).astype(np.int32)
        col = track_colour(int(t))
        if len(pts) > 1:
            cv2.polylines(img, [pts[:, None, :]], False, col, 2, cv2.LINE_AA, shift=3)
        cv2.circle(img, tuple(int(c) for c in pts[-1]), 3 * sub, col, -1, cv2.LINE_AA, shift=3)
    if close:
        key = {(int(p["frame"]), int(p["track"])): i for i, p in enumerate(pos)}
        for pr in close:
            if not pr["close"]:
                continue
            a, b = key.get((pr["frame"], pr["track_a"])), key.get((pr["frame"], pr["track_b"]))
            if a is None or b is None:
                continue
            xs, ys = to_px(pos["ground_x"][[a, b]], pos["ground_y"][[a, b]])
            cv2.line(img, (int(xs[0]), int(ys[0])), (int(xs[1]), int(ys[1])), RED, 1, cv2.LINE_AA)
    ox, oy = to_px(0.0, 0.0)
    tri = np.array([[ox, oy - 9], [ox - 7, oy + 6], [ox + 7, oy + 6]], np.int32)
    cv2.fillPoly(img, [tri], (0, 0, 0))
    cv2.putText(img, "camera", (int(ox) + 9, int(oy) + 5), FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def annotate_frame(image: np.ndarray, pos_frame: np.ndarray, pairs_frame: list) -> np.ndarray:
    """Boxes with track and distance (m); close pairs of people joined in red."""
    img = np.ascontiguousarray(image).copy()
    close_tracks = set()
    where = {int(p["track"]): p for p in pos_frame}
    for pr in pairs_frame:
        if not pr["close"]:
            continue
        a, b = where.get(pr["track_a"]), where.get(pr["track_b"])
        if a is None or b is None:
            continue
        close_tracks |= {pr["track_a"], pr["track_b"]}
        pa, pb = (int(a["u"]), int(a["v"])), (int(b["u"]), int(b["v"]))
        cv2.line(img, pa, pb, RED, 2, cv2.LINE_AA)
        mid = ((pa[0] + pb[0]) // 2, (pa[1] + pb[1]) // 2 - 4)
        cv2.putText(img, f"{pr['distance_m']:.1f}m", mid, FONT, 0.4, (255, 255, 255), 3,
                    cv2.LINE_AA)
        cv2.putText(img, f"{pr['distance_m']:.1f}m", mid, FONT, 0.4, RED, 1, cv2.LINE_AA)
    for p in pos_frame:
        col = RED if int(p["track"]) in close_tracks else track_colour(int(p["track"]))
        l, r, t, b = p["left"], p["right"], p["top_v"], p["v"]
        if np.all(np.isfinite([l, r, t])):
            cv2.rectangle(img, (int(l), int(t)), (int(r), int(b)), col, 2 if col == RED else 1)
        label = (f"{int(p['track'])}: {p['distance_m']:.1f}m"
                 + ("*" if p["source"] == "depth" else ""))
        org = (int(p["u"]) - 20, int(b) + 12)
        cv2.putText(img, label, org, FONT, 0.38, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, org, FONT, 0.38, col, 1, cv2.LINE_AA)
        cv2.circle(img, (int(round(p["u"])), int(round(p["v"]))), 2, col, -1)
    return img


def pick_frames(pos: np.ndarray, k: int) -> list[int]:
    """``k`` frames spread over the sequence, preferring crowded ones."""
    frames, counts = np.unique(pos["frame"], return_counts=True)
    if len(frames) == 0:
        return []
    parts = np.array_split(np.arange(len(frames)), min(k, len(frames)))
    return [int(frames[p[np.argmax(counts[p])]]) for p in parts if len(p)]


def write_bev(path: str, pos: np.ndarray, close: list | None = None) -> None:
    write_image(path, bev_image(pos, close=close))


def check_annotate_path(path: str) -> None:
    """Refuse annotated frames named other than ``.gif`` or ``.mp4``."""
    if os.path.splitext(path)[1].lower() not in (".gif", ".mp4"):
        raise InputError("annotated frames are written as .gif or .mp4", path)


def check_image_path(path: str, option: str) -> None:
    """Refuse an image output whose suffix OpenCV cannot encode (none: PNG, as write_image)."""
    if os.path.splitext(path)[1] and not cv2.haveImageWriter(path):
        raise InputError(f"{option}: cannot write an image of this kind (name it .png)", path)


def write_annotated(path: str, seq_path: str, pos: np.ndarray, pairs: list, k: int = 12,
                    fps: float = 2.0) -> str:
    """Annotated frames as ``path`` (.gif or .mp4) and ``<path stem>_sheet.png``; returns the
    sheet's path."""
    from PIL import Image

    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.fileio import atomic_path

    check_annotate_path(path)
    ext = os.path.splitext(path)[1].lower()
    frames = []
    with SequenceReader(seq_path) as r:
        for f in pick_frames(pos, k):
            pf = [p for p in pairs if p["frame"] == f]
            img = annotate_frame(r.left(f), pos[pos["frame"] == f], pf)
            cv2.putText(img, f"frame {f}", (6, 16), FONT, 0.5, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.putText(img, f"frame {f}", (6, 16), FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
            frames.append(img)
    if not frames:
        raise InputError("no agent was located: nothing to annotate", seq_path)
    with atomic_path(path, "anno" + ext) as tmp:     # OpenCV picks the container by the suffix
        if ext == ".gif":
            ims = [Image.fromarray(f) for f in frames]
            with open(tmp, "wb") as fh:
                ims[0].save(fh, format="GIF", save_all=True, append_images=ims[1:],
                            duration=int(1000 / fps), loop=0)
        else:
            h, w = frames[0].shape[:2]
            vw = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
            if not vw.isOpened():
                raise InputError("OpenCV cannot write MP4 here", path)
            for f in frames:
                vw.write(np.ascontiguousarray(f[..., ::-1]))
            vw.release()
    cols = min(3, len(frames))
    rows = -(-len(frames) // cols)
    h, w = frames[0].shape[:2]
    sheet = np.full((rows * h, cols * w, 3), 255, np.uint8)
    for i, f in enumerate(frames):
        sheet[(i // cols) * h:(i // cols + 1) * h, (i % cols) * w:(i % cols + 1) * w] = f
    write_image(sheet_path(path), sheet)
    return sheet_path(path)


def sheet_path(path: str) -> str:
    """The PNG sheet written beside the annotated frames ``path``."""
    return os.path.splitext(path)[0] + "_sheet.png"
