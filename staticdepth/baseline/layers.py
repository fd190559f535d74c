"""MonoDepth2's building blocks as pure torch functions (no devices, globals or state).

Images are (B, 3, H, W) floats in [0, 1]; disparity / depth maps (B, 1, H, W). Numerical
references: ``disp_to_depth`` and ``SSIM`` follow MonoDepth2's ``layers.py`` exactly.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def disp_to_depth(disp: torch.Tensor, min_depth: float, max_depth: float
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Sigmoid output -> (scaled inverse depth, depth) in metres.

    ``scaled = 1/max + (1/min - 1/max) disp``, ``depth = 1 / scaled`` (MonoDepth2).
    """
    min_disp = 1.0 / max_depth
    max_disp = 1.0 / min_depth
    scaled = min_disp + (max_disp - min_disp) * disp
    return scaled, 1.0 / scaled


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel, per-channel SSIM over 3x3 windows (reflection padded); same shape as ``x``."""
    x = F.pad(x, (1, 1, 1, 1), mode="reflect")
    y = F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x = F.avg_pool2d(x, 3, 1)
    mu_y = F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x ** 2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y ** 2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    n = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    d = (mu_x ** 2 + mu_y ** 2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return n / d


def ssim_dissimilarity(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``clamp((1 - SSIM) / 2, 0, 1)``, MonoDepth2's ``SSIM`` module output."""
    return torch.clamp((1.0 - ssim(x, y)) / 2.0, 0.0, 1.0)


def photometric_error(pred: torch.Tensor, target: torch.Tensor, ssim_weight: float = 0.85
                      ) -> torch.Tensor:
    """``a (1 - SSIM)/2 + (1 - a) L1`` averaged over channels: (B, 3, H, W) -> (B, 1, H, W)."""
    l1 = (pred - target).abs().mean(1, keepdim=True)
    if ssim_weight == 0:
        return l1
    s = ssim_dissimilarity(pred, target).mean(1, keepdim=True)
    return ssim_weight * s + (1.0 - ssim_weight) * l1


def disparity_px_from_depth(depth: torch.Tensor, focal_px: torch.Tensor | float,
                            baseline_m: torch.Tensor | float) -> torch.Tensor:
    """Rectified stereo disparity ``f B / Z`` in pixels (B, 1, H, W); ``focal_px`` and
    ``baseline_m`` scalars or (B,)."""
    fb = torch.as_tensor(focal_px, dtype=depth.dtype, device=depth.device) * \
        torch.as_tensor(baseline_m, dtype=depth.dtype, device=depth.device)
    return fb.reshape(-1, 1, 1, 1) / depth


def warp_horizontal(source: torch.Tensor, disparity_px: torch.Tensor,
                    direction: torch.Tensor | float) -> torch.Tensor:
    """Sample ``source`` at ``(u - direction * disparity, v)`` for every target pixel (u, v).

    For a rectified pair whose source camera sits to the right of the target camera (target =
    left view, source = right view), a target pixel at disparity d is seen at ``u - d`` in the
    source: ``direction = +1``. Target = right, source = left: ``direction = -1``.

    Args:
        source: (B, C, H, W) image of the other view.
        disparity_px: (B, 1, H, W) target-view disparity in pixels of this resolution.
        direction: +1 or -1, scalar or (B,).
    Returns:
        (B, C, H, W) the source resampled into the target view (bilinear, border padding).
    """
    b, _, h, w = source.shape
    d = torch.as_tensor(direction, dtype=source.dtype, device=source.device).reshape(-1, 1, 1)
    u = torch.arange(w, dtype=source.dtype, device=source.device).reshape(1, 1, w)
    v = torch.arange(h, dtype=source.dtype, device=source.device).reshape(1, h, 1)
    u_src = u - d * disparity_px[:, 0]
    grid = torch.stack([2.0 * u_src / (w - 1) - 1.0,
                        (2.0 * v / (h - 1) - 1.0).expand(b, h, w)], dim=-1)
    return F.grid_sample(source, grid, mode="bilinear", padding_mode="border",
                         align_corners=True)


def smoothness_loss(disp: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Edge-aware first-order smoothness (MonoDepth2 ``get_smooth_loss``); scalar.

    ``disp`` (B, 1, H, W) should already be mean-normalised; ``image`` (B, 3, H, W) the target
    view at the same resolution.
    """
    gdx = (disp[:, :, :, :-1] - disp[:, :, :, 1:]).abs()
    gdy = (disp[:, :, :-1, :] - disp[:, :, 1:, :]).abs()
    gix = (image[:, :, :, :-1] - image[:, :, :, 1:]).abs().mean(1, keepdim=True)
    giy = (image[:, :, :-1, :] - image[:, :, 1:, :]).abs().mean(1, keepdim=True)
    return (gdx * torch.exp(-gix)).mean() + (gdy * torch.exp(-giy)).mean()
