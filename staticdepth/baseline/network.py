"""The baseline's monocular network: ResNet18 encoder + MonoDepth2 decoder."""
from __future__ import annotations

import torch
from torch import nn

from staticdepth.baseline.config import BaselineConfig
from staticdepth.baseline.decoder import DepthDecoder
from staticdepth.baseline.layers import disp_to_depth
from staticdepth.baseline.resnet import ResnetEncoder, load_imagenet_weights


class DepthNet(nn.Module):
    """Image -> sigmoid disparities at ``num_scales`` scales (MonoDepth2's ``disp`` outputs)."""

    def __init__(self, encoder_width: int = 64,
                 decoder_channels: tuple[int, ...] = (16, 32, 64, 128, 256), num_scales: int = 4):
        super().__init__()
        self.encoder = ResnetEncoder(encoder_width)
        self.decoder = DepthDecoder(self.encoder.num_ch_enc, decoder_channels, num_scales)

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) RGB in [0, 1], H and W multiples of 32 -> list over scales s of
        (B, 1, H / 2^s, W / 2^s) sigmoid disparities."""
        return self.decoder(self.encoder(image))


def build_model(conf: BaselineConfig, *, load_weights: bool = True) -> DepthNet:
    """A new network for ``conf``; ImageNet encoder weights from ``conf.imagenet_weights``
    when set and ``load_weights``."""
    net = DepthNet(conf.encoder_width, conf.decoder_channels, conf.num_scales)
    if load_weights and conf.imagenet_weights:
        load_imagenet_weights(net.encoder, conf.imagenet_weights)
    return net


def metric_depth(disp: torch.Tensor, conf: BaselineConfig) -> torch.Tensor:
    """Sigmoid disparity -> depth in metres (trained with the true baseline: no rescaling)."""
    return disp_to_depth(disp, conf.min_depth, conf.max_depth)[1]
