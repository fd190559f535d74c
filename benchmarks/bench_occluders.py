"""Agents as occluders: a lower bound on the static scene's depth (issue 19; an oracle, not kept).

A pixel that an agent covers in some frame shows, in every frame where no agent covers it, a
static surface at least as far as that agent was. Over a run's frames each pixel's bound is the
farthest agent seen on it: ``bound(p) = max_t depth_t(p)`` over the frames where an agent's mask
(eroded by ``--erode`` px, so that a mask's rim on a nearer surface does not count) covers p. The
agents' depth is the aligned prediction's own (adapt puts each agent at its contact's plane
depth), or with ``--truth`` the true depth, brought to the prediction's units by the frame's
median scale. Every static pixel of an evaluation frame nearer than its bound is pushed back to it.

Printed per run and prediction, over the evaluation split (median scaling, as the evaluation):
the frame's AbsRel and the structures' before and after; the share of the valid pixels with a
bound (static in the frame), the share of the structures' pixels with one, and the share of those
the bound moves.

On the runs ``bench_gains.py --keep`` left (as ``bench_align_regions.py``); ``--frames all`` takes
the bound from every frame (a fixed camera keeps seeing its agents), ``adapt`` from the adaptation
split only.

Usage:
  python benchmarks/bench_occluders.py --work out/bench --runs i1-m0,i1-m1,i4-m0,i4-m1
      [--pred align,ft-align] [--frames all|adapt] [--erode 1] [--truth]
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import kept_run_parser, kept_runs  # noqa: E402
from bench_contacts import frame_absrel  # noqa: E402


def add_to_bound(bound: np.ndarray, instances: np.ndarray, depth: np.ndarray,
                 erode: int = 1) -> np.ndarray:
    """``bound`` (H, W; 0 = none yet) raised to ``depth`` where an agent of ``instances`` (its
    mask eroded by ``erode`` px, each agent apart) covers the pixel."""
    from scipy import ndimage

    m = instances > 0
    if erode > 0:
        # erode each agent's own mask: two agents touching must not shield each other's rims
        m = np.zeros_like(m)
        for k in np.unique(instances[instances > 0]):
            m |= ndimage.binary_erosion(instances == k, iterations=erode)
    return np.where(m & (depth > bound), depth, bound)


def push_back(A: np.ndarray, instances: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """The frame's depth with every static pixel (no agent in ``instances``) nearer than its
    ``bound`` moved back to it."""
    return np.where((instances == 0) & (A < bound), bound, A)


def region_absrel(pred: np.ndarray, gt: np.ndarray, vm: np.ndarray, region: np.ndarray) -> float:
    """AbsRel over ``region`` with the frame's median scale (from every valid pixel ``vm``), as
    the evaluation's regions; NaN for an empty region."""
    from staticdepth.metrics import apply_protocol, depth_metrics

    if not region.any():
        return float("nan")
    scaled, _ = apply_protocol(pred, gt, "median", vm)
    return depth_metrics(scaled, gt, max_depth=80.0, mask=region)["abs_rel"]


def analyse(seq: str, pred: str, frames: str, erode: int, truth: bool) -> dict:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import apply_protocol, valid_mask

    with SequenceReader(seq) as r:
        K, mount = r.camera.K, (r.meta.mounting.normal, r.meta.mounting.height_m)
        src = range(len(r)) if frames == "all" else r.split("adapt")
        bound = np.zeros((r.height, r.width))
        for i in src:
            bound = add_to_bound(bound, r.instances(i), r.depth(i) if truth
                                 else r.prediction(pred, i), erode)
        out: dict[str, list] = {k: [] for k in ("all", "all_new", "st", "st_new", "covered",
                                                "st_covered", "st_moved")}
        for j in r.split("eval"):
            gt, inst, A = r.depth(j), r.instances(j), r.prediction(pred, j).astype(np.float64)
            vm = valid_mask(gt)
            st = region_masks(gt, inst, r.agents(j), K, mount, 80.0)["structures"] & vm
            b = bound / apply_protocol(A, gt, "median", vm)[1] if truth else bound
            B = push_back(A, inst, b)
            has = (inst == 0) & (b > 0)
            out["all"].append(frame_absrel(A, gt, vm))
            out["all_new"].append(frame_absrel(B, gt, vm))
            out["st"].append(region_absrel(A, gt, vm, st))
            out["st_new"].append(region_absrel(B, gt, vm, st))
            out["covered"].append(np.count_nonzero(has & vm) / max(np.count_nonzero(vm), 1))
            out["st_covered"].append(np.count_nonzero(has & st) / max(np.count_nonzero(st), 1))
            out["st_moved"].append(np.count_nonzero((B != A) & st)
                                   / max(np.count_nonzero(has & st), 1))
    return {k: float(np.nanmean(v)) for k, v in out.items()}


def main() -> None:
    ap = kept_run_parser(__doc__, "i4-m0,i4-m1")
    ap.add_argument("--pred", default="align,ft-align")
    ap.add_argument("--frames", choices=("all", "adapt"), default="all")
    ap.add_argument("--erode", type=int, default=1)
    ap.add_argument("--truth", action="store_true", help="the agents' true depth (an oracle)")
    args = ap.parse_args()
    for run, seq, _ in kept_runs(args):
        for pred in args.pred.split(","):
            m = analyse(seq, pred, args.frames, args.erode, args.truth)
            print(f"{run:>8} {pred:9} all {m['all']:.4f} -> {m['all_new']:.4f}  structures "
                  f"{m['st']:.4f} -> {m['st_new']:.4f}  bounded pixels {m['covered']:.0%}, "
                  f"of the structures {m['st_covered']:.0%}, moved {m['st_moved']:.0%}",
                  flush=True)


if __name__ == "__main__":
    main()
