"""Hugging Face ``transformers`` depth models (DPT, Depth Anything V2), local files only.

``load_hf(source)`` takes a directory written by ``save_pretrained`` (``config.json`` and
weights) or a hub id already in the local Hugging Face cache; nothing is ever downloaded
(``local_files_only=True``). The image preprocessing is our own numpy/torch code reading the
model's ``preprocessor_config.json`` (size, ``keep_aspect_ratio``, ``ensure_multiple_of``, mean,
std) so that torchvision is not needed; without that file the defaults of the model family apply:
DPT 384x384 (aspect not kept, as ``Intel/dpt-large``'s processor), Depth Anything 518 with the
aspect kept and sides a multiple of 14.
"""
from __future__ import annotations

import json
import os
import re

from staticdepth.errors import InputError
from staticdepth.models.base import HALF_MEAN, HALF_STD, IMAGENET_MEAN, IMAGENET_STD, Resize, TorchDepthModel

# Decoder = DPT's neck (reassemble + fusion) and head; head = the depth head only.
LAYER_GROUPS = {"head": ["head"], "decoder": ["neck", "head"]}
FAMILY_DEFAULTS = {
    "dpt": {"size": (384, 384), "keep_aspect_ratio": False, "multiple": 1,
            "mean": HALF_MEAN, "std": HALF_STD},
    "depth_anything": {"size": (518, 518), "keep_aspect_ratio": True, "multiple": 14,
                       "mean": IMAGENET_MEAN, "std": IMAGENET_STD},
}
HOW_TO_PROVIDE = ("give a directory holding config.json and the weights (save_pretrained), or "
                  "pre-populate the Hugging Face cache on a connected machine "
                  "(`huggingface-cli download ID`) and copy it here; nothing is downloaded")


def _cache_dir() -> str:
    try:
        from huggingface_hub import constants
        return str(constants.HF_HUB_CACHE)
    except Exception:  # pragma: no cover - huggingface_hub ships with transformers
        return os.path.join(os.path.expanduser("~"), ".cache", "huggingface", "hub")


def _size_of(value) -> tuple[int, int] | None:
    if value is None:
        return None
    if isinstance(value, int):
        return value, value
    if isinstance(value, dict):
        if "height" in value and "width" in value:
            return int(value["height"]), int(value["width"])
        if "shortest_edge" in value:
            return int(value["shortest_edge"]), int(value["shortest_edge"])
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return int(value[0]), int(value[1])
    raise InputError(f"unsupported preprocessor size {value!r}")


def preprocessing_from(config_dir: str | None, model_type: str) -> tuple[Resize, tuple, tuple]:
    """(resize, mean, std) from ``preprocessor_config.json`` in ``config_dir`` or the defaults."""
    fam = FAMILY_DEFAULTS["depth_anything" if "depth_anything" in model_type else "dpt"]
    pp = {}
    path = os.path.join(config_dir, "preprocessor_config.json") if config_dir else None
    if path and os.path.isfile(path):
        try:
            with open(path) as f:
                pp = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(f"unreadable preprocessor config ({e})", path) from None
    h, w = _size_of(pp.get("size")) or fam["size"]
    resize = Resize(h, w, keep_aspect_ratio=bool(pp.get("keep_aspect_ratio", fam["keep_aspect_ratio"])),
                    multiple=int(pp.get("ensure_multiple_of") or fam["multiple"]))
    mean = tuple(pp.get("image_mean") or fam["mean"])
    std = tuple(pp.get("image_std") or fam["std"])
    return resize, mean, std


def load_hf(source: str | os.PathLike) -> TorchDepthModel:
    """Load a DPT / Depth Anything model for depth estimation from local files (CPU)."""
    try:
        import transformers  # noqa: F401
    except ImportError:
        raise InputError("hf: models need the optional dependency transformers "
                         "(pip install 'staticdepth[hf]')") from None
    from transformers import AutoConfig, AutoModelForDepthEstimation
    from transformers.utils import cached_file

    source = os.fspath(source)
    is_dir = os.path.isdir(source)
    where = (f"directory {source}" if is_dir
             else f"the Hugging Face cache {_cache_dir()} (hub id {source!r}, offline)")
    if not is_dir and (not re.fullmatch(r"[\w.-]+(/[\w.-]+)?", source) or source.startswith(".")):
        raise InputError(f"model directory not found; {HOW_TO_PROVIDE}", source)
    try:
        config = AutoConfig.from_pretrained(source, local_files_only=True)
        net = AutoModelForDepthEstimation.from_pretrained(source, local_files_only=True)
    except (OSError, ValueError, EnvironmentError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"no local depth model found in {where} ({first}); {HOW_TO_PROVIDE}") from None
    config_dir = source if is_dir else None
    if not is_dir:
        try:
            cfg_file = cached_file(source, "preprocessor_config.json", local_files_only=True,
                                   _raise_exceptions_for_missing_entries=False)
            config_dir = os.path.dirname(cfg_file) if cfg_file else None
        except OSError:
            config_dir = None
    resize, mean, std = preprocessing_from(config_dir, config.model_type)
    return TorchDepthModel(net.eval(), name=f"hf:{source}", resize=resize, mean=mean, std=std,
                           layer_groups=LAYER_GROUPS, output="predicted_depth",
                           input_kw="pixel_values")
