"""Agents' observations: per-frame instances -> detections -> tracks -> a tidy observation table.

A detection is one agent instance in one frame (a rider and its bicycle or motorcycle are merged
into one agent of the two-wheeler's class first, :func:`merge_riders`): its foot point (bottom
centre of the mask: the lowest row, the median column of that row; for people the mean of both
feet's lowest points, :func:`walker_foot`), its top point (the highest row, the median column of
that row; the column is NaN when only a box or an agent row without it is known, or the mask
fills its bounding box: a box detection), box and score.
Detections are linked across frames by the Hungarian assignment
(``scipy.optimize.linear_sum_assignment``) on box IoU, or on foot-point distance relative to the
pixel height when there are no boxes; track ids given with the rows (``track_id`` >= 0, e.g. the
synthetic scene's ground truth) are kept instead. Observations keep tracks seen in at least
``min_frames`` frames, dropping detections that touch the image border, are small
(``height_px < min_height_px``), have a low score or are *occluded*: from instance maps, a mask
whose lowest row sits on another instance (feet hidden behind a car or a bag, a rider on a
bicycle, whose lowest row is the saddle) or whose top row is covered by another instance (an
umbrella over the head), within ``contact_px`` rows; from agent rows, a ``visibility`` share
below ``min_visibility`` when one is given. On the synthetic scenes these rows put the foot point
6-30 px above the true foot.

The observation table holds the silhouette's extreme points in continuous pixel coordinates: a
mask's lowest row ``v`` covers the silhouette's lowest point somewhere in [v, v + 1) (pixel
centres sample it), so the foot row is ``v + edge_px`` and the top row ``top - edge_px`` (0.5 by
default; measured on rendered scenes: the rows sit 0.5 px inside the analytic extremes, which
shortens 10-20 px people by 5-10%).

Which tracks are kept (see :func:`observations`): a *static* track (feet within ``min_travel_px``
RMS of their mean in every direction) is always dropped: it fixes only its own height. A
*collinear* track (feet within ``collinear_px`` RMS of their best-fit line, a straight walker) is
dropped only with ``drop_collinear``: the paper asks for it because Eq. 1 needs spread, while for
the exact model a straight track still constrains the normal (its pixel height changes along the
line while its own height s_j stays fixed). :meth:`TrackingConfig.for_model` picks the default per
ground-plane model.

Output: :data:`OBS_DTYPE` rows (frame, track, class_id, foot_u, foot_v, height_px, top_v, score,
top_u, feet: 2 where a walker's foot point is its two feet's mean, 1 one foot, 0 not a person
mask; left, right: the silhouette's extreme columns, the box's sides for a box detection, NaN
when unknown), foot and top rows and the side columns moved ``edge_px`` outwards, the input of
:func:`staticdepth.geometry.agent_plane.fit_agent_plane`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

from staticdepth.dataset.schema import AGENT_CLASSES
from staticdepth.errors import InputError

OBS_DTYPE = np.dtype([("frame", np.int32), ("track", np.int32), ("class_id", np.int16),
                      ("foot_u", np.float32), ("foot_v", np.float32), ("height_px", np.float32),
                      ("top_v", np.float32), ("score", np.float32), ("top_u", np.float32),
                      ("feet", np.uint8), ("left", np.float32), ("right", np.float32)])

DET_DTYPE = np.dtype([("frame", np.int32), ("instance_id", np.int32), ("class_id", np.int16),
                      ("track", np.int32), ("foot_u", np.float32), ("foot_v", np.float32),
                      ("top_v", np.float32), ("left", np.float32), ("right", np.float32),
                      ("score", np.float32), ("border", np.bool_), ("top_u", np.float32),
                      ("occluded", np.bool_), ("feet", np.uint8), ("foot_hidden", np.bool_),
                      ("top_hidden", np.bool_)])


@dataclass(frozen=True)
class TrackingConfig:
    """Which detections and tracks become observations, and how detections are linked."""

    min_height_px: float = 20.0
    min_score: float = 0.3
    min_frames: int = 3
    border_px: int = 1               # a box within this many pixels of the edge touches it
    min_iou: float = 0.1             # linking gate with boxes
    max_step_rel: float = 0.5        # linking gate without boxes: foot step / pixel height
    max_gap: int = 1                 # frames a track may miss and still be continued
    min_travel_px: float = 3.0       # static: feet within this RMS spread in every direction
    drop_collinear: bool = True      # also drop straight walkers (for Eq. 1; see for_model)
    collinear_px: float = 1.0        # RMS distance from the best line below which it is one line
    classes: frozenset[int] | None = AGENT_CLASSES
    drop_occluded: bool = True       # drop detections whose foot or top is hidden (module doc)
    contact_px: int = 2              # rows below the foot / above the top checked for others
    min_visibility: float = 0.9      # agent rows with a known visible share below it are occluded
    edge_px: float = 0.5             # mask rows -> silhouette extremes: foot + edge, top - edge

    def __post_init__(self):
        from staticdepth.config import check_ranges

        check_ranges(self, "tracking.", {
            "min_height_px": ">=0", "min_score": "0..1", "min_frames": ">=1", "border_px": ">=0",
            "min_iou": "0..1", "max_step_rel": ">0|inf", "max_gap": ">=0",
            "min_travel_px": ">=0", "collinear_px": ">=0", "contact_px": ">=0",
            "min_visibility": "0..1", "edge_px": ">=0"})

    @classmethod
    def for_model(cls, model: str, **overrides) -> "TrackingConfig":
        """The default for a ground-plane model: straight walkers are dropped for the Eq. 1 models
        (``paper``, ``affine``) and kept for ``exact``."""
        return cls(**{"drop_collinear": model != "exact", **overrides})


def detections_from_instances(instance_map: np.ndarray, rows: np.ndarray | None = None,
                              frame: int = 0, border_px: int = 1,
                              contact_px: int = 2) -> np.ndarray:
    """Detections (:data:`DET_DTYPE`) of the instances of one (H, W) map (0 = background).

    rows: (K, 3) ``(instance_id, class_id, score)`` or a structured array with those fields
    (AGENT_DTYPE works; its ``track_id`` >= 0 is kept as the track); instances absent from
    ``rows`` are ignored. None = every instance, class unknown (-1), score 1. ``foot_hidden`` /
    ``top_hidden``: within ``contact_px`` rows below the lowest row (columns of that row, +-1) /
    above the top row there is another instance; ``occluded``: either.
    """
    m = np.asarray(instance_map)
    if m.ndim != 2:
        raise InputError(f"an instance map must be 2-D, got shape {m.shape}")
    if rows is not None:
        m = merge_riders(m, rows, contact_px)
    h, w = m.shape
    vs, us = np.nonzero(m)
    ids = m[vs, us].astype(np.int64)
    order = np.lexsort((us, -vs, ids))       # by id, then lowest row first, then column
    ids, vs, us = ids[order], vs[order], us[order]
    uniq, start = np.unique(ids, return_index=True)
    info = _row_info(rows, uniq)
    out = np.zeros(len(uniq), DET_DTYPE)
    out["frame"], out["instance_id"] = frame, uniq
    ends = np.r_[start[1:], len(ids)]
    for k, (a, b) in enumerate(zip(start, ends)):
        v_low, v_top = vs[a], vs[b - 1]
        low_cols, top_cols = us[a:b][vs[a:b] == v_low], us[a:b][vs[a:b] == v_top]
        if info[k, 0] in WALKER_CLASSES:
            out["foot_u"][k], out["foot_v"][k], out["feet"][k] = walker_foot(us[a:b], vs[a:b])
        else:
            out["foot_u"][k], out["foot_v"][k] = np.median(low_cols), v_low
        out["top_v"][k] = v_top
        out["left"][k], out["right"][k] = us[a:b].min(), us[a:b].max()
        # a mask that fills its bounding box is a box detection: its top row's middle is not
        # the silhouette's highest point (the fit then uses its sides)
        box = b - a == (out["right"][k] - out["left"][k] + 1) * (v_low - v_top + 1)
        out["top_u"][k] = np.nan if box else np.median(top_cols)
        out["foot_hidden"][k] = _touches(m, uniq[k], v_low + 1, v_low + 1 + contact_px, low_cols)
        out["top_hidden"][k] = _touches(m, uniq[k], v_top - contact_px, v_top, top_cols)
    out["occluded"] = out["foot_hidden"] | out["top_hidden"]
    out["class_id"], out["score"], out["track"] = info[:, 0], info[:, 1], info[:, 2]
    out["border"] = ((out["left"] <= border_px - 1 + 1e-3) | (out["right"] >= w - border_px)
                     | (out["top_v"] <= border_px - 1 + 1e-3) | (out["foot_v"] >= h - border_px))
    keep = np.isfinite(info[:, 1])
    return out[keep]


TWO_WHEELERS = (1, 3)     # COCO bicycle, motorcycle
WALKER_CLASSES = (0, -1)  # COCO person, unknown class: the foot point of :func:`walker_foot`
FOOT_BAND = 0.25          # a second foot is searched within this share of the height ...
FOOT_DIP = 0.03           # ... and must be a separate peak: the bottom profile dips by this share


def walker_foot(us: np.ndarray, vs: np.ndarray) -> tuple[float, float, int]:
    """Foot point (column, row) of a walker from its mask pixels ``(us, vs)`` and the number of
    feet it averages: the mean of its two feet's lowest points, or its lowest point when it shows
    one foot.

    The bottom profile (per column, the lowest row) has a peak per foot: the second foot is the
    lowest profile point within :data:`FOOT_BAND` of the height above the lowest row that is
    separated from the lowest one by a dip of :data:`FOOT_DIP` of the height (at least 1 px). The
    columns split at the dip; each part's lowest point is its lowest row and that row's median
    column there. A walker's lowest pixel is its nearer foot, up to +-0.3 m from its axis along
    the stride; the feet sit symmetrically about the axis, so their mean is the axis' foot moved
    towards the camera by a foot's size: the foot disk the ground-plane model assumes. A convex
    bottom (feet together, a wide body) has one peak: its lowest point.
    """
    us, vs = np.asarray(us, np.float64), np.asarray(vs, np.float64)
    height = vs.max() - vs.min()
    cols, inv = np.unique(np.round(us), return_inverse=True)
    low = np.full(len(cols), -np.inf)
    np.maximum.at(low, inv, vs)
    k1 = int(np.argmax(low))
    # the profile's highest point (smallest row) between each column and the lowest one
    between = np.empty_like(low)
    between[:k1 + 1] = np.minimum.accumulate(low[k1::-1])[::-1]
    between[k1:] = np.minimum.accumulate(low[k1:])
    ok = ((low - between >= max(1.0, FOOT_DIP * height))
          & (low >= low[k1] - FOOT_BAND * height))
    if not ok.any():
        parts = [np.ones(len(us), bool)]
    else:
        k2 = int(np.flatnonzero(ok)[np.argmax(low[ok])])
        a, b = sorted((k1, k2))
        cut = cols[a + int(np.argmin(low[a:b + 1]))]
        parts = [us < cut, us > cut]
    pts = []
    for part in parts:
        vm = vs[part].max()
        pts.append((float(np.median(us[part & (vs >= vm - 0.5)])), float(vm)))
    u, v = np.mean(pts, axis=0)
    return float(u), float(v), len(pts)


def merge_riders(instance_map: np.ndarray, rows, contact_px: int = 2) -> np.ndarray:
    """The instance map with every rider's pixels relabelled as its two-wheeler's instance.

    A rider is a person instance whose lowest row lies within the rows of a bicycle or motorcycle
    instance (down to ``contact_px`` above its top) and whose columns overlap it; it joins the
    two-wheeler it overlaps most. The merged agent (foot on the wheels, top on the rider's head,
    the two-wheeler's class and track) is one rigid agent for the ground plane."""
    info = np.asarray(rows)
    if info.dtype.names:
        ids, cls = np.asarray(info["instance_id"]), np.asarray(info["class_id"])
    else:
        tab = np.asarray(info, dtype=np.float64).reshape(-1, 3)
        ids, cls = tab[:, 0].astype(np.int64), tab[:, 1].astype(np.int64)
    bikes, people = ids[np.isin(cls, TWO_WHEELERS)], ids[cls == 0]
    if not len(bikes) or not len(people):
        return instance_map
    ext = {}
    for iid in np.r_[bikes, people]:
        vs, us = np.nonzero(instance_map == iid)
        if len(vs):
            ext[int(iid)] = (vs.min(), vs.max(), us.min(), us.max())
    out = None
    for p in people:
        if int(p) not in ext:
            continue
        pt, pb, pl, pr = ext[int(p)]
        best, best_ov = None, 0
        for b in bikes:
            if int(b) not in ext:
                continue
            bt, bb, bl, br = ext[int(b)]
            ov = min(pr, br) - max(pl, bl) + 1
            if bt - contact_px <= pb <= bb and ov > best_ov:
                best, best_ov = b, ov
        if best is not None:
            out = instance_map.copy() if out is None else out
            out[instance_map == p] = best
    return instance_map if out is None else out


def _touches(m: np.ndarray, iid: int, v0: int, v1: int, cols: np.ndarray) -> bool:
    """Whether rows v0..v1-1 (clipped), columns cols.min()-1..cols.max()+1, hold another
    instance than ``iid`` (background 0 does not count)."""
    h, w = m.shape
    v0, v1 = max(v0, 0), min(v1, h)
    if v0 >= v1:
        return False
    patch = m[v0:v1, max(int(cols.min()) - 1, 0):min(int(cols.max()) + 2, w)]
    return bool(np.any((patch != 0) & (patch != iid)))


def _row_info(rows, ids: np.ndarray) -> np.ndarray:
    """(len(ids), 3) class, score and track per instance id; score NaN for ids absent from
    ``rows``, track -1 where unknown."""
    info = np.column_stack([np.full(len(ids), -1.0), np.ones(len(ids)), np.full(len(ids), -1.0)])
    if rows is None:
        return info
    r = np.asarray(rows)
    if r.dtype.names:
        names = r.dtype.names
        tab = np.column_stack([r["instance_id"], r["class_id"],
                               r["score"] if "score" in names else np.ones(len(r)),
                               r["track_id"] if "track_id" in names else np.full(len(r), -1)])
    else:
        tab = np.asarray(r, dtype=np.float64).reshape(-1, 3)
        tab = np.column_stack([tab, np.full(len(tab), -1.0)])
    info[:, 1] = np.nan
    pos = {int(i): k for k, i in enumerate(ids)}
    for iid, cls, score, track in tab:
        k = pos.get(int(iid))
        if k is not None:
            info[k] = (cls, score, track)
    return info


def detections_from_agents(agents: np.ndarray, width: int, height: int,
                           border_px: int = 1, visibility: np.ndarray | None = None,
                           min_visibility: float = 0.9) -> np.ndarray:
    """Detections from ``dataset/schema.py::AGENT_DTYPE`` rows (their track ids are kept); the top
    column comes from a ``top_u`` field when the rows have one, else it is unknown (NaN).

    visibility: (len(agents),) visible share of each agent's silhouette (the synthetic scene's
    ``render()["visibility"]``); rows below ``min_visibility`` are ``occluded``. None = unknown
    (rows carry no mask to test: prefer :func:`detections_from_instances` with the maps)."""
    a = np.asarray(agents)
    out = np.zeros(len(a), DET_DTYPE)
    for f in ("frame", "instance_id", "class_id", "foot_u", "foot_v", "top_v", "score"):
        out[f] = a[f]
    out["top_u"] = a["top_u"] if "top_u" in (a.dtype.names or ()) else np.nan
    out["track"] = a["track_id"]
    out["left"] = out["right"] = np.nan
    out["border"] = ((a["foot_u"] <= border_px - 1) | (a["foot_u"] >= width - border_px)
                     | (out["top_u"] <= border_px - 1) | (out["top_u"] >= width - border_px)
                     | (a["top_v"] <= border_px - 1) | (a["foot_v"] >= height - border_px))
    if visibility is not None:
        vis = np.asarray(visibility, dtype=np.float64)
        if vis.shape != (len(a),):
            raise InputError(f"visibility must have one value per agent row ({len(a)}), got "
                             f"shape {vis.shape}")
        out["occluded"] = vis < min_visibility
    return out


def link_tracks(dets: np.ndarray, conf: TrackingConfig = TrackingConfig()) -> np.ndarray:
    """Assign ``track`` ids frame by frame (Hungarian on 1 - IoU, or on the foot step over the
    pixel height when boxes are unknown); same class only. Returns a copy, sorted by frame."""
    d = np.sort(np.asarray(dets, DET_DTYPE), order=["frame", "instance_id"]).copy()
    d["track"] = -1
    live: dict[int, int] = {}            # track -> index of its last detection
    next_id = 0
    for f in np.unique(d["frame"]):
        cur = np.flatnonzero(d["frame"] == f)
        tracks = [t for t, i in live.items() if f - d["frame"][i] <= conf.max_gap + 1]
        if tracks and len(cur):
            prev = np.array([live[t] for t in tracks])
            cost = _link_cost(d[prev], d[cur], conf)
            r, c = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e6))
            for i, j in zip(r, c):
                if np.isfinite(cost[i, j]):
                    d["track"][cur[j]] = tracks[i]
        for j in cur:
            if d["track"][j] < 0:
                d["track"][j] = next_id
                next_id += 1
            live[int(d["track"][j])] = j
    return d


def _link_cost(a: np.ndarray, b: np.ndarray, conf: TrackingConfig) -> np.ndarray:
    """(len(a), len(b)) cost; inf where the gate or the class forbids the link."""
    boxes = np.all(np.isfinite(a["left"])) and np.all(np.isfinite(b["left"]))
    if boxes:
        l_ = np.maximum(a["left"][:, None], b["left"][None])
        r_ = np.minimum(a["right"][:, None], b["right"][None]) + 1
        t_ = np.maximum(a["top_v"][:, None], b["top_v"][None])
        b_ = np.minimum(a["foot_v"][:, None], b["foot_v"][None]) + 1
        inter = np.clip(r_ - l_, 0, None) * np.clip(b_ - t_, 0, None)
        area = lambda x: (x["right"] - x["left"] + 1) * (x["foot_v"] - x["top_v"] + 1)  # noqa: E731
        iou = inter / (area(a)[:, None] + area(b)[None] - inter)
        cost = np.where(iou >= conf.min_iou, 1.0 - iou, np.inf)
    else:
        step = np.hypot(a["foot_u"][:, None] - b["foot_u"][None],
                        a["foot_v"][:, None] - b["foot_v"][None])
        h = np.maximum(a["foot_v"] - a["top_v"], 1.0)[:, None]
        rel = step / h
        cost = np.where(rel <= conf.max_step_rel, rel, np.inf)
    return np.where(a["class_id"][:, None] == b["class_id"][None], cost, np.inf)


def observations(dets: np.ndarray, conf: TrackingConfig = TrackingConfig()) -> np.ndarray:
    """Filter linked detections into the observation table (:data:`OBS_DTYPE`), sorted by
    (track, frame). Detections without a track are linked first.

    Kept: detections off the border, at least ``min_height_px`` tall, scored ``min_score`` or more,
    of the agent classes, not ``occluded`` (with ``drop_occluded``); then tracks seen in
    ``min_frames`` frames whose feet (sigma_1 >= sigma_2
    the RMS spreads along and across their total-least-squares line) are not static (sigma_1 <
    ``min_travel_px``) and, with ``drop_collinear``, not on one line (sigma_2 < ``collinear_px``).
    """
    d = np.asarray(dets, DET_DTYPE)
    if len(d) and np.any(d["track"] < 0):
        d = link_tracks(d, conf)
    h = d["foot_v"] - d["top_v"]
    ok = (~d["border"]) & (h >= conf.min_height_px) & (d["score"] >= conf.min_score)
    if conf.drop_occluded:
        ok &= ~d["occluded"]
    if conf.classes is not None:
        ok &= np.isin(d["class_id"], list(conf.classes)) | (d["class_id"] < 0)
    d, h = d[ok], h[ok]
    keep = np.zeros(len(d), bool)
    for t in np.unique(d["track"]):
        sel = np.flatnonzero(d["track"] == t)
        if len(np.unique(d["frame"][sel])) < conf.min_frames:
            continue
        uv = np.stack([d["foot_u"][sel], d["foot_v"][sel]], 1).astype(np.float64)
        sv = np.linalg.svd(uv - uv.mean(0), compute_uv=False) / np.sqrt(len(sel))
        if sv[0] < conf.min_travel_px:
            continue
        if conf.drop_collinear and sv[1] < conf.collinear_px:
            continue
        keep[sel] = True
    d, h = d[keep], h[keep]
    out = np.zeros(len(d), OBS_DTYPE)
    for f in ("frame", "track", "class_id", "foot_u", "score", "top_u", "feet"):
        out[f] = d[f]
    out["foot_v"] = d["foot_v"] + conf.edge_px
    out["top_v"] = d["top_v"] - conf.edge_px
    out["height_px"] = out["foot_v"] - out["top_v"]
    out["left"] = d["left"] - conf.edge_px
    out["right"] = d["right"] + conf.edge_px
    return np.sort(out, order=["track", "frame"])


def observations_from_instances(frames: Iterable[tuple[np.ndarray, np.ndarray | None]],
                                conf: TrackingConfig = TrackingConfig()) -> np.ndarray:
    """Observations from per-frame ``(instance_map (H, W), rows)`` pairs (see
    :func:`detections_from_instances`); frames are numbered in order. Track ids come from the
    rows when every detection has one, else detections are linked by IoU."""
    dets = [detections_from_instances(m, rows, i, conf.border_px, conf.contact_px)
            for i, (m, rows) in enumerate(frames)]
    if not dets:
        raise InputError("no frames to track agents in")
    return observations(np.concatenate(dets), conf)


def observations_from_agents(agents: np.ndarray, width: int, height: int,
                             conf: TrackingConfig = TrackingConfig(),
                             visibility: np.ndarray | None = None) -> np.ndarray:
    """Observations from AGENT_DTYPE rows; rows without a track id are linked by foot distance.
    ``visibility`` (one per row, optional) marks rows below ``conf.min_visibility`` occluded."""
    return observations(detections_from_agents(agents, width, height, conf.border_px, visibility,
                                               conf.min_visibility), conf)
