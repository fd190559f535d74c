"""What the joint plane's Laplace uncertainty costs per fit (agent_plane_laplace, issue 13).

Usage: python benchmarks/bench_laplace_cost.py [--detection mask] [--tracks 24] [--cameras 3]
       [--bootstrap 0]

The Laplace step (one Jacobian by central differences at the solution) runs on every joint fit,
also with the bootstrap off. Each scene of tests/plane_generators.py (thin, tapered, cylinder,
ellipsoid; ``--cameras`` seeds from 0) is fitted twice, with the step and with it replaced by an
empty result; the normals must be identical (the step only reports). Prints the mean seconds per
fit both ways, the step's own time and its share of the fit.

Measured (2 shared cores, 4 generators): masks, 24 tracks (163 observations): 0.02 s of 2.15 s
(1%); boxes, 24 tracks: 0.08 s of 7.20 s (1%); masks, 120 tracks (814 observations, one camera
each): 0.09 s of 6.93 s (1%). Not worth computing only where it is used.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from plane_generators import scene  # noqa: E402

import staticdepth.geometry.agent_plane_boot as boot  # noqa: E402
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--detection", default="mask")
    ap.add_argument("--tracks", type=int, default=24)
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--bootstrap", type=int, default=0)
    args = ap.parse_args()
    conf = AgentPlaneConfig(bootstrap=args.bootstrap, column_weight=1.0)
    scenes = [scene(k, s, detection=args.detection, n_tracks=args.tracks)
              for k in ("thin", "tapered", "cylinder", "ellipsoid") for s in range(args.cameras)]
    real, t_on, t_off, t_step = boot.laplace_uncertainty, [], [], []

    def timed(*a, **k):
        t0 = time.perf_counter()
        out = real(*a, **k)
        t_step.append(time.perf_counter() - t0)
        return out

    try:
        for sc in scenes:
            boot.laplace_uncertainty = timed
            t0 = time.perf_counter()
            with_step = fit_agent_plane(sc.K, sc.obs, conf)
            t_on.append(time.perf_counter() - t0)
            boot.laplace_uncertainty = lambda *a, **k: {}
            t0 = time.perf_counter()
            without = fit_agent_plane(sc.K, sc.obs, conf)
            t_off.append(time.perf_counter() - t0)
            if not np.array_equal(with_step.normal, without.normal):
                raise SystemExit("the Laplace step changed the normal")
    finally:
        boot.laplace_uncertainty = real
    on, off, step = map(np.asarray, (t_on, t_off, t_step))
    print(f"{args.detection}, {args.tracks} tracks, bootstrap {args.bootstrap}: {len(on)} fits, "
          f"{np.mean([len(s.obs) for s in scenes]):.0f} observations per fit; seconds per fit "
          f"with the Laplace step {on.mean():.2f}, without {off.mean():.2f}; the step "
          f"{step.mean():.3f} = {step.sum() / on.sum():.1%} of the fit")


if __name__ == "__main__":
    main()
