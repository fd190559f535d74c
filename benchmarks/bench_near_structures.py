"""Near structures the upright alignment pushes too far (issue 19): where their walk ends and
which rule sets their depth.

On the runs ``bench_gains.py --keep`` left (as ``bench_align_regions.py``), the evaluation split's
base predictions aligned again with adapt's settings (``--set align.KEY=VALUE`` over them). The
near structures are the pixels within ``--near`` m (true depth) that are neither true ground nor
agents. For them:
- which rule decides their final depth: ``snapped`` (the ground fit put them on the plane and
  the recession test kept them there), ``plane-recede`` / ``plane-walked`` (took the plane: they
  recede / the walked-region rule), ``traced`` (re-anchored at a contact of their own), ``filled``
  (a row neighbour's ratio), ``refused-pull`` / ``refused-range`` (a contact the trust rules
  refused: ground mode), ``untraced`` (no contact: ground mode); and whether ``plane_bound``
  lowered the result (``+bound``);
- for the traced ones: what stands at the contact in the truth (G, S, A, last row), where it
  lies against the structure's true foot (the first true-ground pixel down the pixel's vertical:
  ``above`` it, i.e. on the structure or what it hides, ``at`` it within one row, ``below``), the
  true depth at the contact over the pixel's, the plane's depth at the contact over the pixel's
  true depth (metric: the plane in camera heights times the true height) and the contact's own
  category (snapped / recede / walked);
- the metric error of the network (brought to the aligned units), the ground mode and the result
  over the truth (median over the pixels; 1 is right, 2 twice too far).
Beside those, per run: the frame's AbsRel (median scaling) now, with the near structures at the
ground mode's depth, and at the truth (the oracles), and the near structures' AbsRel.

``--compare``: instead, AbsRel per region (median scaling, per-frame mean as ``evaluate``) of
base, ``align`` and ``align`` with the colour foot (``align.colour_foot``:
``upright_depth(image=...)`` with the median of the adaptation frames,
adaptation.align.static_image, and alignment_upright's ``FOOT_DIFF`` / ``FOOT_PULL``: a traced
pixel whose colour run down the vertical goes on below its contact stands at the run's foot), the
near structures as a region (``near``), and the regions more than 3% worse than base.

Usage:
  python benchmarks/bench_near_structures.py --work out/bench --runs i4-m1,h3-m1 [--near 10]
  python benchmarks/bench_near_structures.py --work out/bench --runs i1-m1,i4-m1 --compare
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_align_regions import kept_run_parser, kept_runs, run_settings, walked_region  # noqa
from bench_contacts import frame_absrel  # noqa
from bench_edge_stops import REGIONS, frame_regions  # noqa

TRUTH = ("G", "S", "A", "last-row")
RULES = ("snapped", "plane-recede", "plane-walked", "traced", "filled", "refused-pull",
         "refused-range", "untraced")


def first_below(mask: np.ndarray, du: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """Flat index of the first pixel of ``mask`` on or below each flat ``pix`` down the image's
    vertical (``du``: alignment_vertical.down_step), -1 where the walk leaves the image first."""
    h, w = mask.shape
    v, u = np.divmod(pix, w)
    uf = u.astype(np.float64)
    out = np.full(len(pix), -1, np.int64)
    act = np.ones(len(pix), bool)
    while act.any():
        ui = np.clip(np.rint(uf), 0, w - 1).astype(np.int64)
        hit = act & mask[np.minimum(v, h - 1), ui]
        out[hit] = (v * w + ui)[hit]
        act &= ~hit
        step = du[np.minimum(v, h - 1), ui]
        act &= np.isfinite(step) & (v + 1 < h)
        uf = np.where(act, uf + np.nan_to_num(step), uf)
        v = np.where(act, v + 1, v)
    return out


def align_frame(Z, K, n_g, walked, am, conf, info=None, **extra):
    """The frame aligned as adapt's align stage does, before the agents take their contact's
    depth (``extra``: align_upright's keywords over adapt's settings)."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.geometry.alignment import align_upright

    opts = {**upright_options(conf.align), **extra}
    return align_upright(Z, K, n_g, 1.0, walked if am is None else walked & ~am,
                         agent_mask=am, snap_rel=conf.align.snap_rel, info=info, **opts).depth


def rule_of(info: dict, pix: np.ndarray, max_contact: float, max_pull: float) -> np.ndarray:
    """Index into RULES of the rule that set each flat pixel's depth."""
    f = {k: v.ravel()[pix] for k, v in info.items() if isinstance(v, np.ndarray)}
    out = np.full(len(pix), RULES.index("untraced"))
    traced = f["traced"]
    out[traced & ~f["moved"]] = RULES.index("refused-pull")
    with np.errstate(divide="ignore", invalid="ignore"):
        far = traced & ~f["moved"] & ~(1.0 / f["contact_q"] <= max_contact)
    out[far] = RULES.index("refused-range")
    out[f["moved"] & (f["contact"] < 0)] = RULES.index("filled")
    out[f["moved"] & (f["contact"] >= 0)] = RULES.index("traced")
    pl = f["planar"] & ~f["moved"]
    out[pl] = RULES.index("plane-recede")
    out[pl & f["planar_walked"]] = RULES.index("plane-walked")
    out[f["snapped"] & f["ground"] & ~f["moved"] & ~f["planar"]] = RULES.index("snapped")
    return out


def analyse(seq: str, sets: dict, near_m: float) -> dict:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.geometry.alignment import agents_at_contact
    from staticdepth.geometry.alignment_vertical import down_step
    from staticdepth.geometry.projection import ray_grid
    from staticdepth.metrics import valid_mask

    conf, n_g = run_settings(seq, sets)
    keys = ("rule", "bound", "at", "where", "ratio", "push", "ccat", "net", "gmode", "aligned",
            "frame", "near<-ground", "near<-truth", "near_absrel", "share", "walk")
    out: dict = {k: [] for k in keys}
    with SequenceReader(seq) as r:
        K = r.camera.K
        mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
        h_m, w = mount[1], r.width
        rows, walked = walked_region(r, conf)
        du = down_step(K, n_g / np.linalg.norm(n_g), r.width, r.height)
        q = ray_grid(np.asarray(K, np.float64), r.width, r.height) @ (n_g / np.linalg.norm(n_g))
        mc = np.inf if conf.align.contact_range is None else \
            conf.align.contact_range / q[walked & (q > 0)].min()     # as align_upright
        for i in r.split("eval"):
            Z, gt, inst = r.prediction("base", i), r.depth(i), r.instances(i)
            m = inst > 0
            am = m if np.count_nonzero(walked & ~m) >= 50 else None     # as aligned_frame
            reg = region_masks(gt, inst, rows[i], K, mount, 80.0)
            info: dict = {}
            A = align_frame(Z, K, n_g, walked, am, conf, info)
            unbound = align_frame(Z, K, n_g, walked, am, conf, plane_bound=False)
            if conf.align.agents_at_contact:
                A = agents_at_contact(A, K, n_g, 1.0, inst, rows[i], conf.pseudo_labels)[0]
            vm = valid_mask(gt, 1e-3, 80.0)
            near = vm & reg["structures"] & (gt < near_m)
            out["frame"].append(frame_absrel(A, gt, vm))
            med = float(np.median(gt[vm] / A[vm]))
            o = A.copy()
            o[near] = info["ground_mode"][near]
            out["near<-ground"].append(frame_absrel(o, gt, vm))
            o[near] = gt[near] / med
            out["near<-truth"].append(frame_absrel(o, gt, vm))
            out["share"].append(near.sum() / vm.sum())
            pix = np.flatnonzero(near)
            if not len(pix):
                continue
            out["near_absrel"].append(np.abs(med * A.ravel()[pix] / gt.ravel()[pix] - 1.0))
            out["rule"].append(rule_of(info, pix, mc, conf.align.max_pull or np.inf))
            out["bound"].append(A.ravel()[pix] < unbound.ravel()[pix] * (1 - 1e-5))
            truth = np.where(reg["ground"], 0, np.where(reg.get("agents", m), 2, 1))
            c = info["contact"].ravel()[pix]
            has = c >= 0
            cc = np.where(has, c, 0)
            at = np.where(cc // w == r.height - 1, 3, truth.ravel()[cc])
            out["at"].append(np.where(has, at, -1))
            foot = first_below(reg["ground"], du, pix)
            fv = np.where(foot >= 0, foot // w, r.height)
            cv = cc // w
            out["where"].append(np.where(~has, -1, np.where(cv < fv - 1, 0,
                                                            np.where(cv <= fv + 1, 1, 2))))
            with np.errstate(divide="ignore", invalid="ignore"):
                out["ratio"].append(np.where(has, gt.ravel()[cc] / gt.ravel()[pix], np.nan))
                out["push"].append(np.where(has, h_m / info["contact_q"].ravel()[pix]
                                            / gt.ravel()[pix], np.nan))
            ccat = np.where(info["planar_walked"].ravel()[cc], 2,
                            np.where(info["planar"].ravel()[cc], 1, 0))
            out["ccat"].append(np.where(has, ccat, -1))
            out["walk"].append(np.where(has, cv - pix // w, -1))
            for k, mp in (("net", info["raw"]), ("gmode", info["ground_mode"]), ("aligned", A)):
                out[k].append(h_m * mp.ravel()[pix] / gt.ravel()[pix])
    return {k: (np.concatenate(v) if v and np.ndim(v[0]) else np.asarray(v))
            for k, v in out.items()}


def report(name: str, res: dict) -> None:
    err = res["near_absrel"]
    print(f"\n{name}: frame AbsRel {res['frame'].mean():.3f}; near structures "
          f"{res['share'].mean():.1%} of the pixels, AbsRel {err.mean():.3f}; oracles: near at the "
          f"ground mode {res['near<-ground'].mean():.3f}, at the truth "
          f"{res['near<-truth'].mean():.3f}")
    print(f"  metric / true, median: network {np.nanmedian(res['net']):.2f}, ground mode "
          f"{np.nanmedian(res['gmode']):.2f}, aligned {np.nanmedian(res['aligned']):.2f}")
    print(f"  {'rule':14s} share  AbsRel  +bound  net   gmode aligned")
    rule, bound = res["rule"], res["bound"]
    for k, n in enumerate(RULES):
        s = rule == k
        if s.mean() < 0.005:
            continue
        print(f"  {n:14s} {s.mean():5.1%} {err[s].mean():6.3f} {bound[s].mean():6.0%} "
              f"{np.nanmedian(res['net'][s]):5.2f} {np.nanmedian(res['gmode'][s]):5.2f} "
              f"{np.nanmedian(res['aligned'][s]):5.2f}")
    t = rule == RULES.index("traced")
    if t.any():
        at, wh, cc = res["at"][t], res["where"][t], res["ccat"][t]
        print("  traced: contact on " + ", ".join(f"{n} {np.mean(at == k):.0%}"
                                                  for k, n in enumerate(TRUTH))
              + "; against the true foot: " + ", ".join(
                  f"{n} {np.mean(wh == k):.0%}" for k, n in enumerate(("above", "at", "below")))
              + "; contact's category: " + ", ".join(
                  f"{n} {np.mean(cc == k):.0%}" for k, n in enumerate(("snapped", "recede",
                                                                       "walked"))))
        print(f"    true depth at contact / pixel q10/50/90 "
              f"{' / '.join(f'{x:.2f}' for x in np.nanpercentile(res['ratio'][t], [10, 50, 90]))}"
              f"; plane at contact (metric) / pixel "
              f"{' / '.join(f'{x:.2f}' for x in np.nanpercentile(res['push'][t], [10, 50, 90]))}"
              f"; walk rows q50 {np.median(res['walk'][t]):.0f}")
        for k, n in enumerate(("snapped", "recede", "walked")):
            s = cc == k
            if s.mean() >= 0.02:
                print(f"    contact {n:8s} {s.mean():4.0%}: AbsRel {err[t][s].mean():.3f}, on G "
                      f"{np.mean(at[s] == 0):.0%}, above the foot {np.mean(wh[s] == 0):.0%}, "
                      f"plane/pixel q50 {np.nanmedian(res['push'][t][s]):.2f}")


def compare(seq: str, sets: dict, near_m: float) -> dict:
    """Per prediction (base, align, align with the colour foot), per region: the frames' AbsRel."""
    from staticdepth.adaptation.align import static_image
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.geometry.alignment import agents_at_contact
    from staticdepth.metrics import apply_protocol, depth_metrics, valid_mask

    conf, n_g = run_settings(seq, sets)
    out: dict = {}
    with SequenceReader(seq) as r:
        K = r.camera.K
        mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
        rows, walked = walked_region(r, conf)
        img = static_image(r, r.split("adapt"))       # as adapt's align stage
        for i in r.split("eval"):
            Z, gt, inst = r.prediction("base", i), r.depth(i), r.instances(i)
            m = inst > 0
            am = m if np.count_nonzero(walked & ~m) >= 50 else None     # as aligned_frame
            reg = region_masks(gt, inst, rows[i], K, mount, 80.0)
            reg["near"] = reg["structures"] & (gt < near_m)
            vm = valid_mask(gt, 1e-3, 80.0)
            preds = {"base": Z}
            for name, extra in (("align", {}), ("colour-foot", {"image": img})):
                info: dict = {}
                A = align_frame(Z, K, n_g, walked, am, conf, info, **extra)
                if conf.align.agents_at_contact:
                    A = agents_at_contact(A, K, n_g, 1.0, inst, rows[i], conf.pseudo_labels)[0]
                preds[name] = A
            for name, p in preds.items():
                d = out.setdefault(name, {})
                for k, x in frame_regions(p, gt, reg, vm).items():
                    d.setdefault(k, []).append(x)
                if (vm & reg["near"]).any():      # frame_regions keeps evaluate's regions only
                    scaled, _ = apply_protocol(p, gt, "median", vm)
                    d.setdefault("near", []).append(depth_metrics(
                        scaled, gt, max_depth=80.0, mask=vm & reg["near"])["abs_rel"])
    return {n: {k: float(np.mean(v)) for k, v in d.items()} for n, d in out.items()}


def report_compare(name: str, res: dict) -> None:
    keys = [k for k in (*REGIONS, "near") if k in res["base"]]
    print(f"\n{name}: AbsRel {' '.join(f'{k:>10s}' for k in keys)}  worse than base by > 3%")
    for n, d in res.items():
        worse = [k for k in REGIONS if k in d and d[k] > 1.03 * res["base"][k]]
        print(f"  {n:12s} {' '.join(f'{d.get(k, np.nan):10.4f}' for k in keys)}  {len(worse)} "
              f"{','.join(worse)}")


def main() -> None:
    ap = kept_run_parser(__doc__, "i1-m1,i3-m1,i4-m1")
    ap.add_argument("--near", type=float, default=10.0, help="near structures: true depth below")
    ap.add_argument("--compare", action="store_true",
                    help="AbsRel per region of base, align and align with the colour foot")
    args = ap.parse_args()
    for run, seq, sets in kept_runs(args):
        if args.compare:
            report_compare(run, compare(seq, sets, args.near))
        else:
            report(run, analyse(seq, sets, args.near))


if __name__ == "__main__":
    main()
