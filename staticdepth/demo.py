"""``staticdepth demo``: the whole toolkit on a built-in synthetic scene (no data, no weights).

It runs the demo recipe (``staticdepth/data/demo.yaml``, also ``recipes/demo.yaml``) through the
recipe runner: render a high, tilted fixed-camera stereo sequence; train the built-in network on
street-level scenes (the "off-the-shelf" model); adapt it on site (pseudo labels, fine-tuning,
ground plane from the agents, alignment, metric scale); train and run the stereo self-supervised
baseline; evaluate everything and write the paper's three tables and an HTML report. Stages whose
outputs are up to date are skipped, so a second run is quick.
"""
from __future__ import annotations

import argparse
import os
import time

DEMO_RECIPE = os.path.join(os.path.dirname(__file__), "data", "demo.yaml")


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on a built-in synthetic scene",
                       description="Render a synthetic fixed-camera sequence, adapt the built-in "
                                   "depth network to it, train the stereo baseline, evaluate, and "
                                   "write the three tables and an HTML report.")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--var", "--set", dest="var", action="append", default=[],
                   metavar="KEY=VALUE",
                   help="change a demo setting, e.g. --var frames=80 --var adapt_epochs=10")
    p.add_argument("--force", action="store_true", help="rerun every stage")
    p.add_argument("--quick", action="store_true",
                   help="a much smaller run (seconds to a minute) to check the installation")
    p.set_defaults(func=run)


QUICK = {"frames": "30", "adapt_frames": "20", "builtin_frames": "48", "builtin_epochs": "2",
         "builtin_size": "128x64", "adapt_epochs": "2", "baseline_epochs": "2"}

def inputs_note(adapt_args: dict) -> str:
    """Which of the adaptation's inputs were real (as on a site) and which oracle (the scene's
    own ground truth), from the demo recipe's adapt stage."""
    oracle, real = [], []
    if adapt_args.get("detector") == "gt":
        oracle.append("the agents are the scene's ground-truth instances (--detector gt)")
    else:
        real.append(f"the agents come from the {adapt_args.get('detector')} detector")
    settings = adapt_args.get("set") or {}
    if str(settings.get("scale.sequence_height", "true")).lower() in ("true", "1", "yes"):
        oracle.append("the camera height is the true one stored in the rendered sequence")
    else:
        real.append("the camera height comes from the agents' height distributions (the true one "
                    "only scores the result)")
    parts = ([f"real inputs: {'; '.join(real)}"] if real else []) + \
        ([f"oracle inputs: {'; '.join(oracle)}"] if oracle else [])
    return ". ".join(parts)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from staticdepth import report_figures as rf
    from staticdepth.cli import parse_overrides
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.fileio import write_image
    from staticdepth.run import load_recipe, run_recipe

    t0 = time.perf_counter()
    variables = {"out_dir": args.out, **(QUICK if args.quick else {}),
                 **parse_overrides(args.var, "--var")}
    recipe = load_recipe(DEMO_RECIPE, variables)
    run_recipe(recipe, force=args.force)
    seq = os.path.join(recipe["out_dir"], "demo.h5")
    with SequenceReader(seq) as r:
        i = r.split("eval")[len(r.split("eval")) // 2]
        gt = r.depth(i)
        rng = rf.depth_range(gt)          # the report's colours: one range, the ground truth's
        rows = [rf.label(r.left(i), f"frame {i}"),
                rf.depth_panel(gt, "ground truth (metres)", rng)]
        labels = {"base": "base prediction (relative: its own colour range)",
                  "ft-align-metric": "adapted, metric (the ground truth's colours)"}
        for name, text in labels.items():
            if name in r.predictions():
                pred = r.prediction(name, i)
                rows.append(rf.depth_panel(pred, text, rng if "metric" in name else None))
        picture = np.concatenate(rows, axis=0)
    png = os.path.join(recipe["out_dir"], "demo_depth.png")
    write_image(png, picture)
    print(f"picture: {png} (frame {i}: image, ground truth, base prediction, adapted metric "
          f"prediction; turbo, near = red)")
    print(f"report: {os.path.join(recipe['out_dir'], 'report', 'report_demo.html')}")
    print(inputs_note(recipe["stages"]["adapt"]["args"]))
    print(f"demo finished in {time.perf_counter() - t0:.0f} s")
    return 0
