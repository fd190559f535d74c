"""Stage: on-site adaptation of a depth network to one static camera (``staticdepth adapt``).

base prediction -> agents (a detector, or the sequence's own instances with ``detector="gt"``)
-> pseudo labels on the adaptation split -> fine-tuning -> ground plane from the agents ->
scene alignment -> metric scale from the camera height. Predictions written into the sequence
(``pred/<name>/depth``): ``base``, ``ft`` (relative depth 1 / max(D, eps), METHOD.md),
``align``, ``ft-align`` (aligned to the agents' plane with unit camera height: relative), and
``align-metric``, ``ft-align-metric`` (metres: the aligned maps are in units of the camera height,
so they are multiplied by H_c; ``metric_scale="anchor"`` uses the anchor pixel's scale of METHOD.md
section 5 instead, which equals H_c when the anchor lies on the predicted ground; the summary
reports both).
A JSON summary holds the plane, the scale, the fine-tuning history and the stage timings.
"""
from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from staticdepth.config import config_hash
from staticdepth.errors import InputError
from staticdepth.progress import progress

STAGES = ("base", "agents", "pseudo_labels", "finetune", "ground_plane", "align", "scale", "write")


@dataclass(frozen=True)
class AdaptConfig:
    model: str = "builtin"
    detector: str = "motion"              # motion | yolox | mask2former | gt
    detector_model: str = ""              # weights of yolox / mask2former
    camera_height_m: float | None = None  # None: the sequence's, else the 1.7 m agent prior
    epochs: int = 30
    lr: float | None = None               # None: 1e-4 for the built-in model, 1e-5 otherwise
    batch_size: int = 4
    layers: str = "decoder"
    loss: str = "ssi"
    flip: bool = True
    seed: int = 0
    contact: str = "lowest"               # pseudo-label contact: lowest | bottom_rows
    label_source: str = "prediction"      # agents' label: the network's own contact value (paper)
    #                                       or the agents' plane at the contact in its space ("plane")
    label_ground: bool = False            # "plane": label the ground pixels with the plane too
    plane_model: str = "exact"            # exact | affine | paper
    agent_height_m: float = 1.7           # prior, when no camera height is known
    min_height_px: float = 20.0           # tracking: smaller agents do not enter the plane fit
    drop_collinear: bool = False          # tracking: straight walkers still constrain the plane
    erode_px: float | None = None         # ground mask: feet hull eroded by this (None: W/80 px)
    eps: float = 1e-6                     # depth = 1 / max(D, eps)
    agents_at_contact: bool = True        # aligned agents take the plane depth at their contact
    #                                       (False: the paper's Eq. 2 for every pixel)
    align_mode: str = "ground"            # "ground": align what the plane explains, scale and
    #                                       shift the rest (alignment.align_ground); "eq2": paper
    align_snap_rel: float = 0.1           # "ground": pixels this close to the plane take its depth
    metric_scale: str = "plane"           # "plane": x H_c (aligned maps are in units of the
    #                                       camera height); "anchor": METHOD.md 5 anchor pixel

    def __post_init__(self):
        from staticdepth.geometry.alignment import ALIGN_MODES

        if self.align_mode not in ALIGN_MODES:
            raise InputError(f"align_mode must be one of {ALIGN_MODES}, got {self.align_mode!r}")
        from staticdepth.pseudo_labels import LABEL_SOURCES

        if self.label_source not in LABEL_SOURCES:
            raise InputError(f"label_source must be one of {LABEL_SOURCES}, got {self.label_source!r}")
        if self.metric_scale not in ("plane", "anchor"):
            raise InputError(f"metric_scale must be plane or anchor, got {self.metric_scale!r}")


def _finetune_conf(conf: AdaptConfig, is_builtin: bool):
    from staticdepth.finetune import FinetuneConfig

    lr = conf.lr if conf.lr is not None else (1e-4 if is_builtin else 1e-5)
    return FinetuneConfig(epochs=conf.epochs, lr=lr, batch_size=conf.batch_size, seed=conf.seed,
                          flip=conf.flip, loss=conf.loss, layers=conf.layers)


def predict_all(model, images: np.ndarray, desc: str) -> np.ndarray:
    """(N, H, W) float32 relative inverse depth of every frame."""
    return np.stack([model.predict(im) for im in progress(images, total=len(images), desc=desc)])


def detect_agents(conf: AdaptConfig, reader, images: np.ndarray
                  ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Instance maps (N, H, W) uint16 and per-frame AGENT_DTYPE rows."""
    if conf.detector == "gt":
        if not reader.has("instances"):
            raise InputError("--detector gt needs the sequence's 'instances' stream", reader.path)
        inst = np.stack([reader.instances(i) for i in range(len(reader))])
        return inst, [reader.agents(i) for i in range(len(reader))]
    from staticdepth.detectors import make_detector

    opts = {"model": conf.detector_model} if conf.detector in ("yolox", "mask2former") else {}
    det = make_detector(conf.detector, **opts)
    out = list(det.detect_sequence(list(images)))
    return np.stack([m for m, _ in out]), [r for _, r in out]


def fit_ground(conf: AdaptConfig, K: np.ndarray, instances: np.ndarray, rows: list[np.ndarray],
               adapt: range):
    """(plane, foot points (M, 2)) from the agents of the adaptation split."""
    from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
    from staticdepth import tracking

    tconf = tracking.TrackingConfig(min_height_px=conf.min_height_px,
                                    drop_collinear=conf.drop_collinear)
    # Instance maps always: ground-truth track ids are kept, and the occlusion test (feet or head
    # touching another instance: riders, people behind cars, umbrellas) needs the masks.
    obs = tracking.observations_from_instances([(instances[i], rows[i]) for i in adapt], tconf)
    if len(obs) < 3:
        raise InputError(f"only {len(obs)} usable agent observations in the adaptation split: "
                         "the ground plane needs tracked agents (check the detector)")
    plane = fit_agent_plane(K, obs, AgentPlaneConfig(model=conf.plane_model, seed=conf.seed))
    # The ground region covered by the agents' feet: every agent of the adaptation split (the plane
    # fit keeps only clean person tracks; the region where the predicted plane is fitted should
    # not shrink with that filter).
    feet = np.concatenate([np.stack([r["foot_u"], r["foot_v"]], 1) for r in
                           (rows[i][rows[i]["foot_v"] >= 0] for i in adapt) if len(r)])
    return plane, feet


def adapt(seq_path: str | os.PathLike, conf: AdaptConfig = AdaptConfig(), *, device=None,
          summary_path: str | os.PathLike | None = None, save_model: str | None = None,
          log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the whole adaptation on a sequence file; returns the summary (also written as JSON)."""
    import torch

    from staticdepth.dataset.h5 import SequenceReader, add_prediction
    from staticdepth.finetune import finetune
    from staticdepth.geometry.agent_plane import camera_height_from_prior
    from staticdepth.geometry.alignment import (agents_at_contact, align_depth, depth_from_inverse,
                                                 ground_mask_from_feet)
    from staticdepth.geometry.scale import scale_from_anchor, temporal_scale
    from staticdepth.models import TorchDepthModel, load_model
    from staticdepth.geometry.projection import ray_grid
    from staticdepth.pseudo_labels import PseudoLabelConfig, plane_pseudo_label, pseudo_label

    seq_path = os.fspath(seq_path)
    timings: dict[str, float] = {}
    clock = [time.perf_counter()]

    def lap(stage: str) -> None:
        now = time.perf_counter()
        timings[stage] = round(now - clock[0], 3)
        clock[0] = now
        log(f"{stage}: {timings[stage]:.1f} s")

    torch.manual_seed(conf.seed)
    with SequenceReader(seq_path) as r:
        n, H, W = len(r), r.height, r.width
        K = r.camera.K
        adapt_split = r.split("adapt")
        if len(adapt_split) == 0:
            raise InputError("the sequence has no adaptation split (adapt_frames = 0)", seq_path)
        images = np.stack([r.left(i) for i in range(n)])
        seq_height = r.meta.camera_height_m
        model = load_model(conf.model)
        if device is not None and isinstance(model, TorchDepthModel):
            model.to(device)
        D_base = predict_all(model, images, "base")
        lap("base")
        instances, rows = detect_agents(conf, r, images)
    lap("agents")

    plane, feet = fit_ground(conf, K, instances, rows, adapt_split)
    n_inlier_tracks = int(np.count_nonzero(plane.inliers))
    if n_inlier_tracks < 5 or not np.isfinite(plane.normal_std_deg):
        log(f"warning: the ground plane rests on {n_inlier_tracks} agent track(s) (uncertainty "
            f"{plane.normal_std_deg:.2f} deg): use more adaptation frames or a better detector")
    if conf.camera_height_m is not None:
        plane = plane.with_camera_height(conf.camera_height_m, "given")
    elif seq_height is not None:
        plane = plane.with_camera_height(seq_height, "sequence")
    else:
        plane = plane.with_camera_height(camera_height_from_prior(plane, conf.agent_height_m),
                                         f"agent height prior {conf.agent_height_m:g} m")
    ground = ground_mask_from_feet(feet, W, H, W / 80.0 if conf.erode_px is None else conf.erode_px)
    lap("ground_plane")

    pl_conf = PseudoLabelConfig(contact=conf.contact)
    plane_inv = (ray_grid(K, W, H) @ np.asarray(plane.normal)).astype(np.float32)
    labels = np.empty((len(adapt_split),) + (H, W), np.float32)
    n_agent_px = 0
    for k, i in enumerate(adapt_split):
        if conf.label_source == "plane":
            labels[k], m = plane_pseudo_label(D_base[i], instances[i], rows[i], plane_inv, ground,
                                              pl_conf, label_ground=conf.label_ground)
        else:
            labels[k], m = pseudo_label(D_base[i], instances[i], rows[i], pl_conf)
        n_agent_px += int(m.sum())
    lap("pseudo_labels")

    history: list[dict[str, float]] = []
    if conf.epochs > 0:
        if not isinstance(model, TorchDepthModel):
            raise InputError(f"model {conf.model!r} runs inference only (ONNX): fine-tuning needs "
                             "a torch model (builtin:, hf:, torch:) or --epochs 0")
        is_builtin = conf.model.startswith("builtin")
        ckpt = f"{seq_path}.adapt-{config_hash(conf)}.ckpt"
        history = finetune(model, images[adapt_split.start:adapt_split.stop], labels,
                           conf=_finetune_conf(conf, is_builtin), checkpoint=ckpt,
                           on_epoch=lambda rec: log(f"  epoch {rec['epoch']}: loss "
                                                    f"{rec['loss']:.5f} ({rec['seconds']:.1f} s, "
                                                    f"peak {rec['peak_memory_mb']:.0f} MiB)"))
        D_ft = predict_all(model, images, "ft")
        if save_model and is_builtin:
            from staticdepth.models.tiny import save_builtin
            model.to("cpu")
            save_builtin(save_model, model, info={"adapted_on": seq_path, "config": dataclasses.asdict(conf)})
        if os.path.exists(ckpt):
            os.remove(ckpt)
    else:
        D_ft = D_base
    lap("finetune")


    preds: dict[str, np.ndarray] = {"base": np.stack([depth_from_inverse(d, conf.eps) for d in D_base]),
                                    "ft": np.stack([depth_from_inverse(d, conf.eps) for d in D_ft])}
    # the frame's agents leave the ground mask, unless they would leave too little of it
    agent_masks = [m if np.count_nonzero(ground & ~m) >= 50 else None for m in instances > 0]
    for name, src in (("align", "base"), ("ft-align", "ft")):
        preds[name] = np.stack([align_depth(preds[src][i], K, plane.normal, 1.0, ground,
                                            agent_mask=agent_masks[i], mode=conf.align_mode,
                                            snap_rel=conf.align_snap_rel).depth
                                for i in range(n)])
        if conf.agents_at_contact:
            preds[name] = np.stack([agents_at_contact(preds[name][i], K, plane.normal, 1.0,
                                                      instances[i], rows[i], pl_conf)[0]
                                    for i in range(n)])
    lap("align")

    scales, anchor_scales = {}, {}
    for name in ("align", "ft-align"):
        per_frame = [scale_from_anchor(preds[name][i], K, plane.normal, plane.camera_height_m,
                                       agent_mask=instances[i] > 0) for i in range(n)]
        if not any(np.isfinite(a.scale) for a in per_frame):   # agents always on the anchor
            per_frame = [scale_from_anchor(preds[name][i], K, plane.normal,
                                           plane.camera_height_m) for i in range(n)]
        anchor_scales[name] = temporal_scale(per_frame)
        scales[name] = (anchor_scales[name] if conf.metric_scale == "anchor"
                        else float(plane.camera_height_m))
        preds[f"{name}-metric"] = preds[name] * np.float32(scales[name])
    lap("scale")

    h = config_hash(conf)
    for name, maps in preds.items():
        add_prediction(seq_path, name, maps, {"stage": "adapt", "config_hash": h,
                                              "metric": name.endswith("-metric")})
    lap("write")

    summary = {"sequence": seq_path, "config": dataclasses.asdict(conf), "config_hash": h,
               "frames": n, "adapt_frames": len(adapt_split), "size": [W, H],
               "pseudo_label_agent_pixels": n_agent_px,
               "plane": plane.to_dict(), "camera_height_m": plane.camera_height_m,
               "camera_height_source": plane.camera_height_source,
               "scale": scales, "anchor_scale": anchor_scales, "finetune": history, "timings_s": timings,
               "predictions": list(preds)}
    # the paper's Table 2: depth of the bottom-centre anchor pixel from the agents' plane and the
    # camera height, and the parallel-camera baseline f H_c / (v_a - c_y)
    from staticdepth.geometry.scale import anchor_depth, anchor_depth_parallel, anchor_pixel

    u_a, v_a = anchor_pixel(W, H)
    summary["anchor_pixel"] = [u_a, v_a]
    summary["anchor_depth_m"] = float(anchor_depth(K, plane.normal, plane.camera_height_m, u_a, v_a))
    summary["anchor_depth_parallel_m"] = float(anchor_depth_parallel(K, plane.camera_height_m, v_a))
    summary["planes"] = {"agents": {"normal": np.asarray(plane.normal).tolist(),
                                    "d": float(plane.camera_height_m)}}
    summary_path = os.fspath(summary_path) if summary_path else f"{os.path.splitext(seq_path)[0]}.adapt.json"
    tmp = f"{summary_path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=1, default=_json_default)
    os.replace(tmp, summary_path)
    summary["summary_path"] = summary_path
    return summary


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return str(o)


# -- command line ----------------------------------------------------------------------------------
RECIPE_EXTRA_KEYS = ("sequence", "summary", "save_model", "device")
ALIASES = {"camera_height": "camera_height_m", "detector_weights": "detector_model"}


def recipe_settings(path: str | os.PathLike) -> dict[str, Any]:
    """The ``stages: {adapt: {...}}`` section of a recipe as settings (run-style ``args`` too)."""
    from staticdepth.config import load_yaml

    r = load_yaml(path)
    stages = r.get("stages")
    if not isinstance(stages, dict) or not isinstance(stages.get("adapt"), dict):
        raise InputError("the recipe has no 'stages: {adapt: {...}}' section", path)
    sec = dict(stages["adapt"])
    if "args" in sec or "command" in sec:           # staticdepth run's stage format
        sec = dict(sec.get("args") or {})
        if "_" in sec:
            pos = sec.pop("_")
            sec["sequence"] = pos[0] if isinstance(pos, list) else pos
    out = {ALIASES.get(k.replace("-", "_"), k.replace("-", "_")): v for k, v in sec.items()}
    if "camera_height_m" not in out and r.get("camera_height_m") is not None:
        out["camera_height_m"] = r["camera_height_m"]
    return out


def config_from_args(args) -> tuple[AdaptConfig, dict[str, Any]]:
    """(AdaptConfig, extras) from defaults < recipe < explicit flags < ``--set``."""
    from staticdepth.cli import parse_overrides
    from staticdepth.config import from_dict

    values: dict[str, Any] = recipe_settings(args.recipe) if args.recipe else {}
    flags = {"model": args.model, "detector": args.detector, "camera_height_m": args.camera_height,
             "epochs": args.epochs, "seed": args.seed, "sequence": args.sequence,
             "summary": args.summary, "save_model": args.save_model}
    values.update({k: v for k, v in flags.items() if v is not None})
    values.update(parse_overrides(args.set))
    extras = {k: values.pop(k) for k in RECIPE_EXTRA_KEYS if k in values}
    conf = from_dict(AdaptConfig, values, source=args.recipe)
    return conf, extras


def register(sub) -> None:
    from staticdepth.cli import add_device_argument
    from staticdepth import train_builtin

    p = sub.add_parser("adapt", help="adapt a depth network to a static camera's sequence",
                       description="On-site adaptation (BMVC 2023): base prediction, agents, "
                                   "pseudo labels, fine-tuning, ground plane, alignment, metric "
                                   "scale. Predictions are written into the sequence file.")
    p.add_argument("sequence", nargs="?", default=None, help="sequence file (.h5)")
    p.add_argument("--recipe", help="recipe YAML with a 'stages: {adapt: {...}}' section")
    p.add_argument("--model", help="builtin[:PATH.pt] | hf:DIR | onnx:FILE | torch:FILE "
                                   "(default builtin, the user cache)")
    p.add_argument("--detector", help="motion (default) | yolox | mask2former | gt")
    p.add_argument("--camera-height", type=float, help="camera height in metres (default: the "
                                                       "sequence's, else a 1.7 m agent prior)")
    p.add_argument("--epochs", type=int, help="fine-tuning epochs (default 30; 0 = none)")
    p.add_argument("--seed", type=int)
    p.add_argument("--summary", help="summary JSON (default: SEQ.adapt.json)")
    p.add_argument("--save-model", help="write the fine-tuned built-in model here")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help=f"any setting of AdaptConfig ({', '.join(f.name for f in dataclasses.fields(AdaptConfig))})")
    add_device_argument(p)
    p.set_defaults(func=run)
    train_builtin.register(sub)


def run(args) -> int:
    from staticdepth.cli import resolve_device

    conf, extras = config_from_args(args)
    seq = extras.get("sequence")
    if not seq:
        raise InputError("no sequence given (a positional SEQ.h5 or 'sequence:' in the recipe)")
    device = resolve_device(extras.get("device", args.device))
    summary = adapt(seq, conf, device=device, summary_path=extras.get("summary"),
                    save_model=extras.get("save_model"))
    print(f"plane: pitch {summary['plane']['pitch_deg']:.2f} deg, roll "
          f"{summary['plane']['roll_deg']:.2f} deg; camera height {summary['camera_height_m']:.2f} m "
          f"({summary['camera_height_source']})")
    print(f"predictions written to {seq}: {', '.join(summary['predictions'])}")
    print(f"summary: {summary['summary_path']}")
    return 0
