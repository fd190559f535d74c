"""A person's ground contact when the mask's lowest pixel is not the foot.

The alignment (``agents_at_contact``) gives every agent the plane's depth at its contact, the
mask's lowest pixel. In a crowd that pixel is often not the foot: the mask ends on another agent
in front (10-25% of the people in the frames of the independent scenes i1-i4, h1-h3) or at the
image's bottom row. The plane's depth there belongs to a ground point behind the person, up to
1.9x too far. The highest silhouette point is still seen, and the plane fit knows the person's
height (its track's ``s = H / d``, or the people's median), so the contact follows from the top:
the point of the top pixel's ray at height ``s`` above the plane is the highest point of the head
disk's rim; the axis below it ends in the foot disk, whose lowest rim point stands on the ground
(the joint model's people, :mod:`staticdepth.geometry.agent_shape`; rims by
:func:`staticdepth.geometry.agent_cylinder.extreme_rim`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from staticdepth.geometry.agent_cylinder import extreme_rim
from staticdepth.geometry.projection import rays_from_pixels

PEOPLE_CLASSES = (0, -1)      # COCO person, unknown class (the disk model's classes)


def contact_from_top(K: np.ndarray, n: np.ndarray, d: float, top_u, top_v, s,
                     extents: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Depth (camera z, units of ``d``) of the ground point under the lowest silhouette point of
    upright people whose highest silhouette point is at ``(top_u, top_v)`` (continuous pixels, the
    silhouette's edge), of heights ``s`` (over the camera height ``d``, plane ``n . P = d``) and
    foot / head disk radii ``extents`` (over the height). NaN where the top ray never reaches
    height ``s`` in front of the camera, or the foot would lie behind it."""
    n = np.asarray(n, np.float64) / np.linalg.norm(n)
    u, v, s = np.broadcast_arrays(np.asarray(top_u, np.float64), np.asarray(top_v, np.float64),
                                  np.asarray(s, np.float64))
    r = rays_from_pixels(K, u.ravel(), v.ravel())
    s = s.ravel()
    nr = r @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (1.0 - s) / nr                      # the ray's point at height s (plane n . P = 1)
    ok = np.isfinite(t) & (t > 0) & (np.abs(nr) > 1e-9) & (s > 0)
    P = r * np.where(ok, t, 1.0)[:, None]
    e_foot, e_head = (float(x) for x in extents)
    T = P.copy()
    if e_head > 0:          # the axis top whose highest head-rim point is P (as head_points)
        for _ in range(3):
            T = T + (P - extreme_rim(T, n, e_head * s, lowest=False))
    A = T + s[:, None] * n                      # the axis' foot on the plane
    F = extreme_rim(A, n, e_foot * s, lowest=True) if e_foot > 0 else A
    z = F[:, 2] * d
    return np.where(ok & (z > 0), z, np.nan).reshape(u.shape)


@dataclass(frozen=True)
class PersonHeights:
    """People's heights from the plane fit: each inlier track's ``s`` and the median of them for
    a person of no fitted track, with the people's disk extents ``(foot, head)``."""

    tracks: Mapping[int, float]
    default: float
    extents: tuple[float, float] = (0.0, 0.0)

    def of(self, track_ids) -> np.ndarray:
        return np.array([self.tracks.get(int(t), self.default) for t in np.atleast_1d(track_ids)])

    @classmethod
    def from_plane(cls, plane) -> "PersonHeights | None":
        """From an :class:`~staticdepth.geometry.agent_plane.AgentPlane` whose ``extra`` holds
        the tracks' ``classes`` (the ground_plane stage's); None without a person track."""
        classes = np.asarray(plane.extra.get("classes", np.full(len(plane.track_ids), -1)))
        keep = np.asarray(plane.inliers, bool) & np.isin(classes, PEOPLE_CLASSES) \
            & np.isfinite(plane.track_scale) & (np.asarray(plane.track_scale) > 0)
        if not keep.any():
            return None
        ext = plane.extra.get("extents", {}).get("people", (0.0, 0.0))
        return cls({int(t): float(v) for t, v in zip(plane.track_ids[keep],
                                                      plane.track_scale[keep])},
                   float(np.median(plane.track_scale[keep])),
                   (max(float(ext[0]), 0.0), max(float(ext[1]), 0.0)))


def contacts_from_top(K: np.ndarray, n_g, d_g: float, instances: np.ndarray, rows: np.ndarray,
                      heights, inv_plane: np.ndarray, conf, contact_px: int = 2,
                      edge_px: float = 0.5) -> dict[int, float]:
    """instance id -> contact inverse depth (units of 1 / d_g) of the people whose lowest mask
    pixel is not their foot: another instance within ``contact_px`` rows below it, or the image's
    bottom row; their top must be seen (not at the top row, no instance above it). The contact
    follows from the top (``edge_px`` above the top row: the silhouette's edge; the middle of a
    box detection's top) and the person's height (:func:`contact_from_top`), bounded by the
    lowest pixel's plane depth: a foot below the lowest pixel is nearer than it."""
    from staticdepth.pseudo_labels import contact_value
    from staticdepth.tracking import detections_from_instances

    if rows is None or not len(rows):
        return {}
    h = np.shape(instances)[0]
    det = detections_from_instances(instances, rows, border_px=1, contact_px=contact_px)
    pick = (np.isin(det["class_id"], PEOPLE_CLASSES)
            & (det["foot_hidden"] | (det["foot_v"] >= h - 1.5))
            & ~det["top_hidden"] & (det["top_v"] > 0))
    det = det[pick]
    if not len(det):
        return {}
    top_u = np.where(np.isfinite(det["top_u"]), det["top_u"], 0.5 * (det["left"] + det["right"]))
    z = contact_from_top(K, n_g, d_g, top_u, det["top_v"] - edge_px, heights.of(det["track"]),
                         heights.extents)
    out = {}
    for iid, zk in zip(det["instance_id"].tolist(), z.tolist()):
        if np.isfinite(zk):
            out[int(iid)] = max(1.0 / zk, contact_value(inv_plane, instances == iid, conf))
    return out
