"""ONNX exports of MiDaS / DPT / Depth Anything (or any network) through onnxruntime.

Inference only. The input is one (1, 3, h, w) float32 tensor of normalised RGB; a static input
shape in the file fixes (h, w), a dynamic one uses :class:`~staticdepth.models.base.Resize`. The
output (1, h', w') or (1, 1, h', w') relative inverse depth is resized to the image bilinearly.
"""
from __future__ import annotations

import os
from typing import Sequence

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.models.base import IMAGENET_MEAN, IMAGENET_STD, DepthModel, Resize, check_image


class OnnxDepthModel(DepthModel):
    def __init__(self, path: str | os.PathLike, *, resize: Resize | None = None,
                 mean: Sequence[float] = IMAGENET_MEAN, std: Sequence[float] = IMAGENET_STD,
                 providers: Sequence[str] | None = None):
        from staticdepth.onnx_session import onnx_session

        self.path = os.fspath(path)
        if not os.path.isfile(self.path):
            raise InputError("ONNX model file not found (give onnx:FILE.onnx)", self.path)
        self.session = onnx_session(self.path, providers or ["CPUExecutionProvider"])
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise InputError("expected one (1, 3, h, w) input", self.path)
        self.input_name = inputs[0].name
        h, w = inputs[0].shape[2:]
        self.static_size = (h, w) if isinstance(h, int) and isinstance(w, int) else None
        self.resize = resize or Resize(384, 384, keep_aspect_ratio=True, multiple=32)
        self.mean = np.asarray(mean, dtype=np.float32)
        self.std = np.asarray(std, dtype=np.float32)
        self.name = f"onnx:{os.path.basename(self.path)}"

    def input_size(self, height: int, width: int) -> tuple[int, int]:
        return self.static_size or self.resize.output_size(height, width)

    def preprocess(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 -> (1, 3, h, w) float32 normalised."""
        img = check_image(image)
        h, w = self.input_size(*img.shape[:2])
        x = img.astype(np.float32) / 255.0
        if (h, w) != img.shape[:2]:
            x = cv2.resize(x, (w, h), interpolation=cv2.INTER_CUBIC)
        x = (x - self.mean) / self.std
        return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)

    def predict(self, image: np.ndarray) -> np.ndarray:
        H, W = np.asarray(image).shape[:2]
        out = self.session.run(None, {self.input_name: self.preprocess(image)})[0]
        out = np.asarray(out, dtype=np.float32)
        while out.ndim > 2:
            if out.shape[0] != 1:
                raise InputError(f"unexpected output shape {out.shape}", self.path)
            out = out[0]
        if out.shape != (H, W):
            out = cv2.resize(out, (W, H), interpolation=cv2.INTER_LINEAR)
        return out.astype(np.float32)
