"""``staticdepth demo``: the toolkit end to end on a built-in synthetic scene (no data, no weights)."""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the pipeline on a built-in synthetic scene",
                       description="Render a synthetic fixed-camera sequence, write it as a "
                                   "sequence file, and summarise it with pictures.")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--preset", default="demo")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier demo's outputs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.inspect import colorize_depth, format_summary, summarize, write_png
    from staticdepth.dataset.synth_io import render_to_file

    os.makedirs(args.out, exist_ok=True)
    seq = os.path.join(args.out, f"{args.preset}.h5")
    t0 = time.perf_counter()
    if os.path.exists(seq) and not args.overwrite:
        print(f"reusing {seq} (pass --overwrite to render it again)")
    else:
        info = render_to_file(seq, preset_name=args.preset, n_frames=args.frames, seed=args.seed,
                              overwrite=True)
        print(f"rendered {info['frames']} frames {info['size']} in {info['seconds']:.1f} s")
    with SequenceReader(seq) as r:
        print(format_summary(summarize(r)))
        i = len(r) // 2
        picture = np.concatenate([r.left(i), colorize_depth(r.depth(i))], axis=0)
    png = os.path.join(args.out, f"{args.preset}_depth.png")
    write_png(png, picture)
    print(f"picture: {png} (frame {i}: image over ground-truth depth, turbo, near = red)")
    print(f"demo finished in {time.perf_counter() - t0:.1f} s")
    return 0
