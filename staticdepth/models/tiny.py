"""The built-in small depth network: a compact encoder-decoder trained here on synthetic scenes.

It is the toolkit's offline "off-the-shelf" model: trained by ``staticdepth train-builtin`` on
street-level renders (a level camera 1.6 m up), it predicts relative inverse depth like MiDaS and
fails on a high, tilted camera in the way the paper describes. No weights are ever downloaded.

Architecture (``TinyDepthNet``): five stride-2 stages (3x3 convs, GroupNorm, ReLU) to 1/32, an
FPN-style decoder (1x1 lateral + upsampled sum + 3x3 conv) back to 1/2, a 3x3 head with softplus,
bilinear upsampling to the input size. About 1.4 M parameters at the default widths.
"""
from __future__ import annotations

import os
from typing import Any, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from staticdepth.errors import InputError
from staticdepth.fileio import atomic_torch_save
from staticdepth.models.base import IMAGENET_MEAN, IMAGENET_STD, Resize, TorchDepthModel
from staticdepth.models.trust import torch_load

CHECKPOINT_FORMAT = "staticdepth.builtin/1"
DEFAULT_CONFIG: dict[str, Any] = {"enc_channels": (16, 32, 64, 128, 256),
                                  "dec_channels": (128, 64, 32, 16), "input_height": 192,
                                  "input_width": 384}
# Which parameters each training choice covers.
LAYER_GROUPS = {"head": ["head"], "decoder": ["top", "reduce", "lateral", "smooth", "head"]}


def _block(cin: int, cout: int, stride: int) -> nn.Sequential:
    groups = 4 if cout % 4 == 0 else 1
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False),
                         nn.GroupNorm(groups, cout), nn.ReLU(inplace=True))


class TinyDepthNet(nn.Module):
    """(B, 3, h, w) normalised RGB, h and w multiples of 32 -> (B, h, w) inverse depth (>= 0)."""

    def __init__(self, enc_channels: Sequence[int] = DEFAULT_CONFIG["enc_channels"],
                 dec_channels: Sequence[int] = DEFAULT_CONFIG["dec_channels"]):
        super().__init__()
        enc, dec = list(enc_channels), list(dec_channels)
        if len(enc) != 5 or len(dec) != 4:
            raise InputError(f"TinyDepthNet needs 5 encoder and 4 decoder widths, got {enc}, {dec}")
        stages, cin = [], 3
        for i, c in enumerate(enc):
            layers = [_block(cin, c, 2)]
            if i >= 1:
                layers.append(_block(c, c, 1))
            stages.append(nn.Sequential(*layers))
            cin = c
        self.stages = nn.ModuleList(stages)
        # decoder level k works at 1/2^(4-k) (k = 0: 1/16 ... k = 3: 1/2)
        self.top = nn.Conv2d(enc[4], dec[0], 1)
        self.lateral = nn.ModuleList(nn.Conv2d(enc[3 - k], dec[k], 1) for k in range(4))
        self.smooth = nn.ModuleList(_block(dec[k], dec[k], 1) for k in range(4))
        self.reduce = nn.ModuleList(nn.Identity() if k == 0 else nn.Conv2d(dec[k - 1], dec[k], 1)
                                    for k in range(4))
        self.head = nn.Sequential(nn.Conv2d(dec[3], dec[3], 3, 1, 1), nn.ReLU(inplace=True),
                                  nn.Conv2d(dec[3], 1, 3, 1, 1))
        self.config = {"enc_channels": tuple(enc), "dec_channels": tuple(dec)}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        H, W = x.shape[-2:]
        feats = []
        for stage in self.stages:
            x = stage(x)
            feats.append(x)
        y = self.top(feats[4])
        for k in range(4):
            skip = feats[3 - k]
            y = F.interpolate(self.reduce[k](y), size=skip.shape[-2:], mode="nearest")
            y = self.smooth[k](y + self.lateral[k](skip))
        y = F.softplus(self.head(y))
        return F.interpolate(y, size=(H, W), mode="bilinear", align_corners=False)[:, 0]


def builtin_model(net: TinyDepthNet | None = None, *, input_height: int = 192,
                  input_width: int = 384, name: str = "builtin") -> TorchDepthModel:
    """Wrap a :class:`TinyDepthNet` as a :class:`TorchDepthModel` (aspect-keeping resize, x32)."""
    net = TinyDepthNet() if net is None else net
    groups = LAYER_GROUPS
    if getattr(net, "config", {}).get("arch") == "unet":
        from staticdepth.models.unet import UNET_LAYER_GROUPS as groups
    return TorchDepthModel(net, name=name,
                           resize=Resize(input_height, input_width, keep_aspect_ratio=True,
                                         multiple=32),
                           mean=IMAGENET_MEAN, std=IMAGENET_STD, layer_groups=groups)


def save_builtin(path: str | os.PathLike, model: TorchDepthModel, info: dict | None = None) -> str:
    """Write the weights and their configuration atomically (``path`` appears complete or not)."""
    path = os.fspath(path)
    net = model.net
    ckpt = {"format": CHECKPOINT_FORMAT, "config": dict(net.config),
            "input_size": (model.resize.height, model.resize.width),
            "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()},
            "info": dict(info or {})}
    atomic_torch_save(path, ckpt)
    return path


def load_builtin(path: str | os.PathLike) -> TorchDepthModel:
    """Load a checkpoint written by :func:`save_builtin` (on the CPU; move it with ``.to``)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("built-in model weights not found; train them with "
                         f"`staticdepth train-builtin --out {path}`", path)
    ckpt = torch_load(path, what="torch checkpoint")  # tensors and plain values only
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"not a built-in model checkpoint (format {CHECKPOINT_FORMAT!r} "
                         "expected); use torch:FILE for other torch models", path)
    cfg = ckpt["config"]
    if cfg.get("arch") == "unet":
        from staticdepth.models.unet import TinyUNet

        net = TinyUNet(cfg["widths"])
    else:
        net = TinyDepthNet(cfg["enc_channels"], cfg["dec_channels"])
    try:
        net.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise InputError(f"weights do not match the configuration: {e}", path) from None
    h, w = ckpt.get("input_size", (192, 384))
    model = builtin_model(net.eval(), input_height=int(h), input_width=int(w))
    model.info = ckpt.get("info", {})
    return model
