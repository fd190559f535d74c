"""Any stereo network exported to ONNX, run with onnxruntime and described by a contract.

>>> m = OnnxMatcher(num_disparities=192, image_size=(800, 400), model="crestereo.onnx",
...                 contract="crestereo-combined")
>>> out = m.match(left_rgb, right_rgb)   # MatchOutput: float32 disparity (NaN = invalid), valid

Per frame: convert the rectified RGB uint8 pair to the contract's colour, size (pad right/bottom to
a multiple, or resize to the model's fixed size), value scale and layout; run (twice for two-stage
contracts: half resolution first, its output as ``flow_init``); take ``sign * out[channel]``; undo
the padding (crop) or the resize (resize back, disparity times the width ratio).

Validity: disparities that are not finite, <= 0 or > ``num_disparities`` are invalid. With
``lr_check=True`` (contracts with ``lr_flip``) the network also runs on the mirrored, swapped pair,
which gives the right view's disparity, and pixels whose two disparities disagree by more than
``lr_px`` are invalid too (doubles the time). In ground-truth mode invalid pixels are NaN; in dense
mode (``dense=True``) the network's own in-range values are kept where only the left-right check
failed (``valid`` still says which pixels passed), and only out-of-range pixels are NaN (the
pipeline fills them).

Options (``StereoConfig.options`` / ``--set``): ``model`` (required), ``contract`` (a name from
:data:`~staticdepth.stereo.contracts.CONTRACTS` or a JSON file; default: ``crestereo-combined``
when the model has its inputs, else ``crestereo``), ``init_model`` (the ``init`` export for
contracts with ``flow_init_input``), ``lr_check``, ``lr_px``, ``device`` (auto, cpu, cuda),
``threads``, and any :class:`~staticdepth.stereo.contracts.Contract` field to override the contract.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
from typing import Any

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.stereo.contracts import (CONTRACTS, IMAGENET_MEAN_RGB, IMAGENET_STD_RGB, Contract,
                                          load_contract)
from staticdepth.stereo.fill import lr_consistent
from staticdepth.stereo.match import MatchOutput

_CONTRACT_FIELDS = {f.name for f in dataclasses.fields(Contract)}


def _session(path: str, device: str, threads: int):
    """An onnxruntime session for ``path`` on ``device`` (auto, cpu, cuda)."""
    import onnxruntime as ort

    if not os.path.isfile(path):
        raise InputError("ONNX model file not found", path)
    available = ort.get_available_providers()
    if device == "cpu":
        providers = ["CPUExecutionProvider"]
    elif device in ("cuda", "auto"):
        if "CUDAExecutionProvider" in available:
            providers = ["CUDAExecutionProvider", "CPUExecutionProvider"]
        elif device == "cuda":
            raise InputError(f"device 'cuda' requested but onnxruntime has no CUDA provider "
                             f"(available: {', '.join(available)})", path)
        else:
            providers = ["CPUExecutionProvider"]
    else:
        raise InputError(f"unknown device {device!r} for the onnx matcher (auto, cpu or cuda)")
    from staticdepth.onnx_session import onnx_session
    return onnx_session(path, providers, threads=threads)


def _static_hw(shape, layout: str) -> tuple[int, int] | None:
    """(height, width) of an input shape when both are fixed numbers, else None."""
    dims = list(shape)
    if len(dims) == 3:
        dims = [1] + dims
    if len(dims) != 4:
        return None
    h, w = (dims[2], dims[3]) if layout == "nchw" else (dims[1], dims[2])
    return (h, w) if isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0 else None


def default_contract(input_names) -> str:
    """The contract guessed from a model's input names (used when none is given)."""
    c = CONTRACTS["crestereo-combined"]
    if {c.left_input, c.right_input, c.coarse_left_input, c.coarse_right_input} <= set(input_names):
        return "crestereo-combined"
    if "flow_init" in input_names:
        return "crestereo-init-next"
    return "crestereo"


class OnnxMatcher:
    """An ONNX stereo network for one image size (see the module docstring)."""

    name = "onnx"

    def __init__(self, *, num_disparities: int, image_size: tuple[int, int], dense: bool = False,
                 model: str | os.PathLike | None = None, contract: Any = None,
                 init_model: str | os.PathLike | None = None, lr_check: bool = False,
                 lr_px: float = 1.0, device: str = "auto", threads: int = 0, **overrides: Any):
        if model is None:
            raise InputError("the onnx matcher needs a model file (options.model / --model)")
        unknown = sorted(set(overrides) - _CONTRACT_FIELDS)
        if unknown:
            raise InputError(f"unknown onnx matcher option(s) {unknown} (known: model, contract, "
                             f"init_model, lr_check, lr_px, device, threads, and the contract "
                             f"fields {sorted(_CONTRACT_FIELDS)})")
        if num_disparities <= 0:
            raise InputError(f"number of disparities must be positive, got {num_disparities}")
        self.model_path = os.fspath(model)
        self.session = _session(self.model_path, device, threads)
        inputs = {i.name: i.shape for i in self.session.get_inputs()}
        spec = contract if contract not in (None, "") else default_contract(inputs)
        self.contract = c = load_contract(spec, overrides)
        self.num_disparities = int(num_disparities)
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.dense, self.lr_check, self.lr_px = bool(dense), bool(lr_check), float(lr_px)
        if self.lr_check and not c.lr_flip:
            raise InputError(f"contract {c.name!r} does not allow the flipped left-right check")
        self.init_session, self.init_model_path = None, None
        if c.flow_init_input:
            if init_model is None:
                raise InputError(f"contract {c.name!r} needs the coarse 'init' model too "
                                 f"(options.init_model / --set init_model=FILE)", self.model_path)
            self.init_model_path = os.fspath(init_model)
            self.init_session = _session(self.init_model_path, device, threads)
            self._check_inputs(self.init_session, self.init_model_path, c.image_inputs())
        elif init_model is not None:
            raise InputError(f"contract {c.name!r} takes no init_model")
        needed = c.image_inputs() + tuple(n for n in (c.coarse_left_input, c.coarse_right_input,
                                                      c.flow_init_input) if n)
        self._check_inputs(self.session, self.model_path, needed)
        outputs = [o.name for o in self.session.get_outputs()]
        if c.output:
            if c.output not in outputs:
                raise InputError(f"contract {c.name!r} reads the output {c.output!r} but the model "
                                 f"has {outputs}", self.model_path)
            self._output = c.output
        else:
            if not -len(outputs) <= c.output_index < len(outputs):
                raise InputError(f"contract {c.name!r} reads output number {c.output_index} but "
                                 f"the model has {len(outputs)}", self.model_path)
            self._output = outputs[c.output_index]
        # sizes: fixed (contract, else the model's static shape) or padded to a multiple
        fixed = tuple(c.input_size[::-1]) if all(c.input_size) else \
            _static_hw(inputs[c.image_inputs()[0]], c.layout)
        w, h = self.image_size
        if fixed is not None:
            self.net_hw = (int(fixed[0]), int(fixed[1]))
            self.resize = self.net_hw != (h, w)
        else:
            m = c.pad_multiple * (2 if c.two_stage else 1)
            self.net_hw = (h + (-h) % m, w + (-w) % m)
            self.resize = False
        self.coarse_hw = self._coarse_hw(inputs)
        self._sha256: str | None = None

    # -- set-up helpers -------------------------------------------------------------------------

    def _check_inputs(self, session, path: str, needed) -> None:
        names = [i.name for i in session.get_inputs()]
        missing = [n for n in needed if n not in names]
        if missing:
            raise InputError(f"contract {self.contract.name!r} feeds the input(s) {missing} but "
                             f"the model's inputs are {names} (choose another --contract or "
                             f"override the names with --set)", path)
        extra = [n for n in names if n not in needed]
        if extra:
            raise InputError(f"the model has input(s) {extra} that contract "
                             f"{self.contract.name!r} does not feed (its inputs: {names})", path)

    def _coarse_hw(self, inputs) -> tuple[int, int] | None:
        c = self.contract
        if not c.two_stage:
            return None
        if c.coarse_left_input:
            static = _static_hw(inputs[c.coarse_left_input], c.layout)
        else:
            static = _static_hw(self.init_session.get_inputs()[0].shape, c.layout)
        return static or (self.net_hw[0] // 2, self.net_hw[1] // 2)

    def params(self) -> dict[str, Any]:
        if self._sha256 is None:
            with open(self.model_path, "rb") as f:
                self._sha256 = hashlib.file_digest(f, "sha256").hexdigest()
        return {"matcher": self.name, "model": os.path.basename(self.model_path),
                "model_sha256": self._sha256, "init_model": self.init_model_path,
                "contract": self.contract.to_dict(), "num_disparities": self.num_disparities,
                "net_size": [self.net_hw[1], self.net_hw[0]], "lr_check": self.lr_check,
                "lr_px": self.lr_px, "dense": self.dense,
                "providers": self.session.get_providers()}

    # -- per frame ------------------------------------------------------------------------------

    def tensor(self, img_rgb: np.ndarray) -> np.ndarray:
        """One uint8 RGB image (H, W, 3), already at the network size -> its input tensor."""
        c = self.contract
        if c.color == "gray":
            x = cv2.cvtColor(img_rgb, cv2.COLOR_RGB2GRAY)[..., None].astype(np.float32)
        else:
            x = (img_rgb[..., ::-1] if c.color == "bgr" else img_rgb).astype(np.float32)
        if c.scale == "0-1":
            x *= np.float32(1 / 255)
        elif c.scale == "imagenet":
            mean, std = np.array(IMAGENET_MEAN_RGB), np.array(IMAGENET_STD_RGB)
            if c.color == "bgr":
                mean, std = mean[::-1], std[::-1]
            elif c.color == "gray":
                mean, std = mean.mean(keepdims=True), std.mean(keepdims=True)
            x = (x * np.float32(1 / 255) - mean.astype(np.float32)) / std.astype(np.float32)
        if c.layout == "nchw":
            x = x.transpose(2, 0, 1)
        if c.batch:
            x = x[None]
        return np.ascontiguousarray(x, dtype=np.float32)

    def _fit(self, img: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
        """An image brought to the network size (h, w): resized, or padded right/bottom."""
        h, w = img.shape[:2]
        if (h, w) == hw:
            return img
        if self.resize or hw != self.net_hw:
            return cv2.resize(img, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR)
        return cv2.copyMakeBorder(img, 0, hw[0] - h, 0, hw[1] - w, cv2.BORDER_REPLICATE)

    def _feeds(self, left: np.ndarray, right: np.ndarray, names: tuple[str, ...]) -> dict:
        c = self.contract
        if c.stacked_input:
            axis = (1 if c.batch else 0) if c.layout == "nchw" else -1
            return {c.stacked_input: np.concatenate([self.tensor(left), self.tensor(right)], axis)}
        return {names[0]: self.tensor(left), names[1]: self.tensor(right)}

    def _disparity(self, out: np.ndarray, hw: tuple[int, int], path: str) -> np.ndarray:
        """The disparity plane (h, w) of a raw output tensor."""
        c = self.contract
        a = np.asarray(out, dtype=np.float32)
        shape = a.shape
        if c.batch and a.ndim >= 3:
            a = a[0]
        if a.ndim == 3:
            axis = 0 if c.layout == "nchw" else 2
            if not 0 <= c.channel < a.shape[axis]:
                raise InputError(f"contract reads channel {c.channel} but the output has shape "
                                 f"{shape}", path)
            a = a[c.channel] if axis == 0 else a[..., c.channel]
        if a.shape != hw:
            raise InputError(f"output {self._output!r} has shape {shape}, expected a disparity of "
                             f"{hw[1]}x{hw[0]} (the input size)", path)
        return a if c.sign > 0 else -a

    def _run(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Left disparity (H, W) float32 for an RGB pair of the matcher's size, before checks."""
        c = self.contract
        h, w = left.shape[:2]
        L, R = self._fit(left, self.net_hw), self._fit(right, self.net_hw)
        feeds = self._feeds(L, R, (c.left_input, c.right_input))
        if c.two_stage:
            Lc, Rc = self._fit(L, self.coarse_hw), self._fit(R, self.coarse_hw)
            coarse = self._feeds(Lc, Rc, (c.left_input, c.right_input) if c.flow_init_input
                                 else (c.coarse_left_input, c.coarse_right_input))
            if c.flow_init_input:
                feeds[c.flow_init_input] = self._flow_init(self.init_session.run(None, coarse)[0])
            else:
                feeds.update(coarse)
        out = self.session.run([self._output], feeds)[0]
        d = self._disparity(out, self.net_hw, self.model_path)
        if self.resize:
            d = cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR)
            d *= np.float32(w / self.net_hw[1])
        else:
            d = d[:h, :w]
        return np.ascontiguousarray(d, dtype=np.float32)

    def _flow_init(self, coarse: np.ndarray) -> np.ndarray:
        """The coarse output (N, C, h, w) resized to the flow_init input, values times the ratio."""
        c = self.contract
        shape = next(i.shape for i in self.session.get_inputs() if i.name == c.flow_init_input)
        target = _static_hw(shape, "nchw") or (int(round(self.net_hw[0] * c.flow_init_scale)),
                                               int(round(self.net_hw[1] * c.flow_init_scale)))
        coarse = np.asarray(coarse, dtype=np.float32)
        if coarse.shape[-2:] == target:
            return coarse
        ratio = np.float32(target[1] / coarse.shape[-1])
        out = np.empty(coarse.shape[:2] + target, np.float32)
        for n in range(coarse.shape[0]):
            for k in range(coarse.shape[1]):
                out[n, k] = cv2.resize(coarse[n, k], target[::-1],
                                       interpolation=cv2.INTER_LINEAR) * ratio
        return out

    def match(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> MatchOutput:
        if left_rgb.shape[:2][::-1] != self.image_size or right_rgb.shape != left_rgb.shape:
            raise InputError(f"matcher built for {self.image_size[0]}x{self.image_size[1]} images, "
                             f"got {left_rgb.shape[1]}x{left_rgb.shape[0]} and "
                             f"{right_rgb.shape[1]}x{right_rgb.shape[0]}")
        d = self._run(left_rgb, right_rgb)
        in_range = np.isfinite(d) & (d > 0) & (d <= self.num_disparities)
        valid = in_range
        if self.lr_check:
            d_right = self._run(np.ascontiguousarray(right_rgb[:, ::-1]),
                                np.ascontiguousarray(left_rgb[:, ::-1]))[:, ::-1]
            valid = in_range & lr_consistent(d, d_right, self.lr_px)
        disp = np.where(in_range if self.dense else valid, d, np.float32(np.nan))
        return MatchOutput(disp.astype(np.float32, copy=False), valid)
