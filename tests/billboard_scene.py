"""Closed-form scenes for the upright alignment tests: a low camera over a ground plane and
vertical billboards (walls, agents) facing it, each pixel's depth in closed form.

Camera frame (OpenCV: x right, y down, z forward), pitched down by ``pitch_deg`` over a plane
``cam_height`` below; a billboard stands ``dist`` metres ahead (horizontally), ``half_w`` either side
of the optical axis, ``height`` tall from the ground."""
from __future__ import annotations

import math

import numpy as np


def billboard_camera(cam_height: float, pitch_deg: float, width: int, height: int, f: float):
    """(K, n, z_ground, billboard): the intrinsics, the plane's normal (down, camera frame), the
    ground's depth per pixel (inf above the horizon) and ``billboard(dist, half_w, height) ->
    (depth, mask)``, the mask where the billboard is seen in front of the ground."""
    K = np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1.0]])
    t = math.radians(pitch_deg)
    n = np.array([0.0, math.cos(t), math.sin(t)])           # down, camera frame
    fwd = np.array([0.0, -math.sin(t), math.cos(t)])        # horizontal forward
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    r = np.stack([(u - K[0, 2]) / f, (v - K[1, 2]) / f, np.ones_like(u)], -1)
    with np.errstate(divide="ignore"):
        z_ground = np.where(r @ n > 1e-9, cam_height / (r @ n), np.inf)

    def billboard(dist, half_w, tall):
        with np.errstate(divide="ignore"):
            z = np.where(r @ fwd > 1e-9, dist / (r @ fwd), np.inf)
        up = cam_height - (r * z[..., None]) @ n
        return z, (up >= 0) & (up < tall) & (np.abs(r[..., 0] * z) < half_w) & (z < z_ground)

    return K, n, z_ground, billboard
