"""Does the joint ground plane's reported uncertainty cover its true error (normal, camera height)?

Usage: python benchmarks/bench_plane_uncertainty.py [--cameras 20] [--outliers 0.0]
       [--generators thin,tapered,cylinder,ellipsoid,vehicles] [--bootstrap 20]

Scenes from the independent generators of tests/plane_generators.py (masks, 1 px noise, cameras
3-12 m high, pitch 10-50, roll +-5). Per generator, over the cameras:
- normal: error vs the truth (degrees, median / max), the bootstrap standard deviation the fit
  reports (median), the ratio error / std (median / max: about 1 when the uncertainty is honest,
  the 95th percentile of the angle of a 2-D Gaussian is 2.45 std), how many planes the gate
  accepts (std <= 1 degree, ``plane_gate``) and the largest error among them;
- camera height from people (vehicles: every class), ``camera_height_from_agents``: error (%,
  median / max), its reported std (%, median), the ratio error / std (median / max), and the error
  the height distributions alone make (%, median / max: the fitted inlier tracks' true heights
  H_j / d put into the same maximum likelihood), which the plane cannot remove.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from plane_generators import GENERATORS, scene  # noqa: E402

from staticdepth.errors import InputError  # noqa: E402
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane  # noqa: E402
from staticdepth.geometry.agent_plane_gate import (camera_height_from_agents,  # noqa: E402
                                                   camera_height_ml, plane_gate)
from staticdepth.geometry.agent_shape import group_of_class  # noqa: E402
from staticdepth.geometry.plane import angle_between_deg  # noqa: E402


def one_camera(kind: str, seed: int, outliers: float, bootstrap: int,
               verbose: bool = False) -> dict | None:
    s = scene(kind, seed, outliers=outliers)
    try:
        p = fit_agent_plane(s.K, s.obs, AgentPlaneConfig(bootstrap=bootstrap))
    except InputError as e:
        print(f"  {kind} camera {seed}: refused: {e}", flush=True)
        return None
    classes = None if kind == "vehicles" else (0, -1)
    d, sd, _ = camera_height_from_agents(p, classes, bootstrap=200)
    cls = np.asarray(p.extra["classes"])
    use = p.inliers & (True if classes is None else np.isin(cls, classes))
    s_true = np.array([s.agent_heights[int(t)] for t in p.track_ids]) / s.height_m
    d_prior = camera_height_ml(s_true[use], group_of_class(cls[use]))
    err = angle_between_deg(p.normal, s.normal)
    if verbose:
        print(f"  {kind} camera {seed} (pitch {s.pitch_deg:.0f}, {s.height_m:.1f} m): error "
              f"{err:.2f} std {p.normal_std_deg:.2f} deg, height {100 * (d / s.height_m - 1):+.1f}"
              f" % std {100 * sd / d:.1f} %", flush=True)
    return {"err": err, "std": p.normal_std_deg, "ok": plane_gate(p).ok,
            "h": 100 * abs(d / s.height_m - 1), "h_sd": 100 * sd / d,
            "h_prior": 100 * abs(d_prior / s.height_m - 1)}


def main() -> None:
    ap_ = argparse.ArgumentParser(description=__doc__)
    ap_.add_argument("--cameras", type=int, default=20)
    ap_.add_argument("--outliers", type=float, default=0.0)
    ap_.add_argument("--generators", default=",".join(GENERATORS))
    ap_.add_argument("--bootstrap", type=int, default=20)
    ap_.add_argument("--verbose", action="store_true", help="every camera's figures")
    args = ap_.parse_args()
    print(f"{args.cameras} cameras per generator, masks, outliers {args.outliers:.0%}, bootstrap "
          f"{args.bootstrap}")
    print(f"{'generator':10} | normal: err med / max, std med, err/std med / max, accepted, "
          "max err accepted | camera height %: err med / max, std med, err/std med / max, "
          "height distributions alone med / max")
    for kind in args.generators.split(","):
        rows = [r for r in (one_camera(kind, k, args.outliers, args.bootstrap,
                                                       args.verbose)
                            for k in range(args.cameras)) if r is not None]
        if not rows:
            print(f"{kind:10} | all refused")
            continue
        a = {k: np.array([r[k] for r in rows]) for k in rows[0]}
        ratio, h_ratio = a["err"] / a["std"], a["h"] / a["h_sd"]
        acc = a["err"][a["ok"]]
        print(f"{kind:10} | {np.median(a['err']):4.2f} / {a['err'].max():4.2f}, "
              f"{np.median(a['std']):4.2f}, {np.median(ratio):4.2f} / {ratio.max():4.2f}, "
              f"{len(acc)}/{len(rows)}, {acc.max() if len(acc) else float('nan'):4.2f} | "
              f"{np.median(a['h']):3.1f} / {a['h'].max():3.1f}, {np.median(a['h_sd']):3.1f}, "
              f"{np.median(h_ratio):4.2f} / {h_ratio.max():4.2f}, "
              f"{np.median(a['h_prior']):3.1f} / {a['h_prior'].max():3.1f}", flush=True)


if __name__ == "__main__":
    main()
