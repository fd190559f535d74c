"""Any torch module as a depth model: a TorchScript file, or a pickled ``nn.Module`` file.

The module takes a normalised (B, 3, h, w) batch and returns relative inverse depth (B, h', w') or
(B, 1, h', w'); the output is resized to the image. Preprocessing defaults to ImageNet statistics
at the image's own size rounded to a multiple of 32 (override with the keyword arguments).
"""
from __future__ import annotations

import os
from typing import Sequence

from staticdepth.errors import InputError
from staticdepth.models.base import IMAGENET_MEAN, IMAGENET_STD, Resize, TorchDepthModel


def load_torch(path: str | os.PathLike, *, resize: Resize | None = None,
               mean: Sequence[float] = IMAGENET_MEAN, std: Sequence[float] = IMAGENET_STD,
               trusted: bool = True) -> TorchDepthModel:
    """Load ``path`` (TorchScript archive first, else a whole pickled module) on the CPU.

    A pickled module can run code when it is loaded: pass only files you trust (``trusted=False``
    accepts TorchScript only). Every parameter forms the ``all`` layer group; ``head`` is the
    module's ``head`` attribute when it has one.
    """
    import torch

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("torch model file not found (give a TorchScript or a saved nn.Module "
                         "file: torch:FILE.pt)", path)
    net = None
    try:
        net = torch.jit.load(path, map_location="cpu")
    except Exception:
        if not trusted:
            raise InputError("not a TorchScript archive", path) from None
        try:
            net = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as e:
            raise InputError(f"not a readable torch file ({type(e).__name__}: {e})", path) from None
    if not isinstance(net, torch.nn.Module):
        raise InputError(f"the file holds a {type(net).__name__}, not a torch module (a state "
                         "dict alone has no architecture: save the module or a TorchScript)", path)
    groups = {}
    if any(n == "head" or n.startswith("head.") for n, _ in net.named_parameters()):
        groups["head"] = ["head"]
    return TorchDepthModel(net.eval(), name=f"torch:{os.path.basename(path)}",
                           resize=resize or Resize(384, 384, keep_aspect_ratio=True, multiple=32),
                           mean=mean, std=std, layer_groups=groups)
