"""Fit the stereo baseline's settings to the scene, and refuse a collapsed model.

MonoDepth2's KITTI setting (640x192, depth 0.1-100 m) starts every pixel at the sigmoid's middle,
1/depth = 0.5 / min_depth: 0.2 m, a disparity of f B / 0.2 m. For a 27 cm rig at 90 deg that is
about half the image width, so the warp samples outside the image, the photometric loss has no
gradient toward the true (few-pixel) disparities and training collapses to a constant depth
(a1 = 0). Here the depth range comes from the rig and the scene: ``min_depth`` is half the depth
of the nearest ground (the bottom row's ground depth, from the mounting) but never below the
depth whose disparity is a quarter of the network's width, so the start (about twice
``min_depth``) lies near the scene's own depths; the network size follows the sequence's aspect,
at most the preset's width.
"""
from __future__ import annotations

import numpy as np

from staticdepth.baseline.config import BaselineConfig
from staticdepth.errors import InputError

MAX_DISPARITY_FRACTION = 0.25   # of the network width, at min_depth
COLLAPSED_FRACTION = 0.9        # of the pixels at a depth limit: collapsed


def network_size(width: int, height: int, max_width: int = 640) -> tuple[int, int]:
    """The sequence's aspect at most ``max_width`` wide, sides multiples of 32 (>= 64)."""
    w = max(64, min(max_width, width) // 32 * 32)
    h = max(64, int(round(w * height / width / 32.0)) * 32)
    return w, h


def scene_depth_range(fx: float, width: int, height: int, baseline_m: float, net_width: int,
                      K=None, normal=None, camera_height_m: float | None = None
                      ) -> tuple[float, float]:
    """(min_depth, max_depth) in metres for a rig of ``baseline_m`` seen at ``net_width``."""
    f_net = fx * net_width / width
    floor = f_net * baseline_m / (MAX_DISPARITY_FRACTION * net_width)
    near = None
    if K is not None and normal is not None and camera_height_m:
        r = np.linalg.solve(np.asarray(K, float), [width / 2.0, height - 1.0, 1.0])
        nr = float(np.dot(np.asarray(normal, float), r))
        if nr > 0:
            near = camera_height_m / nr
    min_depth = max(floor, 0.5 * near) if near else floor
    max_depth = max(100.0, 20 * min_depth)
    return float(min_depth), float(max_depth)


def fit_to_scene(reader, conf: BaselineConfig, explicit=(), fit_size: bool = True
                 ) -> BaselineConfig:
    """``conf`` with the depth range (and, with ``fit_size``, the network size) fitted to the
    sequence of ``reader``; settings named in ``explicit`` are kept as given."""
    import dataclasses

    rig = reader.meta.rig
    if rig is None:
        raise InputError("sequence has no stereo rig (baseline unknown)", reader.path)
    cam = reader.camera
    changes = {}
    if fit_size and not {"width", "height"} & set(explicit):
        changes["width"], changes["height"] = network_size(cam.width, cam.height, conf.width)
    net_w = changes.get("width", conf.width)
    mnt = reader.meta.mounting
    lo, hi = scene_depth_range(cam.fx, cam.width, cam.height, rig.baseline_m, net_w, cam.K,
                               None if mnt is None else mnt.normal,
                               None if mnt is None else mnt.height_m)
    if "min_depth" not in explicit:
        changes["min_depth"] = lo
    if "max_depth" not in explicit:
        changes["max_depth"] = max(hi, changes.get("min_depth", conf.min_depth) * 2)
    return dataclasses.replace(conf, **changes)


def check_not_collapsed(depth: np.ndarray, conf: BaselineConfig, where: str = "") -> dict:
    """Raise InputError when predicted depths (N, H, W) sit at a depth limit or are constant.

    Returns the statistics (fractions at the limits, relative spread) when the model is sound.
    """
    d = np.asarray(depth, dtype=np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise InputError(f"the stereo baseline predicts no finite depth{where}")
    at_min = float(np.mean(d <= conf.min_depth * 1.05))
    at_max = float(np.mean(d >= conf.max_depth * 0.95))
    med = float(np.median(d))
    spread = float(np.median(np.abs(d - med)) / med)
    stats = {"at_min_depth": at_min, "at_max_depth": at_max, "relative_spread": spread}
    if max(at_min, at_max) > COLLAPSED_FRACTION or spread < 1e-3:
        lim = (f"{at_min:.0%} of the pixels at min_depth {conf.min_depth:g} m" if at_min >= at_max
               else f"{at_max:.0%} at max_depth {conf.max_depth:g} m")
        raise InputError(f"the stereo baseline collapsed ({lim}, spread {spread:.1e}): not a "
                         f"result; retrain with --scene-fit all (a depth range from the "
                         f"rig and the scene) or --set min_depth=...{where}")
    return stats
