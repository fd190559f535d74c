"""Stereo training data: the adaptation split's rectified pairs, sides, flips and colour jitter.

Frames are held in memory at the network's size as uint8 (N, H, W, 3). A sample is a frame and
a target side; ``direction`` says where the source camera sits relative to the target camera
(+1: to its right, as the right camera for a left target). A horizontal flip mirrors the world:
the source camera changes side, so ``direction`` changes sign.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from staticdepth.baseline.config import BaselineConfig
from staticdepth.errors import InputError

JITTER_BRIGHTNESS = JITTER_CONTRAST = JITTER_SATURATION = 0.2
JITTER_HUE = 0.1
JITTER_PROB = 0.5


@dataclass(frozen=True)
class StereoGeometry:
    """What the warp needs: the rectified baseline and the focal length at the network's width."""

    baseline_m: float
    focal_px: float          # at the network input width
    focal_px_full: float     # at the sequence's width
    sequence_size: tuple[int, int]  # (width, height)


def stereo_geometry(reader, conf: BaselineConfig) -> StereoGeometry:
    """Check that ``reader`` (a SequenceReader) has rectified stereo pairs; return the geometry."""
    if not reader.has("right"):
        raise InputError("sequence has no right images, so the stereo baseline cannot train on "
                         "it; for KITTI re-import the drive with the KITTI importer's --right "
                         "option (image_03): staticdepth import-kitti ... --right", reader.path)
    rig = reader.meta.rig
    if rig is None:
        raise InputError("sequence has right images but no stereo rig (baseline unknown)",
                         reader.path)
    cam = reader.camera
    return StereoGeometry(baseline_m=rig.baseline_m, focal_px=cam.fx * conf.width / cam.width,
                          focal_px_full=cam.fx, sequence_size=(cam.width, cam.height))


def resize_rgb(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8 -> (height, width, 3) uint8 (area interpolation when shrinking)."""
    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return np.ascontiguousarray(image)
    interp = cv2.INTER_AREA if width < w and height < h else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interp)


def load_pairs(reader, frames: range | list[int], conf: BaselineConfig
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Left and right views of ``frames`` at the network size: two (N, H, W, 3) uint8 tensors."""
    if len(frames) == 0:
        raise InputError("the adaptation split is empty (adapt_frames = 0): nothing to train on",
                         reader.path)
    left = np.stack([resize_rgb(reader.left(i), conf.width, conf.height) for i in frames])
    right = np.stack([resize_rgb(reader.right(i), conf.width, conf.height) for i in frames])
    return torch.from_numpy(left), torch.from_numpy(right)


def to_float(images_u8: torch.Tensor) -> torch.Tensor:
    """(B, H, W, 3) uint8 -> (B, 3, H, W) float32 in [0, 1]."""
    return images_u8.permute(0, 3, 1, 2).float().div_(255.0)


def _grey(x: torch.Tensor) -> torch.Tensor:
    return (0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2]).unsqueeze(1)


def color_jitter(x: torch.Tensor, brightness: torch.Tensor, contrast: torch.Tensor,
                 saturation: torch.Tensor, hue: torch.Tensor) -> torch.Tensor:
    """Per-image colour jitter of (B, 3, H, W) in [0, 1]; factors (B,), hue in turns (B,).

    Brightness scales, contrast blends with the mean grey, saturation with the grey image
    (torchvision's definitions); hue rotates chroma in YIQ space (a close, cheap stand-in for
    torchvision's HSV hue shift).
    """
    f = lambda t: t.reshape(-1, 1, 1, 1).to(x)  # noqa: E731
    x = (x * f(brightness)).clamp(0, 1)
    m = _grey(x).mean((2, 3), keepdim=True)
    x = ((x - m) * f(contrast) + m).clamp(0, 1)
    g = _grey(x)
    x = ((x - g) * f(saturation) + g).clamp(0, 1)
    to_yiq = x.new_tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322],
                           [0.211, -0.523, 0.312]])
    yiq = torch.einsum("ij,bjhw->bihw", to_yiq, x)
    a = f(hue * 2 * math.pi)
    i2 = yiq[:, 1:2] * torch.cos(a) - yiq[:, 2:3] * torch.sin(a)
    q2 = yiq[:, 1:2] * torch.sin(a) + yiq[:, 2:3] * torch.cos(a)
    yiq = torch.cat([yiq[:, :1], i2, q2], 1)
    rgb = torch.einsum("ij,bjhw->bihw", torch.linalg.inv(to_yiq), yiq)
    return rgb.clamp(0, 1)


def make_batch(left_u8: torch.Tensor, right_u8: torch.Tensor, frame: torch.Tensor,
               target_is_left: torch.Tensor, flip: torch.Tensor, geometry: StereoGeometry,
               jitter: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Assemble a batch (CPU tensors; the caller moves it to its device).

    Args:
        left_u8, right_u8: (N, H, W, 3) uint8 frames; frame: (B,) indices into them.
        target_is_left, flip: (B,) bool. jitter: (B, 4) brightness, contrast, saturation, hue
            (identity = 1, 1, 1, 0) or None.
    Returns:
        ``image`` (network input: target, jittered), ``target``, ``source`` (B, 3, H, W) in
        [0, 1]; ``direction`` (B,) +-1; ``focal_px``, ``baseline_m`` (B,).
    """
    lt, rt = to_float(left_u8[frame]), to_float(right_u8[frame])
    tl = target_is_left.reshape(-1, 1, 1, 1)
    target = torch.where(tl, lt, rt)
    source = torch.where(tl, rt, lt)
    fl = flip.reshape(-1, 1, 1, 1)
    target = torch.where(fl, target.flip(-1), target)
    source = torch.where(fl, source.flip(-1), source)
    direction = torch.where(target_is_left, 1.0, -1.0) * torch.where(flip, -1.0, 1.0)
    image = target if jitter is None else color_jitter(target, *jitter.unbind(1))
    b = len(frame)
    return {"image": image, "target": target, "source": source, "direction": direction,
            "focal_px": torch.full((b,), geometry.focal_px),
            "baseline_m": torch.full((b,), geometry.baseline_m)}


def sample_batch(left_u8: torch.Tensor, right_u8: torch.Tensor, samples: torch.Tensor,
                 geometry: StereoGeometry, conf: BaselineConfig, generator: torch.Generator
                 ) -> dict[str, torch.Tensor]:
    """A training batch for sample ids (frame + N * side), with random flips and jitter."""
    n = len(left_u8)
    frame = samples % n
    target_is_left = samples < n
    b = len(samples)
    flip = (torch.rand(b, generator=generator) < 0.5) if conf.flip else torch.zeros(b, dtype=bool)
    jitter = None
    if conf.color_jitter:
        u = torch.rand(b, 4, generator=generator) * 2 - 1
        on = (torch.rand(b, 1, generator=generator) < JITTER_PROB).float()
        amp = torch.tensor([JITTER_BRIGHTNESS, JITTER_CONTRAST, JITTER_SATURATION, JITTER_HUE])
        jitter = torch.tensor([1.0, 1.0, 1.0, 0.0]) + on * u * amp
    return make_batch(left_u8, right_u8, frame, target_is_left, flip, geometry, jitter)
