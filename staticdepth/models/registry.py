"""Model spec strings -> depth models.

=====================  ==========================================================================
``builtin:PATH.pt``     the built-in small network (``staticdepth train-builtin --out PATH.pt``);
                        ``builtin`` alone uses the user cache (:func:`default_builtin_path`)
``hf:DIR_OR_ID``        transformers DPT / Depth Anything from a local directory or the local cache
``onnx:FILE.onnx``      an ONNX export through onnxruntime (inference only)
``torch:FILE.pt``       a TorchScript archive or a saved ``nn.Module``
=====================  ==========================================================================
Models load on the CPU; the caller moves torch models to its device.
"""
from __future__ import annotations

import os

from staticdepth.errors import InputError
from staticdepth.models.base import DepthModel

SCHEMES = ("builtin", "hf", "onnx", "torch")


def default_builtin_path() -> str:
    """``$STATICDEPTH_CACHE`` or ``$XDG_CACHE_HOME/staticdepth`` (``~/.cache/staticdepth``)/builtin.pt."""
    root = os.environ.get("STATICDEPTH_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"),
        "staticdepth")
    return os.path.join(root, "builtin.pt")


def parse_spec(spec: str) -> tuple[str, str]:
    """``"scheme:location"`` -> (scheme, location); ``builtin`` alone -> the cached weights."""
    spec = str(spec).strip()
    if spec == "builtin":
        return "builtin", default_builtin_path()
    scheme, sep, loc = spec.partition(":")
    if not sep or scheme not in SCHEMES or not loc:
        raise InputError(f"bad model spec {spec!r}: use one of builtin:PATH.pt, hf:DIR, "
                         "onnx:FILE.onnx, torch:FILE.pt")
    return scheme, os.path.expanduser(loc)


def load_model(spec: str) -> DepthModel:
    scheme, loc = parse_spec(spec)
    if scheme == "builtin":
        from staticdepth.models.tiny import load_builtin
        return load_builtin(loc)
    if scheme == "hf":
        from staticdepth.models.hf import load_hf
        return load_hf(loc)
    if scheme == "onnx":
        from staticdepth.models.onnx_model import OnnxDepthModel
        return OnnxDepthModel(loc)
    from staticdepth.models.torch_model import load_torch
    return load_torch(loc)
