"""The exact projective model of an agent: an upright cylinder standing on the ground plane.

In units of the camera height d (plane ``n . P = 1``, camera frame, OpenCV axes) an agent of height
``s = H / d`` stands with its axis along ``-n``; its foot disk has radius ``foot_ratio * s`` and
its head disk (the top of the silhouette) ``head_ratio * s``. A person's head is narrower than
the body (about 0.12 m against 0.2 m): the top of the silhouette is the far edge of the head, and
that edge's column in particular moves with the radius assumed. Functions take ``radius_ratio``
as one number (both disks) or a ``(foot_ratio, head_ratio)`` pair. The silhouette's lowest point
is the lowest point (largest image row) of the foot disk's rim, its highest point the highest
point of the head disk's rim; both are found in closed form (:func:`extreme_rim`). Given the
observed lowest point, the model predicts the top point's row and column (:func:`head_pixels`).

:class:`AgentObservations` is the observation table prepared for the fit (rays, observed top
points, track index); :func:`head_residuals` and :func:`solve_track_scales` are the pieces the
robust fit of :mod:`staticdepth.geometry.agent_plane` is built from.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_BIG = 1e3   # residual (px) that stands in for an impossible prediction (ray above the horizon)

Ratio = float | tuple[float, float]   # one radius/height ratio, or (foot, head)


def split_ratio(radius_ratio) -> tuple[float, float]:
    """(foot_ratio, head_ratio) from one ratio (both disks) or a pair."""
    if np.ndim(radius_ratio) == 0:
        return float(radius_ratio), float(radius_ratio)
    foot, head = radius_ratio
    return float(foot), float(head)


def extreme_rim(C: np.ndarray, n: np.ndarray, rho: np.ndarray, lowest: bool) -> np.ndarray:
    """Point of each horizontal circle (centre C (N,3), radius rho (N,), axis n) with the largest
    (``lowest``) or smallest image row, i.e. extreme Y/Z; closed form of d(Y/Z)/dphi = 0."""
    ex = np.array([1.0, 0.0, 0.0])
    e1 = ex - n[0] * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    p, q = np.array([e1[1], e2[1]]), np.array([e1[2], e2[2]])
    g = C[:, 2:3] * p - C[:, 1:2] * q                         # (N, 2)
    k = p[1] * q[0] - p[0] * q[1]
    R = np.maximum(np.hypot(g[:, 0], g[:, 1]), 1e-300)
    alpha = np.arctan2(g[:, 0], g[:, 1])
    acos = np.arccos(np.clip(-rho * k / R, -1.0, 1.0))
    best = None
    for sign in (1.0, -1.0):
        phi = sign * acos - alpha
        P = C + rho[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        if best is None:
            best = P
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio_new, ratio_old = P[:, 1] / P[:, 2], best[:, 1] / best[:, 2]
            take = ratio_new > ratio_old if lowest else ratio_new < ratio_old
            best = np.where(take[:, None], P, best)
    return best


def head_points(n: np.ndarray, rays: np.ndarray, s: np.ndarray,
                radius_ratio: Ratio) -> np.ndarray:
    """Highest silhouette points (N, 3) (over d) of upright cylinders whose lowest image point is
    on ``rays`` (N, 3); NaN rows where a ray does not meet the ground (n . r <= 0).

    n: (3,) unit ground normal; s: (N,) agent height over camera height; radius_ratio: foot and
    head disk radius over the height, one number or a ``(foot, head)`` pair.
    """
    foot_ratio, head_ratio = split_ratio(radius_ratio)
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        F = rays / nr[:, None]
    F[~(nr > 1e-9)] = np.nan
    rho = foot_ratio * s
    A = F.copy()
    if foot_ratio > 0:
        for _ in range(3):                      # axis foot A such that the lowest rim point is F
            A = A + (F - extreme_rim(A, n, rho, lowest=True))
    return extreme_rim(A - s[:, None] * n, n, head_ratio * s, lowest=False)


def head_pixels(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray,
                radius_ratio: Ratio) -> tuple[np.ndarray, np.ndarray]:
    """Predicted top points (u (N,), v (N,)) in pixels; NaN where the foot ray misses the ground
    or the head lies behind the camera. See :func:`head_points`."""
    T = head_points(n, rays, s, radius_ratio)
    z = T[:, 2]
    bad = ~(z > 1e-9)
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = T[:, 0] / z, T[:, 1] / z
    u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
    v = K[1, 1] * y + K[1, 2]
    u[bad], v[bad] = np.nan, np.nan
    return u, v


def head_rows(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray,
              radius_ratio: Ratio) -> np.ndarray:
    """Predicted top rows (N,) of upright cylinders whose lowest image point is on ``rays`` (N,3).

    n: unit ground normal; s: (N,) agent height over camera height; radius_ratio as in
    :func:`head_points`. NaN where a foot ray does not meet the ground (n . r <= 0).
    """
    return head_pixels(K, n, rays, s, radius_ratio)[1]


@dataclass(frozen=True)
class AgentObservations:
    """Observations prepared for the fit: foot rays (N, 3), observed top rows and columns (N,)
    (``top_u`` NaN where unknown), pixel heights, foot pixels, track index ``idx`` (N,) into
    ``ids`` (J,) and ``cls`` (J,) (class per track, -1 unknown); ``feet`` (N,) how many feet the
    foot point averages (2: a walker's mask showed both apart, 0: unknown)."""

    rays: np.ndarray
    top_v: np.ndarray
    h: np.ndarray
    u: np.ndarray
    v: np.ndarray
    idx: np.ndarray
    ids: np.ndarray
    cls: np.ndarray
    top_u: np.ndarray | None = None
    feet: np.ndarray | None = None
    left: np.ndarray | None = None     # (N,) the silhouette's extreme columns (NaN: unknown)
    right: np.ndarray | None = None

    def __post_init__(self):
        if self.top_u is None:
            object.__setattr__(self, "top_u", np.full(len(self.top_v), np.nan))
        if self.feet is None:
            object.__setattr__(self, "feet", np.zeros(len(self.top_v), np.int64))
        for side in ("left", "right"):
            if getattr(self, side) is None:
                object.__setattr__(self, side, np.full(len(self.top_v), np.nan))

    @property
    def has_u(self) -> np.ndarray:
        """(N,) bool: the top column is known."""
        return np.isfinite(self.top_u)

    def _take(self, sel: np.ndarray, idx: np.ndarray, tracks: np.ndarray) -> "AgentObservations":
        return AgentObservations(self.rays[sel], self.top_v[sel], self.h[sel], self.u[sel],
                                 self.v[sel], idx, self.ids[tracks], self.cls[tracks],
                                 self.top_u[sel], self.feet[sel], self.left[sel],
                                 self.right[sel])

    def subset(self, tracks: np.ndarray) -> "AgentObservations":
        """Observations of the given track indices (duplicates become separate tracks)."""
        parts = [np.flatnonzero(self.idx == t) for t in tracks]
        sel = np.concatenate(parts)
        new_idx = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
        return self._take(sel, new_idx, np.asarray(tracks))

    def select(self, keep: np.ndarray) -> "AgentObservations":
        """The observations where ``keep`` (N,) is true; tracks left without any are dropped."""
        tracks, idx = np.unique(self.idx[keep], return_inverse=True)
        return self._take(keep, idx, tracks)


def head_residuals(K: np.ndarray, obs: AgentObservations, n: np.ndarray, s: np.ndarray,
                   radius_ratio: Ratio) -> tuple[np.ndarray, np.ndarray]:
    """Predicted minus observed top row and column (N,) each, in pixels, for per-track ``s``
    (J,). Row residuals are NaN where the prediction is impossible; column residuals are NaN there
    and where the top column is unknown."""
    u, v = head_pixels(K, n, obs.rays, s[obs.idx], radius_ratio)
    return v - obs.top_v, u - obs.top_u


def observation_residual(r_v: np.ndarray, r_u: np.ndarray) -> np.ndarray:
    """Per observation, the larger absolute residual of row and (known) column; impossible
    predictions count as ``_BIG``. Used for inlier tests."""
    r = np.abs(np.nan_to_num(r_v, nan=_BIG))
    return np.maximum(r, np.where(np.isfinite(r_u), np.abs(r_u), 0.0))


def median_track_scales(K, obs: AgentObservations, n: np.ndarray) -> np.ndarray:
    """Per-track start s_j (J,) of a thin, untilted agent, h = fy s (n . r): each track's median
    (0.3 where a track gives none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s_obs = obs.h / (K[1, 1] * (obs.rays @ n))
    ok = np.isfinite(s_obs) & (s_obs > 0)
    return track_medians(s_obs[ok], obs.idx[ok], len(obs.ids), 0.3)


def track_medians(x: np.ndarray, j: np.ndarray, J: int, empty: float) -> np.ndarray:
    """(J,) the median of ``x`` per track ``j`` (``empty`` for tracks without values), sorted
    once instead of one median call per track (the residuals call this at every evaluation)."""
    out = np.full(J, empty, np.float64)
    if not len(x):
        return out
    order = np.lexsort((x, j))
    xs, js = x[order], j[order]
    tracks, first, count = np.unique(js, return_index=True, return_counts=True)
    lo, hi = first + (count - 1) // 2, first + count // 2
    out[tracks] = 0.5 * (xs[lo] + xs[hi])
    return out


def gauss_newton_track_scales(residual, idx: np.ndarray, s: np.ndarray, iters: int,
                              huber_px: float) -> np.ndarray:
    """Per-track s_j refined by Gauss-Newton on ``residual(s)`` (per observation of track
    ``idx``; a forward-difference Jacobian per track), the later half of the iterations
    Huber-reweighted (``huber_px``) against bad detections."""
    J = len(s)
    for it in range(iters):
        r0 = residual(s)
        eps = 1e-4 * np.maximum(s, 1e-3)
        jac = (residual(s + eps) - r0) / eps[idx]
        ok = np.isfinite(r0) & np.isfinite(jac)
        wt = np.ones_like(r0)
        if it >= iters // 2:
            wt = np.minimum(1.0, huber_px / np.maximum(np.abs(np.nan_to_num(r0)), 1e-12))
        num = np.bincount(idx[ok], (wt * r0 * jac)[ok], minlength=J)
        den = np.bincount(idx[ok], (wt * jac * jac)[ok], minlength=J)
        s = np.clip(s - np.where(den > 0, num / np.maximum(den, 1e-300), 0.0), 1e-4, 100.0)
    return s


def solve_track_scales(K, obs: AgentObservations, n: np.ndarray, ratio: Ratio,
                       s0: np.ndarray | None = None, iters: int = 6,
                       huber_px: float = 3.0) -> np.ndarray:
    """Per-track s_j (J,) with the normal fixed: Gauss-Newton on each track's head-row residuals
    (:func:`gauss_newton_track_scales`), from ``s0`` or the thin, untilted start."""
    s = median_track_scales(K, obs, n) if s0 is None else s0.copy()
    return gauss_newton_track_scales(
        lambda sv: head_rows(K, n, obs.rays, sv[obs.idx], ratio) - obs.top_v,
        obs.idx, s, iters, huber_px)
