"""Agents' extent for the ground-plane fit: per-class shape models with free parameters.

An agent of height ``s = H / d`` (units of the camera height d, plane ``n . P = 1``) stands on the
ground with its vertical axis along ``-n``. Its silhouette's lowest image point (the observed
foot) is the lowest point of its footprint's outline, its highest image point (the observed top)
the highest point of its roof's outline. Two outlines, both scaled with the agent's height:

- ``disk`` (people; unknown classes): a disk of radius ``e_f s`` at the foot and one of ``e_h s``
  at the top; two parameters ``(e_f, e_h)`` (0 = the thin head-foot axis; about 0.12 for a 0.2 m
  body).
- ``box`` (two-wheelers, cars, buses, trucks): a rectangle of half-length ``a s`` along the
  track's heading and half-width ``b s`` across it; two parameters ``(a, b)``. The heading is the
  principal direction of the track's foot points on the ground.

The parameters are unknowns of the fit (one set per class group, with a weak prior, see
:data:`GROUPS`), so no body model is assumed: a thin walker drives ``e`` to 0, a wide one up.
:func:`predict_top_rows` gives the top row of every observation from the foot rays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ShapeGroup:
    """One class group: its outline (``disk`` or ``box``), COCO class ids, the prior mean and
    standard deviation of its extent parameters (ratios to the agent's height) and their bounds,
    and its height distribution: ``(weight, mean m, sd m)`` components (people: adults and 10%
    children)."""

    name: str
    outline: str
    classes: tuple[int, ...]
    prior: tuple[float, ...]
    prior_sd: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    heights: tuple[tuple[float, float, float], ...]

    @property
    def typical_height(self) -> tuple[float, float]:
        """(mean, relative sd) of the main (heaviest) height component."""
        w, m, sd = max(self.heights)
        return m, sd / m


# COCO ids: person 0, bicycle 1, car 2, motorcycle 3, bus 5, truck 7; -1 = unknown (a CSV)
GROUPS = (
    ShapeGroup("people", "disk", (0, -1), (0.07, 0.05), (0.06, 0.05), (0.0, 0.0), (0.3, 0.3),
               ((0.9, 1.70, 0.09), (0.1, 1.25, 0.15))),
    ShapeGroup("two-wheelers", "box", (1, 3), (0.5, 0.17), (0.2, 0.08), (0.0, 0.0), (1.2, 0.5),
               ((1.0, 1.70, 0.10),)),
    ShapeGroup("cars", "box", (2,), (1.5, 0.6), (0.35, 0.12), (0.3, 0.2), (2.5, 1.0),
               ((1.0, 1.52, 0.10),)),
    ShapeGroup("buses-trucks", "box", (5, 7), (1.8, 0.42), (0.6, 0.12), (0.3, 0.1), (4.0, 1.0),
               ((1.0, 3.1, 0.35),)),
)


def group_of_class(cls: np.ndarray) -> np.ndarray:
    """(N,) group index per class id; classes of no group count as people (disk)."""
    out = np.zeros(len(cls), np.int64)
    for g, grp in enumerate(GROUPS):
        out[np.isin(cls, grp.classes)] = g
    return out


def _ground_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane of normal n: ``x`` less its part along n, then
    ``n x e1`` (scalar arithmetic: the fits call this ~10^4 times, numpy's small-array calls
    were an eighth of a box fit's time)."""
    a, b, c = (float(v) for v in n)
    x, y, z = 1.0 - a * a, -a * b, -a * c
    k = 1.0 / (x * x + y * y + z * z) ** 0.5
    x, y, z = x * k, y * k, z * k
    return np.array([x, y, z]), np.array([b * z - c * y, c * x - a * z, a * y - b * x])


def track_headings(n: np.ndarray, feet: np.ndarray, idx: np.ndarray, J: int) -> np.ndarray:
    """(J, 3) unit heading per track: the principal direction of its foot points (N, 3) in the
    plane (the first axis of the plane's basis for tracks with fewer than 2 finite points)."""
    e1, e2 = _ground_basis(n)
    xy = np.stack([feet @ e1, feet @ e2], 1)
    ok = np.all(np.isfinite(xy), 1)
    cnt = np.bincount(idx[ok], minlength=J).astype(np.float64)
    mean = np.stack([np.bincount(idx[ok], xy[ok, k], minlength=J) for k in (0, 1)], 1)
    mean /= np.maximum(cnt, 1)[:, None]
    dxy = np.where(ok[:, None], xy - mean[idx], 0.0)
    sxx = np.bincount(idx, dxy[:, 0] ** 2, minlength=J)
    syy = np.bincount(idx, dxy[:, 1] ** 2, minlength=J)
    sxy = np.bincount(idx, dxy[:, 0] * dxy[:, 1], minlength=J)
    ang = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2


def _rim(C: np.ndarray, basis, rho: np.ndarray, lowest: bool) -> np.ndarray:
    """:func:`~staticdepth.geometry.agent_cylinder.extreme_rim` with the plane's basis given."""
    best, best_row = None, None
    for P in _stationary(C, basis, rho, 1):
        row = np.nan_to_num(_rows(P), nan=-np.inf if lowest else np.inf)
        if best is None:
            best, best_row = P, row
        else:
            take = row > best_row if lowest else row < best_row
            best = np.where(take[:, None], P, best)
    return best


def _stationary(C: np.ndarray, basis, rho: np.ndarray, axis: int) -> list[np.ndarray]:
    """The two points (N, 3 each) of the horizontal circles (centres C (N, 3), radii rho, in the
    plane's ``basis``) where the image coordinate ``P[axis] / P[2]`` (1: the row, 0: the column,
    up to the intrinsics) is stationary, in closed form: its extremes."""
    e1, e2 = basis
    p, q = np.array([e1[axis], e2[axis]]), np.array([e1[2], e2[2]])
    g0, g1 = C[:, 2] * p[0] - C[:, axis] * q[0], C[:, 2] * p[1] - C[:, axis] * q[1]
    k = p[1] * q[0] - p[0] * q[1]
    R = np.maximum(np.hypot(g0, g1), 1e-300)
    alpha, acos = np.arctan2(g0, g1), np.arccos(np.clip(-rho * k / R, -1.0, 1.0))
    return [C + rho[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
            for phi in (acos - alpha, -acos - alpha)]


def _rows(P: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return P[..., 1] / P[..., 2]


def _box_top(n, F, s, a, b, heading) -> np.ndarray:
    """Highest top corners (N, 3) of boxes whose lowest footprint corner is F (N, 3)."""
    top = box_corners(n, F, s, a, b, heading)[:, 4:]
    trows = np.nan_to_num(_rows(top), nan=np.inf)
    trows[top[..., 2] <= 1e-9] = np.inf
    return top[np.arange(len(F)), np.argmin(trows, axis=1)]


def box_corners(n, F, s, a, b, heading) -> np.ndarray:
    """(N, 8, 3) corners of boxes (footprint first, then roof) whose lowest footprint corner in
    the image is F (N, 3): half-length ``a s`` along ``heading`` (N, 3), half-width ``b s``,
    height ``s``."""
    side = np.cross(n, heading)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], np.float64)
    off = (signs[None, :, 0, None] * (a * s)[:, None, None] * heading[:, None, :]
           + signs[None, :, 1, None] * (b * s)[:, None, None] * side[:, None, :])   # (N, 4, 3)
    # hypothesis k: corner k is the lowest one, so the box's centre is F - off_k
    centre = F[:, None, :] - off                                                    # (N, 4, 3)
    corners = centre[:, :, None, :] + off[:, None, :, :]                            # (N, 4, 4, 3)
    rows = _rows(corners)
    margin = rows[:, np.arange(4), np.arange(4)] - np.max(rows, axis=2)             # <= 0
    k = np.argmax(np.nan_to_num(margin, nan=-np.inf), axis=1)
    c = centre[np.arange(len(F)), k]
    return np.concatenate([c[:, None, :] + off, c[:, None, :] - s[:, None, None] * n + off], 1)


WIDTH_AT = 0.75     # a person's widest ring (shoulders, arms, torso) at this share of its height


def person_columns(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray, e_f, e_h,
                   radius) -> tuple[np.ndarray, np.ndarray]:
    """(left (N,), right (N,)) extreme columns in pixels of people seen as boxes: the convex
    hull of the foot disk (radius ``e_f s``, its lowest point on ``rays``), the head disk
    (``e_h s`` at the height s (N,), :func:`top_points`) and a
    ring of ``radius`` (N, units of d) at :data:`WIDTH_AT` of the height (the shoulders). A wide
    cylinder is all three alike, a thin axis none. NaN behind the camera."""
    A = foot_centres(n, rays, s, e_f)
    lo, hi = disk_columns(K, n, A, s, e_f, e_h)
    rlo, rhi = ring_columns(K, n, A, s, radius)
    return np.fmin(lo, rlo), np.fmax(hi, rhi)


def foot_centres(n: np.ndarray, rays: np.ndarray, s: np.ndarray, e_f) -> np.ndarray:
    """(N, 3) centres of the people's foot disks whose lowest image points are on ``rays`` (NaN
    where a ray misses the ground)."""
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        F = rays / nr[:, None]
    F[~(nr > 1e-9)] = np.nan
    A = F.copy()
    if np.any(np.asarray(e_f) > 0):
        basis = _ground_basis(n)
        for _ in range(3):
            A = A + (F - _rim(A, basis, np.asarray(e_f) * s, lowest=True))
    return A


def disk_columns(K, n, A, s, e_f, e_h) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) columns of the hull of the foot disks (centres A) and the head disks."""
    N = len(A)
    lo, hi = circle_columns(K, n, np.r_[A, A - s[:, None] * n],
                            np.r_[np.asarray(e_f) * s * np.ones(N), np.asarray(e_h) * s])
    return np.fmin(lo[:N], lo[N:]), np.fmax(hi[:N], hi[N:])


def ring_columns(K, n, A, s, radius) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) columns of rings of ``radius`` at :data:`WIDTH_AT` of the height."""
    return circle_columns(K, n, A - WIDTH_AT * s[:, None] * n,
                          np.asarray(radius, np.float64) * np.ones(len(A)))


def circle_columns(K, n, C, rho) -> tuple[np.ndarray, np.ndarray]:
    """(leftmost, rightmost) image columns of horizontal circles (centres C (M, 3), radii rho
    (M,)) in closed form: the two stationary points of ``X / Z`` on each (a 16-gon's were up to
    2% of the radius short, a pixel's width error that moved with the viewing direction: 1-2 deg
    of a wide body's plane; the skew ``K[0, 1]`` is taken as 0 for where they lie). NaN behind
    the camera."""
    us = []
    for P in _stationary(C, _ground_basis(n), rho, 0):
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 1] * P[:, 1] / P[:, 2] + K[0, 2]
        u[~(P[:, 2] > 1e-9)] = np.nan
        us.append(u)
    return np.fmin(*us), np.fmax(*us)


def box_columns(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray,
                group: np.ndarray, params: list[np.ndarray], heading: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(left (N,), right (N,)) extreme columns in pixels of the box outlines' projections (the
    sides of a box detection); NaN for the other outlines and where a corner is behind the
    camera. Arguments as :func:`top_points`."""
    left, right = np.full(len(rays), np.nan), np.full(len(rays), np.nan)
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        F = rays / nr[:, None]
    F[~(nr > 1e-9)] = np.nan
    for g, grp in enumerate(GROUPS):
        m = group == g
        if grp.outline != "box" or not m.any():
            continue
        C = box_corners(n, F[m], s[m], params[g][0], params[g][1], heading[m])
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * C[..., 0] / C[..., 2] + K[0, 1] * C[..., 1] / C[..., 2] + K[0, 2]
        u[~(C[..., 2] > 1e-9)] = np.nan
        left[m], right[m] = u.min(1), u.max(1)
    return left, right


def top_points(n: np.ndarray, rays: np.ndarray, s: np.ndarray, group: np.ndarray,
               params: list[np.ndarray], heading: np.ndarray | None,
               extent_s: float | None = None) -> np.ndarray:
    """Highest silhouette points (N, 3) over d for agents whose lowest point is on ``rays``.

    n: unit normal; s: (N,) height over d; group: (N,) index into :data:`GROUPS`; params: one
    parameter vector per group; heading: (N, 3) unit headings (needed for box groups);
    ``extent_s``: the disks' radii ``e * extent_s`` (fixed in metres: a typical agent's s) instead
    of ``e * s``. NaN rows where a ray does not meet the ground."""
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        F = rays / nr[:, None]
    F[~(nr > 1e-9)] = np.nan
    T = np.full_like(F, np.nan)
    basis = _ground_basis(n)
    for g, grp in enumerate(GROUPS):
        m = group == g
        if not m.any():
            continue
        p = params[g]
        if grp.outline == "disk":
            se = s[m] if extent_s is None else np.full(int(m.sum()), extent_s)
            A = F[m].copy()
            if np.any(np.asarray(p[0]) > 0):
                for _ in range(3):
                    A = A + (F[m] - _rim(A, basis, p[0] * se, lowest=True))
            T[m] = _rim(A - s[m, None] * n, basis, p[1] * se, lowest=False)
        else:
            T[m] = _box_top(n, F[m], s[m], p[0], p[1], heading[m])
    return T


def predict_top(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray,
                group: np.ndarray, params: list[np.ndarray],
                heading: np.ndarray | None = None, extent_s: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted top points (u (N,), v (N,)) in pixels (NaN where impossible); see
    :func:`top_points`."""
    T = top_points(n, rays, s, group, params, heading, extent_s)
    z = T[:, 2]
    bad = ~(z > 1e-9)
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = T[:, 0] / z, T[:, 1] / z
    u, v = K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]
    u[bad], v[bad] = np.nan, np.nan
    return u, v
