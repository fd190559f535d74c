"""A second built-in architecture: a small U-Net, so that gains are not tuned to one network.

``TinyUNet`` differs from :class:`~staticdepth.models.tiny.TinyDepthNet` in every part that shapes
its errors: four levels of two 3x3 convolutions with BatchNorm-free ELU blocks (instance
statistics are never frozen or shared), max-pooling instead of strided convolutions, bilinear
upsampling with *concatenated* skips instead of summed 1x1 laterals, and an exponential head
(inverse depth = exp of a bounded log) instead of softplus. About 0.7 M parameters at the default
widths. Trained by ``staticdepth train-builtin --arch unet`` and loaded as ``builtin:PATH.pt``.
"""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from staticdepth.errors import InputError

UNET_CONFIG = {"arch": "unet", "widths": (12, 24, 48, 96)}
UNET_LAYER_GROUPS = {"head": ["head"], "decoder": ["up", "head"]}


def _double(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, 1, 1), nn.ELU(inplace=True),
                         nn.Conv2d(cout, cout, 3, 1, 1), nn.ELU(inplace=True))


class TinyUNet(nn.Module):
    """(B, 3, h, w) normalised RGB, h and w multiples of 16 -> (B, h, w) inverse depth (> 0)."""

    def __init__(self, widths: Sequence[int] = UNET_CONFIG["widths"]):
        super().__init__()
        w = list(widths)
        if len(w) != 4 or min(w) < 1:
            raise InputError(f"TinyUNet needs 4 positive widths, got {w}")
        self.down = nn.ModuleList([_double(3, w[0])] + [_double(w[k - 1], w[k]) for k in range(1, 4)])
        self.bottom = _double(w[3], w[3])
        self.up = nn.ModuleList(_double(w[k] + (w[k + 1] if k < 3 else w[3]), w[k])
                                for k in range(3, -1, -1))
        self.head = nn.Conv2d(w[0], 1, 3, 1, 1)
        self.config = {"arch": "unet", "widths": tuple(w)}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for k, block in enumerate(self.down):
            x = block(x if k == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        y = self.bottom(F.max_pool2d(x, 2))
        for block, skip in zip(self.up, reversed(skips)):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = block(torch.cat([y, skip], 1))
        return torch.exp(torch.clamp(self.head(y), -8.0, 4.0))[:, 0]
