"""Structures whose foot is hidden: what they cost, and what could place them (issue 19; oracles).

On the runs ``bench_gains.py --keep`` left (as ``bench_align_regions.py``), the evaluation split's
base predictions aligned again with adapt's settings (``--set align.KEY=VALUE`` over them). A
*hidden-foot* pixel is a re-anchored structure pixel (not an agent) whose walk down the image of
the vertical, before it reaches a pixel the alignment took for ground, crosses a true occluding
edge: the truth steps nearer by more than ``--step`` (30%) to a pixel that is not true ground. Its
run took the occluder's contact, in front of its own hidden foot. Its true depth lies in the
occlusion interval: behind the occluder (``near``: the aligned depth just below the edge), and no
farther than the vertical line through the ground point just below the edge (``far``: the farthest
its foot can be while hidden; unbounded where that point is above the horizon).

Printed per run: the hidden pixels' share of the valid pixels and their AbsRel; the frame's
AbsRel (median scaling, as the evaluation) as aligned and with the hidden pixels set to
- ``truth``: their true depth (the ceiling of any rule for them);
- ``far`` / ``near`` / ``mid``: the interval's far end, its near end, their geometric mean;
- ``row``: the depth of the nearest pixel of the same row that is re-anchored, crosses no
  occluding edge and lies on the same surface (true depth within 5%): a front-facing facade has
  one depth along an image row (a camera without roll), so this is a geometric fill from the
  part of the surface whose foot is seen, given an oracle that says which pixels share the surface;
the share of hidden pixels whose truth, in the plane's units (camera heights), lies inside
[near, far]; and the share whose pixel just above the edge is true ground (``ground above the
edge``: the foot is not hidden, a strip of ground the alignment did not take for ground lies
between the structure and the occluder's top).

``--detector image`` takes the hidden pixels as adapt could: re-anchored pixels (not agents)
whose walk crosses an edge of the static image (largest channel difference over
``--edge-threshold``, as ``bench_edge_stops.py``) above a pixel the alignment did not take for
ground; ``truth`` and ``row`` stay oracles.

Usage:
  python benchmarks/bench_hidden_feet.py --work out/bench --runs i1-m1,i3-m1,i4-m1 [--step 0.3]
      [--detector true|image] [--edge-threshold 0.3]
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import KeptRun, kept_run_parser, kept_runs  # noqa: E402
from bench_contacts import frame_absrel  # noqa: E402

FILLS = ("truth", "far", "near", "mid", "row")


def below_index(du: np.ndarray) -> np.ndarray:
    """Flat index of the pixel one row below each pixel on its vertical (-1: none)."""
    h, w = du.shape
    v = np.arange(h)[:, None]
    bu = np.rint(np.arange(w)[None, :] + np.nan_to_num(du)).astype(np.int64)
    ok = np.isfinite(du) & (v + 1 < h) & (bu >= 0) & (bu < w)
    return np.where(ok, (v + 1) * w + np.clip(bu, 0, w - 1), -1).ravel()


def first_edge(below: np.ndarray, edge: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Per pixel, the flat index of the pixel just above the first ``edge`` (H, W bool: an edge
    between a pixel and the one below) on its walk down, which ends before a ``stop`` pixel
    (-1: no edge on the walk). One sweep of the rows from the bottom up."""
    h, w = edge.shape
    out = np.full(h * w, -1, np.int64)
    e, s = edge.ravel(), stop.ravel()
    for v in range(h - 2, -1, -1):
        row = slice(v * w, (v + 1) * w)
        b = below[row]
        ok = b >= 0
        bb = np.where(ok, b, 0)
        out[row] = np.where(e[row] & ok, np.arange(v * w, (v + 1) * w),
                            np.where(ok & ~s[bb], out[bb], -1))
    return out


def row_fill(A: np.ndarray, gt: np.ndarray, hidden: np.ndarray, donor: np.ndarray,
             same: float = 0.05) -> np.ndarray:
    """Per hidden pixel (flat, row-major order), the aligned depth of the nearest ``donor`` pixel
    of its row whose true depth is within ``same`` of its own (NaN: none)."""
    h, w = A.shape
    out = np.full(len(hidden), np.nan)
    hv, hu = np.divmod(hidden, w)
    for v in np.unique(hv):
        k = np.flatnonzero(hv == v)
        cols = np.flatnonzero(donor[v])
        if not len(cols):
            continue
        g = gt[v, cols]
        for j in k:
            ok = np.abs(g / gt[v, hu[j]] - 1.0) <= same
            if ok.any():
                c = cols[ok]
                out[j] = A[v, c[np.argmin(np.abs(c - hu[j]))]]
    return out


def image_edges(img: np.ndarray, below: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) bool: the static image's largest channel difference between a pixel and the one
    below it on its vertical exceeds ``threshold`` (bench_edge_stops.py's cue)."""
    h, w = img.shape[:2]
    flat = img.reshape(h * w, -1)
    ok = below >= 0
    diff = np.abs(flat - flat[np.where(ok, below, 0)]).max(-1)
    return (ok & (diff > threshold)).reshape(h, w)


def analyse(seq: str, sets: dict, step: float, detector: str = "true",
            threshold: float = 0.3) -> dict:
    from staticdepth.geometry.alignment_vertical import down_step, vertical_depth
    from staticdepth.geometry.projection import ray_grid

    res = {k: [] for k in ("now",) + FILLS}
    share, err, inside, strip = [], [], [], []
    with KeptRun(seq, sets) as run:
        K = np.asarray(run.K, np.float64)
        h, w = run.height, run.width
        n = run.n_g / np.linalg.norm(run.n_g)
        below = below_index(down_step(K, n, w, h))
        bb = np.where(below >= 0, below, 0)
        rays = ray_grid(K, w, h).reshape(-1, 3)
        q = rays @ n                       # the plane's inverse depth, the plane at distance 1
        edges = None if detector == "true" else image_edges(run.image, below, threshold)
        for f in run.frames():
            gt, m, reg, info, vm = (f[k] for k in ("gt", "agents", "regions", "info", "valid"))
            A = np.asarray(f["aligned"], np.float64)
            g = np.nan_to_num(gt, nan=0.0).ravel()
            if detector == "true":
                with np.errstate(invalid="ignore"):
                    edge = ((below >= 0) & (g[bb] < (1.0 - step) * g)
                            & ~reg["ground"].ravel()[bb]).reshape(h, w)
                truth_s = reg["structures"]
            else:   # what adapt could see: image edges above a pixel it did not take for ground
                edge = edges & ~info["ground"].ravel()[bb].reshape(h, w)
                truth_s = True
            fe = first_edge(below, edge, info["ground"])
            moved = info["moved"] & (info["contact"] >= 0) & ~m & truth_s & vm
            hid = np.flatnonzero(moved.ravel() & (fe >= 0))
            donor = moved & (fe.reshape(h, w) < 0)
            b = below[fe[hid]]              # the pixel just below the edge
            strip.append(reg["ground"].ravel()[fe[hid]])
            near = A.ravel()[b]
            far = np.full(len(hid), np.inf)
            okq = q[b] > 0
            far[okq] = vertical_depth(rays, n, b[okq], q[b][okq], hid[okq])
            scale = float(np.median(gt[vm] / A[vm]))
            t = g[hid] / scale
            fills = {"truth": t, "far": np.where(np.isfinite(far), far, A.ravel()[hid]),
                     "near": near, "mid": np.where(np.isfinite(far), np.sqrt(near * far), near),
                     "row": row_fill(A, gt, hid, donor)}
            res["now"].append(frame_absrel(A, gt, vm))
            for k, fill in fills.items():
                out = A.copy().ravel()
                ok = np.isfinite(fill) & (fill > 0)
                out[hid[ok]] = fill[ok]
                res[k].append(frame_absrel(out.reshape(h, w), gt, vm))
            share.append(len(hid) / max(int(vm.sum()), 1))
            err.append(np.abs(A.ravel()[hid] * scale / g[hid] - 1.0))
            tp = g[hid] / run.mount[1]      # the truth in the plane's units (camera heights)
            inside.append((tp >= near) & (tp <= far))
    e, ins, st = np.concatenate(err), np.concatenate(inside), np.concatenate(strip)
    return {"absrel": {k: float(np.mean(v)) for k, v in res.items()},
            "share": float(np.mean(share)), "hidden_absrel": float(e.mean()) if len(e) else 0.0,
            "inside": float(ins.mean()) if len(ins) else 0.0,
            "strip": float(st.mean()) if len(st) else 0.0}


def main() -> None:
    ap = kept_run_parser(__doc__, "i1-m1,i3-m1,i4-m1")
    ap.add_argument("--step", type=float, default=0.3,
                    help="a true occluding edge: the truth nearer by more than this, one row down")
    ap.add_argument("--detector", choices=("true", "image"), default="true",
                    help="the hidden pixels: true occluding edges (oracle), or image edges of "
                         "the static image (what adapt sees; not restricted to true structures)")
    ap.add_argument("--edge-threshold", type=float, default=0.3,
                    help="--detector image: the channel difference that makes an edge")
    args = ap.parse_args()
    print("| run | hidden share | hidden AbsRel | inside [near, far] | ground above the edge | "
          "aligned | "
          + " | ".join(FILLS) + " |")
    print("|---" * (6 + len(FILLS)) + "|")
    for run, seq, sets in kept_runs(args):
        res = analyse(seq, sets, args.step, args.detector, args.edge_threshold)
        a = res["absrel"]
        print(f"| {run} | {res['share']:.3f} | {res['hidden_absrel']:.3f} | {res['inside']:.0%} | "
              f"{res['strip']:.0%} | "
              f"{a['now']:.4f} | " + " | ".join(f"{a[k]:.4f}" for k in FILLS) + " |", flush=True)


if __name__ == "__main__":
    main()
