"""Is the alignment idempotent? (issue 19) ``align(align(x))`` against ``align(x)``, per region.

ft-align aligns a network fine-tuned on aligned labels: where the network learned its labels,
the alignment meets an already aligned map, and whatever it changes there is its own doing.
Reads sequences that ``bench_gains.py --keep`` left in its work folder (their ``base``
prediction, adapt's summary), aligns the evaluation frames as adapt's align stage does
(``aligned_frame``, ``--set align.KEY=VALUE`` over adapt's settings), aligns the result again,
and prints per region the AbsRel (median scaling per frame, as ``evaluate``) of base, once and
twice, the share of pixels the second pass moves by more than 1%, and which of the upright mode's
pixel categories (``bench_align_regions.categories``) those pixels fall in on each pass.

Usage:
  python benchmarks/bench_align_twice.py --work out/bench --runs i3-m1,i4-m1 [--every 2]
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from benchmarks.bench_align_regions import (categories, kept_run_parser, kept_runs,  # noqa: E402
                                            run_settings, walked_region)

REGIONS = ("all", "ground", "agents", "structures", "0-10m", "10-20m", "20-40m", "40-80m")


def _aligned(conf, K, n_g, walked, inst, rows, Z, info):
    """adapt's ``aligned_frame`` (plane bound on), with the upright mode's categories."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.geometry.alignment import agents_at_contact, align_depth

    m = inst > 0
    am = m if np.count_nonzero(walked & ~m) >= 50 else None
    A = align_depth(Z, K, n_g, 1.0, walked, agent_mask=am, mode=conf.align.mode,
                    snap_rel=conf.align.snap_rel, info=info, **upright_options(conf.align)).depth
    if conf.align.agents_at_contact:
        A = agents_at_contact(A, K, n_g, 1.0, inst, rows, conf.pseudo_labels)[0]
    return A


def analyse(seq: str, sets: dict, every: int) -> dict:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.evaluate import region_masks
    from staticdepth.metrics import apply_protocol, valid_mask

    conf, n_g = run_settings(seq, sets)
    acc: dict = {}
    moved_by: dict = {}
    with SequenceReader(seq) as r:
        K = r.camera.K
        mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
        rows, walked = walked_region(r, conf)
        for i in r.split("eval")[::every]:
            Z, gt, inst = r.prediction("base", i), r.depth(i), r.instances(i)
            info1: dict = {}
            info2: dict = {}
            A1 = _aligned(conf, K, n_g, walked, inst, rows[i], Z, info1)
            A2 = _aligned(conf, K, n_g, walked, inst, rows[i], A1, info2)
            vm = valid_mask(gt, 1e-3, 80.0)
            reg = region_masks(gt, inst, rows[i], K, mount, 80.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                changed = vm & ~(np.abs(A2 / A1 - 1.0) <= 0.01)
            errs = {}
            for name, pred in (("base", Z), ("once", A1), ("twice", A2)):
                scaled, _ = apply_protocol(pred, gt, "median", vm & np.isfinite(pred) & (pred > 0))
                errs[name] = np.abs(scaled - gt) / gt
            for reg_name in REGIONS:
                m = reg.get(reg_name, np.zeros_like(vm)) & vm
                if np.count_nonzero(m) < 20:
                    continue
                a = acc.setdefault(reg_name, {k: [] for k in ("base", "once", "twice", "changed")})
                for k, e in errs.items():
                    a[k].append(float(np.mean(e[m])))
                a["changed"].append(np.count_nonzero(m & changed) / np.count_nonzero(m))
            if "snapped" in info1:
                c1 = categories(info1, walked, inst > 0)
                c2 = categories(info2, walked, inst > 0)
                for a, b in zip(c1[changed], c2[changed]):
                    moved_by[(a, b)] = moved_by.get((a, b), 0) + 1
                moved_by["total"] = moved_by.get("total", 0) + int(vm.sum())
    return {"regions": {k: {kk: float(np.mean(vv)) for kk, vv in v.items()}
                        for k, v in acc.items()}, "moved_by": moved_by}


def report(name: str, res: dict) -> None:
    print(f"\n{name}: region | base | once | twice | share moved > 1%")
    for reg in REGIONS:
        a = res["regions"].get(reg)
        if a:
            print(f"  {reg:10s} | {a['base']:.3f} | {a['once']:.3f} | {a['twice']:.3f} | "
                  f"{a['changed']:.3f}")
    mb = dict(res["moved_by"])
    total = mb.pop("total", 0)
    if total:
        print("  moved by the second pass (category once -> twice): share of the valid pixels")
        for (a, b), k in sorted(mb.items(), key=lambda kv: -kv[1])[:10]:
            print(f"    {a:15s} -> {b:15s} {k / total:.4f}")


def main() -> None:
    ap = kept_run_parser(__doc__, "i3-m1")
    ap.add_argument("--every", type=int, default=1, help="every k-th evaluation frame")
    args = ap.parse_args()
    for run, seq, sets in kept_runs(args):
        report(run, analyse(seq, sets, args.every))


if __name__ == "__main__":
    main()
