"""Seconds per frame of the ``upright`` alignment with its scans vectorised against the row-by-row
loops they replaced (tests/upright_reference.py), measured in one run on the same frames.

A frame of the independent renderer (tests/indep_scenes.py, scene ``--scene``) at ``--size``, a
network-like prediction (the true inverse depth blurred, with an inverse-affine error and a ramp
down the image), the true ground below the middle row as the walked region, the frame's agents,
and adapt's default ``align`` settings (``upright``, its colour foot on the frame's image). Both
versions align the frame ``--repeat`` times (the colour feet's cache warm, as over a sequence);
their maps must be equal to the bit. Prints ms per frame and the ratio (vectorised / loops).

    python benchmarks/bench_upright_scans.py [--size 800x400] [--scene i1] [--repeat 5]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def frame(scene: str, w: int, h: int):
    import cv2

    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.geometry.projection import ray_grid
    from tests.indep_scenes import SCENES, write_scene

    spec = {s.name: s for s in SCENES}[scene]
    with tempfile.TemporaryDirectory() as tmp:
        path = write_scene(os.path.join(tmp, "s.h5"), spec, frames=2, width=w, height=h)
        with SequenceReader(path) as r:
            Z, inst, left = r.depth(1), r.instances(1), r.left(1)
            K, mount = r.camera.K, r.meta.mounting
    yy = np.linspace(0.0, 1.0, h)[:, None]
    inv = cv2.GaussianBlur((1.0 / Z).astype(np.float32), (0, 0), w / 200.0)
    pred = 1.0 / (0.5 * inv + 0.01 + 0.02 * yy)
    plane = mount.height_m / (ray_grid(K, w, h) @ mount.normal).reshape(h, w)
    agents = inst > 0
    ground = (np.abs(Z - plane) < 0.01 * Z) & ~agents
    ground[: h // 2] = False
    return pred, K, mount, ground, agents, left / 255.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="800x400")
    ap.add_argument("--scene", default="i1")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))

    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import AlignConfig
    from staticdepth.geometry import alignment_upright as au
    from staticdepth.geometry.alignment import align_depth
    from tests.upright_reference import (contact_ratios_loop, fill_along_rows_loop,
                                         occluded_runs_loop)

    pred, K, mount, ground, agents, image = frame(args.scene, w, h)
    conf = AlignConfig()
    opts = {**upright_options(conf), "image": image}

    def run():
        t0 = time.perf_counter()
        for _ in range(args.repeat):
            out = align_depth(pred, K, mount.normal, mount.height_m, ground, mode="upright",
                              agent_mask=agents, snap_rel=conf.snap_rel, **opts).depth
        return out, (time.perf_counter() - t0) / args.repeat

    run()                                        # the colour feet's cache, imports
    new, t_new = run()
    loops = {"contact_ratios": contact_ratios_loop, "occluded_runs": occluded_runs_loop,
             "fill_along_rows": fill_along_rows_loop}
    kept = {k: getattr(au, k) for k in loops}
    try:
        for k, f in loops.items():
            setattr(au, k, f)
        old, t_old = run()
    finally:
        for k, f in kept.items():
            setattr(au, k, f)
    if not np.array_equal(new, old, equal_nan=True):
        sys.exit("the vectorised scans' map differs from the loops'")
    print(f"upright alignment of one {w}x{h} frame ({args.scene}, {args.repeat} repeats): loops "
          f"{1000 * t_old:.1f} ms, vectorised {1000 * t_new:.1f} ms, ratio {t_new / t_old:.2f}x; "
          "maps equal")


if __name__ == "__main__":
    main()
