"""Stage pipeline: on-site adaptation of a depth network to one static camera (``staticdepth adapt``).

agents (a detector, or the sequence's own instances with ``detector.name=gt``) -> ground plane from
the agents -> base prediction -> pseudo labels on the adaptation split -> fine-tuning -> scene
alignment -> metric scale from the camera height (the agents and the plane first, so that a sequence
they cannot serve is refused before the network's pass over every frame); one module per stage in
:mod:`staticdepth.adaptation`, each streamed frame by frame and resumable. Predictions (the
sequence's prediction store, ``<SEQ>.h5.pred/<name>.h5``): ``base``, ``ft`` (relative depth 1 /
max(D, eps), METHOD.md), ``align``, ``ft-align`` (aligned to the agents' plane with unit camera
height: relative), and ``align-metric``, ``ft-align-metric`` (metres: the aligned maps are in units
of the camera height, so they are multiplied by H_c; ``scale.metric_scale=anchor`` uses the anchor
pixel's scale of METHOD.md section 5 instead; the summary reports both). The stages' own files
(inverse depth, instance maps, labels, checkpoint, plane) are kept in ``<SEQ>.h5.adapt/`` so that a
rerun with other late settings redoes only the stages after them.
A JSON summary holds the plane, the scale, the fine-tuning history and the stage timings.
"""
from __future__ import annotations

import dataclasses
import os
import time
from typing import Any, Callable

import numpy as np

from staticdepth.errors import InputError

STAGES = ("agents", "ground_plane", "base", "pseudo_labels", "finetune", "ft", "align", "scale")
# adapt's predictions and the stage whose hash each stores (its ``config_hash`` attribute)
PREDICTION_STAGES = {"base": "base", "ft": "ft", "align": "align", "ft-align": "align",
                     "align-metric": "scale", "ft-align-metric": "scale"}


def adapt(seq_path: str | os.PathLike, conf=None, *, device=None,
          summary_path: str | os.PathLike | None = None, save_model: str | None = None,
          log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the whole adaptation on a sequence file; returns the summary (also written as JSON)."""
    from staticdepth.adaptation import (agents, align, checks, finetune, ground_plane, predict,
                                        pseudo_labels, scale)
    from staticdepth.adaptation.common import Agents, Workspace
    from staticdepth.adaptation.config import AdaptConfig, model_identity, stage_hashes
    from staticdepth.fileio import atomic_write_json
    from staticdepth.geometry.scale import anchor_depth, anchor_depth_parallel, anchor_pixel
    from staticdepth.geometry.agent_plane_gate import plane_gate

    conf = conf if conf is not None else AdaptConfig()
    seq_path = os.fspath(seq_path)
    summary_path = os.fspath(summary_path) if summary_path else default_summary_path(seq_path)
    ws = Workspace(seq_path, log)
    model, detector, layers = checks.prepare(conf, ws, device=device, summary_path=summary_path,
                                             save_model=save_model)
    h = stage_hashes(conf, model_identity(conf.model))
    checks.disk_space(conf, ws, h, model)
    checks.probe_model(conf, ws, model, h["base"])
    timings: dict[str, float] = {}
    clock = [time.perf_counter()]

    def lap(stage: str) -> None:
        now = time.perf_counter()
        timings[stage] = round(now - clock[0], 3)
        clock[0] = now
        log(f"{stage}: {timings[stage]:.1f} s")

    # the agents and their plane first: a sequence they refuse (no agents tracked, collinear
    # feet, a nadir camera) fails before the network's pass over every frame, the long part
    # with a real network (neither stage reads the base prediction)
    agents.run(conf, ws, detector, h["agents"])
    lap("agents")
    with Agents(ws, conf.detector.name) as ag:
        plane, feet = ground_plane.run(conf, ws, ag, h["ground_plane"])
        lap("ground_plane")
        predict.run(conf, ws, model, h["base"], name="base")
        lap("base")
        n_agent_px = pseudo_labels.run(conf, ws, ag, h["pseudo_labels"], plane, feet)
        lap("pseudo_labels")
        history: list[dict[str, float]] = []
        if conf.finetune.epochs > 0:
            history = finetune.run(conf, ws, model, h["finetune"], layers)
            predict.run(conf, ws, model, h["ft"], name="ft", keep_inverse=False)
        else:
            predict.copy_base(conf, ws, h["ft"])
        lap("finetune")
        align_info = align.run(conf, ws, ag, plane, feet, h["align"])
        lap("align")
        plane = scale.with_camera_height(conf, ws, plane)
        refuse, metric_note = scale.check(conf, ws, plane, feet)
        scales, anchor_scales = {}, {}
        if metric_note:
            log(f"warning: {metric_note}")
        if not refuse:
            scales, anchor_scales = scale.run(conf, ws, ag, plane, h["scale"])
        else:
            _remove_metric(ws.seq, log)
        lap("scale")

    W, H, K, Hc = ws.width, ws.height, ws.K, plane.camera_height_m
    u_a, v_a = anchor_pixel(W, H)
    summary = {"sequence": seq_path, "sequence_id": ws.identity,
               "config": dataclasses.asdict(conf),
               "config_hash": h["scale"], "stage_hashes": h, "frames": ws.n,
               "adapt_frames": len(ws.adapt_split), "size": [W, H],
               "pseudo_label_agent_pixels": n_agent_px, "plane": plane.to_dict(),
               # the gate's verdict, kept: the stage's warning is printed only when it runs
               "plane_gate": (plane_gate(plane).to_dict() if np.isfinite(plane.normal_std_deg)
                              else None),
               # how well each network sees the agents' ground; outputs that took the plane alone
               "align_ground_r2": align_info["ground_r2"],
               "align_plane_only": align_info["plane_only"],
               "camera_height_m": Hc, "camera_height_source": plane.camera_height_source,
               "scale": scales, "anchor_scale": anchor_scales, "finetune": history,
               "timings_s": timings, "stage_frames": {s: ws.frames.get(s, 0) for s in STAGES},
               "skipped_stages": ws.skipped,
               "predictions": ["base", "ft", "align", "ft-align"]
               + ([] if refuse else ["align-metric", "ft-align-metric"]),
               "metric_refused": metric_note if refuse else None, "metric_note": metric_note,
               # the paper's Table 2: depth of the bottom-centre anchor pixel from the agents'
               # plane and the camera height, and the parallel-camera baseline f H_c / (v_a - c_y)
               "anchor_pixel": [u_a, v_a],
               "anchor_depth_m": float(anchor_depth(K, plane.normal, Hc, u_a, v_a)),
               "anchor_depth_parallel_m": float(anchor_depth_parallel(K, Hc, v_a)),
               "planes": {"agents": {"normal": np.asarray(plane.normal).tolist(), "d": float(Hc)}}}
    if save_model and conf.finetune.epochs > 0:
        # at the end, just before the summary: a run interrupted earlier leaves no model file
        # that its resume would have to be told to overwrite
        from staticdepth.models.tiny import save_builtin

        model.to("cpu")
        # plain values only: load_builtin refuses pickled objects (sets)
        save_builtin(save_model, model, info={
            "adapted_on": seq_path, "config": _jsonable(dataclasses.asdict(conf))})
    atomic_write_json(summary_path, _jsonable(summary), indent=1)
    summary["summary_path"] = summary_path
    return summary


def _remove_metric(seq_path: str, log: Callable[[str], None]) -> None:
    """A run whose metric maps are refused removes those of an earlier run (``--overwrite``
    let it replace that run's predictions; kept, they would be read beside this run's)."""
    from staticdepth.dataset.predictions import prediction_path

    for name in ("align-metric", "ft-align-metric"):
        p = prediction_path(seq_path, name)
        if os.path.exists(p):
            os.remove(p)
            log(f"removed {p}: an earlier run's metric map (this run writes none)")


def other_runs_predictions(seq_path: str, hashes: dict[str, str],
                           names=PREDICTION_STAGES) -> list[str]:
    """The complete adapt predictions of ``seq_path`` (among ``names``) that were written with
    other settings, another model or another sequence than the stage ``hashes`` say: their
    paths. An interrupted file is not one (it is resumed or redone)."""
    from staticdepth.dataset.predictions import prediction_path, sequence_id_of

    paths = {n: prediction_path(seq_path, n) for n in names}
    paths = {n: p for n, p in paths.items() if os.path.isfile(p)}
    if not paths:
        return []
    identity = sequence_id_of(seq_path)
    out = []
    for n, p in paths.items():
        complete, sid, h = _attrs(p, "complete", "sequence_id", "config_hash")
        if complete is True and (sid, h) != (identity, hashes.get(PREDICTION_STAGES[n])):
            out.append(p)
    return out


def _attrs(path: str, *keys: str) -> tuple:
    """The attributes ``keys`` of the HDF5 file ``path`` (None where absent or unreadable)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            vals = [f.attrs.get(k) for k in keys]
    except OSError:
        return (None,) * len(keys)
    return tuple(v.item() if hasattr(v, "item") else v for v in vals)


def replaced_since(summary: dict[str, Any], seq_path: str) -> str | None:
    """The first prediction ``summary`` lists that another run has written over since (its
    stored ``config_hash`` is not the summary's for its stage), or None; also None for a
    summary without stage hashes (written before they were kept)."""
    from staticdepth.dataset.predictions import prediction_path

    hashes = summary.get("stage_hashes")
    if not isinstance(hashes, dict):
        return None
    for name in summary.get("predictions") or []:
        stage = PREDICTION_STAGES.get(name)
        p = prediction_path(seq_path, name) if stage else None
        if p and os.path.isfile(p) and _attrs(p, "config_hash")[0] != hashes.get(stage):
            return p
    return None


def default_summary_path(seq_path: str | os.PathLike) -> str:
    """``SEQ.adapt.json`` beside ``SEQ.h5``."""
    return f"{os.path.splitext(os.fspath(seq_path))[0]}.adapt.json"


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (set, frozenset)):
        return sorted(_jsonable(v) for v in o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return o


# -- command line ----------------------------------------------------------------------------------
EXTRA_KEYS = ("sequence", "summary", "save_model", "device")
# flags (and the same keys in a recipe's adapt section) -> settings of the tree
FLAG_KEYS = {"model": ("model",), "detector": ("detector.name",),
             "camera_height": ("scale.camera_height_m",),
             "camera_height_m": ("scale.camera_height_m",), "epochs": ("finetune.epochs",),
             "seed": ("finetune.seed", "plane.seed"), "detector_weights": ("detector.model",)}


def _settings(values: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in values.items():
        if k == "set":
            out.update({str(kk): vv for kk, vv in (v or {}).items()})
            continue
        key = k.replace("-", "_")
        for target in FLAG_KEYS.get(key, (key,)):
            out[target] = v
    return out


def recipe_settings(path: str | os.PathLike) -> dict[str, Any]:
    """The ``stages: {adapt: {...}}`` section of a recipe as dotted settings (run-style ``args``
    too: flags by name, ``set: {a.b: value}``)."""
    from staticdepth.config import load_yaml

    r = load_yaml(path)
    stages = r.get("stages")
    if not isinstance(stages, dict) or not isinstance(stages.get("adapt"), dict):
        raise InputError("the recipe has no 'stages: {adapt: {...}}' section", path)
    sec = dict(stages["adapt"])
    if "args" in sec or "command" in sec:           # staticdepth run's stage format
        if "name" in r:                             # a whole run recipe: its {vars} filled in
            from staticdepth.run import load_recipe

            sec["args"] = load_recipe(path)["stages"]["adapt"]["args"]
        sec = dict(sec.get("args") or {})
        if "_" in sec:
            pos = sec.pop("_")
            sec["sequence"] = pos[0] if isinstance(pos, list) else pos
    out = _settings(sec)
    if "scale.camera_height_m" not in out and r.get("camera_height_m") is not None:
        out["scale.camera_height_m"] = r["camera_height_m"]
    return out


def config_from_args(args) -> tuple[Any, dict[str, Any]]:
    """(AdaptConfig, extras) from defaults < recipe < explicit flags < ``--set``."""
    from staticdepth.adaptation.config import build_config
    from staticdepth.config import parse_set
    from staticdepth.geometry.camera import check_camera_height

    if args.camera_height is not None:      # named as the option (the setting names its key)
        check_camera_height(args.camera_height, "--camera-height")
    values: dict[str, Any] = recipe_settings(args.recipe) if args.recipe else {}
    flags = {"model": args.model, "detector": args.detector, "camera_height": args.camera_height,
             "epochs": args.epochs, "seed": args.seed, "sequence": args.sequence,
             "summary": args.summary, "save_model": args.save_model}
    values.update(_settings({k: v for k, v in flags.items() if v is not None}))
    values.update(parse_set(args.set))
    extras = {k: values.pop(k) for k in EXTRA_KEYS if k in values}
    return build_config(values, source=args.recipe), extras


def register(sub) -> None:
    from staticdepth import train_builtin
    from staticdepth.cli import add_device_argument, add_overwrite_argument

    p = sub.add_parser("adapt", help="adapt a depth network to a static camera's sequence",
                       description="On-site adaptation (BMVC 2023) as resumable stages: base "
                                   "prediction, agents, pseudo labels, fine-tuning, ground plane, "
                                   "alignment, metric scale. Predictions are written beside the "
                                   "sequence (SEQ.h5.pred/), stage files into SEQ.h5.adapt/.")
    p.add_argument("sequence", nargs="?", default=None, help="sequence file (.h5)")
    p.add_argument("--recipe", help="recipe YAML with a 'stages: {adapt: {...}}' section")
    p.add_argument("--model", help="builtin[:PATH.pt] | hf:DIR | onnx:FILE | torch:FILE "
                                   "(default builtin, the user cache)")
    p.add_argument("--detector", help="motion (default) | yolox | mask2former | gt "
                                      "(= --set detector.name=...)")
    p.add_argument("--camera-height", type=float, help="camera height in metres (default: the "
                                                       "sequence's, else from the agents' "
                                                       "per-class height distributions; "
                                                       "--set scale.agent_height_m=H uses one "
                                                       "fixed agent height instead)")
    p.add_argument("--epochs", type=int, help="fine-tuning epochs (default 30, cut at "
                   "finetune.max_steps optimiser steps, default 60; 0 = none)")
    p.add_argument("--seed", type=int, help="seed of fine-tuning and of the plane's RANSAC "
                   "(= --set finetune.seed=N --set plane.seed=N)")
    p.add_argument("--summary", help="summary JSON (default: SEQ.adapt.json)")
    p.add_argument("--save-model", help="write the fine-tuned built-in model here")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="any setting, dotted (e.g. tracking.min_height_px=8); "
                        "--print-config lists them")
    p.add_argument("--print-config", action="store_true",
                   help="print the configuration tree (defaults, recipe, flags and --set "
                        "applied) and exit")
    add_device_argument(p)
    add_overwrite_argument(p, "replace the summary and --save-model files when they exist "
                              "(refused otherwise; stages up to date are skipped either way)")
    p.set_defaults(func=run)
    train_builtin.register(sub)


def refuse_other_runs(seq: str, conf) -> None:
    """Predictions an earlier run wrote with other settings are replaced with ``--overwrite``
    only: another ``--summary`` would leave the earlier summary describing maps that are gone."""
    from staticdepth.adaptation.config import model_identity, stage_hashes

    if not os.path.isfile(seq):
        return                          # adapt names the missing or unreadable sequence
    others = other_runs_predictions(seq, stage_hashes(conf, model_identity(conf.model)))
    if others:
        more = f" (and {len(others) - 1} more)" if len(others) > 1 else ""
        raise InputError(f"holds an earlier adapt run's prediction{more}, written with other "
                         "settings or another model; pass --overwrite to replace them",
                         others[0])


def run(args) -> int:
    from staticdepth.cli import refuse_existing, refuse_foreign_kind, resolve_device
    from staticdepth.config import format_config

    conf, extras = config_from_args(args)
    if args.print_config:
        print(format_config(conf))
        return 0
    seq = extras.get("sequence")
    if not seq:
        raise InputError("no sequence given (a positional SEQ.h5 or 'sequence:' in the recipe)")
    summary = extras.get("summary") or default_summary_path(seq)
    refuse_foreign_kind(summary, "--summary", "adapt", "summary")
    refuse_existing(summary, extras.get("save_model"), overwrite=args.overwrite)
    if not args.overwrite:
        refuse_other_runs(seq, conf)
    device = resolve_device(extras.get("device", args.device))
    summary = adapt(seq, conf, device=device, summary_path=extras.get("summary"),
                    save_model=extras.get("save_model"))
    unc = summary["plane"].get("uncertainty") or {}
    sd, sp, sr = (unc.get(k) for k in ("camera_height_std_m", "pitch_std_deg", "roll_std_deg"))

    def pm(x):
        return "" if x is None else f" +- {x:.2f}"

    print(f"plane: pitch {summary['plane']['pitch_deg']:.2f}{pm(sp)} deg, roll "
          f"{summary['plane']['roll_deg']:.2f}{pm(sr)} deg; camera height "
          f"{summary['camera_height_m']:.2f}{pm(sd)} m ({summary['camera_height_source']})")
    gate = summary.get("plane_gate")
    if gate and not gate["ok"]:     # also on a rerun that skipped the ground_plane stage
        print(f"warning: {gate['message']}; adapt went on with it (alignment and metric scale "
              "inherit its error)")
    if summary.get("metric_note"):
        print(summary["metric_note"])
    print(f"predictions written to {seq}.pred/: {', '.join(summary['predictions'])}")
    print(f"summary: {summary['summary_path']}")
    return 0
