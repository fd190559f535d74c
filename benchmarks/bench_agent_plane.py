"""Accuracy of the exact ground-plane fit (METHOD.md section 2) over random synthetic cameras.

Usage: python benchmarks/bench_agent_plane.py [--cameras 20] [--seed 2024] [--bad 0.0]

Cameras 3-8 m high, pitched 10-45 degrees, roll within 5, f 400-800 px at 800x400; 40 tracked
upright cylinders (r = 0.2 m) with 1 px noise on the foot and top points, from the independent
generator of tests/test_agent_plane.py (``--bad`` shrinks that fraction of the heights to 40-70%).
For head rows only (boxes) and rows + columns (masks) it prints the normal's error of the
estimator and its noise-limited floor: the same cost minimised from the true normal (least
squares on all observations), both measured in this run, and the seconds per fit. With ``--bad``
the floor column is plain least squares over the outliers too, so it is no floor there.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_agent_plane import (camera_K, people_observations, shrink_heights,  # noqa: E402
                              true_normal)

from staticdepth.geometry import agent_plane as ap  # noqa: E402
from staticdepth.geometry.plane import angle_between_deg  # noqa: E402


def floor_error(K, obs, conf, pitch, roll, n) -> float:
    """Error of the cost's minimum nearest the truth (started there, least squares)."""
    o = ap._prepare(K, obs, conf.model)
    p, r, _, _ = ap._fit_exact(K, o, conf, [(pitch, roll)])
    return angle_between_deg(ap.normal_from_pitch_roll(math.degrees(p), math.degrees(r)), n)


def main() -> None:
    ap_ = argparse.ArgumentParser(description=__doc__)
    ap_.add_argument("--cameras", type=int, default=20)
    ap_.add_argument("--seed", type=int, default=2024)
    ap_.add_argument("--bad", type=float, default=0.0, help="fraction of shrunk heights")
    args = ap_.parse_args()
    rng0 = np.random.default_rng(args.seed)
    conf = ap.AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    variants = {"rows": ap.AgentPlaneConfig(bootstrap=0, column_weight=0.0), "rows+cols": conf}
    table, times = [], []
    print("cam     f  pitch  roll    H | rows: est floor | rows+cols: est floor  (deg)")
    for k in range(args.cameras):
        f, pitch = rng0.uniform(400, 800), rng0.uniform(10, 45)
        roll, height = rng0.uniform(-5, 5), rng0.uniform(3, 8)
        rng = np.random.default_rng(k)
        K, w, h = camera_K(f)
        n = true_normal(pitch, roll)
        obs = people_observations(rng, K, w, h, n, height)
        if args.bad > 0:
            obs = shrink_heights(rng, obs, args.bad)
        row = []
        for c in variants.values():
            t0 = time.perf_counter()
            est = ap.fit_agent_plane(K, obs, c)
            times.append(time.perf_counter() - t0)
            row += [angle_between_deg(est.normal, n), floor_error(K, obs, c, pitch, roll, n)]
        table.append(row)
        print(f"{k:3d} {f:5.0f} {pitch:6.1f} {roll:+5.1f} {height:4.1f} | "
              f"{row[0]:9.3f} {row[1]:5.3f} | {row[2]:14.3f} {row[3]:5.3f}", flush=True)
    a = np.array(table)
    for name, vals in (("median", np.median(a, 0)), ("p90", np.percentile(a, 90, 0)),
                       ("max", a.max(0))):
        print(f"{name:>24} | {vals[0]:9.3f} {vals[1]:5.3f} | {vals[2]:14.3f} {vals[3]:5.3f}")
    print(f"fit time: median {np.median(times):.2f} s, max {np.max(times):.2f} s")


if __name__ == "__main__":
    main()
