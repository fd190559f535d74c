"""An exported model (export-model) vs adapt's own stored output on a real adapt run, with and
without the colour foot in the graph; and the graph's onnxruntime speed with and without it.

Usage: python benchmarks/bench_export_adapted.py --sequence SEQ.h5 --summary SEQ.adapt.json
       --model builtin:FT.pt [--base-model builtin:BASE.pt] [--threads 1] [--frames 0]

``--model`` is adapt's fine-tuned network (``adapt --save-model``), compared with the stored
``ft-align-metric``; ``--base-model`` the network adapt started from, compared with
``align-metric``. Each is exported twice from the same summary: as it is (``align.colour_foot``
as adapt ran it) and with ``align.colour_foot=false`` (what export-model did before the graph had
the rule). Printed per export, over the sequence's evaluation frames (``--frames``: at most that
many, 0 = all): the max / median relative difference to adapt's output, over every pixel and over
the pixels the rule moves (where the numpy reference with the rule differs from the one without),
and frames per second of the ONNX graph (same threads, same frames).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np


def _export(spec: str, summary: str, seq: str, tmp: str, tag: str, colour_foot: bool | None):
    """The ONNX file of ``spec`` exported from ``summary`` (``colour_foot``: that setting forced)
    and its deployment constants."""
    from staticdepth.deploy import deployment_constants, export_model

    if colour_foot is not None:
        with open(summary) as f:
            s = json.load(f)
        s.setdefault("config", {}).setdefault("align", {})["colour_foot"] = colour_foot
        summary = os.path.join(tmp, f"{tag}.adapt.json")
        with open(summary, "w") as f:
            json.dump(s, f)
    out = os.path.join(tmp, f"{tag}.onnx")
    t0 = time.perf_counter()
    info = export_model(spec, summary, seq, out, check_frames=2, log=lambda s: None)
    return out, deployment_constants(summary, seq, log=lambda s: None), info, \
        time.perf_counter() - t0


AWAY = 8      # pixels: adapt's agents (its ground mask, occlusion, agents_at_contact) act nearby


def _away_from_agents(seq: str, summary: str, frames) -> list[np.ndarray]:
    """Per frame, the pixels at least AWAY pixels from the agents adapt found (its own detector's
    instance maps, the agents stage's): where the graph, which has no agent mask, can equal it."""
    import cv2

    from staticdepth.adaptation.common import Agents, Workspace
    from staticdepth.config import setting_from

    with open(summary) as f:
        det = setting_from(json.load(f).get("config") or {}, "detector.name", "motion")
    with Agents(Workspace(seq, log=lambda s: None), det) as ag:
        return [cv2.dilate((ag.instances(i) > 0).astype(np.uint8),
                           np.ones((2 * AWAY + 1, 2 * AWAY + 1), np.uint8)) == 0 for i in frames]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", required=True)
    ap.add_argument("--summary", required=True)
    ap.add_argument("--model", required=True, help="adapt's fine-tuned network (ft-align)")
    ap.add_argument("--base-model", help="the network adapt started from (align)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--frames", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3, help="timing passes over the frames")
    args = ap.parse_args()
    import torch

    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.deploy import MetricOnnx, metric_depth_reference
    from staticdepth.models import load_model

    torch.set_num_threads(args.threads)
    with SequenceReader(args.sequence) as r:
        ev = list(r.split("eval")) or list(range(len(r)))
        if args.frames:
            ev = [ev[k] for k in np.linspace(0, len(ev) - 1, min(args.frames, len(ev))).astype(int)]
        frames = [r.left(i) for i in ev]
        stored = {name: [r.prediction(name, i) for i in ev]
                  for name in ("ft-align-metric", "align-metric") if name in r.predictions()}
    away = _away_from_agents(args.sequence, args.summary, ev)
    print(f"{args.sequence}: {len(ev)} evaluation frames, {args.threads} threads")
    tmp = tempfile.mkdtemp(prefix="bench_export_adapted_")
    runs = [("ft-align-metric", args.model)] + ([("align-metric", args.base_model)]
                                                  if args.base_model else [])
    for name, spec in runs:
        if name not in stored:
            print(f"-- {name}: not in the sequence")
            continue
        model = load_model(spec)
        refs, outs, sess, best = {}, {}, {}, {}
        for tag, cf in (("without", False), ("with", None)):
            path, c, info, t_exp = _export(spec, args.summary, args.sequence, tmp,
                                           f"{name}-{tag}", cf)
            sess[tag] = MetricOnnx(path, threads=args.threads)
            refs[tag] = [metric_depth_reference(model, im, c) for im in frames]
            outs[tag] = [sess[tag].predict(im) for im in frames]          # also the warm-up
            print(f"-- {name}, graph {tag} the colour foot "
                  f"({sess[tag].metadata['staticdepth.colour_foot']}; export {t_exp:.1f} s, its "
                  f"check vs numpy median {100 * info['median_rel_diff']:.4f}%)")
        for _ in range(args.repeats):       # interleaved, the best pass of each: a shared CPU
            for tag in sess:
                t0 = time.perf_counter()
                for im in frames:
                    sess[tag].predict(im)
                best[tag] = min(best.get(tag, np.inf), time.perf_counter() - t0)
        rule = [np.abs(a - b) > 1e-6 * b for a, b in zip(refs["with"], refs["without"])]
        print(f"   pixels the rule moves (numpy reference): {np.mean([m.mean() for m in rule]):.4%}"
              f" of the frames' pixels")
        for tag in ("without", "with"):
            rel = [np.abs(g - s) / s for g, s in zip(outs[tag], stored[name])]
            allp = np.concatenate([x[np.isfinite(x)] for x in rel])
            onr = np.concatenate([x[m & np.isfinite(x)] for x, m in zip(rel, rule)])
            far = np.concatenate([x[a & np.isfinite(x)] for x, a in zip(rel, away)])
            far_r = np.concatenate([x[a & m & np.isfinite(x)]
                                    for x, a, m in zip(rel, away, rule)])
            vs_np = np.concatenate([(np.abs(g - f) / f).ravel()
                                    for g, f in zip(outs[tag], refs[tag])])
            print(f"   ONNX {tag:7s} vs adapt's {name}: all pixels max {allp.max():.4f} median "
                  f"{np.median(allp):.2e} mean {allp.mean():.4f}; rule's pixels max "
                  f"{onr.max() if onr.size else float('nan'):.4f} median "
                  f"{np.median(onr) if onr.size else float('nan'):.4f}; vs its numpy reference "
                  f"max {vs_np.max():.2e}")
            share = 100 * far.size / allp.size
            print(f"   {'':12s} >= {AWAY} px from adapt's agents ({share:.1f}%"
                  f" of the pixels): max {far.max():.4f} mean {far.mean():.5f}; rule's pixels "
                  f"there max {far_r.max() if far_r.size else float('nan'):.4f} median "
                  f"{np.median(far_r) if far_r.size else float('nan'):.4f}")
        print(f"   ONNX frames/s (best of {args.repeats} interleaved passes): without "
              f"{len(frames) / best['without']:.2f}, with {len(frames) / best['with']:.2f}; "
              f"with / without {best['without'] / best['with']:.3f}x")


if __name__ == "__main__":
    main()
