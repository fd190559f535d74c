"""Regions a prediction makes worse than base, and whether that is more than fine-tuning's noise
(issue 19). Fine-tuning is not bit-reproducible and its seed moves the result: compare two
``bench_gains.py --json`` runs of the same settings with another ``finetune.seed`` before
calling a region worse or a change a gain.

Prints, per prediction (``ft``, ``ft-align``): the regions more than ``--margin`` (3%) worse than
base in each run, those worse in both, and the run-to-run spread ``|a - b| / base`` over every
scene and region (median, 90th percentile, max).

Usage:
  python benchmarks/bench_ft_noise.py out/seed0.json [out/seed1.json] [--margin 0.03]
"""
from __future__ import annotations

import argparse
import json

import numpy as np

REGIONS = ("all", "ground", "agents", "structures", "0-10m", "10-20m", "20-40m", "40-80m")


def worse(table: dict, pred: str, margin: float) -> dict:
    """{(model, scene, region): (base, pred)} where pred > (1 + margin) x base."""
    out = {}
    for model, per in table.items():
        for scene, v in per.items():
            t = v["table"]
            for r in REGIONS:
                if r in t.get(pred, {}) and t[pred][r] > (1 + margin) * t["base"][r]:
                    out[(model, scene, r)] = (t["base"][r], t[pred][r])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="one or two bench_gains.py --json files")
    ap.add_argument("--margin", type=float, default=0.03)
    args = ap.parse_args()
    runs = [json.load(open(p)) for p in args.runs[:2]]
    for pred in ("ft", "ft-align"):
        per_run = [worse(t, pred, args.margin) for t in runs]
        total = sum(1 for per in runs[0].values() for v in per.values() for r in REGIONS
                    if r in v["table"].get(pred, {}))
        for path, w in zip(args.runs, per_run):
            print(f"{pred} ({path}): {len(w)} of {total} regions worse than base: " + "; ".join(
                f"{m.split('/')[-1]} {s} {r} {b:.3f} -> {p:.3f}" for (m, s, r), (b, p) in w.items()))
        if len(runs) == 2:
            both = sorted(set(per_run[0]) & set(per_run[1]))
            d = np.array([abs(runs[0][m][s]["table"][pred][r] - runs[1][m][s]["table"][pred][r])
                          / runs[0][m][s]["table"]["base"][r]
                          for m in runs[0] for s in runs[0][m] for r in REGIONS
                          if r in runs[0][m][s]["table"].get(pred, {})])
            print(f"{pred}: worse in both runs {len(both)}: " + "; ".join(
                f"{m.split('/')[-1]} {s} {r}" for m, s, r in both))
            print(f"{pred}: run-to-run |a - b| / base: median {np.median(d):.3f}, p90 "
                  f"{np.percentile(d, 90):.3f}, max {d.max():.3f}")


if __name__ == "__main__":
    main()
