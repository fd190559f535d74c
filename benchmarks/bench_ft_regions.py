"""What does fine-tuning learn wrong, region by region? (issue 19)

Reads sequences that ``bench_gains.py`` has adapted (``--work`` folder, ``<scene>-m<k>.h5`` with
its ``.adapt`` stages and ``.pred`` predictions) and prints, per region (ground, agents,
structures, distance bands), on the adaptation frames: the share of pixels with a label, the
share of those that are trusted (agents and static pixels whose alignment is stable over the
split, :mod:`staticdepth.adaptation.pseudo_labels`), and the AbsRel against the truth of the
labels read as depth (``1 / label``: adapt's labels are shift-free) on trusted / untrusted pixels,
beside base, ft, align and ft-align on the same pixels; then the same predictions on the
evaluation frames, with two more on the adaptation frames: ``label-align``, the labels read as
depth and aligned as adapt's align stage does (what ft-align would be if the network learned its
labels exactly), and ``align-twice``, adapt's ``align`` output aligned again (whether the
alignment is idempotent: ft-align aligns a network trained on aligned labels). Every
prediction is median-scaled per frame over all its valid pixels, as
``evaluate`` does; labels over their labelled pixels.

Usage:
  python benchmarks/bench_ft_regions.py out/bench/i1-m1.h5 [more.h5 ...]
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

REGIONS = ("all", "ground", "agents", "structures", "0-10m", "10-20m", "20-40m", "40-80m")
PREDS = ("base", "ft", "align", "ft-align")


def trusted_masks(seq: str):
    """The stable mask of the pseudo-label stage (trusted: it, or an agent), and f(i, depth): a
    depth map of frame i aligned as adapt's align stage does it (its plane, ground, settings)."""
    from staticdepth.adaptation import ground_plane
    from staticdepth.adaptation.align import ground_region
    from staticdepth.adaptation.common import Agents, Workspace
    from staticdepth.adaptation.config import build_config
    from staticdepth.adaptation.pseudo_labels import _dense

    with open(seq + ".adapt.json") as f:
        summary = json.load(f)
    conf = build_config(summary["config"])
    ws = Workspace(seq, log=lambda s: None)
    with Agents(ws, conf.detector.name) as ag:
        plane, feet = ground_plane.run(conf, ws, ag, summary["stage_hashes"]["ground_plane"])
        ground = ground_region(conf, ws, feet)
        _, stable = _dense(conf, ws, ag, plane, ground)
    from staticdepth.adaptation.align import aligned_frame

    def align(inst, rows, Z):
        return aligned_frame(conf, ws.K, plane.normal, ground, inst, rows, Z, plane_bound=True)
    return stable, align


def scaled(pred, gt, vm):
    from staticdepth.metrics import apply_protocol

    return apply_protocol(pred, gt, "median", vm & np.isfinite(pred) & (pred > 0))[0]


def region_rows(seq: str) -> dict:
    from staticdepth.adaptation.common import FrameFile
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import depth_metrics, valid_mask

    stable, align = trusted_masks(seq)
    acc: dict = {}

    def add(key, pred, gt, m):
        if np.count_nonzero(m) >= 20:
            acc.setdefault(key, []).append(depth_metrics(pred, gt, mask=m)["abs_rel"])

    with SequenceReader(seq) as r, FrameFile(seq + ".adapt/labels.h5", None) as lab:
        plane = (r.meta.mounting.normal, r.meta.mounting.height_m)
        have = [p for p in PREDS if p in r.predictions()]
        for split in ("adapt", "eval"):
            for k, i in enumerate(r.split(split)):
                gt = r.depth(i)
                vm = valid_mask(gt)
                masks = region_masks(gt, r.instances(i), r.agents(i), r.camera.K, plane, 80.0)
                preds = {p: scaled(r.prediction(p, i), gt, vm) for p in have}
                if split == "adapt":
                    y = lab[k]
                    pos = np.isfinite(y) & (y > 0)
                    with np.errstate(divide="ignore"):
                        ld = scaled(np.where(pos, 1.0 / np.where(pos, y, 1.0), np.nan), gt, vm)
                    trusted = stable | (r.instances(i) > 0)
                    # what ft-align would be if the network learned its labels exactly
                    la = scaled(align(r.instances(i), r.agents(i), 1.0 / np.where(pos, y, np.nan)),
                                gt, vm)
                    # the alignment applied twice: is it idempotent? (ft-align aligns a network
                    # trained on aligned labels)
                    a2 = scaled(align(r.instances(i), r.agents(i), r.prediction("align", i)),
                                gt, vm)
                for reg, m in masks.items():
                    m = m & vm
                    n = np.count_nonzero(m)
                    if n == 0:
                        continue
                    if split == "adapt":
                        acc.setdefault((split, reg, "labelled"), []).append(
                            np.count_nonzero(m & pos) / n)
                        acc.setdefault((split, reg, "trusted"), []).append(
                            np.count_nonzero(m & pos & trusted) / max(1, np.count_nonzero(m & pos)))
                        add((split, reg, "label-T"), ld, gt, m & pos & trusted)
                        add((split, reg, "label-U"), ld, gt, m & pos & ~trusted)
                        add((split, reg, "label-align"), la, gt, m)
                        add((split, reg, "align-twice"), a2, gt, m)
                        for p in have:
                            add((split, reg, p + "-T"), preds[p], gt, m & pos & trusted)
                            add((split, reg, p + "-U"), preds[p], gt, m & pos & ~trusted)
                    for p in have:
                        add((split, reg, p), preds[p], gt, m)
    return {k: float(np.mean(v)) for k, v in acc.items()}


def main() -> None:
    for seq in sys.argv[1:]:
        res = region_rows(seq)
        print(f"\n{seq}")
        print("adaptation frames: region | labelled | trusted | label T/U | base T/U | ft T/U | "
              "align T/U | ft-align T/U")
        for reg in REGIONS:
            def g(name):
                return res.get(("adapt", reg, name), np.nan)
            print(f"  {reg:10s} | {g('labelled'):.2f} | {g('trusted'):.2f} | " + " | ".join(
                f"{g(p + '-T'):.3f}/{g(p + '-U'):.3f}" for p in ("label",) + PREDS))
        for split in ("adapt", "eval"):
            extra = ("label-align", "align-twice") if split == "adapt" else ()
            print(f"{split} frames, all pixels: region | " + " | ".join(PREDS + extra))
            for reg in REGIONS:
                print(f"  {reg:10s} | " + " | ".join(
                    f"{res.get((split, reg, p), np.nan):.3f}" for p in PREDS + extra))


if __name__ == "__main__":
    main()
