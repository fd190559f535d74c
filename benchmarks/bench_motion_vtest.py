"""The ground plane and camera height on the real video vtest.avi from each detector, per half.

The data: ``$STATICDEPTH_DATA`` or ``<repo>/../shared/data`` (tests/conftest.py). vtest.avi has
no calibration (f = 700 px and the centre assumed, as tests/test_plane_vtest.py):
the figures check consistency, not truth. Every 4th frame; each half of the video gives a plane
(people only, joint model, bootstrap 8) and a camera height from the people's height
distribution; printed with the angle between the halves' normals. The motion detector's
observations are also counted by what it drops (merged or odd-shaped regions: score).

    python benchmarks/bench_motion_vtest.py [--detectors motion,yolox] [--step 4]
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

F_PX = 700.0


def main() -> None:
    from conftest import shared_data_dir, vtest_frames

    from staticdepth import tracking
    from staticdepth.detectors import make_detector
    from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
    from staticdepth.geometry.agent_plane_gate import camera_height_from_agents
    from staticdepth.geometry.plane import angle_between_deg

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--detectors", default="motion,yolox")
    ap.add_argument("--step", type=int, default=4)
    ap.add_argument("--motion", action="append", default=[], metavar="KEY=INT",
                    help="motion detector option (e.g. low_threshold=20)")
    args = ap.parse_args()
    frames, model = vtest_frames(shared_data_dir(), args.step)
    H, W = frames[0].shape[:2]
    K = np.array([[F_PX, 0, (W - 1) / 2], [0, F_PX, (H - 1) / 2], [0, 0, 1.0]])
    for name in args.detectors.split(","):
        opts = ({"model": str(model)} if name == "yolox" else
                {k: int(v) for k, v in (kv.split("=", 1) for kv in args.motion)})
        det = make_detector(name, **opts)
        planes = []
        for k, part in enumerate((frames[:len(frames) // 2], frames[len(frames) // 2:])):
            pairs = list(det.detect_sequence(part))
            rows = np.concatenate([r for _, r in pairs])
            obs = tracking.observations_from_instances(pairs,
                                                       tracking.TrackingConfig.for_model("joint"))
            p = fit_agent_plane(K, obs, AgentPlaneConfig(bootstrap=8, classes=(0,)))
            d, sd, n = camera_height_from_agents(p, bootstrap=100)
            planes.append(p)
            print(f"{name} half {k + 1}: pitch {p.pitch_deg:.2f} roll {p.roll_deg:.2f} +- "
                  f"{p.normal_std_deg:.2f} deg, camera height {d:.2f} +- {sd:.2f} m, inlier "
                  f"tracks {int(p.inliers.sum())}/{len(p.inliers)}, {len(obs)} observations; "
                  f"detections {len(rows)}, scored below 0.3: "
                  f"{int(np.count_nonzero(rows['score'] < 0.3))}", flush=True)
        print(f"{name}: angle between the halves' normals "
              f"{angle_between_deg(planes[0].normal, planes[1].normal):.2f} deg")


if __name__ == "__main__":
    main()
