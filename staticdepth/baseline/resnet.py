"""ResNet18 encoder in plain torch (torchvision's layout and parameter names).

Construction and weight loading are separate: :class:`ResnetEncoder` builds a randomly initialised
network; :func:`load_imagenet_weights` fills it from a local torchvision-style state dict (``.pth``
with the standard keys ``conv1.weight``, ``bn1.*``, ``layer1.0.conv1.weight``, ...,
``layer2.0.downsample.0.weight``; ``fc.*`` is ignored). Nothing is downloaded.
"""
from __future__ import annotations

import os

import torch
from torch import nn

from staticdepth.errors import InputError

IMAGE_MEAN = 0.45    # MonoDepth2's input normalisation: (x - 0.45) / 0.225
IMAGE_STD = 0.225


def _conv3x3(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride, 1, bias=False)


class BasicBlock(nn.Module):
    """torchvision's ResNet basic block: two 3x3 convolutions and a residual connection."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = _conv3x3(cin, cout, stride)
        self.bn1 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(cout, cout)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False),
                                            nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResnetEncoder(nn.Module):
    """ResNet18 feature pyramid (MonoDepth2 ``ResnetEncoder``, 18 layers).

    ``width`` is the first stage's channel count: 64 is the standard ResNet18 (the only width that
    ImageNet weights fit); smaller widths make test-sized networks.
    """

    def __init__(self, width: int = 64):
        super().__init__()
        if width < 1:
            raise InputError(f"encoder width must be positive, got {width}")
        self.width = width
        c = [width, width, 2 * width, 4 * width, 8 * width]
        self.num_ch_enc = tuple(c)
        self.conv1 = nn.Conv2d(3, width, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = nn.Sequential(BasicBlock(c[0], c[1]), BasicBlock(c[1], c[1]))
        self.layer2 = nn.Sequential(BasicBlock(c[1], c[2], 2), BasicBlock(c[2], c[2]))
        self.layer3 = nn.Sequential(BasicBlock(c[2], c[3], 2), BasicBlock(c[3], c[3]))
        self.layer4 = nn.Sequential(BasicBlock(c[3], c[4], 2), BasicBlock(c[4], c[4]))
        for m in self.modules():  # torchvision's initialisation
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) RGB in [0, 1] -> 5 feature maps at strides 2, 4, 8, 16, 32."""
        x = (image - IMAGE_MEAN) / IMAGE_STD
        f0 = self.relu(self.bn1(self.conv1(x)))
        f1 = self.layer1(self.maxpool(f0))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        f4 = self.layer4(f3)
        return [f0, f1, f2, f3, f4]


def load_imagenet_weights(encoder: ResnetEncoder, path: str | os.PathLike) -> None:
    """Load a torchvision ResNet18 ImageNet state dict from a local file into ``encoder``.

    Accepts a bare state dict or one wrapped in ``{"state_dict": ...}`` / ``{"model": ...}``,
    with or without a ``module.`` prefix; ``fc.*`` is dropped. Every encoder tensor must be present
    with the right shape, else :class:`InputError` names the problem.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("ImageNet weights file not found", path)
    from staticdepth.models.trust import torch_load
    sd = torch_load(path, what="torch state dict")  # weights_only unless --trust-model
    for key in ("state_dict", "model"):
        if isinstance(sd, dict) and isinstance(sd.get(key), dict):
            sd = sd[key]
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise InputError("expected a state dict of tensors (torchvision resnet18 keys)", path)
    sd = {k.removeprefix("module."): v for k, v in sd.items() if not k.removeprefix(
        "module.").startswith("fc.")}
    own = encoder.state_dict()
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    if missing or unexpected:
        raise InputError(f"not a torchvision resnet18 state dict: {len(missing)} missing keys "
                         f"{missing[:3]}, {len(unexpected)} unexpected {unexpected[:3]}", path)
    bad = [k for k in own if own[k].shape != sd[k].shape]
    if bad:
        raise InputError(f"tensor {bad[0]!r} has shape {tuple(sd[bad[0]].shape)}, the encoder "
                         f"{tuple(own[bad[0]].shape)} (ImageNet weights need encoder_width=64)",
                         path)
    encoder.load_state_dict(sd, strict=True)
