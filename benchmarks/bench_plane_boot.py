"""Why outliers inflate the joint plane's bootstrap: per camera, the bootstrap's variants on the same
fit and the same resampled tracks (common random numbers), and each variant's gate verdict.

Usage: python benchmarks/bench_plane_boot.py --generators thin --cameras 20 [--first-camera 0]
       [--outliers 0.2] [--bootstrap 20]

Variants (each replicate's normal from the same resampled inlier tracks):
``all``: every row of the drawn tracks, refitted from the solution (the default before);
``kept``: only the rows the final fit kept; ``reselect``: ``all``, then that replicate's own
threshold and kept rows refitted (the fit's own procedure); ``all0`` / ``reselect0``: the RMS
angle to the replicates' mean normal instead of the solution (the offset between the refit's
procedure and the fit's left out); ``*_med``: 1.2 x the median angle (a 2-D Gaussian's RMS) instead
of the RMS. The gate: that bootstrap, the class misfit and the Laplace std in quadrature <= 1 deg.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from plane_generators import scene  # noqa: E402

import staticdepth.geometry.agent_plane_boot as boot  # noqa: E402
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane  # noqa: E402
from staticdepth.geometry.plane import angle_between_deg  # noqa: E402

_captured = {}
_orig = boot.joint_uncertainty


def _capture(*args):
    _captured["args"] = args
    return _orig(*args)


boot.joint_uncertainty = _capture


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def variants(K, prob, conf, n, theta, inl, rng, s, thr, B: int) -> dict[str, float]:
    tracks = np.flatnonzero(inl)
    draws = [rng.choice(tracks, len(tracks)) for _ in range(B)]
    normals = {k: [] for k in boot.BOOT_MODES}
    for d in draws:
        for k in boot.BOOT_MODES:
            normals[k].append(boot.replicate_normal(K, prob, conf, n, theta, d, thr, k, s)[0])
    out = {}
    for k, ns in normals.items():
        ns = np.array(ns)
        a = np.array([angle_between_deg(m, n) for m in ns])
        c = ns.mean(0)
        c /= np.linalg.norm(c)
        a0 = np.array([angle_between_deg(m, c) for m in ns])
        out[k] = _rms(a)
        out[k + "0"] = _rms(a0)
        out[k + "_med"] = 1.2 * float(np.median(a))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--generators", default="thin")
    ap.add_argument("--cameras", type=int, default=20)
    ap.add_argument("--first-camera", type=int, default=0)
    ap.add_argument("--outliers", type=float, default=0.2)
    ap.add_argument("--bootstrap", type=int, default=20)
    args = ap.parse_args()
    conf = AgentPlaneConfig(bootstrap=1, column_weight=1.0)
    tally = {}
    for kind in args.generators.split(","):
        for seed in range(args.first_camera, args.first_camera + args.cameras):
            try:
                sc = scene(kind, seed, detection="mask", outliers=args.outliers)
            except ValueError:
                continue
            p = fit_agent_plane(sc.K, sc.obs, conf)
            err = angle_between_deg(p.normal, sc.normal)
            q = p.normal_std_parts
            rest = q.get("class_misfit_deg", 0.0) ** 2 + q.get("laplace_std_deg", 0.0) ** 2
            a = _captured["args"]
            v = variants(*a[:6], np.random.default_rng(seed), *a[7:], B=args.bootstrap)
            line = [f"{kind} {seed}: error {err:.2f} laplace {q.get('laplace_std_deg', 0):.2f}"]
            for k, b in v.items():
                ok = np.sqrt(b * b + rest) <= 1.0
                t = tally.setdefault(k, [0, 0, 0, 0])
                t[0] += ok and err > 1.0
                t[1] += (not ok) and err < 0.5
                t[2] += err > 1.0
                t[3] += err < 0.5
                line.append(f"{k} {b:.2f}{'' if ok else '*'}")
            print(" ".join(line), flush=True)
    for k, t in tally.items():
        print(f"{k:12}: accepts {t[0]} of {t[2]} over 1 deg, refuses {t[1]} of {t[3]} under 0.5")


if __name__ == "__main__":
    main()
