"""Compare settings of ``bench_gains.py`` over several runs each (e.g. fine-tuning seeds).

Each ``--run LABEL=FILE[,FILE...]`` is one setting: the JSON files of ``bench_gains.py --json``
for it, one per seed (a seed's scenes may be split over several files: files of one seed are
joined with ``+``). Per model, prediction and region it prints, for every setting, each scene's
mean over the seeds with their spread (max - min) and count, then the mean over the scenes and
the mean ratio to ``base``; the scenes are those every setting has (``--scenes`` to choose).
Base itself does not depend on fine-tuning: its ratio uses the first run that has the scene.

Usage (the built-in preset's learning rate, issue 19's eighteenth round):
  for lr in 0.0003 0.001; do for s in 0 1 2; do
    python benchmarks/bench_gains.py --models builtin:out/builtin.pt,builtin:out/unet.pt \\
      --scenes i1,i2,i3,i4 --frames 60 --epochs 30 --min-height-px 10 --extra-modes eq2 \\
      --set finetune.seed=$s --set finetune.lr=$lr --json out/lr$lr-s$s.json; done; done
  python benchmarks/gains_sweep.py --run 3e-4=out/lr0.0003-s0.json,out/lr0.0003-s1.json,... \\
      --run 1e-3=out/lr0.001-s0.json,... [--predictions ft-align,ft] [--regions all,agents]
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from staticdepth.errors import InputError


def load_seed(spec: str) -> dict:
    """One seed's results: the files joined by ``+`` merged (model -> scene -> table)."""
    out: dict = {}
    for path in spec.split("+"):
        try:
            with open(path) as f:
                data = json.load(f)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read a bench_gains JSON ({e})", path) from None
        for model, per in data.items():
            out.setdefault(model, {}).update({s: v["table"] for s, v in per.items()})
    return out


def parse_run(item: str) -> tuple[str, list[dict]]:
    label, sep, files = item.partition("=")
    if not sep or not label or not files:
        raise InputError(f"--run {item!r}: expected LABEL=FILE[,FILE...]")
    return label, [load_seed(f) for f in files.split(",")]


def summarise(runs: dict[str, list[dict]], scenes: list[str] | None, predictions: list[str],
              regions: list[str]) -> list[str]:
    models = sorted({m for seeds in runs.values() for seed in seeds for m in seed})
    lines = []
    for model in models:
        have = [set.intersection(*[set(seed.get(model, {})) for seed in seeds])
                for seeds in runs.values()]
        common = sorted(set.intersection(*have))
        use = scenes or common
        missing = [s for s in use if s not in common]
        if missing:
            raise InputError(f"{model}: scene(s) {', '.join(missing)} missing from some run's "
                             "seeds")
        base = {s: next(seed[model][s]["base"] for seeds in runs.values() for seed in seeds)
                for s in use}
        for pred in predictions:
            for reg in regions:
                lines.append(f"{model}: {pred}, {reg} (per scene: mean over seeds (spread, n); "
                             f"mean over {', '.join(use)}; mean ratio to base)")
                for label, seeds in runs.items():
                    cells, means, ratios = [], [], []
                    for s in use:
                        v = [seed[model][s][pred][reg] for seed in seeds]
                        m = float(np.mean(v))
                        means.append(m)
                        ratios.append(m / base[s][reg])
                        cells.append(f"{s} {m:.3f} ({max(v) - min(v):.3f}, {len(v)})")
                    lines.append(f"  {label:>8}: " + "  ".join(cells)
                                 + f" | mean {np.mean(means):.4f} ratio {np.mean(ratios):.3f}")
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", action="append", required=True, metavar="LABEL=FILE[,FILE...]")
    ap.add_argument("--scenes", help="comma-separated (default: those every run has)")
    ap.add_argument("--predictions", default="ft-align,ft")
    ap.add_argument("--regions", default="all,agents")
    args = ap.parse_args(argv)
    try:
        runs = dict(parse_run(item) for item in args.run)
        lines = summarise(runs, args.scenes.split(",") if args.scenes else None,
                          args.predictions.split(","), args.regions.split(","))
    except InputError as e:          # bad input: one line, exit code 2 (as the CLI does)
        print(e, file=sys.stderr)
        sys.exit(2)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
