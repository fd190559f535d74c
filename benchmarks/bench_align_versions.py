"""Time per frame of the ``upright`` alignment (numpy, and its torch twin) of this tree against
another version of the package, measured in one run on the same frames.

The frames: a clip of the synthetic ``c1`` scene (``--size``, the paper's 800x400 by default,
``--frames`` of them) whose true depth is seen through a network-like error (an inverse-depth
scale and shift, and a smooth multiplicative error growing with depth: the ground recedes less
than the plane, so runs walk), its true plane and the ground mask of adapt (from the agents'
feet). Each tree runs in its own child process (``sys.path`` first entry: the tree's root) with
its own ``AlignConfig`` defaults, alternately, ``--rounds`` times; printed per tree the median
over rounds of the mean ms per frame, and their ratio. An older tree is made with e.g.
``mkdir -p out/old && git archive ef29000 staticdepth | tar -x -C out/old``. ``--camera``: the
numpy frames share one ``AlignCamera`` (the per-camera constants, computed on the first frame),
as adapt's align stage gives them; a tree without one aligns each frame alone. The wall times
include the page faults of numpy's fresh temporaries, which vary with the allocation pattern
(glibc's dynamic mmap threshold): ``MALLOC_MMAP_THRESHOLD_=268435456
MALLOC_TRIM_THRESHOLD_=2147483648`` in the environment takes them out.

Usage:
  python benchmarks/bench_align_versions.py --old out/old [--frames 8] [--size 800x400]
      [--rounds 3] [--threads 1] [--camera]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")

CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np, torch
torch.set_num_threads(int(sys.argv[3]))
import staticdepth
from staticdepth.adaptation.align import upright_options
from staticdepth.adaptation.config import AlignConfig
from staticdepth.geometry.alignment import align_depth
from staticdepth.geometry.alignment_torch import alignment_module
d = np.load(sys.argv[2])
conf = AlignConfig()
opts = upright_options(conf)
K, n, G, Zs, A = d["K"], d["n"], d["ground"], d["Z"], d["agents"]
H, W = G.shape
cam = {}
if sys.argv[4] == "1":
    try:
        from staticdepth.geometry.alignment_upright import AlignCamera
    except ImportError:
        pass
    else:
        cam["camera"] = AlignCamera(K, W, H, n, 1.0)
t0 = time.perf_counter()
for Z, a in zip(Zs, A):
    align_depth(Z, K, n, 1.0, G, agent_mask=a, mode="upright", snap_rel=conf.snap_rel, **opts,
                **cam)
t_np = (time.perf_counter() - t0) / len(Zs)
mod = alignment_module("upright", K, W, H, n, 1.0, G, snap_rel=conf.snap_rel, **opts).eval()
with torch.no_grad():
    mod(torch.from_numpy(Zs[0]))
    t0 = time.perf_counter()
    for Z in Zs:
        mod(torch.from_numpy(Z))
t_torch = (time.perf_counter() - t0) / len(Zs)
print(json.dumps({"file": staticdepth.__file__, "numpy_ms": 1e3 * t_np, "torch_ms": 1e3 * t_torch}))
"""


def make_frames(path: str, frames: int, w: int, h: int) -> None:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.geometry.alignment import ground_mask_from_feet
    from dataset.synth_io import render_to_file

    with tempfile.TemporaryDirectory() as tmp:
        seq = os.path.join(tmp, "c1.h5")
        render_to_file(seq, preset_name="c1", n_frames=frames, adapt_frames=frames, seed=1,
                       overrides={"width": w, "height": h})
        with SequenceReader(seq) as r:
            K = r.camera.K
            n = np.asarray(r.meta.mounting.normal, float)
            rows = [r.agents(i) for i in range(frames)]
            feet = np.concatenate([np.stack([x["foot_u"], x["foot_v"]], 1) for x in
                                   (a[a["foot_v"] >= 0] for a in rows) if len(x)])
            ground = ground_mask_from_feet(feet, w, h, w / 80.0)
            rng = np.random.default_rng(0)
            Zs, agents = [], []
            for i in range(frames):
                gt = np.nan_to_num(r.depth(i), nan=200.0, posinf=200.0).clip(0.5, 200.0)
                # a network-like map: inverse depth up to scale and shift, and a smooth error
                # that grows with depth (far ground nearer than the plane)
                inv = 3.0 / gt + 0.05
                err = 1.0 - 0.15 * np.log1p(gt / 20.0) + 0.02 * rng.standard_normal(gt.shape)
                Zs.append((err / inv).astype(np.float32))
                agents.append(r.instances(i) > 0)
    np.savez(path, K=K, n=n, ground=ground, Z=np.stack(Zs), agents=np.stack(agents))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--old", required=True, help="root of the other tree (holds staticdepth/)")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", default="800x400")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--camera", action="store_true",
                    help="numpy: one AlignCamera for all frames (a tree without one: none)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    trees = {"this": os.path.abspath(ROOT), "old": os.path.abspath(args.old)}
    res: dict = {k: [] for k in trees}
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "frames.npz")
        make_frames(data, args.frames, w, h)
        for _ in range(args.rounds):
            for name, root in trees.items():
                out = subprocess.run([sys.executable, "-c", CHILD, root, data, str(args.threads),
                                      str(int(args.camera))],
                                     capture_output=True, text=True, check=True)
                rec = json.loads(out.stdout.strip().splitlines()[-1])
                if not rec["file"].startswith(root):
                    sys.exit(f"{name}: imported {rec['file']}, not from {root}")
                res[name].append(rec)
    print(f"upright alignment, {args.size}, {args.frames} frames, {args.rounds} rounds, "
          f"{args.threads} thread(s){', one camera' if args.camera else ''}: median of the "
          f"rounds' ms per frame")
    for key in ("numpy_ms", "torch_ms"):
        med = {k: float(np.median([r[key] for r in v])) for k, v in res.items()}
        print(f"  {key[:-3]:6s} this {med['this']:8.1f}  old {med['old']:8.1f}  "
              f"ratio this/old {med['this'] / med['old']:.2f}")


if __name__ == "__main__":
    sys.path.insert(0, ROOT)
    main()
