"""The adaptation's one configuration: a tree of the stages' own config dataclasses.

Every leaf is reachable as a dotted key (``--set tracking.min_height_px=8``, recipes
``set: {finetune.epochs: 3}``); :func:`staticdepth.config.format_config` prints the tree
(``staticdepth adapt --print-config``). :func:`stage_hashes` names each stage's output by the
settings it depends on, its upstream stages' hashes included, so changing a late setting reruns
only the stages after it.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping

from staticdepth.config import config_hash, from_dict
from staticdepth.errors import InputError
from staticdepth.finetune import PRESETS as FINETUNE_PRESETS
from staticdepth.finetune import FinetuneConfig
from staticdepth.geometry.agent_plane import AgentPlaneConfig
from staticdepth.geometry.camera import check_camera_height
from staticdepth.pseudo_labels import PseudoLabelConfig
from staticdepth.tracking import TrackingConfig

DETECTORS = ("motion", "yolox", "mask2former", "gt")


@dataclass(frozen=True)
class PredictConfig:
    batch_size: int = 4          # frames per forward pass (does not enter the stage hash)
    eps: float = 1e-6            # relative depth = 1 / max(D, eps)

    def __post_init__(self):
        if self.batch_size < 1 or not self.eps > 0:
            raise InputError(f"predict: need batch_size >= 1 and eps > 0 (got {self.batch_size}, "
                             f"{self.eps})")


@dataclass(frozen=True)
class DetectorConfig:
    name: str = "motion"         # motion | yolox | mask2former | gt (the sequence's instances)
    model: str = ""              # weights of yolox (.onnx) / mask2former (folder)

    def __post_init__(self):
        if self.name not in DETECTORS:
            raise InputError(f"unknown detector {self.name!r} (one of {', '.join(DETECTORS)})")


HIDDEN_CONTACTS = ("top", "lowest")


@dataclass(frozen=True)
class AlignConfig:
    erode_px: float | None = None    # ground mask: the feet's hull eroded by this (None: W/80)
    agents_at_contact: bool = True   # agents take the plane depth at their contact pixel
    #                                  (False: the paper's Eq. 2 for every pixel)
    mode: str = "upright"            # upright: ground, then structures re-anchored at their
    #                                  contact with it (geometry/alignment_upright.py); ground:
    #                                  align what the plane explains (the ground, pixels near
    #                                  it, agents), scale and shift the rest in inverse depth
    #                                  (alignment.align_ground); eq2: the paper's Eq. 2
    snap_rel: float = 0.1            # ground: pixels this close to the plane (relative) take it
    shape: str = "network"           # upright: network (its shape, scaled at the contact) or
    #                                  vertical (the vertical line through the contact)
    jump_rel: float = 0.08           # upright: a relative depth step this large ends a structure
    recede_min: float = 0.1          # upright: pixels whose depth recedes up the image this
    recede_max: float = 8.0          # fast relative to the plane's are ground (0 and 0: off)
    fill: bool = False               # upright: runs without a contact take a row neighbour's
    #                                  ratio (off: they keep the ground mode)
    max_pull: float | None = 1.1     # upright: a run pulled nearer than its ground-mode depth
    #                                  / max_pull keeps the ground mode (null: no limit; a
    #                                  traced contact is never behind the structure's foot)
    contact_range: float | None = 2.0    # upright: contacts beyond this x the farthest ground
    #                                  mask depth keep the ground mode (null: no limit)
    recede_push: float | None = 2.0  # upright: a receding pixel takes the plane only if that is
    #                                  at most this x its ground-mode depth (null: no limit)
    walked_ratio: float | None = 1.2     # upright: inside the walked region (the ground mask)
    #                                  a pixel farther than this x its contact's plane depth
    #                                  is ground, not a structure (null: off)
    occlude: bool = True             # upright: runs stop at the frame's agents (the foot behind
    #                                  an agent is hidden) and take a row neighbour's ratio
    step_occlude: bool = False       # upright: runs that end at a depth step down to a nearer
    #                                  pixel (its foot hidden by what stands in front) take a
    #                                  row neighbour's ratio too (no agent mask: exportable);
    #                                  off: neutral on i1-i4 / h1-h3 (issue 19, tenth round)
    colour_foot: bool = True         # upright: a traced pixel whose colour run down the vertical
    #                                  (the adaptation frames' median image) goes on below its
    #                                  contact, and is not a colour common on the walked ground
    #                                  (16 levels per channel: alignment_upright.FOOT_LEVELS),
    #                                  stands on the vertical through the run's foot (align
    #                                  outputs, `align --sequence` and export-model; not the
    #                                  pseudo labels; issue 19, eleventh round, docs/gains.md)
    plane_bound: bool = True         # upright: no pixel below the agents' horizon farther than
    #                                  the plane along its ray (align outputs, the align command,
    #                                  export-model; not the pseudo labels)
    hidden_contact: str = "top"      # agents_at_contact, people whose mask ends on another
    #                                  agent or the image's bottom: "top" = the contact from
    #                                  their top and fitted height (geometry/agent_contact.py),
    #                                  "lowest" = the plane at their lowest pixel
    min_ground_r2: float = 0.2       # a prediction whose inverse depth over the walked ground
    #                                  the agents' plane explains less than this (R^2, median
    #                                  of 8 adaptation frames) does not see the ground: its
    #                                  aligned output is the plane's depth with the agents at
    #                                  their contact, no network (0: never; issue 19)

    @property
    def uses_image(self) -> bool:
        """Whether this alignment reads the static scene's image (the colour foot, upright)."""
        return self.colour_foot and self.mode == "upright"

    def __post_init__(self):
        from staticdepth.geometry.alignment import ALIGN_MODES

        if self.mode not in ALIGN_MODES:
            raise InputError(f"align.mode must be one of {ALIGN_MODES}, got {self.mode!r}")
        if not (math.isfinite(self.snap_rel) and self.snap_rel >= 0):
            raise InputError(f"align.snap_rel must be >= 0, got {self.snap_rel}")
        from staticdepth.geometry.alignment_upright import SHAPES

        if self.shape not in SHAPES:
            raise InputError(f"align.shape must be one of {SHAPES}, got {self.shape!r}")
        if not (math.isfinite(self.jump_rel) and self.jump_rel > 0):
            raise InputError(f"align.jump_rel must be > 0, got {self.jump_rel}")
        if not (0 <= self.recede_min <= self.recede_max and math.isfinite(self.recede_max)):
            raise InputError(f"align.recede_min/recede_max must satisfy 0 <= min <= max, got "
                             f"{self.recede_min}, {self.recede_max}")
        if self.max_pull is not None and not (math.isfinite(self.max_pull)
                                                and self.max_pull >= 1):
            raise InputError(f"align.max_pull must be >= 1 or null, got {self.max_pull}")
        if self.recede_push is not None and not (math.isfinite(self.recede_push)
                                                 and self.recede_push >= 1):
            raise InputError(f"align.recede_push must be >= 1 or null, got {self.recede_push}")
        if self.walked_ratio is not None and not (math.isfinite(self.walked_ratio)
                                                  and self.walked_ratio >= 1):
            raise InputError(f"align.walked_ratio must be >= 1 or null, got {self.walked_ratio}")
        if not (math.isfinite(self.min_ground_r2) and 0 <= self.min_ground_r2 < 1):
            raise InputError(f"align.min_ground_r2 must be in [0, 1), got {self.min_ground_r2}")
        if self.hidden_contact not in HIDDEN_CONTACTS:
            raise InputError(f"align.hidden_contact must be one of {HIDDEN_CONTACTS}, got "
                             f"{self.hidden_contact!r}")
        if self.contact_range is not None and not (math.isfinite(self.contact_range)
                                                   and self.contact_range > 0):
            raise InputError(f"align.contact_range must be > 0 or null, got {self.contact_range}")
        if self.erode_px is not None and not (math.isfinite(self.erode_px) and self.erode_px >= 0):
            raise InputError(f"align.erode_px must be >= 0, got {self.erode_px}")


@dataclass(frozen=True)
class ScaleConfig:
    camera_height_m: float | None = None   # None: the sequence's, else from the agents
    agent_height_m: float | None = None    # from the agents: None = per-class height
                                           # distributions; a number = one fixed agent height
    metric_scale: str = "plane"            # plane: x H_c; anchor: METHOD.md 5's anchor pixel
    sequence_height: bool = True           # false: ignore the sequence's stored height (the
                                           # agents give it, as on a site without one)
    max_rel_error: float = 0.15            # refuse the metric outputs when the plane's and the
                                           # height's uncertainty give a larger relative depth
                                           # error over the agents' feet (inf: never refuse)

    def __post_init__(self):
        if self.metric_scale not in ("plane", "anchor"):
            raise InputError(f"metric_scale must be plane or anchor, got {self.metric_scale!r}")
        if self.camera_height_m is not None:
            check_camera_height(self.camera_height_m, "scale.camera_height_m")
        if not self.max_rel_error > 0:
            raise InputError(f"scale.max_rel_error must be > 0, got {self.max_rel_error}")
        a = self.agent_height_m
        if a is not None and not (math.isfinite(a) and a > 0):
            raise InputError(f"agent height must be positive, got {self.agent_height_m}")


@dataclass(frozen=True)
class AdaptConfig:
    model: str = "builtin"       # builtin[:PATH.pt] | hf:DIR | onnx:FILE | torch:FILE
    predict: PredictConfig = field(default_factory=PredictConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracking: TrackingConfig = field(default_factory=lambda: TrackingConfig(drop_collinear=False))
    plane: AgentPlaneConfig = field(default_factory=AgentPlaneConfig)
    pseudo_labels: PseudoLabelConfig = field(default_factory=PseudoLabelConfig)
    finetune: FinetuneConfig = field(default_factory=lambda: FINETUNE_PRESETS["builtin"])
    align: AlignConfig = field(default_factory=AlignConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)


def is_builtin(model: str) -> bool:
    return str(model).split(":", 1)[0] == "builtin"


def build_config(settings: Mapping[str, Any], source: str | None = None) -> AdaptConfig:
    """AdaptConfig from dotted settings over the defaults. The fine-tuning preset follows the
    model: ``builtin`` (Adam 3e-4) for the built-in network, ``paper`` (1e-5) for the others,
    unless ``finetune.lr`` is given."""
    settings = dict(settings)
    model = str(settings.get("model", AdaptConfig.model))
    preset = FINETUNE_PRESETS["builtin" if is_builtin(model) else "paper"]
    base = AdaptConfig(model=model, finetune=preset)
    return from_dict(AdaptConfig, settings, base=base, source=source)


def model_identity(spec: str) -> dict[str, Any]:
    """The model spec and its weights' size and modification time (a new file is a new model)."""
    from staticdepth.models.registry import parse_spec

    _, loc = parse_spec(spec)
    out: dict[str, Any] = {"spec": spec}
    paths = [loc] if os.path.isfile(loc) else (
        sorted(os.path.join(d, f) for d, _, fs in os.walk(loc) for f in fs)
        if os.path.isdir(loc) else [])
    out["files"] = [[os.path.relpath(p, loc) if p != loc else "", os.path.getsize(p),
                     os.stat(p).st_mtime_ns] for p in paths]
    return out


# The version of each stage's method: raised whenever a code change alters what a stage writes
# for the same settings, so that outputs an older version wrote are computed again instead of
# being reused (the stage hashes name outputs by settings; without this an upgrade would
# silently keep, e.g., the former pseudo labels). Raising one reruns that stage and the stages
# after it, as a changed setting does.
STAGE_VERSIONS = {"base": 1, "agents": 3, "ground_plane": 12, "pseudo_labels": 9, "finetune": 2,
                  "align": 12, "scale": 1}


def _versioned(stage: str, settings: dict) -> str:
    return config_hash({**settings, "version": STAGE_VERSIONS[stage]})


def stage_hashes(conf: AdaptConfig, model_id: Mapping[str, Any] | None = None) -> dict[str, str]:
    """Hash of each stage's output: its own settings, its inputs' hashes and its method's
    version (:data:`STAGE_VERSIONS`)."""
    mid = model_id if model_id is not None else {"spec": conf.model}
    h: dict[str, str] = {}
    h["base"] = _versioned("base", {"model": mid, "eps": conf.predict.eps})
    h["agents"] = _versioned("agents", {"detector": conf.detector})
    h["ground_plane"] = _versioned("ground_plane", {
        "tracking": conf.tracking, "plane": conf.plane, "agents": h["agents"],
        # a known camera height enters the fit (ground_plane.plane_config)
        "known_height": (conf.scale.camera_height_m, conf.scale.sequence_height)})
    labels: dict[str, Any] = {"conf": conf.pseudo_labels, "base": h["base"], "agents": h["agents"]}
    if conf.pseudo_labels.source == "plane":  # labels read from the plane over the feet's region
        labels.update(plane=h["ground_plane"], erode_px=conf.align.erode_px)
    elif conf.pseudo_labels.source == "aligned":   # labels are the base's alignment
        labels.update(plane=h["ground_plane"], align=conf.align)
    h["pseudo_labels"] = _versioned("pseudo_labels", labels)
    if conf.finetune.epochs > 0:
        h["finetune"] = _versioned("finetune", {"conf": conf.finetune,
                                                "labels": h["pseudo_labels"], "model": mid})
        h["ft"] = config_hash({"finetune": h["finetune"], "eps": conf.predict.eps})
    else:
        h["finetune"] = config_hash({"epochs": 0})
        h["ft"] = config_hash({"copy_of": h["base"]})
    h["align"] = _versioned("align", {"conf": conf.align, "pl": conf.pseudo_labels,
                                      "base": h["base"], "ft": h["ft"],
                                      "plane": h["ground_plane"], "agents": h["agents"]})
    h["scale"] = _versioned("scale", {"conf": conf.scale, "align": h["align"],
                                      "plane": h["ground_plane"]})
    return h
