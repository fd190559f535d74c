"""YOLOX (ONNX) boxes with masks from motion or GrabCut inside each box.

Pre-processing as YOLOX's demo: letterbox to ``input_size`` (top-left aligned, scale r =
min(S/H, S/W), pad 114), BGR 0-255 float32. Decoding: per anchor (cx, cy) = (raw + grid) x
stride, (w, h) = exp(raw) x stride on the stride 8/16/32 grids; score = objectness x class
probability (both already sigmoid in the export); class-wise NMS (``cv2.dnn.NMSBoxes``).
Masks: the foreground (median background of the sequence, opened and closed: neither the motion
detector's low threshold nor its reconstruction of thin parts, which on vtest.avi made the people's
pixel heights in the boxes less consistent, tests/test_detectors_vtest.py) inside the box when it
fills at least ``min_fill`` of the box, else GrabCut initialised with the box (``mask="grabcut"`` always uses
GrabCut, ``mask="box"`` the box itself).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterable, Iterator, Sequence

import cv2
import numpy as np

from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_CLASSES, COCO, VEHICLE_CLASSES
from staticdepth.detectors.base import Detector, rows_from_masks
from staticdepth.detectors.motion import foreground_mask, median_background
from staticdepth.errors import InputError

STRIDES = (8, 16, 32)
MASK_MODES = ("motion", "grabcut", "box")
#: a box within this many pixels of the network's input (2 px of 416 = 3.7 px of a 768-wide
#: frame) of an image edge reaches it: the boxes of people whose feet the bottom edge of vtest.avi
#: cuts end 1.1-2.2 px above its last row (frames 507-612 of the second half), so their GrabCut
#: masks, 1 px short, passed tracking's border test and their cut feet entered the ground plane
EDGE_TOL_INPUT_PX = 2.0


def letterbox(image_rgb: np.ndarray, size: int) -> tuple[np.ndarray, float]:
    """(1, 3, S, S) float32 BGR 0-255 padded with 114, and the scale r applied to the image."""
    h, w = image_rgb.shape[:2]
    r = min(size / h, size / w)
    nh, nw = int(h * r), int(w * r)
    out = np.full((size, size, 3), 114, np.uint8)
    out[:nh, :nw] = cv2.resize(np.ascontiguousarray(image_rgb[..., ::-1]), (nw, nh),
                               interpolation=cv2.INTER_LINEAR)
    return out.transpose(2, 0, 1)[None].astype(np.float32), r


def decode(raw: np.ndarray, size: int, strides: Sequence[int] = STRIDES) -> np.ndarray:
    """(A, 5 + C) raw head output -> (A, 5 + C) with boxes (cx, cy, w, h) in input pixels."""
    grids, steps = [], []
    for s in strides:
        n = size // s
        yv, xv = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        grids.append(np.stack([xv, yv], -1).reshape(-1, 2))
        steps.append(np.full((n * n, 1), s))
    grid = np.concatenate(grids).astype(np.float32)
    step = np.concatenate(steps).astype(np.float32)
    if len(grid) != len(raw):
        raise InputError(f"YOLOX output has {len(raw)} anchors; input {size} with strides "
                         f"{tuple(strides)} gives {len(grid)}")
    out = raw.astype(np.float32).copy()
    out[:, :2] = (out[:, :2] + grid) * step
    out[:, 2:4] = np.exp(out[:, 2:4]) * step
    return out


def boxes_from_output(decoded: np.ndarray, r: float, score_thr: float, nms_thr: float,
                      classes: Iterable[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes (N, 4) u0 v0 u1 v1 in image pixels, scores (N,), class ids (N,) after class-wise NMS,
    the vehicle classes (car, bus, truck) as one: one vehicle is one of them, and YOLOX often
    scores a van as both a truck and a car (vtest.avi's parked van: 0.75 and 0.65, boxes 0.92
    IoU); the two masks, painted one over the other, swapped the van's foot point between frames
    by 8 px, and the static van passed for a moving agent. A person and a bicycle, or a car and a
    person, stay two objects."""
    cls = decoded[:, 5:].argmax(1)
    score = decoded[:, 4] * decoded[np.arange(len(decoded)), 5 + cls]
    keep = (score >= score_thr) & np.isin(cls, list(classes))
    d, cls, score = decoded[keep], cls[keep], score[keep]
    xywh = np.stack([d[:, 0] - d[:, 2] / 2, d[:, 1] - d[:, 3] / 2, d[:, 2], d[:, 3]], 1) / r
    boxes, scores, ids = [], [], []
    group = np.where(np.isin(cls, list(VEHICLE_CLASSES)), COCO["car"], cls)
    for c in np.unique(group):
        sel = np.nonzero(group == c)[0]
        idx = cv2.dnn.NMSBoxes(xywh[sel].tolist(), score[sel].tolist(), score_thr, nms_thr)
        for k in np.asarray(idx).reshape(-1):
            x, y, w, h = xywh[sel[k]]
            boxes.append((x, y, x + w, y + h))
            scores.append(score[sel[k]])
            ids.append(cls[sel[k]])
    order = np.argsort(-np.asarray(scores)) if scores else np.zeros(0, int)
    return (np.asarray(boxes, np.float32).reshape(-1, 4)[order],
            np.asarray(scores, np.float32)[order], np.asarray(ids, int)[order])


def grabcut_mask(image_rgb: np.ndarray, box: Sequence[float], iters: int = 3,
                 margin: int = 16) -> np.ndarray:
    """GrabCut initialised with the box, run on a crop of the box plus ``margin`` pixels."""
    h, w = image_rgb.shape[:2]
    u0, v0 = max(int(box[0]), 0), max(int(box[1]), 0)
    u1, v1 = min(int(np.ceil(box[2])), w - 1), min(int(np.ceil(box[3])), h - 1)
    out = np.zeros((h, w), bool)
    if u1 - u0 < 3 or v1 - v0 < 3:
        out[v0:v1 + 1, u0:u1 + 1] = True
        return out
    cu0, cv0 = max(u0 - margin, 0), max(v0 - margin, 0)
    cu1, cv1 = min(u1 + margin, w - 1), min(v1 + margin, h - 1)
    crop = np.ascontiguousarray(image_rgb[cv0:cv1 + 1, cu0:cu1 + 1, ::-1])
    m = np.zeros(crop.shape[:2], np.uint8)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.grabCut(crop, m, (u0 - cu0, v0 - cv0, u1 - u0, v1 - v0), bgd, fgd, iters,
                    cv2.GC_INIT_WITH_RECT)
        out[cv0:cv1 + 1, cu0:cu1 + 1] = (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)
    except cv2.error:
        out[v0:v1 + 1, u0:u1 + 1] = True
    return out


def reach_cut_edges(mask: np.ndarray, box: tuple[int, int, int, int], tol_px: float = 0.0
                    ) -> np.ndarray:
    """``mask`` (H, W) bool, extended to each image edge its box (u0, v0, u1, v1, inclusive
    pixels) reaches, within ``tol_px``: an object the frame cuts (a car half outside, a person's
    feet below the bottom row) continues there, but a motion or GrabCut mask inside its box often
    stops a few pixels short, and then the object passes for a whole one (tracking's border test
    reads the mask; on vtest.avi a car cut by the right edge, box to column 767, mask to 763,
    entered the ground plane). On each reached edge the mask's own rows (columns) get that edge's
    pixel, so its extent along the edge is unchanged."""
    h, w = mask.shape
    u0, v0, u1, v1 = box
    cut_cols = [c for c, hit in ((0, u0 <= tol_px), (w - 1, u1 >= w - 1 - tol_px)) if hit]
    cut_rows = [r for r, hit in ((0, v0 <= tol_px), (h - 1, v1 >= h - 1 - tol_px)) if hit]
    if not (cut_cols or cut_rows) or not mask.any():
        return mask
    out = mask.copy()
    rows, cols = mask.any(1), mask.any(0)
    for c in cut_cols:
        out[rows, c] = True
    for r in cut_rows:
        out[r, cols] = True
    return out


@dataclass
class YoloxDetector(Detector):
    model: str = ""
    input_size: int = 416
    score_thr: float = 0.35
    nms_thr: float = 0.45
    mask: str = "motion"
    min_fill: float = 0.15
    classes: frozenset = field(default_factory=lambda: AGENT_CLASSES | ACCESSORY_CLASSES)
    name: str = "yolox"

    def __post_init__(self):
        if self.mask not in MASK_MODES:
            raise InputError(f"yolox mask mode must be one of {MASK_MODES}, got {self.mask!r}")
        if not self.model or not os.path.isfile(self.model):
            # the caller names its own option (adapt: detector.model, observations:
            # --detector-model); here the file and what it should be
            raise InputError("YOLOX ONNX model not found (a YOLOX ONNX export such as "
                             "yolox_nano.onnx)" if self.model else "no YOLOX ONNX model given",
                             self.model or None)
        from staticdepth.onnx_session import onnx_session
        self.session = onnx_session(self.model, what="YOLOX ONNX model")
        self.input_name = self.session.get_inputs()[0].name

    def boxes(self, image_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, r = letterbox(image_rgb, self.input_size)
        raw = self.session.run(None, {self.input_name: x})[0]
        raw = raw[0] if raw.ndim == 3 else raw
        return boxes_from_output(decode(raw, self.input_size), r, self.score_thr, self.nms_thr,
                                 self.classes)

    def masks(self, image_rgb, boxes, fg: np.ndarray | None) -> list[np.ndarray]:
        h, w = image_rgb.shape[:2]
        tol = EDGE_TOL_INPUT_PX * max(h, w) / self.input_size     # in image pixels
        out = []
        for b in boxes:
            u0, v0 = max(int(np.floor(b[0])), 0), max(int(np.floor(b[1])), 0)
            u1, v1 = min(int(np.ceil(b[2])), w - 1), min(int(np.ceil(b[3])), h - 1)
            inside = np.zeros((h, w), bool)
            inside[v0:v1 + 1, u0:u1 + 1] = True
            if self.mask == "box":
                out.append(reach_cut_edges(inside, (u0, v0, u1, v1), tol))
                continue
            if self.mask == "motion" and fg is not None:
                m = fg & inside
                if m.sum() >= self.min_fill * inside.sum():
                    out.append(reach_cut_edges(m, (u0, v0, u1, v1), tol))
                    continue
            out.append(reach_cut_edges(grabcut_mask(image_rgb, b) & inside, (u0, v0, u1, v1),
                                       tol))
        return out

    def detect_sequence(self, images: Iterable[np.ndarray]
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        frames = images if isinstance(images, Sequence) else list(images)
        bg = median_background(frames) if self.mask == "motion" and len(frames) >= 5 else None
        for i, im in enumerate(frames):
            boxes, scores, cls = self.boxes(im)
            fg = None if bg is None else foreground_mask(im, bg, close_px=7, reconstruct=False)
            masks = self.masks(im, boxes, fg)
            # paint far (high) agents first so that nearer ones, lower in the image, win overlaps
            order = np.argsort(boxes[:, 3]) if len(boxes) else np.zeros(0, int)
            yield rows_from_masks(i, [masks[k] for k in order], cls[order], scores[order],
                                  im.shape[:2])
