"""Accuracy of ``staticdepth locate`` against known geometry: contact points and pairwise distances.

Usage: python benchmarks/bench_locate.py [--frames 30] [--presets demo c1 r2] [--seeds 0 1 2]
       [--bikes demo c1]

Scenes: the project's renderer (``staticdepth synth`` presets, true foot points and depth) and the
independent generator of the tests (``tests/upright_scene.py``: upright cylinders on a tilted
ground, closed-form ray casting). The plane is the scene's true one (the plane fit is measured by
``bench_plane_on_synth.py``). Printed per scene: for people whose contact is visible (not flagged
by locate, and on synthetic scenes the true depth just under the contact is the ground's), the
contact-point error relative to the distance (median, p90, max; goals <= 2% median, <= 5% max),
the pairwise distance error between people within 20 m (median; goal <= 0.2 m), and, apart, the
riders (the azimuth of their silhouette, the ground distance of their vehicle's near edge; scenes
``--bikes`` are the presets with 60% two-wheelers; a rider whose vehicle's contact is hidden
counts as a hidden contact) and the flagged hidden contacts.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))


def errors(pos, truth_of, visible=lambda row: True):
    rel, pair_err, riders, hidden = [], [], [], []
    for f in np.unique(pos["frame"]):
        est, tru = [], []
        for row in pos[(pos["frame"] == f) & (pos["class_id"] == 0)]:
            T = truth_of(int(f), int(row["track"]))
            if T is None:
                continue
            e = np.linalg.norm(np.array([row["X"], row["Y"], row["Z"]]) - T) / np.linalg.norm(T)
            if row["rider"] and not row["occluded"]:
                riders.append(e)                 # its vehicle's near edge is visible
            elif row["occluded"] or not visible(row):
                hidden.append(e)
            else:
                rel.append(e)
                est.append(np.array([row["X"], row["Y"], row["Z"]])), tru.append(T)
        for a in range(len(est)):
            for b in range(a + 1, len(est)):
                if max(np.linalg.norm(tru[a]), np.linalg.norm(tru[b])) <= 20:
                    pair_err.append(abs(np.linalg.norm(est[a] - est[b])
                                        - np.linalg.norm(tru[a] - tru[b])))
    return [np.array(x) for x in (rel, pair_err, riders, hidden)]


def report(name, rel, pair_err, riders, hidden):
    def q(x):
        return (f"n {len(x):4d} median {100 * np.median(x):5.2f}% p90 {100 * np.percentile(x, 90):5.2f}%"
                f" max {100 * x.max():5.2f}%") if len(x) else "n    0"
    pe = f"median {np.median(pair_err):.3f} m (n {len(pair_err)})" if len(pair_err) else "none"
    print(f"{name:22s} visible people: {q(rel)} | pairs <= 20 m: {pe}")
    print(f"{'':22s} riders: {q(riders)} | hidden contacts: {q(hidden)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--presets", nargs="+", default=["demo", "c1", "r2"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--bikes", nargs="*", default=["demo", "c1"],
                    help="presets rendered again with 60%% two-wheelers (riders)")
    args = ap.parse_args()
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.geometry.plane import plane_depth_at_pixels
    from staticdepth.locate import LocateConfig, locate
    from upright_scene import UprightScene

    tmp = tempfile.mkdtemp(prefix="bench_locate_")
    for name, bikes in [(p, False) for p in args.presets] + [(p, True) for p in args.bikes]:
        seq = os.path.join(tmp, f"{name}{'_bikes' if bikes else ''}.h5")
        over = {"width": 400, "height": 200} if name in ("c1", "c2", "c3") else {}
        if bikes:
            over.update(agent_mix=(0.3, 0.1, 0.6), n_agents=24)
        render_to_file(seq, preset_name=name, n_frames=args.frames, seed=0, overrides=over)
        with SequenceReader(seq) as r:
            m, K = r.meta.mounting, r.camera.K
            key = {(int(a["frame"]), int(a["track_id"])): a for a in r.agents()}
            depth = [r.depth(i) for i in range(len(r))]

        def truth_of(f, t):
            a = key.get((f, t))
            return None if a is None else np.array([a["foot_x"], a["foot_y"], a["foot_z"]])

        def visible(row):
            u, v = int(round(row["u"])), int(row["v"]) + 2
            if v >= depth[0].shape[0]:
                return False
            zp = plane_depth_at_pixels(K, m.normal, m.height_m, u, v)
            return bool(abs(depth[int(row["frame"])][v, u] / zp - 1) < 0.03)

        pos = locate(seq, m.normal, m.height_m, LocateConfig())
        report(f"synth {name}{' bikes' if bikes else ''}", *errors(pos, truth_of, visible))
    cams = [dict(height_m=5.0, pitch_deg=30, roll_deg=0), dict(height_m=3.5, pitch_deg=18, roll_deg=-4),
            dict(height_m=8.0, pitch_deg=42, roll_deg=3, focal_px=300),
            dict(height_m=6.0, pitch_deg=55, roll_deg=6, focal_px=200)]
    for seed in args.seeds:
        for k, cam in enumerate(cams):
            scene = UprightScene(n_people=12, seed=seed, **cam)
            seq = os.path.join(tmp, f"up{seed}_{k}.h5")
            truth = scene.write(seq, frames=max(args.frames // 2, 6))
            pos = locate(seq, scene.normal, scene.height_m, LocateConfig())
            report(f"independent s{seed} c{k}", *errors(pos, lambda f, t: truth[f][t]))


if __name__ == "__main__":
    main()
