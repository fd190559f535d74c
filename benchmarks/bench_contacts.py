"""Where do the traced structures' contacts lie, and what would the right contact give? (issue 19)

On the runs ``bench_gains.py --keep`` left (as ``bench_align_regions.py``), the evaluation split's
base predictions aligned again with adapt's settings (``--set align.KEY=VALUE`` over them). For
the traced structure pixels (re-anchored at a contact of their own), the true depth at the contact
over the pixel's (``ratio``: 1 the right contact, below 1 a contact in front) and, for those in
front (``ratio < --front``) and those pushed too far:
- what stands at the run's base in the truth (ground G, structure S, agent A; ``last-row``: the
  image's bottom row): the base is the run's lowest pixel, or the ground pixel its foot walked to;
  and below it, the pixel the alignment took for ground;
- what the depths do along the walk from the pixel down to its contact: the truth's largest step
  nearer going down one row (an occluding edge the walk crossed when it is large), and the
  network's (the map the walk is taken on) largest step over one row and over ``--window`` rows;
- oracles, AbsRel of the frame (median scaling) with each run (pixels sharing a contact) scaled by
  its best scale (the median of truth / aligned over the run, in the frame's median units): every
  run (``oracle-all``), only the runs whose contact lies in front (``oracle-front``), and the near
  structures' runs (``oracle-near``).

Usage:
  python benchmarks/bench_contacts.py --work out/bench --runs i1-m1,i3-m1,i4-m1 [--front 0.7]
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import KeptRun, kept_run_parser, kept_runs  # noqa: E402


def walk_profiles(src: np.ndarray, gt: np.ndarray, du: np.ndarray, pix: np.ndarray,
                  contact: np.ndarray, window: int) -> dict[str, np.ndarray]:
    """Per traced pixel (flat ``pix``, its flat ``contact``), walking down the image's vertical
    (``du``) to the contact's row: the truth's and the network's (``src``) largest relative step
    nearer going down one row, the network's over ``window`` rows, and the share of rows whose
    network step is nearer."""
    h, w = src.shape
    v, u = np.divmod(pix, w)
    cv = contact // w
    uf = u.astype(np.float64)
    gt_step = np.zeros(len(pix))
    net_step = np.zeros(len(pix))
    net_win = np.zeros(len(pix))
    hist = [src[v, u]]
    while True:
        act = v < cv
        if not act.any():
            break
        step = np.nan_to_num(du[v, np.clip(np.rint(uf), 0, w - 1).astype(np.int64)])
        vn = np.where(act, v + 1, v)
        uf = np.where(act, uf + step, uf)
        un = np.clip(np.rint(uf), 0, w - 1).astype(np.int64)
        uo = np.clip(np.rint(uf - step), 0, w - 1).astype(np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            g = gt[v, uo] / gt[vn, un] - 1.0
            s = src[v, uo] / src[vn, un] - 1.0
        gt_step = np.where(act, np.fmax(gt_step, g), gt_step)
        net_step = np.where(act, np.fmax(net_step, s), net_step)
        cur = np.where(act, src[vn, un], hist[-1])
        hist.append(cur)
        if len(hist) > window:
            with np.errstate(invalid="ignore", divide="ignore"):
                net_win = np.where(act, np.fmax(net_win, hist[-window - 1] / cur - 1.0), net_win)
        v = vn
    return {"gt_step": gt_step, "net_step": net_step, "net_win": net_win}


def frame_absrel(pred: np.ndarray, gt: np.ndarray, vm: np.ndarray) -> float:
    """The frame's AbsRel as the evaluation computes it (median scaling, depth_metrics)."""
    from staticdepth.metrics import apply_protocol, depth_metrics

    scaled, _ = apply_protocol(pred, gt, "median", vm)
    return depth_metrics(scaled, gt, max_depth=80.0, mask=vm)["abs_rel"]


def run_oracle(A: np.ndarray, gt: np.ndarray, vm: np.ndarray, contact: np.ndarray,
               runs: np.ndarray) -> np.ndarray:
    """A with each run of ``runs`` (pixels sharing a contact) scaled by its best scale."""
    out = A.copy()
    m = float(np.median(gt[vm] / A[vm]))
    ids = contact[runs]
    with np.errstate(invalid="ignore", divide="ignore"):
        r = gt[runs] / (m * A[runs])
    uniq, inv = np.unique(ids, return_inverse=True)
    best = np.array([np.nanmedian(r[inv == k]) for k in range(len(uniq))])
    out[runs] = A[runs] * best[inv]
    return out


def analyse(seq: str, sets: dict, front: float, window: int) -> dict:
    from staticdepth.geometry.alignment_vertical import down_step

    out: dict = {k: [] for k in ("ratio", "ratio_near", "at", "at_near", "gt_step", "net_step",
                                 "net_win", "frame", "oracle-all", "oracle-front",
                                 "oracle-near", "near_scale", "near_cat", "front_err",
                                 "below", "near_net")}
    with KeptRun(seq, sets) as run:
        r = run.reader
        du = down_step(run.K, run.n_g / np.linalg.norm(run.n_g), r.width, r.height)
        for f in run.frames():
            gt, m, reg, info, A, vm = (f[k] for k in ("gt", "agents", "regions", "info",
                                                       "aligned", "valid"))
            truth = np.where(reg["ground"], 0, np.where(reg.get("agents", m), 2, 1))
            c = info["contact"]
            tr = vm & info["moved"] & reg["structures"] & (c >= 0)
            pix = np.flatnonzero(tr)
            ratio = gt.ravel()[c.ravel()[pix]] / gt.ravel()[pix]
            at = truth.ravel()[c.ravel()[pix]]
            at = np.where(c.ravel()[pix] // r.width == r.height - 1, 3, at)
            near = gt.ravel()[pix] < 10
            out["ratio"].append(ratio[~near])
            out["at"].append(at[~near])
            out["ratio_near"].append(ratio[near])
            out["at_near"].append(at[near])
            fr = (ratio < front) & ~near
            bv, bu = np.divmod(c.ravel()[pix[fr]], r.width)
            bu = np.clip(np.rint(bu + np.nan_to_num(du[bv, bu])), 0, r.width - 1).astype(int)
            out["below"].append(np.where(bv + 1 < r.height,
                                         truth[np.minimum(bv + 1, r.height - 1), bu], 3))
            prof = walk_profiles(info["raw"], gt, du, pix[fr], c.ravel()[pix[fr]], window)
            for k, val in prof.items():
                out[k].append(val)
            # the frame's median scale: aligned / true over the traced far front pixels and near
            med = float(np.median(gt[vm] / A[vm]))
            with np.errstate(invalid="ignore", divide="ignore"):
                sc = med * A.ravel()[pix] / gt.ravel()[pix]
            out["near_scale"].append(sc[near])
            med_raw = float(np.median(gt[vm] / info["raw"][vm]))
            out["near_net"].append(med_raw * info["raw"].ravel()[pix[near]] / gt.ravel()[pix[near]])
            out["near_cat"].append(info["planar"].ravel()[c.ravel()[pix[near]]])
            out["front_err"].append(np.abs(sc[fr] - 1.0))
            out["frame"].append(frame_absrel(A, gt, vm))
            front_runs = np.zeros_like(tr)
            front_runs.ravel()[pix[fr]] = True
            # every pixel of a front run, not just those with ratio < front
            front_ids = np.unique(c.ravel()[pix[fr]])
            front_runs |= tr & np.isin(c, front_ids)
            near_runs = tr & np.isin(c, np.unique(c.ravel()[pix[near]]))
            out["oracle-all"].append(frame_absrel(run_oracle(A, gt, vm, c, tr), gt, vm))
            out["oracle-front"].append(frame_absrel(run_oracle(A, gt, vm, c, front_runs), gt,
                                                    vm))
            out["oracle-near"].append(frame_absrel(run_oracle(A, gt, vm, c, near_runs), gt, vm))
    return {k: (np.concatenate(v) if v and np.ndim(v[0]) else np.asarray(v))
            for k, v in out.items()}


def report(name: str, res: dict, front: float, window: int) -> None:
    names = ["G", "S", "A", "last-row"]
    r, at = res["ratio"], res["at"]
    fr = r < front
    print(f"\n{name}: frame AbsRel {res['frame'].mean():.3f}; oracle (each run at its best "
          f"scale) all {res['oracle-all'].mean():.3f}, front runs {res['oracle-front'].mean():.3f},"
          f" near runs {res['oracle-near'].mean():.3f}")
    print(f"  traced structures >= 10 m: {len(r)} px, contact ratio q10/50/90 "
          f"{' / '.join(f'{x:.2f}' for x in np.percentile(r, [10, 50, 90]))}, "
          f"< {front}: {fr.mean():.0%}; aligned/true (median units) off by median "
          f"{np.median(res['front_err']):.2f} there")
    print("  at the base of those in front: " + ", ".join(
        f"{n} {np.mean(at[fr] == k):.0%}" for k, n in enumerate(names)) + "; below it: " +
        ", ".join(f"{n} {np.mean(res['below'] == k):.0%}" for k, n in enumerate(names)))
    gs, ns, nw = res["gt_step"], res["net_step"], res["net_win"]
    edge = gs > 0.3
    print(f"  along their walk: the truth steps > 30% nearer on {edge.mean():.0%} (an occluding "
          f"edge crossed); network's largest 1-row nearer step there q50/90 "
          f"{np.nanpercentile(ns[edge], 50):.3f} / {np.nanpercentile(ns[edge], 90):.3f}, over "
          f"{window} rows {np.nanpercentile(nw[edge], 50):.3f} / "
          f"{np.nanpercentile(nw[edge], 90):.3f}")
    for t in (0.04, 0.08, 0.15, 0.3):
        print(f"    network {window}-row nearer step > {t}: {np.mean(nw[edge] > t):.0%} of the "
              f"edge-crossing walks")
    rn, an, sc = res["ratio_near"], res["at_near"], res["near_scale"]
    if len(rn):
        print(f"  traced structures < 10 m: {len(rn)} px, contact ratio q10/50/90 "
              f"{' / '.join(f'{x:.2f}' for x in np.percentile(rn, [10, 50, 90]))}; aligned/true "
              f"q10/50/90 {' / '.join(f'{x:.2f}' for x in np.nanpercentile(sc, [10, 50, 90]))};"
              f" the network's own (median units) {np.nanmedian(res['near_net']):.2f}; base "
              f"took the plane (receding/walked rule) {res['near_cat'].mean():.0%}; at the base: "
              + ", ".join(f"{n} {np.mean(an == k):.0%}" for k, n in enumerate(names)))


def main() -> None:
    ap = kept_run_parser(__doc__, "i1-m1,i3-m1,i4-m1")
    ap.add_argument("--front", type=float, default=0.7)
    ap.add_argument("--window", type=int, default=4)
    args = ap.parse_args()
    for run, seq, sets in kept_runs(args):
        report(run, analyse(seq, sets, args.front, args.window), args.front, args.window)


if __name__ == "__main__":
    main()
