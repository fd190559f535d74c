"""Metric scale from the camera height (METHOD.md section 5).

The anchor is the bottom row's centre pixel ``(u_a, v_a) = (W/2, H-1)``, assumed to see the ground.
Its depth on the plane ``n_g . P = H_c`` is ``D'_min = H_c / (n_g . K^-1 [u_a, v_a, 1])``; the scale
of a prediction is ``D'_min / Z_pred(anchor)``. Methods that assume a camera parallel to the ground
(McCraith et al.; Xue et al.) use ``f H_c / (v_a - c_y)`` instead, kept here for comparison.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import check_camera_height
from staticdepth.geometry.projection import rays_from_pixels


def anchor_pixel(width: int, height: int) -> tuple[float, float]:
    """The paper's anchor: bottom row, centre column ``(W/2, H-1)``."""
    return width / 2.0, float(height - 1)


def anchor_depth(K: np.ndarray, normal, camera_height_m: float, u: float, v: float) -> float:
    """Depth (m) of the ground seen at pixel (u, v): ``H_c / (n . K^-1 [u, v, 1])``.

    Raises when the pixel looks above the horizon (n . r <= 0) or the height is not one
    (:func:`~staticdepth.geometry.camera.check_camera_height`).
    """
    camera_height_m = check_camera_height(camera_height_m)
    nr = float(rays_from_pixels(K, u, v) @ np.asarray(normal, dtype=np.float64))
    if nr <= 1e-9:
        raise InputError(f"the anchor pixel ({u:g}, {v:g}) looks above the ground's horizon")
    return camera_height_m / nr


def anchor_depth_parallel(K: np.ndarray, camera_height_m: float, v: float) -> float:
    """The parallel-camera baseline ``f_y H_c / (v - c_y)``; raises for v <= c_y."""
    K = np.asarray(K, dtype=np.float64)
    camera_height_m = check_camera_height(camera_height_m)
    if v <= K[1, 2]:
        raise InputError(f"row {v:g} is not below the principal point (c_y = {K[1, 2]:g}): a "
                         "parallel camera sees no ground there")
    return float(K[1, 1] * camera_height_m / (v - K[1, 2]))


@dataclass(frozen=True)
class AnchorScale:
    """Scale of one predicted frame: ``scale`` = anchor_depth_m / pred_anchor (NaN when skipped)."""

    scale: float
    anchor_depth_m: float
    anchor_depth_parallel_m: float
    pred_anchor: float
    skipped: str | None = None


def scale_from_anchor(pred_depth: np.ndarray, K: np.ndarray, normal, camera_height_m: float, *,
                      patch_px: int = 5, agent_mask: np.ndarray | None = None) -> AnchorScale:
    """The metric scale of a relative depth map (H, W) from its anchor.

    The scale is the median of ``plane depth / prediction`` over a ``patch_px`` square around the
    anchor (clipped to the image; ``pred_anchor`` = anchor depth / scale); a frame whose patch touches ``agent_mask`` or holds no valid depth is skipped
    (``scale`` NaN, ``skipped`` says why) so that :func:`temporal_scale` can ignore it.
    """
    Z = np.asarray(pred_depth)
    h, w = Z.shape
    u_a, v_a = anchor_pixel(w, h)
    D = anchor_depth(K, normal, camera_height_m, u_a, v_a)
    try:
        Dp = anchor_depth_parallel(K, camera_height_m, v_a)
    except InputError:
        Dp = float("nan")
    r = max(patch_px // 2, 0)
    uc = min(int(round(u_a)), w - 1)
    sl = (slice(max(int(v_a) - r, 0), int(v_a) + 1), slice(max(uc - r, 0), min(uc + r + 1, w)))
    if agent_mask is not None and np.asarray(agent_mask, bool)[sl].any():
        return AnchorScale(float("nan"), D, Dp, float("nan"), "an agent covers the anchor")
    vs, us = np.mgrid[sl]
    nr = rays_from_pixels(K, us, vs) @ np.asarray(normal, dtype=np.float64)
    z_pred = Z[sl]
    ok = np.isfinite(z_pred) & (z_pred > 0) & (nr > 1e-9)
    if not ok.any():
        return AnchorScale(float("nan"), D, Dp, float("nan"), "no valid depth at the anchor")
    ratio = camera_height_m / nr[ok] / z_pred[ok]        # plane depth / prediction, per pixel
    scale = float(np.median(ratio))
    z = D / scale
    return AnchorScale(scale, D, Dp, z)


def temporal_scale(scales) -> float:
    """Median of the per-frame scales, ignoring skipped (NaN) frames; raises when all are."""
    s = np.asarray([x.scale if isinstance(x, AnchorScale) else x for x in scales], dtype=float)
    s = s[np.isfinite(s) & (s > 0)]
    if len(s) == 0:
        raise InputError("no frame gave a scale (the anchor was covered or invalid in all)")
    return float(np.median(s))



def plane_depth_rel_error(K: np.ndarray, normal, normal_std_deg: float, rays: np.ndarray,
                          row_px: float = 0.0) -> np.ndarray:
    """Each ray's relative std of the plane depth ``d / (n . r)`` read along it (``rays`` (..., 3),
    ``K^-1 [u, v, 1]``): a contact row off by ``row_px`` rows changes ``n . r`` by
    ``(n . K^-1 e_v) row_px``, a normal tilted by ``normal_std_deg`` (its RMS angle, taken whole
    in the worst direction; NaN counts as 0) by up to ``sigma |r - (n . r) n|`` (a small rotation
    of n moves n . r by at most sigma |n x r|); both relative to ``n . r``, in quadrature. Near
    the horizon ``n . r`` goes to 0 (a grazing ray), so a one-row or sub-degree error moves the
    depth most there. NaN at and above the horizon (no depth)."""
    K = np.asarray(K, np.float64)
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    r = np.asarray(rays, np.float64)
    q = r @ n
    dq_row = abs(float(n @ np.linalg.solve(K, [0.0, 1.0, 0.0]))) * row_px
    sigma = np.radians(normal_std_deg) if np.isfinite(normal_std_deg) else 0.0
    dq_tilt = sigma * np.linalg.norm(r - q[..., None] * n, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.hypot(dq_row, dq_tilt) / q
    return np.where(q > 0, rel, np.nan)


def plane_depth_rel_std(K: np.ndarray, normal, normal_std_deg: float, u, v) -> float:
    """Median over the pixels (u, v) of the plane depth's relative error when the normal is off
    by ``normal_std_deg`` in the worst direction (:func:`plane_depth_rel_error`, no row error).
    Grazing rays (far ground) make it large; NaN std gives NaN; pixels above the horizon are
    ignored (inf when every one is)."""
    if not np.isfinite(normal_std_deg):
        return float("nan")
    rel = plane_depth_rel_error(K, normal, normal_std_deg,
                                rays_from_pixels(K, np.asarray(u, np.float64),
                                                 np.asarray(v, np.float64)))
    rel = rel[np.isfinite(rel)]
    return float(np.median(rel)) if len(rel) else float("inf")


def metric_check(K: np.ndarray, normal, normal_std_deg: float, feet: np.ndarray,
                 camera_height_m: float, camera_height_std_m: float | None,
                 max_rel_std: float, unmeasured: bool = False) -> tuple[bool, str | None]:
    """(refuse, message): whether a metric depth from this plane must not be written, and why;
    (False, None) when it can be trusted.

    The metric depth's relative error is taken as the plane depth's over the agents' feet
    (:func:`plane_depth_rel_std`, the ground the alignment is fitted on) combined with the camera
    height's relative std (None or NaN: a given height, 0); above ``max_rel_std`` it is refused.
    A plane without an uncertainty (fewer than 3 inlier tracks: no bootstrap) is not refused but
    flagged (False, "metric depth unverified: ..."); ``unmeasured``: the fit was asked for no
    uncertainty (``plane.bootstrap`` 0), which the message says instead of too few tracks."""
    feet = np.asarray(feet, dtype=np.float64).reshape(-1, 2)
    if unmeasured and not np.isfinite(normal_std_deg):
        return False, ("metric depth unverified: the ground plane's uncertainty was not "
                       "measured (plane.bootstrap=0)")
    if len(feet) == 0 or not np.isfinite(normal_std_deg):
        return False, ("metric depth unverified: the ground plane has no uncertainty (fewer than "
                       "3 inlier agent tracks); more adaptation frames or agents are needed")
    rel_n = plane_depth_rel_std(K, normal, normal_std_deg, feet[:, 0], feet[:, 1])
    sd = camera_height_std_m
    rel_h = sd / camera_height_m if sd is not None and np.isfinite(sd) else 0.0
    rel = float(np.hypot(rel_n, rel_h))
    if rel <= max_rel_std:
        return False, None
    return True, (f"metric depth refused: its relative error would be about {100 * rel:.0f}% "
                  f"(plane normal +-{normal_std_deg:.2f} deg -> {100 * rel_n:.0f}% over the "
                  f"agents' feet, camera height {100 * rel_h:.0f}%) > {100 * max_rel_std:.0f}%; "
                  f"about {(rel / max_rel_std) ** 2:.1f}x the adaptation frames would bring it "
                  "under (or give --set scale.max_rel_error)")
