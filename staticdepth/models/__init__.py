"""Monocular depth networks behind one interface: RGB image -> relative inverse depth.

Load one with :func:`staticdepth.models.registry.load_model` from a spec string
(``builtin:PATH.pt``, ``hf:DIR``, ``onnx:FILE.onnx``, ``torch:FILE.pt``).
"""
from staticdepth.models.base import DepthModel, Resize, TorchDepthModel  # noqa: F401
from staticdepth.models.registry import load_model  # noqa: F401
