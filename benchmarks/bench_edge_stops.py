"""Do the image's own edges mark the occluders the network's depth hides? (issue 19, edge19)

The U-Net carries a far facade's depth through the crate, wall or vehicle in front of it, so the
``upright`` alignment's walk down the vertical crosses the occluding edge and takes the nearer
structure's contact (bench_contacts.py). The camera is static: the median of the adaptation
frames is the scene without its agents, and an occluding edge is a horizontal edge in it. On the
runs ``bench_gains.py --keep`` left (as bench_contacts.py), the evaluation split's base
predictions aligned again with adapt's settings (``--set align.KEY=VALUE`` over them):

1. Along every traced structure pixel's walk (>= 10 m, re-anchored at a contact of its own) down
   the vertical to its contact, over pixels that are not ground: the first true occluding edge
   (the truth nearer by over 30% one row down) and the first image edge above ``T`` (the largest
   channel difference of the median image between a pixel and the one below it, 0-1). The rule
   "stop at the first image edge above T": ``recall`` the share of the front walks (contact
   ratio below ``--front``) with a true edge that it stops there (within one row), ``early`` the
   share it stops above it (texture, shadows, a facade's own stripes), ``false`` the share of the
   walks whose contact is right (ratio >= ``--front``) that it cuts, ``precision`` the share of
   all its stops that lie on a true occluding edge.
2. ``--oracle``: the alignment again with ``edge_below`` = the image edges above each ``T``
   (alignment_upright: runs do not cross them to a pixel that is not ground and take a row
   neighbour's ratio), AbsRel (median scaling, per-frame mean as evaluate) per region beside base
   and the plain alignment; and cut at the true occluding edges (``truth-cut``: the ceiling of
   the cut itself), where the front pixels end: filled from a row neighbour, kept the ground
   mode, or still traced (no true edge one row tall on their walk).

Usage:
  python benchmarks/bench_edge_stops.py --work out/bench --runs i1-m1,i3-m1,i4-m1 \
      [--thresholds 0.05,0.1,0.2] [--oracle]
"""
from __future__ import annotations

import contextlib
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import (kept_run_parser, kept_runs, run_heights,  # noqa: E402
                                 run_image, run_settings, walked_region)

REGIONS = ("all", "ground", "agents", "structures", "0-10m", "10-20m", "20-40m", "40-80m")


def edge_below(img: np.ndarray, du: np.ndarray) -> np.ndarray:
    """(H, W): the largest channel difference between a pixel and the one below it on its
    vertical (the step ``upright``'s trace takes); 0 on the last row."""
    h, w = du.shape
    out = np.zeros((h, w))
    cols = np.arange(w)
    for v in range(h - 1):
        ub = np.clip(np.rint(cols + np.nan_to_num(du[v])), 0, w - 1).astype(np.int64)
        out[v] = np.abs(img[v] - img[v + 1, ub]).max(-1)
    return out


def walk_edges(E: np.ndarray, gt: np.ndarray, ground: np.ndarray, du: np.ndarray,
               pix: np.ndarray, contact: np.ndarray, thresholds: list[float]) -> dict:
    """Per walk (flat ``pix`` down to its flat ``contact``, over pixels that are not ``ground``):
    the row of its first true occluding edge and of its first image edge above each threshold
    (-1: none)."""
    h, w = E.shape
    v, u = np.divmod(pix, w)
    cv = contact // w
    first_gt = np.full(len(pix), -1)
    first_im = np.full((len(thresholds), len(pix)), -1)
    while True:
        act = v < cv
        if not act.any():
            break
        un = np.clip(np.rint(u + np.nan_to_num(du[v, u])), 0, w - 1).astype(np.int64)
        vn = np.minimum(v + 1, h - 1)
        act &= ~ground[vn, un]
        with np.errstate(invalid="ignore", divide="ignore"):
            occ = act & (gt[v, u] / gt[vn, un] > 1.3)
        first_gt = np.where(occ & (first_gt < 0), v, first_gt)
        for k, t in enumerate(thresholds):
            hit = act & (E[v, u] > t)
            first_im[k] = np.where(hit & (first_im[k] < 0), v, first_im[k])
        v, u = np.where(act, vn, cv), np.where(act, un, u)
    return {"gt": first_gt, "im": first_im}


@contextlib.contextmanager
def unfilled_cuts():
    """The runs an edge cuts keep the ground mode instead of a row neighbour's ratio (the
    runs an agent cuts are still filled)."""
    from staticdepth.geometry import alignment_upright as au

    orig = au.occluded_runs
    au.occluded_runs = lambda A, occ, ground, du, jump_rel, steps=False, cut=None: orig(
        A, occ, ground, du, jump_rel, steps)
    try:
        yield
    finally:
        au.occluded_runs = orig


def frame_regions(pred: np.ndarray, gt: np.ndarray, masks: dict, vm: np.ndarray) -> dict:
    from staticdepth.metrics import apply_protocol, depth_metrics

    scaled, _ = apply_protocol(pred, gt, "median", vm)
    return {k: depth_metrics(scaled, gt, max_depth=80.0, mask=m)["abs_rel"]
            for k, m in masks.items() if k in REGIONS and (vm & m).any()}


def analyse(seq: str, sets: dict, thresholds: list[float], front: float, oracle: bool) -> dict:
    from staticdepth.adaptation.align import static_image, upright_options
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.geometry.alignment import agents_at_contact, align_upright
    from staticdepth.geometry.alignment_vertical import down_step
    from staticdepth.metrics import valid_mask

    conf, n_g = run_settings(seq, sets)
    walks = {"gt": [], "im": [], "front": []}
    regions: dict = {}
    with SequenceReader(seq) as r:
        K = r.camera.K
        mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
        rows, walked = walked_region(r, conf)
        img, heights = run_image(r, conf), run_heights(seq, conf)
        du = down_step(K, n_g / np.linalg.norm(n_g), r.width, r.height)
        E = edge_below(static_image(r, r.split("adapt")), du)
        for i in r.split("eval"):
            Z, gt, inst = r.prediction("base", i), r.depth(i), r.instances(i)
            m = inst > 0
            am = m if np.count_nonzero(walked & ~m) >= 50 else None
            reg = region_masks(gt, inst, rows[i], K, mount, 80.0)
            vm = valid_mask(gt, 1e-3, 80.0)

            def aligned(edges, info=None):
                A = align_upright(Z, K, n_g, 1.0, walked if am is None else walked & ~am,
                                  agent_mask=am, snap_rel=conf.align.snap_rel, info=info,
                                  edge_below=edges, image=img,
                                  **upright_options(conf.align)).depth
                if conf.align.agents_at_contact:
                    A = agents_at_contact(A, K, n_g, 1.0, inst, rows[i], conf.pseudo_labels,
                                          heights=heights)[0]
                return A

            info: dict = {}
            A = aligned(None, info)
            c = info["contact"]
            tr = vm & info["moved"] & reg["structures"] & (c >= 0) & (gt >= 10)
            pix = np.flatnonzero(tr)
            ratio = gt.ravel()[c.ravel()[pix]] / gt.ravel()[pix]
            res = walk_edges(E, gt, info["ground"], du, pix, c.ravel()[pix], thresholds)
            walks["gt"].append(res["gt"])
            walks["im"].append(res["im"])
            walks["front"].append(ratio < front)
            preds = {"base": Z, "align": A}
            if oracle:
                preds.update({f"edge>{t:g}": aligned(E > t) for t in thresholds})
                # the mechanism's ceiling: cut at the true occluding edges (truth > 30% nearer)
                with np.errstate(divide="ignore", invalid="ignore"):
                    T = edge_below(np.log(gt)[..., None], du) > np.log(1.3)
                tinfo: dict = {}
                preds["truth-cut"] = aligned(T, tinfo)
                # the front pixels there: filled from a row neighbour, kept the ground mode, or
                # still traced (|aligned / true - 1| in each frame's median units)
                fp = pix[ratio < front]
                state = np.where(tinfo["contact"].ravel()[fp] >= 0, 2,
                                 np.where(tinfo["moved"].ravel()[fp], 0, 1))
                for k, P in (("err_plain", A), ("err_cut", preds["truth-cut"])):
                    med = float(np.median(gt[vm] / P[vm]))
                    walks.setdefault(k, []).append(np.abs(med * P.ravel()[fp] / gt.ravel()[fp]
                                                          - 1.0))
                walks.setdefault("state", []).append(state)
                with unfilled_cuts():   # cut runs keep the ground mode
                    preds["truth-cut-nofill"] = aligned(T)
                    preds.update({f"edge>{t:g}-nofill": aligned(E > t) for t in thresholds})
            for name, p in preds.items():
                for k, x in frame_regions(p, gt, reg, vm).items():
                    regions.setdefault(name, {}).setdefault(k, []).append(x)
    return {"gt": np.concatenate(walks["gt"]), "im": np.concatenate(walks["im"], 1),
            "front": np.concatenate(walks["front"]),
            **{k: np.concatenate(walks[k]) for k in ("state", "err_plain", "err_cut")
               if k in walks},
            "regions": {n: {k: float(np.mean(v)) for k, v in d.items()}
                        for n, d in regions.items()}}


def q50(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def report(name: str, res: dict, thresholds: list[float]) -> None:
    g, im, fr = res["gt"], res["im"], res["front"]
    edge = fr & (g >= 0)
    print(f"\n{name}: {len(g)} traced walks >= 10 m, front {fr.mean():.0%}, of those a true "
          f"occluding edge {np.mean(g[fr] >= 0):.0%}; walks with a right contact crossing one "
          f"{np.mean(g[~fr] >= 0):.0%}")
    for k, t in enumerate(thresholds):
        s = im[k]
        stop = s >= 0
        at = stop & (g >= 0) & (np.abs(s - g) <= 1)
        early = stop & ((g < 0) | (s < g - 1))
        print(f"  T {t:<5g} recall {np.mean(at[edge]):4.0%}  early {np.mean(early[edge]):4.0%}"
              f"  (front walks with a true edge); false cuts {np.mean(stop[~fr]):4.0%} (right "
              f"contacts); precision {at[stop].mean() if stop.any() else np.nan:.0%}")
    if "state" in res:
        st, ep, ec = res["state"], res["err_plain"], res["err_cut"]
        print(f"  front pixels cut at the true edges (truth-cut): |aligned/true - 1| q50 plain "
              f"{np.median(ep):.2f} -> {np.median(ec):.2f}; " + ", ".join(
                  f"{n} {np.mean(st == k):.0%} ({q50(ep[st == k]):.2f} -> {q50(ec[st == k]):.2f})"
                  for k, n in enumerate(("filled from a row neighbour", "kept the ground mode",
                                         "still traced"))))
    reg = res["regions"]
    base = reg["base"]
    print(f"  {'AbsRel':10s} " + " ".join(f"{k:>10s}" for k in REGIONS if k in base)
          + "  worse than base by > 3%")
    for n, d in reg.items():
        worse = [k for k in REGIONS if k in d and k in base and d[k] > 1.03 * base[k]]
        print(f"  {n:10s} " + " ".join(f"{d[k]:10.4f}" for k in REGIONS if k in base)
              + f"  {len(worse)} {','.join(worse)}")


def main() -> None:
    ap = kept_run_parser(__doc__, "i1-m1,i3-m1,i4-m1")
    ap.add_argument("--thresholds", default="0.05,0.1,0.15,0.2,0.3")
    ap.add_argument("--front", type=float, default=0.7)
    ap.add_argument("--oracle", action="store_true",
                    help="align again with runs cut at the image edges above each threshold")
    args = ap.parse_args()
    ts = [float(x) for x in args.thresholds.split(",")]
    for run, seq, sets in kept_runs(args):
        report(run, analyse(seq, sets, ts, args.front, args.oracle), ts)


if __name__ == "__main__":
    main()
