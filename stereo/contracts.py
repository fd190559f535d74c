"""How an ONNX stereo network wants its inputs and gives its disparity: the *contract*.

A contract is a frozen record of everything the ``onnx`` matcher needs to know about one export:
input names (two images, or one tensor with both stacked along the channels), colour order, value
scale, layout, padding or fixed input size, where the disparity sits in the output and its sign,
and an optional coarse-to-fine (two-stage) scheme. Contracts are chosen by name (``CONTRACTS``) or
read from a JSON file whose keys are the field names below (unknown keys are an error).

What the shipped contracts are based on (checked against the public export and inference code):

- ``crestereo`` / ``crestereo-init-next`` / ``crestereo-combined``: megvii-research/CREStereo
  ``test.py`` and ``dataset.py`` feed ``cv2.imread`` images, i.e. **BGR**, 0-255 float32 NCHW (the
  network normalises to [-1, 1] itself); the coarse pass runs at half resolution without
  ``flow_init``, the fine pass at full resolution with ``flow_init`` = the coarse output *at half
  resolution* (the network rescales it: ``flow = -scale * interpolate(flow_init)``), and the
  disparity is channel 0 of the (N, 2, H, W) output, positive (``flow_up = -convex_upsample(..)``).
  ibaiGorordo/CREStereo-Pytorch ``convert_to_onnx.py`` names the inputs ``left``, ``right``,
  ``flow_init`` and the output ``output``; PINTO_model_zoo 284_CREStereo ``onnx_merge.py`` merges
  an ``init`` and a ``next`` export with prefixes, giving inputs ``init_left``, ``init_right``,
  ``next_left``, ``next_right`` and the output ``next_output``; those exports have a fixed input
  size (e.g. 480x640), which the matcher reads from the model. (ibaiGorordo's ONNX demo converts to
  RGB before feeding; the original code does not, so the contract says BGR: ``--set color=rgb``
  switches.)
- ``hitnet`` (ETH3D model) / ``hitnet-rgb`` (Middlebury, FlyingThings): ibaiGorordo
  ONNX-HITNET-Stereo-Depth-estimation feeds one NCHW tensor with left and right stacked along the
  channels (2 grey channels, or 6 RGB), values 0-1, fixed input size; output = positive disparity.
  The input's name is not fixed by those exports (the demo takes ``get_inputs()[0]``): ``input`` is
  assumed, override with ``--set stacked_input=NAME`` (the error lists the model's names).
- ``raft-stereo``: princeton-vl/RAFT-Stereo ``demo.py``: RGB 0-255 NCHW, padded to a multiple of 32,
  ``test_mode`` returns (low-res flow, ``flow_up``); ``flow_up`` (N, 1, H, W) is the x-flow, so
  disparity = ``-flow_up`` (the demo plots ``-flow_up``): last output, channel 0, sign -1.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import Any, Mapping

from staticdepth.config import from_dict
from staticdepth.errors import InputError
from staticdepth.geometry.camera import read_json

COLORS = ("rgb", "bgr", "gray")
SCALES = ("0-1", "0-255", "imagenet")
LAYOUTS = ("nchw", "nhwc")
IMAGENET_MEAN_RGB = (0.485, 0.456, 0.406)
IMAGENET_STD_RGB = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class Contract:
    """The input/output convention of one ONNX stereo export (see the module docstring).

    Inputs: ``left_input``/``right_input`` are two image tensors, unless ``stacked_input`` names one
    tensor with the left channels followed by the right channels. ``input_size`` = (width, height)
    resizes to a fixed size (disparity rescaled by the width ratio); (0, 0) reads a static size from
    the model and otherwise pads right/bottom to ``pad_multiple`` (cropped after).
    Output: ``output`` (a name) or else output number ``output_index``; disparity =
    ``sign * out[channel]`` with ``out`` in ``layout`` (a missing channel axis is fine).
    Two stages: ``coarse_left_input``/``coarse_right_input`` name half-resolution inputs of the same
    graph (merged init+next model); ``flow_init_input`` names the flow input of a ``next`` model run
    after a separate ``init_model`` on the half-resolution pair, fed with the coarse output resized
    to ``flow_init_scale`` times the full input size, values multiplied by that resize's ratio.
    """

    name: str = "custom"
    left_input: str = "left"
    right_input: str = "right"
    stacked_input: str = ""
    color: str = "rgb"
    scale: str = "0-255"
    layout: str = "nchw"
    batch: bool = True
    pad_multiple: int = 1
    input_size: tuple[int, int] = (0, 0)
    output: str = ""
    output_index: int = 0
    channel: int = 0
    sign: float = 1.0
    coarse_left_input: str = ""
    coarse_right_input: str = ""
    flow_init_input: str = ""
    flow_init_scale: float = 0.5
    lr_flip: bool = True            # the net may be run on the mirrored, swapped pair (lr_check)

    def __post_init__(self):
        for key, value, allowed in (("color", self.color, COLORS), ("scale", self.scale, SCALES),
                                    ("layout", self.layout, LAYOUTS)):
            if value not in allowed:
                raise InputError(f"contract {self.name!r}: {key} must be one of {allowed}, "
                                 f"got {value!r}")
        if self.pad_multiple < 1:
            raise InputError(f"contract {self.name!r}: pad_multiple must be >= 1, "
                             f"got {self.pad_multiple}")
        if len(self.input_size) != 2 or min(self.input_size) < 0:
            raise InputError(f"contract {self.name!r}: input_size must be (width, height) >= 0, "
                             f"got {self.input_size}")
        if self.sign not in (1.0, -1.0):
            raise InputError(f"contract {self.name!r}: sign must be 1 or -1, got {self.sign}")
        if bool(self.coarse_left_input) != bool(self.coarse_right_input):
            raise InputError(f"contract {self.name!r}: give both coarse_left_input and "
                             f"coarse_right_input, or neither")
        if self.two_stage and self.stacked_input:
            raise InputError(f"contract {self.name!r}: two-stage contracts need separate "
                             f"left/right inputs")
        if self.two_stage and (self.layout != "nchw" or not self.batch):
            raise InputError(f"contract {self.name!r}: two-stage contracts must be NCHW with a "
                             f"batch axis")
        if self.coarse_left_input and self.flow_init_input:
            raise InputError(f"contract {self.name!r}: a merged model (coarse_*_input) takes no "
                             f"flow_init_input")
        if not self.flow_init_scale > 0:
            raise InputError(f"contract {self.name!r}: flow_init_scale must be positive")

    @property
    def two_stage(self) -> bool:
        return bool(self.coarse_left_input or self.flow_init_input)

    @property
    def channels(self) -> int:
        return 1 if self.color == "gray" else 3

    def image_inputs(self) -> tuple[str, ...]:
        """Names of the full-resolution image inputs the model must have."""
        return (self.stacked_input,) if self.stacked_input else (self.left_input, self.right_input)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["input_size"] = list(self.input_size)
        return d


_CRE = dict(color="bgr", scale="0-255", pad_multiple=32, output="", channel=0, sign=1.0)
CONTRACTS: dict[str, Contract] = {
    # one pass, inputs left/right (an ``init`` export or any two-input CREStereo export)
    "crestereo": Contract(name="crestereo", **_CRE),
    # model = the ``next`` export (left, right, flow_init), options.init_model = the ``init`` export
    "crestereo-init-next": Contract(name="crestereo-init-next", flow_init_input="flow_init",
                                    **_CRE),
    # PINTO's merged init+next model
    "crestereo-combined": Contract(name="crestereo-combined", left_input="next_left",
                                   right_input="next_right", coarse_left_input="init_left",
                                   coarse_right_input="init_right", **_CRE),
    "hitnet": Contract(name="hitnet", stacked_input="input", color="gray", scale="0-1",
                       pad_multiple=32),
    "hitnet-rgb": Contract(name="hitnet-rgb", stacked_input="input", color="rgb", scale="0-1",
                           pad_multiple=32),
    "raft-stereo": Contract(name="raft-stereo", color="rgb", scale="0-255", pad_multiple=32,
                            output_index=-1, channel=0, sign=-1.0),
}


def contract_names() -> list[str]:
    return sorted(CONTRACTS)


def load_contract(spec: str | os.PathLike | Contract | Mapping[str, Any],
                  overrides: Mapping[str, Any] | None = None) -> Contract:
    """A contract by name, from a JSON file (field names as keys) or a dict; then overrides."""
    if isinstance(spec, Contract):
        base, source = spec, None
    elif isinstance(spec, Mapping):
        base, source = from_dict(Contract, spec, source="contract"), None
    else:
        spec = os.fspath(spec)
        if spec in CONTRACTS:
            base, source = CONTRACTS[spec], None
        elif spec.lower().endswith(".json") or os.path.sep in spec:
            values = read_json(spec)
            values.setdefault("name", os.path.splitext(os.path.basename(spec))[0])
            base, source = from_dict(Contract, values, source=spec), spec
        else:
            raise InputError(f"unknown ONNX contract {spec!r} (known: {', '.join(contract_names())}"
                             f"; or a JSON file)")
    if not overrides:
        return base
    return from_dict(Contract, overrides, base=base, source=source)
