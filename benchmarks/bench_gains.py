"""Do the method's gains hold on scenes it was not built on? (issue 19)

Renders the independent scenes of ``tests/indep_scenes.py`` (own textures, ellipsoid people, box
vehicles, static structures; C1/C2/C3-like mounts), runs ``adapt`` on each with each network
(ground-truth instances or a real detector, the known camera height), adds other alignment modes
(``--extra-modes``, default the paper's Eq. 2 and ``ground``) beside adapt's default, optionally
trains the stereo baseline with its scene fit, and prints AbsRel per scene, prediction and region,
then the issue's checks.

Usage:
  python benchmarks/bench_gains.py --models builtin:out/builtin.pt,builtin:out/unet.pt \\
      [--scenes i1,i2,i3] [--frames 90] [--epochs 6] [--detector gt] [--stereo-epochs 0] \\
      [--label-source aligned|plane|prediction] [--work out/bench] [--json out/bench/gains.json] \\
      [--set align.mode=ground] [--extra-modes eq2,ground] [--reuse] [--keep] \\
      [--scene-spec h1:4.2:30:11 --scenes i1,h1]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from tests.indep_scenes import SCENES, write_scene  # noqa: E402

REGIONS = ("all", "ground", "agents", "structures", "0-10m", "10-20m", "20-40m", "40-80m")
def prediction_names(extra_modes: list[str]) -> tuple[str, ...]:
    """The table's rows: adapt's predictions with every extra alignment mode beside them."""
    return ("base", "ft", *(f"align-{m}" for m in extra_modes), "align",
            *(f"ft-align-{m}" for m in extra_modes), "ft-align", "ft-align-metric",
            "stereo-baseline")


def add_mode(seq: str, summary: dict, mode: str = "eq2", suffix: str = "-eq2") -> None:
    """Another alignment mode (default the paper's Eq. 2) of the stored base and ft predictions,
    aligned by adapt's own ``aligned_frame`` with the run's settings and ``align.mode=mode`` (same
    plane, ground mask and agents at their contact); written as ``align<suffix>`` and
    ``ft-align<suffix>``."""
    from dataclasses import replace

    from staticdepth.adaptation.align import aligned_frame
    from staticdepth.adaptation.config import build_config
    from staticdepth.dataset.h5 import SequenceReader, add_prediction
    from staticdepth.geometry.alignment import ground_mask_from_feet

    conf = build_config(summary["config"])
    conf = replace(conf, align=replace(conf.align, mode=mode))
    n_g = np.asarray(summary["plane"]["normal"])
    with SequenceReader(seq) as r:
        K, W, H, n = r.camera.K, r.width, r.height, len(r)
        rows = [r.agents(i) for i in range(n)]
        inst = np.stack([r.instances(i) for i in range(n)])
        ad = r.split("adapt")
        feet = np.concatenate([np.stack([x["foot_u"], x["foot_v"]], 1) for x in
                               (rows[i][rows[i]["foot_v"] >= 0] for i in ad) if len(x)])
        erode = conf.align.erode_px
        ground = ground_mask_from_feet(feet, W, H, W / 80.0 if erode is None else erode)
        maps = {src: np.stack([r.prediction(src, i) for i in range(n)]) for src in ("base", "ft")}
    for name, src in (("align" + suffix, "base"), ("ft-align" + suffix, "ft")):
        out = [aligned_frame(conf, K, n_g, ground, inst[i], rows[i], maps[src][i])
               for i in range(n)]
        add_prediction(seq, name, out, {"stage": "bench_gains", "align_mode": mode})


def label_error(seq: str) -> dict:
    """The pseudo labels read as a prediction (depth = 1 / label, median scaling per frame over
    every valid pixel, as ``evaluate`` does) against the truth on the adaptation split: agents'
    AbsRel of the labels, and of the base and ft predictions on the same frames and pixels (those
    with a positive label; ``label_nonpositive``: the agents' pixels without)."""
    from staticdepth.adaptation.common import FrameFile
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import apply_protocol, depth_metrics, valid_mask

    out: dict = {"label": [], "base": [], "ft": [], "label_nonpositive": []}
    with SequenceReader(seq) as r, FrameFile(seq + ".adapt/labels.h5", None) as lab:
        for k, i in enumerate(r.split("adapt")):
            gt = r.depth(i)
            m = region_masks(gt, r.instances(i), r.agents(i), None, None, 80.0).get("agents")
            vm = valid_mask(gt)
            if m is None or not (m & vm).any():
                continue
            pos = lab[k] > 0            # a label <= 0 (beyond the network's horizon) has no depth
            out["label_nonpositive"].append(1.0 - np.count_nonzero(m & vm & pos)
                                            / np.count_nonzero(m & vm))
            m = m & pos
            if not (m & vm).any():
                continue
            with np.errstate(divide="ignore"):
                preds = {"label": 1.0 / np.maximum(lab[k], 1e-6), "base": r.prediction("base", i)}
            if "ft" in r.predictions():
                preds["ft"] = r.prediction("ft", i)
            for name, pred in preds.items():
                scaled, _ = apply_protocol(pred, gt, "median", vm & (pos if name == "label" else vm))
                out[name].append(depth_metrics(scaled, gt, mask=m)["abs_rel"])
    res = {name: float(np.mean(v)) for name, v in out.items() if v}
    res.update(agent_label_error(seq))
    return res


def label_regions(seq: str) -> dict:
    """Per region, over the adaptation split: AbsRel of the pseudo labels read as depth, of the
    base and of the ft prediction, each after the per-frame scale and shift in inverse depth
    that fits it to the truth (``lsq``: what the scale-and-shift-invariant loss sees; labels
    live in the network's space, so 1 / label alone is not a depth). Where the labels beat base and ft does not, the network learns them wrong; where the
    labels are worse than base, they teach it wrong."""
    from staticdepth.adaptation.common import FrameFile
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import apply_protocol, depth_metrics, valid_mask

    rows: dict = {}
    with SequenceReader(seq) as r, FrameFile(seq + ".adapt/labels.h5", None) as lab:
        plane = (r.meta.mounting.normal, r.meta.mounting.height_m)
        for k, i in enumerate(r.split("adapt")):
            gt, y = r.depth(i), lab[k]
            masks = region_masks(gt, r.instances(i), r.agents(i), r.camera.K, plane, 80.0)
            vm = valid_mask(gt)
            pos = np.isfinite(y)
            shift = np.float32(1.0 - np.nanmin(y))   # any shift: lsq fits its own
            with np.errstate(divide="ignore"):
                preds = {"label": np.where(pos, 1.0 / (np.where(pos, y, 0.0) + shift), np.nan),
                         "base": r.prediction("base", i)}
            if "ft" in r.predictions():
                preds["ft"] = r.prediction("ft", i)
            for name, pred in preds.items():
                scaled, _ = apply_protocol(pred, gt, "lsq", vm & (pos if name == "label"
                                                                   else vm))
                for reg, m in masks.items():
                    m = m & vm & (pos if name == "label" else True)
                    if m.any():
                        rows.setdefault((reg, name), []).append(
                            depth_metrics(scaled, gt, mask=m)["abs_rel"])
    return {f"{reg}:{name}": float(np.mean(v)) for (reg, name), v in rows.items()}


def agent_label_error(seq: str) -> dict:
    """Each agent's pseudo label against its true depth, in metres: the aligned labels give an
    agent the depth of the agents' plane at its contact (``align.agents_at_contact``; the label is
    that depth mapped into the network's space), read here from adapt's ``align`` prediction (the
    base aligned, units of the camera height) x the true camera height; per agent (instance,
    frame of the adaptation split) the relative error of its median against the median true
    depth. ``base``: the base prediction's agents the same way after median scaling per frame.
    Returns median / mean / 90th percentile over the agents and their count."""
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_CLASSES
    from staticdepth.metrics import valid_mask

    errs: dict = {"label": [], "base": []}
    with SequenceReader(seq) as r:
        h_c = r.meta.mounting.height_m
        for i in r.split("adapt"):
            gt, inst, rows = r.depth(i), r.instances(i), r.agents(i)
            vm = valid_mask(gt)
            ids = rows["instance_id"][np.isin(rows["class_id"],
                                              list(AGENT_CLASSES | ACCESSORY_CLASSES))]
            base = r.prediction("base", i)
            preds = {"label": r.prediction("align", i) * h_c,
                     "base": base * np.nanmedian(gt[vm]) / np.nanmedian(base[vm])}
            for iid in ids:
                m = (inst == iid) & vm
                if np.count_nonzero(m) < 5:
                    continue
                z_true = np.median(gt[m])
                for name, z in preds.items():
                    errs[name].append(abs(np.nanmedian(z[m]) - z_true) / z_true)
    out = {}
    for name, v in errs.items():
        v = np.asarray(v)
        v = v[np.isfinite(v)]
        if len(v):
            out.update({f"{name}_agent_median": float(np.median(v)),
                        f"{name}_agent_mean": float(np.mean(v)),
                        f"{name}_agent_p90": float(np.percentile(v, 90)), f"{name}_agents": len(v)})
    return out


def run_scene(seq: str, model: str, args) -> dict:
    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config
    from staticdepth.evaluate import evaluate_sequence

    sets = {"model": model, "detector.name": args.detector, "finetune.epochs": args.epochs,
            "finetune.seed": 0, "plane.seed": 0, "tracking.min_height_px": args.min_height_px,
            "pseudo_labels.source": args.label_source, **dict(kv.split("=", 1) for kv in args.set)}
    if args.reuse:      # keep the network's predictions and the adaptation stages, align again
        keep = {"base.h5", "ft.h5"}
        pred_dir = seq + ".pred"
        for name in os.listdir(pred_dir) if os.path.isdir(pred_dir) else ():
            if name.split(".lock")[0] not in keep:
                os.remove(os.path.join(pred_dir, name))
    summary = adapt(seq, build_config(sets), summary_path=seq + ".adapt.json", log=lambda s: None)
    extra = [m for m in args.extra_modes.split(",") if m]
    for mode in extra:
        add_mode(seq, summary, mode=mode, suffix="-" + mode)
    if args.stereo_epochs > 0:
        train_stereo(seq, args.stereo_epochs, args.stereo_preset)
    res = evaluate_sequence(seq, protocols=None)["results"]
    table = {}
    for name in prediction_names(extra):
        if name in res:
            prot = next(iter(res[name]))
            table[name] = {reg: res[name][prot][reg]["abs_rel"] for reg in REGIONS
                           if reg in res[name][prot]}
            if name == "stereo-baseline":
                table[name]["a1"] = res[name][prot]["all"]["a1"]
    has = os.path.exists(seq + ".adapt/labels.h5")
    labels = label_error(seq) if has else {}
    return {"table": table, "plane": summary["plane"], "finetune": summary["finetune"],
            "labels_agents": labels, "labels_regions": label_regions(seq) if has else {},
            "metric_refused": summary.get("metric_refused")}


def train_stereo(seq: str, epochs: int, preset_name: str = "default") -> None:
    from staticdepth.baseline.config import preset
    from staticdepth.baseline.predict import predict_sequence
    from staticdepth.baseline.scene_fit import fit_to_scene
    from staticdepth.baseline.train import train
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(seq) as r:
        over = {"epochs": epochs} if preset_name != "default" else {"epochs": epochs, "batch_size": 6}
        conf = fit_to_scene(r, preset(preset_name, over))
    ckpt = seq + ".baseline.pt"
    train(seq, ckpt, conf, "cpu", overwrite=True)
    predict_sequence(seq, ckpt, "cpu")


def checks(results: dict) -> list[str]:
    """The issue's 'must show' inequalities, one line each (PASS/FAIL with the figures)."""
    lines = []
    for model, per in results.items():
        t = {s: v["table"] for s, v in per.items()}
        ratios = [t[s]["ft-align"]["all"] / t[s]["base"]["all"] for s in t]
        ok_each = all(t[s]["ft-align"]["all"] <= t[s]["base"]["all"] for s in t)
        lines.append(f"{model}: ft-align <= base on every scene: {'PASS' if ok_each else 'FAIL'} "
                     f"(ratios {', '.join(f'{r:.2f}' for r in ratios)})")
        mean = float(np.mean(ratios))
        lines.append(f"{model}: ft-align <= 0.7 x base on average: "
                     f"{'PASS' if mean <= 0.7 else 'FAIL'} ({mean:.2f})")
        fails = [s for s in t if t[s]["base"]["all"] > 0.3]
        if fails:
            ok = all(t[s]["align"]["all"] <= 0.12 for s in fails)
            lines.append(f"{model}: where base > 0.3 ({', '.join(fails)}) align <= 0.12: "
                         f"{'PASS' if ok else 'FAIL'} "
                         f"({', '.join('%.3f' % t[s]['align']['all'] for s in fails)})")
        ag = [(t[s]["ft"]["agents"], t[s]["base"]["agents"]) for s in t]
        lines.append(f"{model}: ft better than base on agents: "
                     f"{'PASS' if all(a < b for a, b in ag) else 'FAIL'} "
                     f"({', '.join(f'{a:.3f}/{b:.3f}' for a, b in ag)})")
        mr = [t[s]["ft-align-metric"]["all"] / t[s]["ft-align"]["all"] if "ft-align-metric" in t[s]
              else float("nan") for s in t]       # NaN: adapt refused the metric depth
        verdict = ("FAIL" if np.nanmax(mr + [0]) > 1.2 else
                   "REFUSED" if np.isnan(mr).any() else "PASS")
        lines.append(f"{model}: metric within 1.2x of median scaling: {verdict} ("
                     + ", ".join("refused" if np.isnan(r) else f"{r:.2f}" for r in mr) + ")")
        st = [t[s]["stereo-baseline"]["a1"] for s in t if "stereo-baseline" in t[s]]
        if st:
            lines.append(f"{model}: stereo baseline a1 >= 0.8: {'PASS' if min(st) >= 0.8 else 'FAIL'}"
                         f" ({', '.join(f'{a:.3f}' for a in st)})")
    return lines


def markdown(results: dict) -> str:
    out = []
    for model, per in results.items():
        out.append(f"\n{model}\n")
        out.append("| scene | prediction | " + " | ".join(REGIONS) + " |")
        out.append("|---|---|" + "---|" * len(REGIONS))
        for scene, v in per.items():
            for name, regs in v["table"].items():
                out.append(f"| {scene} | {name} | " + " | ".join(
                    f"{regs[r]:.3f}" if r in regs else "-" for r in REGIONS) + " |")
    return "\n".join(out)


def held_out_specs(items: list[str]) -> dict:
    """``--scene-spec NAME:HEIGHT:PITCH:SEED[:ROLL]`` -> {name: SceneSpec}; i1-i4 keep their
    specs."""
    from tests.indep_scenes import SceneSpec

    out = {}
    form = "NAME:HEIGHT_M:PITCH_DEG:SEED[:ROLL_DEG]"
    for item in items:
        parts = item.split(":")
        try:
            name, (height, pitch, seed) = parts[0], (float(parts[1]), float(parts[2]), int(parts[3]))
            roll = float(parts[4]) if len(parts) == 5 else 0.0
        except (IndexError, ValueError):
            sys.exit(f"--scene-spec {item!r}: expected {form}")
        if len(parts) not in (4, 5) or name in {s.name for s in SCENES}:
            sys.exit(f"--scene-spec {item!r}: expected {form} with a new name")
        out[name] = SceneSpec(name, height, pitch, seed, roll_deg=roll)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", required=True, help="comma-separated model specs")
    ap.add_argument("--scenes", default="i1,i2,i3")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--size", default="320x160")
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--detector", default="gt")
    ap.add_argument("--min-height-px", type=float, default=12.0)
    ap.add_argument("--stereo-epochs", type=int, default=0)
    ap.add_argument("--stereo-preset", default="default", help="baseline preset (site: CPU)")
    ap.add_argument("--label-source", default="aligned", choices=("aligned", "plane", "prediction"))
    ap.add_argument("--work", default="out/bench")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="adapt setting (e.g. align.mode=ground)")
    ap.add_argument("--extra-modes", default="eq2,ground",
                    help="alignment modes written beside adapt's as align-MODE, ft-align-MODE")
    ap.add_argument("--reuse", action="store_true",
                    help="keep an earlier run's sequence, predictions base/ft and adaptation "
                         "stages (same settings): only the alignment and scale run again")
    ap.add_argument("--keep", action="store_true",
                    help="keep an earlier run's sequence and stages: adapt reruns only the stages "
                         "whose settings changed (e.g. fine-tuning over the same labels)")
    ap.add_argument("--scene-spec", action="append", default=[],
                    metavar="NAME:HEIGHT:PITCH:SEED[:ROLL]",
                    help="another scene of tests/indep_scenes.py's generator (camera height in m, "
                         "pitch in degrees, seed, roll in degrees, default 0): scenes held out "
                         "from those a rule was chosen on")
    ap.add_argument("--json")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    os.makedirs(os.path.join(args.work, "scenes"), exist_ok=True)
    specs = {s.name: s for s in SCENES}
    specs.update(held_out_specs(args.scene_spec))
    results: dict = {}
    for scene in args.scenes.split(","):
        src = os.path.join(args.work, "scenes", f"{scene}-{args.frames}-{args.size}.h5")
        if not os.path.exists(src):
            write_scene(src, specs[scene], args.frames, width=w, height=h)
        for k, model in enumerate(args.models.split(",")):
            seq = os.path.join(args.work, f"{scene}-m{k}.h5")
            if args.keep and os.path.exists(seq):
                pass        # adapt's stage hashes decide what runs again
            elif not (args.reuse and os.path.exists(seq + ".adapt.json")):
                for stale in (seq + ".adapt", seq + ".pred"):      # an earlier run's stages
                    shutil.rmtree(stale, ignore_errors=True)
                shutil.copyfile(src, seq)
            results.setdefault(model, {})[scene] = run_scene(seq, model, args)
            got = results[model][scene]
            print(f"{scene} {model}: " + ", ".join(
                f"{n} {v['all']:.3f}" for n, v in got["table"].items()), flush=True)
            print(f"{scene} {model}: agents base {got['table']['base'].get('agents', np.nan):.3f}"
                  f" ft {got['table'].get('ft', {}).get('agents', np.nan):.3f}; adaptation "
                  f"frames' agents: labels {got['labels_agents'].get('label', np.nan):.3f}, base "
                  f"{got['labels_agents'].get('base', np.nan):.3f}, ft "
                  f"{got['labels_agents'].get('ft', np.nan):.3f} (label <= 0 on "
                  f"{got['labels_agents'].get('label_nonpositive', np.nan):.1%})", flush=True)
            la = got["labels_agents"]
            if "label_agents" in la:
                print(f"{scene} {model}: per agent ({la['label_agents']} agent-frames, metres): "
                      f"labels median {la['label_agent_median']:.3f} mean "
                      f"{la['label_agent_mean']:.3f} p90 {la['label_agent_p90']:.3f}; base median "
                      f"{la.get('base_agent_median', np.nan):.3f} mean "
                      f"{la.get('base_agent_mean', np.nan):.3f} p90 "
                      f"{la.get('base_agent_p90', np.nan):.3f}", flush=True)
            lr = got["labels_regions"]
            if lr:
                print(f"{scene} {model}: adaptation frames per region, label / base / ft "
                      "(lsq): " + "; ".join(
                          f"{reg} {lr.get(reg + ':label', np.nan):.3f} / "
                          f"{lr.get(reg + ':base', np.nan):.3f} / {lr.get(reg + ':ft', np.nan):.3f}"
                          for reg in REGIONS), flush=True)
    print(markdown(results))
    print()
    print("\n".join(checks(results)))
    if args.json:
        from staticdepth.fileio import atomic_write_json

        atomic_write_json(args.json, json.loads(json.dumps(results, default=str)))


if __name__ == "__main__":
    main()
