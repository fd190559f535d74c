"""Settings of the stereo baseline: one frozen dataclass and its named presets."""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping

from staticdepth.config import from_dict
from staticdepth.errors import InputError


def _whole(x: Any) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


def _finite(x: Any) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class BaselineConfig:
    """MonoDepth2 "S" (stereo-only) training, METHOD.md section 7. Defaults = MonoDepth2's."""

    width: int = 640                 # network input size (multiples of 32, >= 64)
    height: int = 192
    min_depth: float = 0.1           # depth = 1 / (1/max + (1/min - 1/max) sigmoid), metres
    max_depth: float = 100.0
    encoder_width: int = 64          # ResNet18 first-stage channels (64 = standard)
    decoder_channels: tuple[int, ...] = (16, 32, 64, 128, 256)
    num_scales: int = 4
    imagenet_weights: str | None = None  # local torchvision resnet18 .pth; None = random init
    ssim_weight: float = 0.85        # photometric = a (1 - SSIM)/2 + (1 - a) L1
    smoothness_weight: float = 1e-3  # divided by 2^scale
    automask: bool = True            # per-pixel min with the identity error (+1e-5 noise)
    both_sides: bool = True          # train on left and right views as targets
    flip: bool = True                # random horizontal flips (stereo sign handled)
    color_jitter: bool = True        # brightness/contrast/saturation 0.2, hue 0.1, p = 0.5
    epochs: int = 20
    batch_size: int = 12
    lr: float = 1e-4                 # Adam
    lr_step_epochs: int = 15         # step decay: lr x lr_gamma every lr_step_epochs
    lr_gamma: float = 0.1
    seed: int = 0                    # 0 <= seed < 2**32

    def __post_init__(self):
        # every message names the setting and its value (``--set KEY=VALUE``)
        for name in ("width", "height"):
            v = getattr(self, name)
            if not _whole(v) or v < 64 or v % 32:
                raise InputError(f"width and height must be multiples of 32, at least 64 (the "
                                 f"decoder pads the stride-32 features), got {name} {v!r}")
        for name in ("min_depth", "max_depth"):
            if not (_finite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"need a finite {name} > 0 (metres), got {name} "
                                 f"{getattr(self, name)!r}")
        if not self.min_depth < self.max_depth:
            raise InputError(f"need 0 < min_depth < max_depth, got min_depth {self.min_depth}, "
                             f"max_depth {self.max_depth}")
        if len(self.decoder_channels) != 5 or not all(_whole(c) and c >= 1
                                                      for c in self.decoder_channels):
            raise InputError(f"decoder_channels needs 5 positive values, got "
                             f"{self.decoder_channels}")
        if not (_whole(self.num_scales) and 1 <= self.num_scales <= 4):
            raise InputError(f"num_scales must be 1..4, got {self.num_scales!r}")
        for name in ("encoder_width", "epochs", "batch_size", "lr_step_epochs"):
            if not (_whole(getattr(self, name)) and getattr(self, name) >= 1):
                raise InputError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not (_finite(self.lr) and self.lr > 0):
            raise InputError(f"need a finite lr > 0, got lr {self.lr!r}")
        if not (_finite(self.lr_gamma) and 0 < self.lr_gamma <= 1):
            raise InputError(f"need 0 < lr_gamma <= 1, got lr_gamma {self.lr_gamma!r}")
        if not (_finite(self.ssim_weight) and 0 <= self.ssim_weight <= 1):
            raise InputError(f"need 0 <= ssim_weight <= 1, got ssim_weight {self.ssim_weight!r}")
        if not (_finite(self.smoothness_weight) and self.smoothness_weight >= 0):
            raise InputError(f"need a finite smoothness_weight >= 0, got smoothness_weight "
                             f"{self.smoothness_weight!r}")
        if not (_whole(self.seed) and 0 <= self.seed < 2**32):
            raise InputError(f"need 0 <= seed < 2**32, got seed {self.seed!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


PRESETS: dict[str, BaselineConfig] = {
    # MonoDepth2's KITTI setting: 640x192, ResNet18, batch 12, 20 epochs, decay at 15.
    "default": BaselineConfig(),
    # Seconds on a CPU: small images, a narrow encoder; for tests and smoke runs.
    # min_depth 1 m keeps the initial disparity (sigmoid ~ 0.5 -> 2 m) inside narrow images.
    "tiny": BaselineConfig(width=128, height=64, min_depth=1.0, encoder_width=16,
                           decoder_channels=(8, 16, 16, 32, 64), epochs=16, batch_size=4, lr=1e-3,
                           lr_step_epochs=12, lr_gamma=0.3),
    # ``tiny`` at the sequence's own resolution (at most 640 wide; ``--scene-fit all`` follows
    # the sequence's aspect): a CPU run for a real site. Disparity is what the network resolves:
    # a 27 cm rig at 90 deg gives a 40 m facade 0.43 px of disparity at 128 px wide and 1.1 px at
    # 320 (tests/indep_scenes.py i4, a1: 0.684 at 128x64 and 0.81 at 320x160 after 8 epochs,
    # 0.875 after 16).
    "site": BaselineConfig(width=640, height=320, min_depth=1.0, encoder_width=16,
                           decoder_channels=(8, 16, 16, 32, 64), epochs=16, batch_size=4, lr=1e-3,
                           lr_step_epochs=12, lr_gamma=0.3),
}


def preset(name: str = "default", overrides: Mapping[str, Any] | None = None) -> BaselineConfig:
    """The named preset with ``overrides`` (strings from ``--set`` are converted); strict."""
    if name not in PRESETS:
        raise InputError(f"unknown baseline preset {name!r} (one of {sorted(PRESETS)})")
    return from_dict(BaselineConfig, overrides or {}, base=PRESETS[name])


def config_from_dict(values: Mapping[str, Any], source: str | None = None) -> BaselineConfig:
    """Rebuild a config stored in a checkpoint (lists become tuples); unknown keys are errors."""
    return from_dict(BaselineConfig, dict(values), source=source)
