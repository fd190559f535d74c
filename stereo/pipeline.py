"""The per-frame stereo path: rectify, match, (fill), triangulate.

>>> pipe = StereoPipeline(rig, StereoConfig(matcher="sgbm", max_depth_m=80.0))
>>> res = pipe.process(left_rgb, right_rgb)       # raw (unrectified) RGB uint8 pair
>>> res.depth                   # float32 metres, NaN = invalid, in pipe.camera's frame

The pipeline is a pure function of (images, rig, config): it holds no per-frame state and pickles
as (rig, config, the rig's file name for errors), so worker processes can rebuild it.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from staticdepth.config import from_dict
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig
from staticdepth.geometry.projection import depth_from_disparity, points_from_depth
from staticdepth.stereo.fill import fill_from_background
from staticdepth.stereo.match import create_matcher, num_disparities_for
from staticdepth.stereo.rectify import Rectifier

DEFAULT_NUM_DISPARITIES = 192


@dataclass(frozen=True)
class StereoConfig:
    """How to turn a stereo pair into depth.

    The disparity range is ``num_disparities`` when given, else ``f B / min_depth_m`` rounded up
    to 16 when ``min_depth_m`` is given, else 192. ``fill`` selects dense mode (every pixel gets a
    disparity, holes filled from the background side); otherwise ground-truth mode (validated
    disparities only). ``options`` go to the matcher (e.g. ``{"uniqueness": 20}`` for sgbm,
    ``{"model": "x.onnx", "contract": "crestereo"}`` for onnx).
    """

    matcher: str = "sgbm"
    max_depth_m: float = 80.0
    min_depth_m: float | None = None
    num_disparities: int | None = None
    fill: bool = False
    alpha: float = 0.0                      # stereoRectify's free scaling when the rig has none
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        if not self.max_depth_m > 0:
            raise InputError(f"max_depth_m must be positive, got {self.max_depth_m}")
        if self.min_depth_m is not None and not 0 < self.min_depth_m < self.max_depth_m:
            raise InputError(f"min_depth_m must be in (0, max_depth_m), got {self.min_depth_m}")
        if self.num_disparities is not None and (self.num_disparities <= 0
                                                 or self.num_disparities % 16):
            raise InputError(f"num_disparities must be a positive multiple of 16, "
                             f"got {self.num_disparities}")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None, source: str | None = None
                  ) -> "StereoConfig":
        return from_dict(cls, values, source=source)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class StereoResult:
    """One frame's output, all (H, W) in the rectified left view (``StereoPipeline.camera``)."""

    disparity: np.ndarray    # float32 px, NaN = invalid (finite everywhere in dense mode)
    depth: np.ndarray        # float32 m, NaN = invalid or beyond max_depth_m
    valid: np.ndarray        # bool, measured and consistency-checked (not filled)
    left_rect: np.ndarray    # uint8 RGB (H, W, 3)
    right_rect: np.ndarray   # uint8 RGB (H, W, 3)


class StereoPipeline:
    """Rectification maps and matcher built once for ``rig``; :meth:`process` per frame."""

    def __init__(self, rig: StereoRig, config: StereoConfig | None = None,
                 rig_source: str | None = None):
        """``rig_source`` (the rig's file) is named when the rig cannot be rectified."""
        self.rig = rig
        self.config = config or StereoConfig()
        self.rig_source = rig_source
        self._build()

    def _build(self) -> None:
        c = self.config
        self.rectifier = Rectifier(self.rig, c.alpha, source=self.rig_source)
        self.camera: Camera = self.rectifier.camera
        self.baseline_m: float = self.rectifier.baseline_m
        if c.num_disparities is not None:
            n = c.num_disparities
        elif c.min_depth_m is not None:
            n = num_disparities_for(self.camera.fx, self.baseline_m, c.min_depth_m)
        else:
            n = DEFAULT_NUM_DISPARITIES
        self.num_disparities = n
        self.matcher = create_matcher(c.matcher, num_disparities=n, image_size=self.camera.size,
                                      dense=c.fill, options=c.options)

    def __getstate__(self) -> dict[str, Any]:
        return {"rig": self.rig, "config": self.config, "rig_source": self.rig_source}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.rig, self.config = state["rig"], state["config"]
        self.rig_source = state.get("rig_source")
        self._build()

    def provenance(self) -> dict[str, Any]:
        """Config, resolved matcher parameters and the rectified geometry, for the output file."""
        return {"stereo": self.config.to_dict(), "matcher": self.matcher.params(),
                "focal_px": self.camera.fx, "baseline_m": self.baseline_m,
                "num_disparities": self.num_disparities}

    def check_frame(self, left_rgb: np.ndarray, right_rgb: np.ndarray,
                    source: str | None = None) -> None:
        """Raise :class:`InputError` unless the pair is two RGB uint8 images of the rig's size."""
        w, h = self.rig.left.size
        for name, img in (("left", left_rgb), ("right", right_rgb)):
            if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
                raise InputError(f"{name} image must be RGB uint8 (H, W, 3), got {img.dtype} "
                                 f"{img.shape}", source)
            if img.shape[:2] != (h, w):
                raise InputError(f"{name} image is {img.shape[1]}x{img.shape[0]} but the rig was "
                                 f"calibrated for {w}x{h}", source)

    def process(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> StereoResult:
        """Raw RGB uint8 pair (H, W, 3) -> :class:`StereoResult`."""
        self.check_frame(left_rgb, right_rgb)
        left_rect, right_rect = self.rectifier.rectify(left_rgb, right_rgb)
        out = self.matcher.match(left_rect, right_rect)
        disparity = out.disparity
        if self.config.fill:
            disparity = fill_from_background(disparity,
                                             median_rows=_median_rows(disparity.shape[0]))
            # dense means every pixel has a depth: nothing beyond the depth cap
            d_min = np.float32(self.camera.fx * self.baseline_m / self.config.max_depth_m)
            disparity = np.maximum(disparity, d_min)
        depth = depth_from_disparity(disparity, self.camera.fx, self.baseline_m,
                                     None if self.config.fill else self.config.max_depth_m)
        return StereoResult(disparity.astype(np.float32, copy=False), depth, out.valid,
                            left_rect, right_rect)

    def points(self, result: StereoResult) -> np.ndarray:
        """Camera-frame points (H, W, 3) of a result's depth (NaN where invalid)."""
        return points_from_depth(result.depth, self.camera.K)


def _median_rows(height: int) -> int:
    """Rows of the fill's vertical median: about 1/18 of the image height, odd, at least 3."""
    k = max(3, int(round(height / 18)))
    return k + 1 - k % 2
