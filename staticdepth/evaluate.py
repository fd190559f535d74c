"""Evaluation stage: metrics of stored predictions per protocol, split and region.

Commands: ``staticdepth evaluate SEQ.h5`` (predictions stored in a sequence file) and
``staticdepth metrics --pred P --gt G`` (maps made elsewhere, as ``.npy`` files or folders).
"""
from __future__ import annotations

import argparse
import os
from typing import Any, Iterable, Sequence

import numpy as np

from staticdepth.dataset import schema
from staticdepth.errors import InputError
from staticdepth.fileio import read_npy
from staticdepth.metrics import (METRIC_KEYS, PROTOCOLS, apply_protocol, average,
                                 check_depth_range, check_prediction, depth_metrics, evaluate,
                                 valid_mask)
from staticdepth.progress import progress

DISTANCE_BANDS_M = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 80.0))
GROUND_TOLERANCE_M = 0.10


CONFIDENCE_BANDS = 4     # accuracy by confidence: quartiles of each frame's confidence


def default_protocol(name: str, attrs: dict[str, Any] | None = None) -> str:
    """Metric predictions (``*-metric``, the stereo baseline, attribute ``metric``, e.g. stereo
    ground truth from ``stereo --sequence``) are evaluated without rescaling."""
    metric = name.endswith("-metric") or name.startswith("stereo-baseline")
    return "metric" if metric or int((attrs or {}).get("metric", 0)) else "median"


def prediction_protocols(reader, names: Sequence[str] | None = None
                         ) -> tuple[dict[str, str], str | None]:
    """The depth predictions of an open sequence (``names``, else all; confidence maps left out)
    with the protocol ``evaluate`` gives each: its attribute ``metric`` where stored, else its
    name (:func:`default_protocol`). The second value is a one-line note naming the predictions
    whose protocol came from the name (None when every one stores it)."""
    attrs = {n: reader.prediction_attrs(n) for n in (names or reader.predictions())}
    prot = {n: default_protocol(n, a) for n, a in attrs.items() if a.get("kind") != "confidence"}
    guessed = [n for n in prot if "metric" not in attrs[n]]
    if not guessed:
        return prot, None
    return prot, (f"note: {reader.path}: {len(guessed)} prediction(s) store no 'metric' "
                  "attribute; protocol from the name (metric if it ends in -metric or starts "
                  "with stereo-baseline, else median): "
                  + ", ".join(f"{n} {prot[n]}" for n in guessed))


def confidence_masks(confidence: np.ndarray, bands: int = CONFIDENCE_BANDS
                     ) -> dict[str, np.ndarray]:
    """``conf qK`` masks: the K-th of ``bands`` equal shares of the pixels with a confidence
    (> 0) by rank, ``q1`` the least confident; ties stay together (a score, not a probability,
    so ranks rather than fixed values)."""
    c = np.asarray(confidence, dtype=np.float32)
    have = np.isfinite(c) & (c > 0)
    if not have.any():
        return {}
    edges = np.quantile(c[have], np.linspace(0, 1, bands + 1)[1:-1])
    k = np.searchsorted(edges, c, side="right")
    return {f"conf q{j + 1}": have & (k == j) for j in range(bands)}


def region_masks(gt: np.ndarray, instances: np.ndarray | None, agents: np.ndarray | None,
                 K: np.ndarray | None, plane: tuple[np.ndarray, float] | None,
                 max_depth: float) -> dict[str, np.ndarray]:
    """Boolean masks: ``all``, ``agents`` (agent and accessory instances), ``ground`` (pixels whose
    ground-truth point lies within 10 cm of the true ground plane), ``structures`` (neither ground
    nor agent), and distance bands."""
    out = {"all": np.ones(gt.shape, bool)}
    if instances is not None and agents is not None and len(agents):
        ids = agents["instance_id"][np.isin(agents["class_id"], list(schema.AGENT_CLASSES
                                                                      | schema.ACCESSORY_CLASSES))]
        out["agents"] = np.isin(instances, ids) & (instances > 0)
    if plane is not None and K is not None:
        from staticdepth.geometry.projection import points_from_depth

        n, d = plane
        P = points_from_depth(np.nan_to_num(gt, nan=0.0), K)
        with np.errstate(invalid="ignore"):
            on = np.abs(P @ n - d) < GROUND_TOLERANCE_M
        if instances is not None:
            on &= instances == 0
        out["ground"] = on
        # everything above the ground that is not an agent: walls, poles, buildings
        out["structures"] = ~on & ~out.get("agents", np.zeros(gt.shape, bool))
    for lo, hi in DISTANCE_BANDS_M:
        if lo < max_depth:
            with np.errstate(invalid="ignore"):
                out[f"{lo:g}-{min(hi, max_depth):g}m"] = (gt >= lo) & (gt < hi)
    return out


def evaluate_sequence(path: str | os.PathLike, names: Sequence[str] | None = None, *,
                      split: str = "eval", protocols: Iterable[str] | None = None,
                      max_depth: float = 80.0, min_depth: float = 1e-3,
                      regions: bool = True) -> dict[str, Any]:
    """Per prediction and protocol: averages over the split's frames, per region.

    Returns ``{"sequence": ..., "split": ..., "frames": n, "frames_with_gt": m, "results":
    {name: {protocol: {region: averages}}}, "missing": {name: {"pixels", "share"}},
    "protocol_note": ...}``:
    ``missing`` counts the pixels of valid ground truth where a prediction has no depth (NaN:
    a stereo map's holes), which its metrics leave out. ``protocols=None`` uses
    :func:`default_protocol` per prediction (``protocol_note``: the line naming those whose
    protocol came from their name, :func:`prediction_protocols`; None otherwise). Raises when no
    frame of the split has ground truth within the depth range.
    """
    from staticdepth.dataset.h5 import SequenceReader

    check_depth_range(min_depth, max_depth)

    with SequenceReader(path) as r:
        if not r.has("depth"):
            raise InputError("sequence has no ground-truth depth to evaluate against", r.path)
        attrs = {n: r.prediction_attrs(n) for n in r.predictions()}
        # confidence maps (attribute kind = confidence) are not depth: they split their depth
        names = list(names) if names else [n for n in r.predictions()
                                           if attrs[n].get("kind") != "confidence"]
        missing = [n for n in names if n not in r.predictions()]
        if missing:
            raise InputError(f"no prediction(s) {missing} (has {r.predictions()})", r.path)
        if not names:
            raise InputError("sequence has no predictions to evaluate", r.path)
        frames = r.split(split)
        if len(frames) == 0:
            raise InputError(f"split {split!r} has no frames", r.path)
        K = r.camera.K
        plane = None
        if r.meta.mounting is not None:
            plane = (r.meta.mounting.normal, r.meta.mounting.height_m)
        per: dict[tuple[str, str, str], list[dict]] = {}
        prot_of = {n: list(protocols) if protocols else [default_protocol(n, attrs.get(n))]
                   for n in names}
        # said when a protocol comes from a name, not an attribute
        note = None if protocols else prediction_protocols(r, names)[1]
        conf_of = {n: attrs[n].get("confidence") for n in names
                   if attrs[n].get("confidence") in attrs}
        used, n_valid, n_missing = 0, 0, dict.fromkeys(names, 0)
        for i in progress(frames, desc="evaluate", unit="frame"):
            gt = r.depth(i)
            inst = r.instances(i) if r.has("instances") else None
            masks = region_masks(gt, inst, r.agents(i), K, plane, max_depth) if regions \
                else {"all": np.ones(gt.shape, bool)}
            vm = valid_mask(gt, min_depth, max_depth)
            if not vm.any():
                continue
            used, n_valid = used + 1, n_valid + int(vm.sum())
            for name in names:
                pred = r.prediction(name, i)
                n_missing[name] += int((~np.isfinite(pred) & vm).sum())
                # pixels with a depth (+inf: beyond the range, scored at max_depth)
                has = vm & (np.isfinite(pred) | np.isposinf(pred))
                bands = confidence_masks(r.prediction(conf_of[name], i)) if name in conf_of \
                    else {}
                for prot in prot_of[name]:
                    if prot != "metric" and not (has & np.isfinite(pred) & (pred > 0)).any():
                        continue    # nothing to scale by in this frame: its pixels are missing
                    # one scale per image from all valid pixels; regions are evaluated with it
                    scaled, s = apply_protocol(pred, gt, prot, vm)
                    for reg, m in {**masks, **bands}.items():
                        if not (has & m).any():
                            continue
                        res = depth_metrics(scaled, gt, min_depth=min_depth, max_depth=max_depth,
                                            mask=m)
                        res["scale"] = s
                        per.setdefault((name, prot, reg), []).append(res)
        name_seq = r.meta.name
        if used == 0:
            raise InputError(f"no frame of split {split!r} ({len(frames)} frames) has ground truth "
                             f"between {min_depth:g} and {max_depth:g} m: nothing to evaluate",
                             r.path)
        for name in names:
            if not any(k[0] == name for k in per):
                from staticdepth.dataset.predictions import prediction_path

                raise InputError(f"the prediction has no depth (NaN) at any of the {n_valid} "
                                 f"pixels of split {split!r} with valid ground truth: nothing "
                                 "to evaluate", prediction_path(r.path, name))
    results: dict[str, Any] = {}
    for (name, prot, reg), rows in per.items():
        avg = average(rows)
        avg["scale_median"] = float(np.median([x["scale"] for x in rows]))
        avg["pixels"] = int(sum(x["n"] for x in rows))
        results.setdefault(name, {}).setdefault(prot, {})[reg] = avg
    missing = {n: {"pixels": k, "share": k / n_valid} for n, k in n_missing.items()}
    return {"sequence": name_seq, "path": os.fspath(path), "split": split,
            "frames": len(frames), "frames_with_gt": used, "results": results,
            "missing": missing, "protocol_note": note}


# --------------------------------------------------------------------------------------------
# .npy inputs for `staticdepth metrics`

def load_maps(path: str | os.PathLike) -> list[np.ndarray]:
    """One ``.npy`` (H x W or N x H x W) or a folder of them in sorted order -> list of H x W."""
    path = os.fspath(path)
    if os.path.isdir(path):
        files = sorted(f for f in os.listdir(path) if f.endswith(".npy"))
        if not files:
            raise InputError("folder holds no .npy files", path)
        out = []
        for f in files:
            out.extend(load_maps(os.path.join(path, f)))
        return out
    a = read_npy(path)
    if a.dtype.kind == "c":  # no silent cast to real numbers
        raise InputError(f"the array holds complex numbers ({a.dtype}): depth is real", path)
    if a.dtype.kind not in "fiub":
        raise InputError(f"the array is not numeric (dtype {a.dtype})", path)
    if a.ndim == 2:
        return [a.astype(np.float64)]
    if a.ndim == 3:
        return [x.astype(np.float64) for x in a]
    raise InputError(f"expected an H x W or N x H x W array, got shape {a.shape}", path)


def metrics_on_maps(preds: list[np.ndarray], gts: list[np.ndarray], protocol: str,
                    max_depth: float, pred_src: str = "", gt_src: str = "") -> dict[str, Any]:
    check_depth_range(1e-3, max_depth)
    if len(preds) != len(gts):
        raise InputError(f"{len(preds)} predictions ({pred_src}) but {len(gts)} ground-truth "
                         f"maps ({gt_src})")
    per = []
    for i, (p, g) in enumerate(zip(preds, gts)):
        if p.shape != g.shape:
            raise InputError(f"image {i}: prediction {p.shape} vs ground truth {g.shape}", pred_src)
        g = np.where(g > 0, g, np.nan)  # 0 = unknown in ground truth
        check_prediction(p, f"{pred_src} (image {i})" if len(preds) > 1 else pred_src,
                         valid=valid_mask(g, max_depth=max_depth))
        try:
            per.append(evaluate(p, g, protocol, max_depth=max_depth))
        except InputError as e:
            raise InputError(f"image {i}: {e.problem}", gt_src) from None
    out = average(per)
    out["per_image"] = per
    out["protocol"] = protocol
    return out


# --------------------------------------------------------------------------------------------
# CLI

def register(sub) -> None:
    p = sub.add_parser("metrics", help="depth metrics of .npy predictions against ground truth",
                       description="SiLog, AbsRel, SqRel, RMSE, RMSE log, delta thresholds as in "
                                   "the paper (METHOD.md section 6).")
    p.add_argument("--pred", required=True, help=".npy (H x W or N x H x W) or folder of them")
    p.add_argument("--gt", required=True, help="same layout; metres, NaN or 0 = unknown")
    p.add_argument("--protocol", choices=PROTOCOLS, default="median",
                   help="median: per-image median scaling; metric: none; lsq: scale and shift")
    p.add_argument("--max-depth", type=float, default=80.0, help="evaluation depth cap (m)")
    p.add_argument("--json", help="write averages and per-image values here")
    _overwrite(p)
    p.set_defaults(func=_metrics_cmd)

    p = sub.add_parser("evaluate", help="evaluate the predictions stored in a sequence file",
                       description="Metrics of the sequence's predictions (SEQ.h5.pred/NAME.h5) "
                                   "against its ground truth, per protocol and region (all, "
                                   "agents, ground, distance bands).")
    p.add_argument("sequence", help="sequence file (.h5) with stored predictions")
    p.add_argument("--pred", nargs="*", help="prediction names (default: all stored)")
    p.add_argument("--split", default="eval", choices=("eval", "adapt", "all"),
                   help="frames to evaluate")
    p.add_argument("--protocol", nargs="*", choices=PROTOCOLS,
                   help="default: metric for *-metric and stereo-baseline, median otherwise")
    p.add_argument("--max-depth", type=float, default=80.0, help="evaluation depth cap (m)")
    p.add_argument("--json", help="write the full results here")
    _overwrite(p)
    p.set_defaults(func=_evaluate_cmd)


def _overwrite(p) -> None:
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)


def _write_json(path: str, obj: Any) -> None:
    from staticdepth.fileio import atomic_write_json

    atomic_write_json(path, obj)


def format_row(name: str, m: dict[str, float]) -> str:
    return f"{name:24s} " + " ".join(f"{m[k]:8.4f}" for k in METRIC_KEYS)


def header() -> str:
    return f"{'':24s} " + " ".join(f"{k:>8s}" for k in METRIC_KEYS)


def _check_json_output(args: argparse.Namespace) -> None:
    if args.json:  # a folder, a read-only place: refused before the evaluation runs
        from staticdepth.fileio import check_writable
        check_writable(args.json)


def _metrics_cmd(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing

    _check_json_output(args)
    refuse_existing(args.json, overwrite=args.overwrite)
    out = metrics_on_maps(load_maps(args.pred), load_maps(args.gt), args.protocol,
                          args.max_depth, args.pred, args.gt)
    print(header())
    print(format_row(f"{args.protocol} ({out['n_images']} img)", out))
    if args.json:
        _write_json(args.json, out)
    return 0


def _evaluate_cmd(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing

    _check_json_output(args)
    refuse_existing(args.json, overwrite=args.overwrite)
    res = evaluate_sequence(args.sequence, args.pred, split=args.split,
                            protocols=args.protocol, max_depth=args.max_depth)
    used = res["frames_with_gt"]
    print(f"{res['sequence']}: split {res['split']} ({res['frames']} frames"
          + ("" if used == res["frames"] else f", {used} with ground truth") + ")")
    if res["protocol_note"]:
        print(res["protocol_note"])
    for name, miss in res["missing"].items():
        if miss["pixels"]:
            print(f"warning: {name} has no depth (NaN) at {miss['pixels']} pixels "
                  f"({100 * miss['share']:.1f}%) of valid ground truth; its metrics leave them out")
    print(header())
    for name, by_prot in res["results"].items():
        for prot, regs in by_prot.items():
            print(format_row(f"{name} [{prot}]", regs["all"]))
            bands = sorted(b for b in regs if b.startswith("conf "))
            for band in bands:      # accuracy by confidence band, with its share of the pixels
                share = regs[band]["pixels"] / max(sum(regs[b]["pixels"] for b in bands), 1)
                print(format_row(f"  {band} {100 * share:4.1f}%", regs[band]))
    if args.json:
        _write_json(args.json, res)
    return 0
