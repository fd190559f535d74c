"""Back-projection, projection and disparity <-> depth (pure numpy).

Depth is in metres, float32 where it is a map, NaN = unknown. Rays have ``r_z = 1``, so a pixel at
depth Z is the point ``Z * r``.
"""
from __future__ import annotations

import numpy as np


def pixel_grid(width: int, height: int, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) coordinate maps of shape (height, width)."""
    u = np.arange(width, dtype=dtype)
    v = np.arange(height, dtype=dtype)
    return np.meshgrid(u, v)


def rays_from_pixels(K: np.ndarray, u, v) -> np.ndarray:
    """Rays ``K^-1 [u, v, 1]`` for pixel arrays ``u``, ``v``; shape ``u.shape + (3,)``, r_z = 1."""
    K = np.asarray(K, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = (v - cy) / fy
    x = (u - cx - s * y) / fx
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def ray_grid(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Rays of every pixel, shape (height, width, 3)."""
    u, v = pixel_grid(width, height)
    return rays_from_pixels(K, u, v)


def points_from_depth(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Back-project a depth map (H, W) to camera-frame points (H, W, 3); NaN depth gives NaN points."""
    depth = np.asarray(depth)
    h, w = depth.shape
    return ray_grid(K, w, h) * depth[..., None]


def project_points(points: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (..., 3) to pixels (..., 2); also returns their depth (...,)."""
    P = np.asarray(points, dtype=np.float64)
    z = P[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = P @ np.asarray(K, dtype=np.float64).T
        uv = uvw[..., :2] / uvw[..., 2:3]
    return uv, z


def transform_points(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``R p + t`` for points (..., 3)."""
    return np.asarray(points) @ np.asarray(R).T + np.asarray(t)


def depth_from_disparity(disparity: np.ndarray, focal_px: float, baseline_m: float,
                         max_depth_m: float | None = None) -> np.ndarray:
    """Depth = f B / d; NaN where the disparity is NaN, non-positive, or the depth exceeds the cap."""
    d = np.asarray(disparity, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.float32(focal_px * baseline_m) / d
    bad = ~(d > 0)
    if max_depth_m is not None:
        bad |= z > max_depth_m
    z[bad] = np.nan
    return z.astype(np.float32, copy=False)


def disparity_from_depth(depth: np.ndarray, focal_px: float, baseline_m: float) -> np.ndarray:
    """Disparity = f B / Z; NaN where the depth is NaN or non-positive."""
    z = np.asarray(depth, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.float32(focal_px * baseline_m) / z
    d[~(z > 0)] = np.nan
    return d.astype(np.float32, copy=False)
