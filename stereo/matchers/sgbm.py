"""OpenCV semi-global block matching with parameters derived from the image and the depth range.

What the defaults add to a textbook ``StereoSGBM_create`` (measured on Aloe, Middlebury Art and
Midd1, see ``benchmarks/bench_stereo.py``):
- block size 3 (5 above 1400 px width), P1 = 8 c b^2 and a softer P2 = 16 c b^2 (less smearing of
  the foreground over the background);
- the left image border: SGBM leaves the first ``num_disparities`` columns empty (24% of an
  800 px image at 192 disparities). ``border="half"`` (default) matches those columns again at
  half resolution (half the range, a quarter of the pixels, stricter uniqueness): about 1/8 of the
  cost of padding at full resolution, which adds a third to SGBM's time. ``"full"`` pads the
  images by the disparity range instead (sharper border, about 1.45x a bare ``compute`` at
  800x400 and 192 disparities, against about 1.2x), ``"none"`` leaves the border empty;
- SGBM's own left-right check (``disp12MaxDiff = 1``, free), uniqueness 15, and a speckle filter
  whose window grows with the image (300 px at 0.17 MP) with a 1 px range;
- in ground-truth mode, foreground-fattened pixels beside depth edges are removed
  (:func:`~staticdepth.stereo.fill.trim_foreground_edges`);
- optional: a full right-view matcher (``full_lr``, doubles the time) and the WLS filter (``wls``).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from staticdepth.config import from_dict
from staticdepth.errors import InputError
from staticdepth.stereo.fill import lr_consistent, trim_foreground_edges
from staticdepth.stereo.match import MatchOutput

MODES = {"3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
         "hh": cv2.STEREO_SGBM_MODE_HH, "hh4": cv2.STEREO_SGBM_MODE_HH4}

BORDERS = ("half", "full", "none")
BORDER_CONTEXT_PX = 32     # columns right of the border that the half-resolution strip also sees


@dataclass(frozen=True)
class SGBMConfig:
    """SGBM settings; 0 / -1 mean "derive from the image" (see :meth:`resolved`)."""

    block_size: int = 0            # 0: 3 up to 1400 px wide, 5 above
    p1_factor: float = 8.0         # P1 = p1_factor * channels * block^2
    p2_factor: float = 16.0        # P2 = p2_factor * channels * block^2
    uniqueness: int = 15
    speckle_window: int = 0        # 0: 300 px * sqrt(area / 0.171 MP)
    speckle_range: int = 1         # px
    disp12_max_diff: int = 1       # SGBM's internal left-right check, px (-1: off)
    pre_filter_cap: int = 63
    mode: str = "3way"
    border: str = "half"           # left border: "half" resolution, "full" padding or "none"
    border_uniqueness: int = 25    # uniqueness of the half-resolution border match
    trim_radius: int = -1          # -1: the block size; 0: keep fattened edges
    trim_jump_px: float = 2.0
    full_lr: bool = False          # a second matcher on the right view, consistency within lr_px
    lr_px: float = 1.0
    wls: bool = False              # ximgproc WLS filter (needs full_lr's right disparity)
    wls_lambda: float = 8000.0
    wls_sigma: float = 1.5

    def __post_init__(self):
        if self.mode not in MODES:
            raise InputError(f"sgbm mode must be one of {sorted(MODES)}, got {self.mode!r}")
        if self.border not in BORDERS:
            raise InputError(f"sgbm border must be one of {list(BORDERS)}, got {self.border!r}")
        if self.block_size and (self.block_size < 1 or self.block_size % 2 == 0):
            raise InputError(f"sgbm block_size must be odd and positive, got {self.block_size}")

    def resolved(self, width: int, height: int) -> "SGBMConfig":
        """The settings with every automatic value replaced by its number for this image size."""
        bs = self.block_size or (3 if width <= 1400 else 5)
        sw = self.speckle_window or int(round(300 * math.sqrt(width * height / 171_000)))
        tr = bs if self.trim_radius < 0 else self.trim_radius
        return dataclasses.replace(self, block_size=bs, speckle_window=sw, trim_radius=tr)


PRESETS = {
    "ground_truth": SGBMConfig(),
    # Dense output is filled from the background afterwards: keep more (mostly right) matches in
    # weak texture and leave depth edges to the fill.
    "dense": SGBMConfig(uniqueness=10, trim_radius=0),
    # The textbook parameters, for comparison (OpenCV's sample, block 5).
    "textbook": SGBMConfig(block_size=5, p2_factor=32.0, uniqueness=10, speckle_window=100,
                           speckle_range=2, disp12_max_diff=-1, border="none", trim_radius=0),
}


class SGBMMatcher:
    """OpenCV SGBM for one image size and disparity range (see the module docstring)."""

    name = "sgbm"

    def __init__(self, *, num_disparities: int, image_size: tuple[int, int], dense: bool = False,
                 preset: str | None = None, **overrides: Any):
        if preset is None:
            preset = "dense" if dense else "ground_truth"
        if preset not in PRESETS:
            raise InputError(f"unknown sgbm preset {preset!r} (known: {sorted(PRESETS)})")
        if num_disparities <= 0 or num_disparities % 16:
            raise InputError(f"number of disparities must be a positive multiple of 16, "
                             f"got {num_disparities}")
        width, height = image_size
        if num_disparities >= width:
            raise InputError(f"disparity range {num_disparities} px is not below the image width "
                             f"{width} px (raise the minimum depth)")
        self.preset = preset
        self.num_disparities = int(num_disparities)
        self.image_size = (int(width), int(height))
        self.conf = from_dict(SGBMConfig, overrides, base=PRESETS[preset]).resolved(width, height)
        c = self.conf
        self._left = self._sgbm(self.num_disparities, c.uniqueness, c.speckle_window)
        self._right = None
        if c.full_lr or c.wls:
            self._right = cv2.ximgproc.createRightMatcher(self._left)
        # the full-right-view path checks the padded images; "half" then pads like "full"
        half = c.border == "half" and self._right is None
        self._pad_px = self.num_disparities if c.border == "full" or (
            c.border == "half" and not half) else 0
        self._border = None
        if half:
            self._border_px = self.num_disparities
            self._border_range = 16 * math.ceil(self.num_disparities / 32)
            self._border = self._sgbm(self._border_range, c.border_uniqueness,
                                      max(1, c.speckle_window // 4))

    def _sgbm(self, num_disparities: int, uniqueness: int, speckle_window: int):
        c = self.conf
        bs, ch = c.block_size, 3
        return cv2.StereoSGBM_create(
            minDisparity=0, numDisparities=num_disparities, blockSize=bs,
            P1=int(c.p1_factor * ch * bs * bs), P2=int(c.p2_factor * ch * bs * bs),
            disp12MaxDiff=c.disp12_max_diff, preFilterCap=c.pre_filter_cap,
            uniquenessRatio=uniqueness, speckleWindowSize=speckle_window,
            speckleRange=c.speckle_range, mode=MODES[c.mode])

    def params(self) -> dict[str, Any]:
        return {"matcher": self.name, "preset": self.preset,
                "num_disparities": self.num_disparities, **dataclasses.asdict(self.conf)}

    def _pad(self, img: np.ndarray) -> np.ndarray:
        if not self._pad_px:
            return img
        return cv2.copyMakeBorder(img, 0, 0, self._pad_px, 0, cv2.BORDER_REPLICATE)

    def _crop(self, raw: np.ndarray) -> np.ndarray:
        return raw[:, self._pad_px:] if self._pad_px else raw

    def _match_border(self, left_rgb: np.ndarray, right_rgb: np.ndarray, disp: np.ndarray) -> None:
        """Fill the first ``num_disparities`` columns of ``disp`` (in place) at half resolution.

        The strip (the border plus ``BORDER_CONTEXT_PX`` columns) is halved in both directions,
        padded on the left by the halved range, matched, and its disparities doubled and
        upsampled (nearest) back onto the full-resolution columns.
        """
        h, w = disp.shape
        strip = min(w, self._border_px + BORDER_CONTEXT_PX) // 2 * 2
        size, r = (strip // 2, (h + 1) // 2), self._border_range
        halves = [cv2.copyMakeBorder(cv2.resize(img[:, :strip], size, interpolation=cv2.INTER_AREA),
                                     0, 0, r, 0, cv2.BORDER_REPLICATE)
                  for img in (left_rgb, right_rgb)]
        small = _float_disparity(self._border.compute(*halves)[:, r:])
        small *= np.float32(2)
        up = cv2.resize(small, (strip, h), interpolation=cv2.INTER_NEAREST)
        n = min(self._border_px, strip)
        disp[:, :n] = up[:, :n]

    def match(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> MatchOutput:
        if left_rgb.shape[:2][::-1] != self.image_size or right_rgb.shape != left_rgb.shape:
            raise InputError(f"matcher built for {self.image_size[0]}x{self.image_size[1]} images, "
                             f"got {left_rgb.shape[1]}x{left_rgb.shape[0]} and "
                             f"{right_rgb.shape[1]}x{right_rgb.shape[0]}")
        c = self.conf
        L, R = self._pad(left_rgb), self._pad(right_rgb)
        raw_left = self._left.compute(L, R)
        if self._right is None:       # the default path: crop first, convert once, trim in place
            disp = _float_disparity(self._crop(raw_left))
            if self._border is not None:
                self._match_border(left_rgb, right_rgb, disp)
            if c.trim_radius:
                disp = trim_foreground_edges(disp, c.trim_radius, c.trim_jump_px, copy=False)
            return MatchOutput(disp, ~np.isnan(disp))
        disp = _float_disparity(raw_left)
        raw_right = self._right.compute(R, L)
        if c.wls:
            wls = cv2.ximgproc.createDisparityWLSFilter(self._left)
            wls.setLambda(c.wls_lambda)
            wls.setSigmaColor(c.wls_sigma)
            filtered = wls.filter(raw_left, L, disparity_map_right=raw_right)
            conf_map = wls.getConfidenceMap()
            disp = filtered.astype(np.float32) / 16.0
            disp[(conf_map < 128) | (filtered < 0)] = np.nan
        if c.full_lr:
            disp[~lr_consistent(disp, -raw_right.astype(np.float32) / 16.0, c.lr_px)] = np.nan
        disp = self._crop(disp)
        if c.trim_radius:
            disp = trim_foreground_edges(disp, c.trim_radius, c.trim_jump_px)
        return MatchOutput(disp, ~np.isnan(disp))


def _float_disparity(raw: np.ndarray) -> np.ndarray:
    """SGBM's fixed-point disparity (int16, x16, negative = invalid) -> float32 px, NaN invalid."""
    disp = raw.astype(np.float32)
    disp *= np.float32(1 / 16)
    disp[raw < 0] = np.nan
    return disp
