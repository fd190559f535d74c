"""Temporal stereo fusion against per-frame SGBM: accuracy on exact depth, and its cost.

    python benchmarks/bench_stereo_temporal.py [--frames 60] [--noise 4] [--size 320x160]

Scenes (27 cm baseline, moving people, Gaussian sensor noise of --noise DN per view and frame):
``own`` (tests/stereo_scene.py: independent ray caster, gratings + tiles, camera 7 m high) and
``synth`` (the project's renderer, preset demo, fractal texture, 5 m high).

Accuracy, pooled over the frames, for the static background (bad-1 %, AbsRel, holes %) and the
agents (bad-1 %, AbsRel), per frame (SGBM, the project's ground-truth settings) and fused, with
the ratios fused / per frame; the confidence's top half against its bottom half (bad-1, AbsRel).
Pixels whose true match lies outside the right image are left out (no stereo truth there).

Speed, measured in the same run on the same frames: one bare ``StereoSGBM.compute`` (same range
and block size) per frame, against the fusion's extra work: per frame (foreground test, fusion,
confidence) and the background model (built once) spread over the sequence (this run's length
and 1000 frames); also against the project's full per-frame matcher (border, trimming).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from stereo_scene import FusionScore, Scene, SceneRenderer  # noqa: E402

from staticdepth.stereo.match import create_matcher  # noqa: E402
from staticdepth.stereo.temporal import (TemporalConfig, build_background,  # noqa: E402
                                         fuse_frame, sample_indices)

NUM_DISPARITIES = 16


def frames_of(which: str, n: int, noise: float, size: tuple[int, int]):
    w, h = size
    if which == "own":
        r = SceneRenderer(Scene(width=w, height=h, focal_px=200.0 * w / 320, noise_dn=noise))
        return r.disparity_scale, [r.render(i) for i in range(n)]
    from staticdepth.dataset.synth import SyntheticScene, preset

    sc = SyntheticScene(preset("demo", width=w, height=h, seed=0))
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        f = sc.render(i)
        for v in ("left", "right"):
            f[v] = np.clip(np.round(f[v] + rng.normal(0, noise, f[v].shape)), 0, 255
                           ).astype(np.uint8)
        out.append(f)
    return sc.config.focal * sc.config.baseline_m, out


def run(which: str, n: int, noise: float, size: tuple[int, int]) -> None:
    fB, frames = frames_of(which, n, noise, size)
    h, w = frames[0]["depth"].shape
    n_disp = NUM_DISPARITIES * max(1, w // 320)
    c = TemporalConfig()
    one = create_matcher("sgbm", num_disparities=n_disp, image_size=(w, h))
    up = create_matcher("sgbm", num_disparities=n_disp * c.plate_scale,
                        image_size=(w * c.plate_scale, h * c.plate_scale))
    match = lambda a, b: one.match(a, b).disparity  # noqa: E731
    bs = one.conf.block_size
    bare = cv2.StereoSGBM_create(0, n_disp, bs, P1=8 * 3 * bs * bs, P2=16 * 3 * bs * bs,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)

    t0 = time.perf_counter()
    picks = sample_indices(n, c.samples)
    model = build_background(((frames[i]["left"], frames[i]["right"]) for i in picks), match,
                             lambda a, b: up.match(a, b).disparity, c)
    t_build = time.perf_counter() - t0
    score = FusionScore(fB)
    t_bare = t_fuse = t_ours = 0.0
    for f in frames:
        bgr = [np.ascontiguousarray(f[v][..., ::-1]) for v in ("left", "right")]
        s = time.perf_counter()
        bare.compute(*bgr)
        t_bare += time.perf_counter() - s
        s = time.perf_counter()
        d = match(f["left"], f["right"])
        t_ours += time.perf_counter() - s
        s = time.perf_counter()
        fused = fuse_frame(model, f["left"], d)
        t_fuse += time.perf_counter() - s
        score.add(f, d, fused)
    t, halves = score.t, score.halves()

    print(f"\n{which}: {w}x{h}, {n} frames, noise {noise:g} DN, {n_disp} disparities")
    print(f"  {'region':12} {'method':9} {'bad-1 %':>8} {'AbsRel':>8} {'holes %':>8}")
    for region in ("bg", "agents"):
        a, b = t[f"frame_{region}"], t[f"fused_{region}"]
        for name, x in (("per-frame", a), ("fused", b)):
            print(f"  {region:12} {name:9} {100 * x.bad1:8.3f} {x.abs_rel:8.4f} "
                  f"{100 * x.holes:8.3f}")
        print(f"  {region:12} {'ratio':9} {b.bad1 / max(a.bad1, 1e-12):8.3f} "
              f"{b.abs_rel / max(a.abs_rel, 1e-12):8.3f}")
    for key in ("bad1", "abs_rel"):
        top, bottom = halves[key]
        print(f"  confidence {key:8}: top half {top:.4f}, bottom half {bottom:.4f}, "
              f"ratio {top / max(bottom, 1e-12):.3f}")
    per_bare = t_bare / n
    print(f"  speed: bare SGBM {1e3 * per_bare:.2f} ms/frame ({1 / per_bare:.0f} frames/s); "
          f"fusion {1e3 * t_fuse / n:.2f} ms/frame = {t_fuse / n / per_bare:.3f}x; background "
          f"model {1e3 * t_build:.0f} ms once = {t_build / n / per_bare:.3f}x per frame over "
          f"{n} frames; overhead {(t_fuse + t_build) / n / per_bare:.3f}x "
          f"({(t_fuse / n + t_build / 1000) / per_bare:.3f}x over 1000 frames); the project's "
          f"per-frame SGBM matcher {1e3 * t_ours / n:.2f} ms/frame, fusion = "
          f"{t_fuse / t_ours:.3f}x of it")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--noise", type=float, default=4.0)
    ap.add_argument("--size", default="320x160")
    ap.add_argument("--scenes", default="own,synth")
    a = ap.parse_args()
    size = tuple(int(x) for x in a.size.lower().split("x"))
    for which in a.scenes.split(","):
        run(which, a.frames, a.noise, size)


if __name__ == "__main__":
    main()
