"""The walker test on boxes (issue 13; staticdepth/geometry/agent_gait.py): how well it separates
rigid bodies from walkers, before any plane fit.

Usage: python benchmarks/bench_agent_gait.py [--generators thin,tapered,cylinder,ellipsoid]
       [--cameras 20] [--first-camera 0] [--gait 1.3] [--outliers 0.0] [--jitter 2.0]
       [--csv observations.csv] [--vtest 1] [--vtest-frames 300]

Per generator (tests/plane_generators.py, people seen as +-2 px boxes; ``--gait`` the walkers'
leg phase per frame, 1.3 rad by default, e.g. 0.5 for a slower gait): each camera's pooled
ratio (median |width residual| / median |height residual| after each track's straight line in
time), its min / median / max over the cameras and the verdict counts (rigid / walker /
unknown). ``--csv``: an observation CSV of ``staticdepth observations`` (e.g. YOLOX on the real
vtest.avi), per class its ratio and verdict, from the rows' frames and, where the CSV has no
``left`` / ``right`` columns, says so. ``--vtest STEP``: the real vtest.avi
($STATICDEPTH_DATA/video, YOLOX nano from $STATICDEPTH_DATA/models; ``mask="box"``: the
detector's boxes, no top column, as people seen as boxes), every STEP-th of its first
``--vtest-frames`` frames, tracked as ``adapt`` tracks them; per class and per half of the frames.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from plane_generators import scene  # noqa: E402

from staticdepth.geometry.agent_gait import box_gait, gait_ratio  # noqa: E402


def _table_ratio(obs, cls=None):
    sel = np.ones(len(obs), bool) if cls is None else obs["class_id"] == cls
    o = obs[sel]
    order = np.lexsort((o["frame"], o["track"]))
    o = o[order]
    w = np.asarray(o["right"], float) - np.asarray(o["left"], float)
    h = np.asarray(o["height_px"], float)
    return (gait_ratio(o["track"], w, h),
            box_gait(o["track"], w, h))


def _vtest(step: int, n_frames: int) -> None:
    import os

    import cv2

    from staticdepth import tracking
    from staticdepth.detectors import make_detector
    data = Path(os.environ.get("STATICDEPTH_DATA", "/work/shared/data"))
    cap = cv2.VideoCapture(str(data / "video" / "vtest.avi"))
    frames = []
    for i in range(n_frames):
        ok, f = cap.read()
        if not ok:
            break
        if i % step == 0:
            frames.append(np.ascontiguousarray(f[..., ::-1]))
    det = make_detector("yolox", model=str(data / "models" / "yolox_nano" / "yolox_nano.onnx"),
                        mask="box")
    for name, part in (("all", frames), ("first half", frames[:len(frames) // 2]),
                       ("second half", frames[len(frames) // 2:])):
        obs = tracking.observations_from_instances(list(det.detect_sequence(part)),
                                                   tracking.TrackingConfig.for_model("joint"))
        for c in np.unique(obs["class_id"]):
            (g, used), v = _table_ratio(obs, c)
            n = len(np.unique(obs["track"][obs["class_id"] == c]))
            print(f"vtest step {step}, {len(part)} frames ({name}), class {c}: {n} tracks, "
                  f"{used} with 5+ boxes, top columns {np.isfinite(obs['top_u']).mean():.0%}, "
                  f"ratio {g:.2f}: {v}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--generators", default="thin,tapered,cylinder,ellipsoid")
    ap.add_argument("--cameras", type=int, default=20)
    ap.add_argument("--first-camera", type=int, default=0)
    ap.add_argument("--gait", type=float, default=1.3)
    ap.add_argument("--outliers", type=float, default=0.0)
    ap.add_argument("--jitter", type=float, default=2.0)
    ap.add_argument("--csv", default=None)
    ap.add_argument("--vtest", type=int, default=0)
    ap.add_argument("--vtest-frames", type=int, default=300)
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    if args.vtest:
        _vtest(args.vtest, args.vtest_frames)
        return
    if args.csv:
        from staticdepth.ground_plane import read_observations_csv
        obs, _ = read_observations_csv(args.csv)
        names = obs.dtype.names
        if "left" not in names or "right" not in names:
            print(f"{args.csv}: no left / right columns, no box widths")
            return
        for c in np.unique(obs["class_id"]):
            (g, used), v = _table_ratio(obs, c)
            n = len(np.unique(obs["track"][obs["class_id"] == c]))
            print(f"class {c}: {n} tracks, {used} with 5+ boxes, ratio {g:.2f}: {v}")
        return
    print(f"boxes +-{args.jitter} px, gait {args.gait} rad/frame, outliers {args.outliers:.0%}, "
          f"cameras {args.first_camera}-{args.first_camera + args.cameras - 1}")
    for gen in args.generators.split(","):
        ratios, verdicts = [], []
        for cam in range(args.first_camera, args.first_camera + args.cameras):
            s = scene(gen, cam, detection="box", outliers=args.outliers,
                      box_jitter_px=args.jitter, gait=args.gait)
            (g, _), v = _table_ratio(s.obs)
            ratios.append(g)
            verdicts.append(v)
            if args.verbose:
                print(f"  {gen} camera {cam}: ratio {g:.2f} {v}")
        r = np.array(ratios)
        counts = {k: verdicts.count(k) for k in ("rigid", "walker", "unknown")}
        print(f"{gen:9s} ratio min / median / max {np.nanmin(r):.2f} / {np.nanmedian(r):.2f} / "
              f"{np.nanmax(r):.2f}; rigid {counts['rigid']}, walker {counts['walker']}, "
              f"unknown {counts['unknown']}")


if __name__ == "__main__":
    main()
