"""MonoDepth2's stereo training loss (pure torch).

Per scale s (disparity upsampled to the input resolution, MonoDepth2's default):
    reproj   = pe(warp(source, f B / depth_s), target)
    identity = pe(source, target) + N(0, 1e-5)          (auto-masking)
    photo_s  = mean(min(identity, reproj))
    smooth_s = edge-aware smoothness of disp_s / mean(disp_s) against the target at scale s
    loss_s   = photo_s + smoothness_weight * smooth_s / 2^s
and the loss is the mean over scales; pe = a (1 - SSIM)/2 + (1 - a) L1 (a = 0.85, 3x3 SSIM).
"""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F

from staticdepth.baseline.config import BaselineConfig
from staticdepth.baseline.layers import (disp_to_depth, disparity_px_from_depth,
                                         photometric_error, smoothness_loss, warp_horizontal)


def stereo_loss(disps: Sequence[torch.Tensor], target: torch.Tensor, source: torch.Tensor,
                focal_px: torch.Tensor | float, baseline_m: torch.Tensor | float,
                direction: torch.Tensor | float, conf: BaselineConfig
                ) -> dict[str, torch.Tensor]:
    """Stereo self-supervision for one batch.

    Args:
        disps: per scale s, (B, 1, H / 2^s, W / 2^s) sigmoid disparities of the target view.
        target, source: (B, 3, H, W) target and other view in [0, 1] (not colour-jittered).
        focal_px: focal length in pixels at this H x W; baseline_m: rectified baseline, metres
            (scalars or (B,)).
        direction: +1 where the source camera is to the right of the target, -1 where it is to
            the left (scalar or (B,)); see :func:`~staticdepth.baseline.layers.warp_horizontal`.
    Returns:
        dict with ``loss`` (scalar to minimise), ``photometric`` and ``smoothness`` (detached,
        summed over scales and divided by their count).
    """
    h, w = target.shape[-2:]
    identity = None
    if conf.automask:
        identity = photometric_error(source, target, conf.ssim_weight)
        identity = identity + torch.randn_like(identity) * 1e-5
    total = target.new_zeros(())
    photo_sum = target.new_zeros(())
    smooth_sum = target.new_zeros(())
    for s, disp in enumerate(disps):
        disp_full = F.interpolate(disp, (h, w), mode="bilinear", align_corners=False)
        depth = disp_to_depth(disp_full, conf.min_depth, conf.max_depth)[1]
        warped = warp_horizontal(source, disparity_px_from_depth(depth, focal_px, baseline_m),
                                 direction)
        reproj = photometric_error(warped, target, conf.ssim_weight)
        per_pixel = reproj if identity is None else torch.minimum(reproj, identity)
        photo = per_pixel.mean()
        color = target if disp.shape[-2:] == (h, w) else F.interpolate(
            target, disp.shape[-2:], mode="area")
        norm_disp = disp / (disp.mean((2, 3), keepdim=True) + 1e-7)
        smooth = smoothness_loss(norm_disp, color)
        total = total + photo + conf.smoothness_weight * smooth / (2 ** s)
        photo_sum = photo_sum + photo.detach()
        smooth_sum = smooth_sum + smooth.detach()
    n = len(disps)
    return {"loss": total / n, "photometric": photo_sum / n, "smoothness": smooth_sum / n}
