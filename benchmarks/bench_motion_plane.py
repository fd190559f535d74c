"""Why a plane from the motion detector is off: its foot/top points against the scene's truth.

On the independent scenes of ``tests/indep_scenes.py`` (exact instance maps and rows), runs the
``motion`` detector over each sequence, measures every detection of the adaptation split (the
same mask -> foot/top extraction as the ground-plane stage, tracking.detections_from_instances)
against the ground-truth instance it overlaps most, sorts the errors by cause, then fits the
ground plane (adapt's tracking and plane defaults) from the motion detections and from the
ground-truth instances (with the plane settings ``adapt`` uses for each detector: people only for
motion, every class for gt) and prints the normal's error against the true mounting. Columns:
median and 90th percentile of |motion - truth| (px) of the foot row, top row and foot column;
how many the tracker drops for their score (the detector's merge test) and how many have the
wrong class (motion labels upright regions person, others car).

Causes (first that applies): ``ghost`` (overlaps no true agent), ``merged`` (covers two or more
true agents, each by >= 20% of the blob), ``border`` (the true agent touches the image border),
``occluded`` (the true agent's foot or top touches another instance), ``foot-cut`` / ``top-cut``
(the blob's lowest / highest row more than 1 px inside the truth's: part lost to background
similarity), ``ok``.

    python benchmarks/bench_motion_plane.py [--scenes i1,i2,i3,i4] [--frames 60] [--size 320x160]
        [--work out/bench/scenes] [--set detector.threshold=20 ...]
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from collections import defaultdict
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from tests.indep_scenes import SCENES, write_scene  # noqa: E402

CAUSES = ("ghost", "merged", "border", "occluded", "foot-cut", "top-cut", "ok")


def classify(det_map, gt_map, det, gt_dets: dict) -> tuple[str, dict | None]:
    """(cause, matched true detection) of one motion detection."""
    blob = det_map == det["instance_id"]
    ids, counts = np.unique(gt_map[blob], return_counts=True)
    keep = ids > 0
    ids, counts = ids[keep], counts[keep]
    if not len(ids) or counts.max() < 0.2 * blob.sum():
        return "ghost", None
    best = int(ids[np.argmax(counts)])
    g = gt_dets.get(best)
    if g is None:
        return "ghost", None
    if np.count_nonzero(counts >= 0.2 * blob.sum()) >= 2:
        return "merged", g
    if g["border"]:
        return "border", g
    if g["occluded"]:
        return "occluded", g
    if det["foot_v"] < g["foot_v"] - 1:
        return "foot-cut", g
    if det["top_v"] > g["top_v"] + 1:
        return "top-cut", g
    return "ok", g


def angle_deg(a, b) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b) / np.linalg.norm(a)
                                                / np.linalg.norm(b), -1, 1))))


def scene_report(path: str, detector_opts: dict, sets: dict, oracle: tuple = ()) -> dict:
    from dataset.h5 import SequenceReader
    from staticdepth import tracking
    from staticdepth.adaptation.config import build_config
    from staticdepth.adaptation.ground_plane import plane_config
    from staticdepth.adaptation.scale import known_camera_height
    from staticdepth.detectors import make_detector
    from staticdepth.geometry.agent_plane import fit_agent_plane
    from staticdepth.geometry.projection import rays_from_pixels
    from staticdepth.geometry.scale import plane_depth_rel_std

    conf = build_config({"tracking.min_height_px": 10, **sets})
    with SequenceReader(path) as r:
        frames = [r.left(i) for i in range(len(r))]
        gt = [(r.instances(i), r.agents(i)) for i in range(len(r))]
        K, truth = r.camera.K, r.meta.mounting
        known = known_camera_height(conf, r.meta.camera_height_m)
        split = list(r.split("adapt"))
    det = list(make_detector("motion", **detector_opts).detect_sequence(frames))
    errs: dict[str, list] = defaultdict(list)
    for i in split:
        dm, drows = det[i]
        gm, grows = gt[i]
        dd = tracking.detections_from_instances(dm, drows, i, conf.tracking.border_px,
                                                conf.tracking.contact_px)
        gd = tracking.detections_from_instances(gm, grows, i, conf.tracking.border_px,
                                                conf.tracking.contact_px)
        gd = {int(g["instance_id"]): g for g in gd}
        for d in dd:
            if d["foot_v"] - d["top_v"] < conf.tracking.min_height_px:
                continue
            cause, g = classify(dm, gm, d, gd)
            k = np.flatnonzero(drows["instance_id"] == d["instance_id"])
            if "class" in oracle and g is not None:       # what the truth's class would give
                drows["class_id"][k] = g["class_id"]
            if "merge" in oracle and cause in ("merged", "occluded", "ghost") \
                    or f"drop-{cause}" in oracle:
                drows["score"][k] = 0.0
            e = ((np.nan,) * 3 if g is None else
                 (d["foot_v"] - g["foot_v"], d["top_v"] - g["top_v"], d["foot_u"] - g["foot_u"]))
            errs[cause].append(e + (float(d["score"] < conf.tracking.min_score),
                                    float(g is not None and g["class_id"] != d["class_id"])))
    out = {"causes": {c: np.asarray(errs[c], float).reshape(-1, 5) for c in CAUSES}}
    for name, pairs in (("motion", [det[i] for i in split]), ("gt", [gt[i] for i in split])):
        obs = tracking.observations_from_instances(pairs, conf.tracking)
        try:       # the plane settings adapt uses with that detector
            p = fit_agent_plane(K, obs, plane_config(replace(
                conf, detector=replace(conf.detector, name=name)), None if known is None else known[0]))
            # the plane depth's error over the feet (true, and as the bootstrap predicts it)
            rays = rays_from_pixels(K, obs["foot_u"], obs["foot_v"])
            true_rel = float(np.median(np.abs(rays @ truth.normal / (rays @ p.normal) - 1)))
            rel = plane_depth_rel_std(K, p.normal, p.normal_std_deg, obs["foot_u"], obs["foot_v"])
            out[name] = (angle_deg(p.normal, truth.normal), int(np.count_nonzero(p.inliers)),
                         len(p.inliers), float(p.normal_std_deg), len(obs), true_rel, rel)
        except Exception as e:  # noqa: BLE001 - a refused fit is a result here
            out[name] = (float("nan"), 0, 0, float("nan"), len(obs), str(e))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="i1,i2,i3,i4")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", default="320x160")
    ap.add_argument("--work", default="out/bench/scenes")
    ap.add_argument("--detector", action="append", default=[], metavar="KEY=VALUE",
                    help="motion detector option (e.g. threshold=20)")
    ap.add_argument("--oracle", default="",
                    help="comma-separated: class (the truth's class for each detection), merge "
                         "(drop every merged / occluded / ghost detection), drop-CAUSE: what a "
                         "perfect fix of that cause would give")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="adapt setting (tracking.*, plane.*)")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    specs = {s.name: s for s in SCENES}
    dopts = {k: (int(v) if v.lstrip("-").isdigit() else v)
             for k, v in (kv.split("=", 1) for kv in args.detector)}
    sets = dict(kv.split("=", 1) for kv in args.set)
    os.makedirs(args.work, exist_ok=True)
    for scene in args.scenes.split(","):
        path = os.path.join(args.work, f"{scene}-{args.frames}-{args.size}.h5")
        if not os.path.exists(path):
            write_scene(path, specs[scene], args.frames, width=w, height=h)
        rep = scene_report(path, dopts, sets, tuple(args.oracle.split(",")))
        print(f"\n{scene}: detections by cause (px, motion - truth: median |err| / p90 |err|)")
        print("| cause | n | foot_v | top_v | foot_u | dropped (score) | class wrong |")
        print("|---|---|---|---|---|---|---|")
        for c in CAUSES:
            e = rep["causes"][c]
            if not len(e):
                continue
            cells = [f"{np.nanmedian(np.abs(e[:, k])):.1f} / {np.nanpercentile(np.abs(e[:, k]), 90):.1f}"
                     if np.isfinite(e[:, k]).any() else "-" for k in range(3)]
            print(f"| {c} | {len(e)} | " + " | ".join(cells)
                  + f" | {int(e[:, 3].sum())} | {int(e[:, 4].sum())} |")
        for name in ("motion", "gt"):
            v = rep[name]
            print(f"{scene} plane from {name}: normal error {v[0]:.2f} deg, inlier tracks "
                  f"{v[1]}/{v[2]}, bootstrap std {v[3]:.2f} deg, {v[4]} observations"
                  + (f"; feet depth error {100 * v[5]:.1f}%, predicted {100 * v[6]:.1f}%"
                     if len(v) == 7 else f" ({v[5]})"), flush=True)


if __name__ == "__main__":
    main()
