"""The matcher interface and its registry: rectified pair in, left disparity out.

A matcher is built once per rig and image size (``create_matcher``) and then called per frame:

>>> m = create_matcher("sgbm", num_disparities=192, image_size=(800, 400))
>>> out = m.match(left_rgb, right_rgb)   # MatchOutput(disparity float32 NaN = invalid, valid bool)

Backends register themselves with :func:`register_matcher`; ``sgbm`` (OpenCV, always available)
and ``onnx`` (any stereo network exported to ONNX, described by a contract) ship with the toolkit.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol

import numpy as np

from staticdepth.errors import InputError


@dataclass(frozen=True)
class MatchOutput:
    """Left-view disparity (H, W) float32 in pixels, NaN = invalid, and its validity (H, W) bool.

    ``valid`` marks measured (consistency-checked) pixels; in dense mode ``disparity`` is finite
    everywhere and ``valid`` still says which values were measured rather than filled.
    """

    disparity: np.ndarray
    valid: np.ndarray


class Matcher(Protocol):
    name: str

    def match(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> MatchOutput:
        """Rectified RGB uint8 (H, W, 3) pair -> left disparity."""

    def params(self) -> dict[str, Any]:
        """Everything that determines the output (for provenance)."""


MatcherFactory = Callable[..., Matcher]
_REGISTRY: dict[str, str | MatcherFactory] = {
    "sgbm": "staticdepth.stereo.matchers.sgbm:SGBMMatcher",
    "onnx": "staticdepth.stereo.matchers.onnx:OnnxMatcher",
}


def register_matcher(name: str, factory: MatcherFactory) -> None:
    """Make ``factory(num_disparities=, image_size=, dense=, **options)`` available by ``name``."""
    _REGISTRY[name] = factory


def matcher_names() -> list[str]:
    return sorted(_REGISTRY)


def create_matcher(name: str, *, num_disparities: int, image_size: tuple[int, int],
                   dense: bool = False, options: Mapping[str, Any] | None = None) -> Matcher:
    """Build the matcher ``name`` for images of ``image_size`` = (width, height)."""
    if name not in _REGISTRY:
        raise InputError(f"unknown matcher {name!r} (known: {', '.join(matcher_names())})")
    factory = _REGISTRY[name]
    if isinstance(factory, str):
        module, attr = factory.split(":")
        try:
            factory = getattr(importlib.import_module(module), attr)
        except ImportError as e:
            raise InputError(f"matcher {name!r} is not available ({e})") from None
    return factory(num_disparities=num_disparities, image_size=image_size, dense=dense,
                   **dict(options or {}))


def num_disparities_for(focal_px: float, baseline_m: float, min_depth_m: float) -> int:
    """Disparity range for objects as near as ``min_depth_m``: f B / Z_min rounded up to 16."""
    if not min_depth_m > 0:
        raise InputError(f"minimum depth must be positive, got {min_depth_m}")
    d_max = focal_px * baseline_m / min_depth_m
    return int(max(16, 16 * np.ceil(d_max / 16.0)))
