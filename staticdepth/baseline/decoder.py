"""MonoDepth2's depth decoder: ELU conv blocks, nearest upsampling, skip connections, sigmoid
disparity heads at 4 scales."""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from staticdepth.errors import InputError

DEFAULT_CHANNELS = (16, 32, 64, 128, 256)


class ConvBlock(nn.Sequential):
    """3x3 convolution (reflection padding) followed by ELU."""

    def __init__(self, cin: int, cout: int):
        super().__init__(nn.ReflectionPad2d(1), nn.Conv2d(cin, cout, 3), nn.ELU(inplace=True))


class DispHead(nn.Sequential):
    """3x3 convolution (reflection padding) to one channel, then sigmoid."""

    def __init__(self, cin: int):
        super().__init__(nn.ReflectionPad2d(1), nn.Conv2d(cin, 1, 3), nn.Sigmoid())


class DepthDecoder(nn.Module):
    """Decoder over the encoder's 5 feature maps (strides 2..32).

    Level i (4 down to 0): ``upconv_i_0``, nearest x2 upsampling, concatenation with encoder
    feature ``i-1`` (for i > 0), ``upconv_i_1``; levels 0..num_scales-1 carry a disparity head.
    """

    def __init__(self, num_ch_enc: Sequence[int], channels: Sequence[int] = DEFAULT_CHANNELS,
                 num_scales: int = 4):
        super().__init__()
        if len(channels) != 5 or min(channels) < 1:
            raise InputError(f"decoder needs 5 positive channel counts, got {tuple(channels)}")
        if not 1 <= num_scales <= 4:
            raise InputError(f"num_scales must be 1..4, got {num_scales}")
        self.num_scales = num_scales
        self.up0 = nn.ModuleList()
        self.up1 = nn.ModuleList()
        for i in range(4, -1, -1):
            cin = num_ch_enc[-1] if i == 4 else channels[i + 1]
            self.up0.append(ConvBlock(cin, channels[i]))
            skip = num_ch_enc[i - 1] if i > 0 else 0
            self.up1.append(ConvBlock(channels[i] + skip, channels[i]))
        self.heads = nn.ModuleList(DispHead(channels[s]) for s in range(num_scales))

    def forward(self, features: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """Features -> sigmoid disparities ``[scale 0 (H, W), scale 1 (H/2, W/2), ...]``,
        each (B, 1, H / 2^s, W / 2^s) in (0, 1)."""
        x = features[-1]
        out: list[torch.Tensor | None] = [None] * self.num_scales
        for k, i in enumerate(range(4, -1, -1)):
            x = F.interpolate(self.up0[k](x), scale_factor=2, mode="nearest")
            if i > 0:
                x = torch.cat([x, features[i - 1]], dim=1)
            x = self.up1[k](x)
            if i < self.num_scales:
                out[i] = self.heads[i](x)
        return out  # type: ignore[return-value]
