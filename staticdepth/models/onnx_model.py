"""ONNX exports of MiDaS / DPT / Depth Anything (or any network) through onnxruntime.

Inference only. The input is one (1, 3, h, w) float32 tensor of normalised RGB; a static input
shape in the file fixes (h, w), a dynamic one uses :class:`~staticdepth.models.base.Resize`. The
output (1, h', w'), (1, 1, h', w') or (h', w') relative inverse depth is resized to the image
bilinearly. An output that is not one such map is refused (:func:`check_depth_output`): h' and w'
within 1/32 to 2x of the input's h and w, at the input's aspect within 2x (a detector's (1, N, 85)
boxes are not a map): from the file's shapes when they are fixed, else on the first image.
"""
from __future__ import annotations

import os
from typing import Sequence

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.models.base import IMAGENET_MEAN, IMAGENET_STD, DepthModel, Resize, check_image


def check_depth_output(shape: Sequence, input_hw: Sequence, path: str) -> None:
    """Refuse an output ``shape`` that is not one depth map for an input of ``input_hw``; a dim
    that is not an int (dynamic in the file) passes."""
    fixed = [isinstance(n, int) for n in shape]
    lead = {2: 0, 3: 1, 4: 2}.get(len(shape))
    ok = lead is not None and all(n == 1 for n, f in zip(shape[:lead], fixed) if f)
    if ok and all(fixed[lead:]) and all(isinstance(n, int) for n in input_hw):
        sy, sx = shape[lead] / input_hw[0], shape[lead + 1] / input_hw[1]
        ok = 1 / 32 <= min(sy, sx) and max(sy, sx) <= 2 and max(sy / sx, sx / sy) <= 2
    if not ok:
        dims = " x ".join(str(n) for n in input_hw)
        raise InputError(f"the output {tuple(shape)} is not one depth map for the {dims} input "
                         f"((1, h, w), (1, 1, h, w) or (h, w) near its size): not a depth model",
                         path)


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
        outputs = self.session.get_outputs()
        check_depth_output(outputs[0].shape, (h, w), self.path)
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
        x = self.preprocess(image)
        out = np.asarray(self.session.run(None, {self.input_name: x})[0], dtype=np.float32)
        check_depth_output(out.shape, x.shape[2:], self.path)
        out = out.reshape(out.shape[-2:])
        if out.shape != (H, W):
            out = cv2.resize(out, (W, H), interpolation=cv2.INTER_LINEAR)
        return out.astype(np.float32)
