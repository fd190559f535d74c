"""Agents' positions in metres from their ground contact pixel, the ground plane and the camera height.

Camera frame: OpenCV (X right, Y down, Z forward), ground plane ``n . P = d`` with ``|n| = 1``,
``n`` pointing from the camera to the ground and ``d`` the camera height (METHOD.md).

- The contact pixel ``(u, v)`` (bottom of the silhouette) seen on the ground is
  ``G = d r / (n . r)`` with ``r = K^-1 [u, v, 1]``. For an upright body of radius ``rho`` that
  pixel is the near edge of its feet; its axis stands ``rho`` further along the horizontal viewing
  direction: :func:`contact_points` moves ``G`` by ``rho`` along ``G``'s horizontal direction from
  the camera's foot point.
- The ground frame: origin ``O = d n`` (on the ground, under the camera), ``y`` = the optical axis
  projected onto the ground (forward), ``x = y x (-n)`` (right), so ``(x, y, up)`` is right-handed.
- A rider (:func:`rider_point`): the azimuth of its own silhouette, the ground distance of its
  vehicle's visible near edge.
- Speeds: a straight line fitted to each track's ground positions over a centred time window.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import check_camera_height
from staticdepth.geometry.projection import rays_from_pixels


def _plane(n, d: float) -> tuple[np.ndarray, float]:
    n = np.asarray(n, dtype=np.float64).reshape(3)
    s = np.linalg.norm(n)
    if not (np.all(np.isfinite(n)) and s > 1e-12):
        raise InputError(f"the ground normal must be a finite non-zero 3-vector, got {n}")
    return n / s, check_camera_height(d, "the camera height")


@dataclass(frozen=True)
class GroundFrame:
    """Origin under the camera and the right / forward axes on the ground (camera frame)."""

    origin: np.ndarray
    x_axis: np.ndarray
    y_axis: np.ndarray
    normal: np.ndarray
    camera_height_m: float

    @classmethod
    def from_plane(cls, n, d: float) -> "GroundFrame":
        n, d = _plane(n, d)
        fwd = np.array([0.0, 0.0, 1.0]) - n[2] * n
        if np.linalg.norm(fwd) < 1e-6:            # nadir camera: image "up" is forward
            fwd = np.array([0.0, -1.0, 0.0]) - (-n[1]) * n
        y = fwd / np.linalg.norm(fwd)
        x = np.cross(y, -n)
        return cls(d * n, x / np.linalg.norm(x), y, n, d)

    def to_ground(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) camera-frame points -> (..., 2) ground (x right, y forward) in metres."""
        P = np.asarray(points, dtype=np.float64) - self.origin
        return np.stack([P @ self.x_axis, P @ self.y_axis], axis=-1)

    def to_camera(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) ground coordinates -> (..., 3) camera-frame points on the plane."""
        xy = np.asarray(xy, dtype=np.float64)
        return self.origin + xy[..., :1] * self.x_axis + xy[..., 1:2] * self.y_axis


def ground_points(K: np.ndarray, n, d: float, u, v) -> np.ndarray:
    """(N, 3) points where the pixels' rays meet the ground; NaN above the horizon."""
    n, d = _plane(n, d)
    r = rays_from_pixels(np.asarray(K, dtype=np.float64), np.atleast_1d(u), np.atleast_1d(v))
    nr = r @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        P = d * r / nr[:, None]
    P[nr <= 1e-9] = np.nan
    return P


def contact_points(K: np.ndarray, n, d: float, u, v, radius_m=0.0) -> np.ndarray:
    """(N, 3) contact points (body axis on the ground) of bodies whose silhouettes' lowest pixels
    are (u, v): the ground point of the pixel moved by ``radius_m`` (scalar or (N,)) away from the
    camera, horizontally. NaN where the pixel looks above the horizon."""
    n, d = _plane(n, d)
    G = ground_points(K, n, d, u, v)
    horiz = G - d * n                           # from the camera's foot point, on the ground
    dist = np.linalg.norm(horiz, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(dist > 1e-9, horiz / dist, 0.0)
    return G + np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (len(G),))[:, None] * step


def rider_point(inst: np.ndarray, rider_id: int, vehicle_id: int, K: np.ndarray,
                gframe: GroundFrame, radius_m: float) -> np.ndarray:
    """A rider's axis on the ground (camera frame) from the (H, W) instance map ``inst``: in the
    direction of its own silhouette, as far as the middle of its vehicle's near edge plus
    ``radius_m``.

    The vehicle's contact (its silhouette's lowest pixel) is the footprint's nearest point, up to
    half the vehicle's length from where the rider sits, sideways and in depth. Direction: every
    point of a vertical axis has the same azimuth about the camera's foot point, and a body is
    symmetric about its axis, so the median azimuth of the rider's pixels is the axis's. Distance:
    the vehicle's lowest pixel in each of its columns meets the ground along the footprint's near
    edges (columns where another instance lies just below are left out: hidden there); their
    median ground distance is the middle of that edge (the vehicle's middle, but for one seen
    end-on), plus the step from a near surface to the axis used for people."""
    vs, us = np.nonzero(inst == rider_id)
    step = -(-len(vs) // 4000)
    vs, us = vs[::step], us[::step]
    rays = np.linalg.solve(np.asarray(K, dtype=np.float64),
                           np.stack([us + 0.0, vs + 0.0, np.ones(len(vs))]))
    az = float(np.median(np.arctan2(gframe.x_axis @ rays, gframe.y_axis @ rays)))
    vehicle = inst == vehicle_id
    cols = np.flatnonzero(vehicle.any(axis=0))
    low = vehicle.shape[0] - 1 - np.argmax(vehicle[::-1, cols], axis=0)
    below = np.minimum(low + 1, vehicle.shape[0] - 1)
    free = (low + 1 < vehicle.shape[0]) & (inst[below, cols] == 0)
    if free.any():
        cols, low = cols[free], low[free]
    G = ground_points(K, gframe.normal, gframe.camera_height_m, cols + 0.0, low + 0.5)
    rng = float(np.nanmedian(np.linalg.norm(gframe.to_ground(G), axis=1))) + radius_m
    return gframe.to_camera(np.array([rng * np.sin(az), rng * np.cos(az)]))


def drop_to_ground(points: np.ndarray, n, d: float) -> np.ndarray:
    """Project (N, 3) points onto the plane along its normal."""
    n, d = _plane(n, d)
    P = np.asarray(points, dtype=np.float64)
    return P + (d - P @ n)[..., None] * n


def track_speeds(t: np.ndarray, xy: np.ndarray, window_s: float = 1.0,
                 min_points: int = 3) -> np.ndarray:
    """Speed (m/s) at each sample of one track: the slope of a least-squares line through the
    ground positions (N, 2) within ``window_s`` centred on the sample (times ``t`` in seconds,
    increasing). NaN where fewer than ``min_points`` samples or less than a quarter of the
    window's span are available."""
    t = np.asarray(t, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    out = np.full(len(t), np.nan)
    ok = np.all(np.isfinite(xy), axis=1) & np.isfinite(t)
    half = window_s / 2.0
    for i in range(len(t)):
        if not ok[i]:
            continue
        sel = ok & (np.abs(t - t[i]) <= half + 1e-9)
        ts = t[sel]
        if len(ts) < min_points or ts.max() - ts.min() < 0.25 * window_s:
            continue
        tc = ts - ts.mean()
        vel = (tc @ (xy[sel] - xy[sel].mean(0))) / (tc @ tc)
        out[i] = float(np.hypot(*vel))
    return out


def pairwise_distances(points: np.ndarray) -> np.ndarray:
    """(N, N) Euclidean distances between (N, k) points."""
    P = np.asarray(points, dtype=np.float64)
    return np.linalg.norm(P[:, None, :] - P[None, :, :], axis=-1)
