"""Planes ``n . P = d`` (|n| = 1) in the camera frame: fitting, distances, ground depth, horizon."""
from __future__ import annotations

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.projection import ray_grid, rays_from_pixels


def normalize_plane(n, d: float) -> tuple[np.ndarray, float]:
    """Scale (n, d) so that |n| = 1 and d >= 0 (n then points from the origin to the plane)."""
    n = np.asarray(n, dtype=np.float64)
    s = np.linalg.norm(n)
    if s < 1e-15:
        raise InputError("plane normal is zero")
    n, d = n / s, float(d) / s
    if d < 0:
        n, d = -n, -d
    return n, d


def fit_plane(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Total-least-squares plane through points (N, 3): SVD of the centred points.

    Returns (n, d) normalised by :func:`normalize_plane`. Raises when fewer than 3 finite points or
    when the points are collinear.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ok = np.all(np.isfinite(P), axis=1)
    w = None if weights is None else np.asarray(weights, dtype=np.float64).ravel()[ok]
    P = P[ok]
    if len(P) < 3:
        raise InputError(f"plane fit needs at least 3 finite points, got {len(P)}")
    if w is None:
        c = P.mean(axis=0)
        A = P - c
    else:
        c = (P * w[:, None]).sum(0) / w.sum()
        A = (P - c) * np.sqrt(w)[:, None]
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise InputError("plane fit: the points are collinear")
    n = vt[-1]
    return normalize_plane(n, float(n @ c))


def point_plane_distance(points: np.ndarray, n, d: float) -> np.ndarray:
    """Signed distance ``n . P - d`` of points (..., 3)."""
    return np.asarray(points) @ np.asarray(n, dtype=np.float64) - d


def plane_depth_at_pixels(K: np.ndarray, n, d: float, u, v) -> np.ndarray:
    """Depth Z = d / (n . r) of the plane along the rays of pixels (u, v); NaN where n . r <= 0."""
    r = rays_from_pixels(K, u, v)
    nr = r @ np.asarray(n, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(nr > 1e-12, d / nr, np.nan)
    return z


def plane_depth_map(K: np.ndarray, n, d: float, width: int, height: int) -> np.ndarray:
    """Depth of the plane at every pixel (float32, NaN above its horizon)."""
    nr = ray_grid(K, width, height) @ np.asarray(n, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(nr > 1e-12, d / nr, np.nan)
    return z.astype(np.float32)


def horizon_line(K: np.ndarray, n) -> np.ndarray:
    """The plane's horizon as a line (a, b, c), ``a u + b v + c = 0``, scaled so a^2 + b^2 = 1.

    Pixels with ``a u + b v + c > 0`` see the plane (n . r > 0).
    """
    line = np.linalg.inv(np.asarray(K, dtype=np.float64)).T @ np.asarray(n, dtype=np.float64)
    s = np.hypot(line[0], line[1])
    if s < 1e-15:
        raise InputError("the plane is parallel to the image: it has no horizon (nadir camera)")
    return line / s


def angle_between_deg(n1, n2) -> float:
    """Angle between two directions in degrees (sign-insensitive to vector length, not direction)."""
    a = np.asarray(n1, dtype=np.float64)
    b = np.asarray(n2, dtype=np.float64)
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
