"""Stereo self-supervised baseline (MonoDepth2 "S", METHOD.md section 7).

A ResNet18 + MonoDepth2-decoder monocular network trained on the scene's own rectified stereo pairs
with the sequence's real baseline, so its depth is metric. Stages: :mod:`.train` (``train``),
:mod:`.predict` (``predict``); math in :mod:`.layers` and :mod:`.losses`; model in :mod:`.resnet`,
:mod:`.decoder`, :mod:`.network`; settings in :mod:`.config`.
"""
from staticdepth.baseline.config import BaselineConfig, preset

__all__ = ["BaselineConfig", "preset"]
