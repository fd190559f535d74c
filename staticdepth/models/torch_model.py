"""Any torch module as a depth model: a TorchScript file, or a pickled ``nn.Module`` file.

A pickled module runs code when it is loaded, so it loads only under ``--trust-model``
(:mod:`staticdepth.models.trust`); a TorchScript archive loads without it.

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
               mean: Sequence[float] = IMAGENET_MEAN, std: Sequence[float] = IMAGENET_STD
               ) -> TorchDepthModel:
    """Load ``path`` (TorchScript archive first, else a torch file) on the CPU.

    A file that is not TorchScript goes through :func:`~staticdepth.models.trust.torch_load`: a
    pickled module is refused unless the user passed ``--trust-model``. Every parameter forms the
    ``all`` layer group; ``head`` is the module's ``head`` attribute when it has one.
    """
    import torch

    from staticdepth.models.trust import torch_load

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("torch model file not found (give a TorchScript or a saved nn.Module "
                         "file: torch:FILE.pt)", path)
    try:
        net = torch.jit.load(path, map_location="cpu")
    except Exception:
        net = torch_load(path, what="torch file")
    if not isinstance(net, torch.nn.Module):
        raise InputError(f"the file holds a {type(net).__name__}, not a torch module (a state "
                         "dict alone has no architecture: save the module or a TorchScript)", path)
    groups = {}
    if any(n == "head" or n.startswith("head.") for n, _ in net.named_parameters()):
        groups["head"] = ["head"]
    return TorchDepthModel(net.eval(), name=f"torch:{os.path.basename(path)}",
                           resize=resize or Resize(384, 384, keep_aspect_ratio=True, multiple=32),
                           mean=mean, std=std, layer_groups=groups)
