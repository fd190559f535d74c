"""Where the aligned depth's AbsRel goes: what each part of the frame would give if it were right
(issue 19's floor; oracles, they use the truth to pick pixels and to set them).

On the runs ``bench_gains.py --keep`` left, for a stored prediction (``--pred``, default
``align``) over the evaluation split, the frame's AbsRel (median scaling, as the evaluation) and
the same with one part of the frame at its true depth, everything else as predicted:
- ``near-S``: structures (not ground, not agents) within 10 m;
- ``agents``: every agent; ``cut-agents``: the agents whose mask reaches the image's bottom row
  (their contact is not seen);
- ``hidden-people``: people whose lowest mask pixel sits on another agent (feet hidden);
- and, keeping the prediction's shape, one best scale for all the structures (``S-scale``), one
  per distance band (``S-band-scale``), one per image row (``S-row-scale``).
Printed also: each part's share of the valid pixels.

Usage:
  python benchmarks/bench_error_budget.py --work out/bench --runs i1-m1,i4-m1,h3-m1 [--pred align]
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import kept_run_parser, kept_runs  # noqa: E402
from bench_contacts import frame_absrel  # noqa: E402

BANDS = ((0, 10), (10, 20), (20, 40), (40, 80))
PARTS = ("near-S", "agents", "cut-agents", "hidden-people")
SCALED = ("S-scale", "S-band-scale", "S-row-scale")


def agent_parts(inst: np.ndarray, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Masks of the agents cut by the image's bottom row and of the people whose lowest mask
    pixel sits on another agent (the tracker's own test)."""
    from staticdepth.tracking import detections_from_instances

    h = inst.shape[0]
    cut = np.zeros(inst.shape, bool)
    hidden = np.zeros(inst.shape, bool)
    if rows is None or not len(rows):
        return {"cut-agents": cut, "hidden-people": hidden}
    det = detections_from_instances(inst, rows, border_px=1)
    for d in det:
        m = inst == d["instance_id"]
        if d["foot_v"] >= h - 1.5:
            cut |= m
        elif d["foot_hidden"] and d["class_id"] in (0, -1):
            hidden |= m
    return {"cut-agents": cut, "hidden-people": hidden}


def scaled(P: np.ndarray, gt: np.ndarray, groups) -> np.ndarray:
    """P with each group of pixels at its best (median) scale against the truth."""
    out = P.copy()
    for k in groups:
        if k.any():
            out[k] = P[k] * np.median(gt[k] / P[k])
    return out


def budget(seq: str, pred: str) -> dict[str, float]:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import valid_mask

    acc: dict[str, list[float]] = {}
    with SequenceReader(seq) as r:
        K = r.camera.K
        mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
        for i in r.split("eval"):
            A = r.prediction(pred, i).astype(np.float64)
            gt, inst, rows = r.depth(i), r.instances(i), r.agents(i)
            vm = valid_mask(gt, 1e-3, 80.0)
            reg = region_masks(gt, inst, rows, K, mount, 80.0)
            A = A * np.median(gt[vm] / A[vm])           # the frame's median scale, as evaluated
            st = reg["structures"] & vm
            parts = {"near-S": st & (gt < 10), "agents": reg.get("agents", inst > 0) & vm,
                     **{k: v & vm for k, v in agent_parts(inst, rows).items()}}
            acc.setdefault("now", []).append(frame_absrel(A, gt, vm))
            for name, m in parts.items():
                o = A.copy()
                o[m] = gt[m]
                acc.setdefault(name, []).append(frame_absrel(o, gt, vm))
                acc.setdefault("share " + name, []).append(m.sum() / vm.sum())
            row = np.arange(st.shape[0])[:, None]
            groups = {"S-scale": [st],
                      "S-band-scale": [st & (gt >= lo) & (gt < hi) for lo, hi in BANDS],
                      "S-row-scale": [st & (row == v) for v in range(st.shape[0])]}
            for name, gs in groups.items():
                acc.setdefault(name, []).append(frame_absrel(scaled(A, gt, gs), gt, vm))
    return {k: float(np.mean(v)) for k, v in acc.items()}


def main() -> None:
    ap = kept_run_parser(__doc__, "i1-m1,i3-m1,i4-m1")
    ap.add_argument("--pred", default="align", help="the stored prediction to break down")
    args = ap.parse_args()
    cols = ("now",) + PARTS + SCALED
    print("| run | " + " | ".join(cols) + " | " + " | ".join("share " + p for p in PARTS) + " |")
    print("|---" * (len(cols) + len(PARTS) + 1) + "|")
    for run, seq, _ in kept_runs(args):
        b = budget(seq, args.pred)
        print(f"| {run} | " + " | ".join(f"{b[c]:.3f}" for c in cols) + " | "
              + " | ".join(f"{100 * b['share ' + p]:.1f}%" for p in PARTS) + " |", flush=True)


if __name__ == "__main__":
    main()
