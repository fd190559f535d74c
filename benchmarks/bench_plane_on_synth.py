"""The ground plane fitted from the synthetic scenes' own agents, against the true plane.

Usage: python benchmarks/bench_plane_on_synth.py [--scenes c1,c2,c3,demo]
           [--sizes 256x128,400x200,800x400] [--frames 40] [--seed 0]

Renders the first ``--frames`` frames of each preset at each size with the real generator
(``SyntheticScene``), builds observations from the scene's ground-truth agent rows and instance
maps, fits the exact model and prints the pitch and roll errors (fitted - true, degrees) and the
inlier/total person tracks, for three pipelines measured in the same run:

- ``before``: the settings before the fix: every agent class, no occlusion test, mask rows taken
  as the silhouette's extremes, head disk as wide as the body, head-column residuals weighted 1;
- ``rows``: the defaults on the agent rows, with the renderer's visibility share (< 0.9 dropped);
- ``maps``: the defaults on the instance maps with the rows' track ids (occlusion from the masks:
  what ``adapt.fit_ground`` can do with a sequence file, which stores no visibility).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from staticdepth import tracking
from staticdepth.dataset.synth import SyntheticScene, preset
from staticdepth.errors import InputError
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.camera import pitch_roll_from_normal

BEFORE_TRACKING = dict(drop_occluded=False, edge_px=0.0)
BEFORE_PLANE = dict(head_radius_m=0.2, column_weight=1.0, classes=None)


def render(name: str, width: int, height: int, frames: int, seed: int):
    scene = SyntheticScene(preset(name, seed=seed, width=width, height=height))
    maps, rows, vis = [], [], []
    for fr in scene.frames(frames):
        maps.append(fr["instances"])
        rows.append(fr["agents"])
        vis.append(fr["visibility"])
    return scene, maps, rows, vis


def fit(scene, maps, rows, vis, pipeline: str):
    """(pitch error, roll error, inlier tracks, tracks) of one pipeline."""
    w, h = scene.camera.size
    base = dict(min_height_px=20, drop_collinear=False)
    if pipeline == "before":
        tconf = tracking.TrackingConfig(**base, **BEFORE_TRACKING)
        obs = tracking.observations_from_agents(np.concatenate(rows), w, h, tconf)
        pconf = AgentPlaneConfig(model="exact", bootstrap=0, **BEFORE_PLANE)
    elif pipeline == "rows":
        obs = tracking.observations_from_agents(np.concatenate(rows), w, h,
                                                tracking.TrackingConfig(**base),
                                                visibility=np.concatenate(vis))
        pconf = AgentPlaneConfig(model="exact", bootstrap=0)
    else:
        obs = tracking.observations_from_instances(zip(maps, rows),
                                                   tracking.TrackingConfig(**base))
        pconf = AgentPlaneConfig(model="exact", bootstrap=0)
    plane = fit_agent_plane(scene.camera.K, obs, pconf)
    pitch, roll = pitch_roll_from_normal(scene.mounting.normal)
    return (plane.pitch_deg - pitch, plane.roll_deg - roll, int(plane.inliers.sum()),
            len(plane.inliers))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", default="c1,c2,c3,demo")
    ap.add_argument("--sizes", default="256x128,400x200,800x400")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pipelines = ("before", "rows", "maps")
    print(f"first {args.frames} frames, seed {args.seed}: pitch/roll error (deg), inlier/all "
          "tracks")
    print("scene size     | " + " | ".join(f"{p:>23s}" for p in pipelines))
    for name in args.scenes.split(","):
        for size in args.sizes.split(","):
            w, h = (int(x) for x in size.split("x"))
            t0 = time.perf_counter()
            data = render(name, w, h, args.frames, args.seed)
            cells = []
            for p in pipelines:
                try:
                    dp, dr, i, j = fit(*data, p)
                    cells.append(f"{dp:+6.2f} {dr:+6.2f} ({i:2d}/{j:2d})")
                except InputError as e:
                    cells.append(f"{'fails: ' + str(e)[:16]:>23s}")
            print(f"{name:5s} {size:8s} | " + " | ".join(cells)
                  + f"   [{time.perf_counter() - t0:.0f} s]", flush=True)


if __name__ == "__main__":
    main()
