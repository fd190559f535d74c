"""Which agents' pseudo labels to trust on a low camera? (issue 19, grazing contacts)

Reads sequences that ``bench_gains.py`` has adapted (``--keep``: ``<scene>-m<k>.h5`` with its
``.adapt`` stages and ``.pred`` predictions). Per agent and adaptation frame: the label's depth
(the agents' plane at its contact, read from adapt's ``align`` prediction x the true camera
height, as ``bench_gains.agent_label_error``), the base network's depth at the labels' scale,
each one's relative error of the agent's median against its median true depth, and the label's
expected relative error propagated from the plane's uncertainty and the contact row
(:func:`staticdepth.pseudo_labels.plane_depth_rel_std`). Prints the label and base errors per
band of that expected error, and what the agents' labels would be if those whose expected error
exceeds the base's (:func:`staticdepth.pseudo_labels.grazing_agents`, measured per frame without
the truth) took the base's depth instead (``hard``) or the inverse-variance mix of both
(``blend``), or only those whose contact is not seen (``unseen``).

Usage:
  python benchmarks/bench_label_trust.py out/bench/i4-m0.h5 [more.h5 ...] [--row-px 1]
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def agent_rows(seq: str, row_px: float) -> np.ndarray:
    """(N, 4): per agent-frame label error, base error, expected label error, frame's base error."""
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_CLASSES
    from staticdepth.metrics import valid_mask
    from staticdepth.pseudo_labels import (PseudoLabelConfig, contact_label_std,
                                           plane_depth_rel_std)

    with open(seq + ".adapt.json") as f:
        plane = json.load(f)["plane"]
    out = []
    with SequenceReader(seq) as r:
        h_c = r.meta.mounting.height_m
        std_map = plane_depth_rel_std(r.camera.K, plane["normal"],
                                      float(plane["uncertainty"]["normal_std_deg"] or np.nan),
                                      r.width, r.height, row_px)
        for i in r.split("adapt"):
            gt, inst, rows = r.depth(i), r.instances(i), r.agents(i)
            vm = valid_mask(gt)
            label = r.prediction("align", i) * h_c
            base = r.prediction("base", i)
            sig, _ = contact_label_std(std_map, inst, rows, PseudoLabelConfig())
            agents = inst > 0
            ok = agents & np.isfinite(label) & np.isfinite(base) & (base > 0)
            if np.count_nonzero(ok) < 5:
                continue
            c = np.median(label[ok] / base[ok])          # the base at the labels' scale
            base = base * c
            frame_base_err = float(np.median(np.abs(base[ok] / label[ok] - 1)))
            ids = rows["instance_id"][np.isin(rows["class_id"],
                                              list(AGENT_CLASSES | ACCESSORY_CLASSES))]
            for iid in ids:
                m = (inst == iid) & vm
                if np.count_nonzero(m) < 5:
                    continue
                z = np.median(gt[m])
                out.append((np.nanmedian(label[m]) / z - 1, np.nanmedian(base[m]) / z - 1,
                            float(np.nanmedian(sig[m])), frame_base_err))
    return np.asarray(out)


def summary(name: str, e: np.ndarray) -> str:
    a = np.abs(e[np.isfinite(e)])
    if not len(a):
        return f"{name} -"
    return (f"{name} median {np.median(a):.3f} mean {np.mean(a):.3f} "
            f"p90 {np.percentile(a, 90):.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("seqs", nargs="+")
    ap.add_argument("--row-px", type=float, default=1.0)
    args = ap.parse_args()
    for seq in args.seqs:
        R = agent_rows(seq, args.row_px)
        lab, base, sig, sb = R.T
        print(f"\n{seq}: {len(R)} agent-frames; contact unseen {np.isinf(sig).sum()}, expected label error"
              f" of the others median {np.median(sig[np.isfinite(sig)]):.3f}; frames' base error median {np.median(sb):.3f}")
        for lo, hi in ((0, 0.02), (0.02, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, np.inf),
                       (np.inf, np.inf)):
            m = (sig >= lo) & (sig < hi) if hi > lo else np.isinf(sig)
            if m.any():
                print(f"  expected {lo:.2f}-{hi:.2f}: n {m.sum():4d} | " + summary("label", lab[m])
                      + " | " + summary("base", base[m]))
        bad = sig > sb
        hard = np.where(bad, base, lab)
        unseen = np.where(np.isinf(sig), base, lab)     # only the contacts not seen
        w = sb ** 2 / (sig ** 2 + sb ** 2)      # inverse-variance weight of the label
        blend = (1 + lab) ** w * (1 + base) ** (1 - w) - 1     # in log depth
        print(f"  untrusted (expected > frame's base error): {bad.sum()} of {len(R)}")
        for name, e in (("label", lab), ("base", base), ("hard", hard), ("blend", blend),
                        ("unseen", unseen)):
            print("   " + summary(name, e))
        if bad.any():
            print("   on the untrusted: " + summary("label", lab[bad]) + " | "
                  + summary("base", base[bad]) + " | " + summary("blend", blend[bad]))


if __name__ == "__main__":
    main()
