"""Which agent's contact value each agent's pseudo label takes (METHOD.md section 1).

- A person riding a bicycle or motorcycle takes the vehicle's contact value: the person's foot
  point lies inside the vehicle's box, or the two masks touch while the person's lowest row stays
  above the vehicle's (a pedestrian beside a parked bike stands on the ground and keeps its own).
- A bag or umbrella takes the value of the nearest person (distance from its mask centroid to the
  person's box, at most ``accessory_reach`` x the person's pixel height); with no person near, it
  is an agent of its own.
Pure numpy/cv2 on one frame's instance map (H, W) uint16 and its AGENT_DTYPE rows.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from staticdepth.dataset.schema import ACCESSORY_CLASSES, COCO, RIDEABLE_CLASSES


@dataclass(frozen=True)
class Box:
    u0: float
    v0: float
    u1: float
    v1: float

    def contains(self, u: float, v: float, margin: float = 0.0) -> bool:
        return (self.u0 - margin <= u <= self.u1 + margin) and (self.v0 - margin <= v <= self.v1 + margin)

    def distance(self, u: float, v: float) -> float:
        du = max(self.u0 - u, 0.0, u - self.u1)
        dv = max(self.v0 - v, 0.0, v - self.v1)
        return float(np.hypot(du, dv))


def mask_box(mask: np.ndarray) -> Box | None:
    vs, us = np.nonzero(mask)
    if len(vs) == 0:
        return None
    return Box(float(us.min()), float(vs.min()), float(us.max()), float(vs.max()))


def label_sources(instances: np.ndarray, rows: np.ndarray, *, accessory_reach: float = 0.5,
                  touch_px: int = 2) -> dict[int, int]:
    """instance id -> instance id whose contact value labels it (itself when independent).

    Only instances present in both ``rows`` and the map are returned.
    """
    masks, boxes, cls = {}, {}, {}
    for r in rows:
        iid = int(r["instance_id"])
        m = instances == iid
        b = mask_box(m)
        if iid == 0 or b is None:
            continue
        masks[iid], boxes[iid], cls[iid] = m, b, int(r["class_id"])
    source = {iid: iid for iid in masks}
    persons = [i for i in masks if cls[i] == COCO["person"]]
    rideables = [i for i in masks if cls[i] in RIDEABLE_CLASSES]
    kernel = np.ones((2 * touch_px + 1, 2 * touch_px + 1), np.uint8)
    for p in persons:
        bp = boxes[p]
        foot_u = float(np.median(np.nonzero(masks[p][int(bp.v1)])[0]))
        best, best_score = None, 0.0
        grown = None
        for v in rideables:
            bv = boxes[v]
            if bv.contains(foot_u, bp.v1):
                score = 2.0
            else:
                if grown is None:
                    grown = cv2.dilate(masks[p].astype(np.uint8), kernel).astype(bool)
                touch = np.count_nonzero(grown & masks[v])
                score = 1.0 if touch > 0 and bp.v1 < bv.v1 else 0.0
            if score > best_score:
                best, best_score = v, score
        if best is not None:
            source[p] = best
    for a in [i for i in masks if cls[i] in ACCESSORY_CLASSES]:
        vs, us = np.nonzero(masks[a])
        cu, cv = float(us.mean()), float(vs.mean())
        best, best_d = None, np.inf
        for p in persons:
            bp = boxes[p]
            d = bp.distance(cu, cv)
            if d <= accessory_reach * max(bp.v1 - bp.v0, 1.0) and d < best_d:
                best, best_d = p, d
        if best is not None:
            source[a] = source[best]
    return source
