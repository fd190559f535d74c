"""The depth-network interface: image (H, W, 3) uint8 RGB -> relative inverse depth (H, W).

Every model outputs the network's native relative inverse depth ``D = s / Z + t`` (unknown scale
``s > 0`` and shift ``t``, METHOD.md) at the image's full resolution, float32. Input sizing follows
the networks' own preprocessing (MiDaS / HF ``DPTImageProcessor``): :class:`Resize`.

Torch-backed models (:class:`TorchDepthModel`) are also differentiable (``forward``) so that
:mod:`staticdepth.finetune` can adapt them; the device is chosen by the caller (``model.to``).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np

from staticdepth.errors import InputError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
HALF_MEAN = (0.5, 0.5, 0.5)
HALF_STD = (0.5, 0.5, 0.5)


def _to_multiple(val: float, multiple: int, max_val: int | None = None, min_val: int = 0) -> int:
    x = round(val / multiple) * multiple
    if max_val is not None and x > max_val:
        x = math.floor(val / multiple) * multiple
    if x < min_val:
        x = math.ceil(val / multiple) * multiple
    return int(x)


@dataclass(frozen=True)
class Resize:
    """How an image of any size becomes the network's input size (MiDaS ``Resize`` semantics).

    ``height`` x ``width`` is the target; with ``keep_aspect_ratio`` the image is scaled as little
    as possible so that one side reaches its target and the other keeps the aspect; both sides are
    rounded to a multiple of ``multiple``.
    """

    height: int
    width: int
    keep_aspect_ratio: bool = False
    multiple: int = 1

    def __post_init__(self):
        if self.height <= 0 or self.width <= 0 or self.multiple <= 0:
            raise InputError(f"bad input size {self.width}x{self.height} (multiple {self.multiple})")

    def output_size(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) of the network input for an image of ``height`` x ``width``."""
        sh, sw = self.height / height, self.width / width
        if self.keep_aspect_ratio:
            if abs(1 - sw) < abs(1 - sh):
                sh = sw
            else:
                sw = sh
        h = _to_multiple(sh * height, self.multiple, min_val=self.multiple)
        w = _to_multiple(sw * width, self.multiple, min_val=self.multiple)
        return h, w


def check_image(image: np.ndarray) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise InputError(f"expected an RGB uint8 image (H, W, 3), got {a.dtype} {a.shape}")
    return a


class DepthModel(ABC):
    """Image -> relative inverse depth at full resolution."""

    name: str = "model"

    @abstractmethod
    def predict(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB -> (H, W) float32 relative inverse depth (larger = nearer)."""

    def predict_many(self, images: Iterable[np.ndarray]) -> list[np.ndarray]:
        return [self.predict(im) for im in images]


def _group_params(net, prefixes: Sequence[str]):
    out = []
    for name, p in net.named_parameters():
        if any(name == pre or name.startswith(pre + ".") for pre in prefixes):
            out.append(p)
    return out


class TorchDepthModel(DepthModel):
    """Any torch module mapping a normalised (B, 3, h, w) batch to inverse depth (B, [1,] h', w').

    ``layer_groups`` names which parameters each training choice covers, as lists of module-name
    prefixes, e.g. ``{"head": ["head"], "decoder": ["neck", "head"]}``; ``"all"`` is always every
    parameter. ``output`` picks the tensor out of a structured output (e.g. ``predicted_depth``).
    """

    def __init__(self, net, *, name: str = "torch", resize: Resize | None = None,
                 mean: Sequence[float] = IMAGENET_MEAN, std: Sequence[float] = IMAGENET_STD,
                 layer_groups: Mapping[str, Sequence[str]] | None = None,
                 output: str | None = None, input_kw: str | None = None):
        import torch

        self.net = net
        self.name = name
        self.resize = resize
        self.layer_groups = dict(layer_groups or {})
        self.output = output
        self.input_kw = input_kw
        self._mean = torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1)
        self._std = torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1)

    # -- device and training choices -------------------------------------------------------------
    @property
    def device(self):
        import torch

        for p in self.net.parameters():
            return p.device
        return torch.device("cpu")

    def to(self, device) -> "TorchDepthModel":
        self.net.to(device)
        return self

    def parameters_for(self, layers: str) -> list:
        """Parameters trained for ``layers`` ('head', 'decoder', 'all' or a group name)."""
        if layers == "all":
            return list(self.net.parameters())
        if layers not in self.layer_groups:
            raise InputError(f"model {self.name!r} has no layer group {layers!r} "
                             f"(has: all, {', '.join(sorted(self.layer_groups))})")
        params = _group_params(self.net, self.layer_groups[layers])
        if not params:
            raise InputError(f"layer group {layers!r} of model {self.name!r} matches no parameter")
        return params

    def set_trainable(self, layers: str) -> list:
        """Freeze every parameter except those of ``layers``; returns the trainable ones."""
        keep = {id(p) for p in self.parameters_for(layers)}
        params = []
        for p in self.net.parameters():
            p.requires_grad_(id(p) in keep)
            if id(p) in keep:
                params.append(p)
        return params

    # -- inference --------------------------------------------------------------------------------
    def input_size(self, height: int, width: int) -> tuple[int, int]:
        return (height, width) if self.resize is None else self.resize.output_size(height, width)

    def forward(self, images):
        """Differentiable: (B, 3, H, W) float RGB in [0, 1] -> (B, H, W) relative inverse depth.

        The batch is resized to the network's input size, normalised, run, and the output resized
        back to (H, W) bilinearly.
        """
        import torch.nn.functional as F

        B, _, H, W = images.shape
        h, w = self.input_size(H, W)
        x = images
        if (h, w) != (H, W):
            x = F.interpolate(x, size=(h, w), mode="bicubic", align_corners=False)
        x = (x - self._mean.to(x.device)) / self._std.to(x.device)
        out = self.net(**{self.input_kw: x}) if self.input_kw else self.net(x)
        if self.output is not None:
            out = getattr(out, self.output) if hasattr(out, self.output) else out[self.output]
        if out.dim() == 4:
            if out.shape[1] != 1:
                raise InputError(f"model {self.name!r} returned {tuple(out.shape)}; "
                                 "expected one channel")
            out = out[:, 0]
        if out.dim() != 3:
            raise InputError(f"model {self.name!r} returned shape {tuple(out.shape)}; "
                             "expected (B, h, w) or (B, 1, h, w)")
        if out.shape[-2:] != (H, W):
            out = F.interpolate(out[:, None], size=(H, W), mode="bilinear",
                                align_corners=False)[:, 0]
        return out

    def predict(self, image: np.ndarray) -> np.ndarray:
        return self.predict_many([image])[0]

    def predict_many(self, images: Iterable[np.ndarray]) -> list[np.ndarray]:
        """One forward pass over the images (same size): (H, W) float32 inverse depth each."""
        import torch

        batch = np.stack([check_image(im) for im in images])
        x = torch.from_numpy(batch).permute(0, 3, 1, 2).float() / 255.0
        was_training = self.net.training
        self.net.eval()
        try:
            with torch.no_grad():
                out = self.forward(x.to(self.device))
        finally:
            self.net.train(was_training)
        return list(out.float().cpu().numpy().astype(np.float32))
