"""Ground-plane accuracy per body model: the paper's Eq. 1, the fixed-shape exact model, the joint one.

Usage: python benchmarks/bench_agent_plane.py [--cameras 8] [--first-camera 0] [--outliers 0.0] [--detection mask]
       [--generators thin,tapered,cylinder,ellipsoid,vehicles] [--models paper,exact,joint,joint-h]
       [--bootstrap 0] [--verbose] [--truth foot|top|foot,top]
       python benchmarks/bench_agent_plane.py --scenes i1,i2,i3,i4 [--frames 27] [--bootstrap 20]

Scenes from the independent generators of tests/plane_generators.py (cameras 3-12 m high, pitched
10-50 degrees, roll +-5, 24 tracks, 1 px noise; ``--detection box`` gives boxes with +-2 px
jitter and no top column, ``--detection mask,box`` both, each generator's rows side by side;
``--outliers 0.2`` corrupts 20% of the observations). Per generator and
model: median and max error of the normal (degrees) and of the camera height from the agents
(percent: Eq. 1 and exact from a 1.72 m agent height, people's median; joint from the classes'
height distributions, maximum likelihood), of the anchor depth given the true camera height
(percent; the ground's depth at the bottom row's centre pixel, the metric scale's anchor) and
seconds per fit (``joint-h``: the joint model told the true camera height, a prior
``known_height_sd`` apart, as ``adapt`` does with a sequence's or a given height; its camera
height column is still the agents' own estimate); a fit that refuses (InputError,
e.g. a near-nadir camera) is printed and counted, not in the statistics. ``--bootstrap N``: the
joint model's bootstrap too, and the ratio of the true normal error to its reported uncertainty
(median / max; <= 1 where the uncertainty covers the error) and how many cameras over 1 degree
the gate accepts and under 0.5 it refuses. ``--verbose``: per camera also the joint fit's
Laplace std (priors in / data only) and the Cramer-Rao bound at the truth (data only / priors
in; agent_plane_laplace), the chance an unbiased fit with that RMS is over 1 degree and the tracks
that would make it 5%. ``--truth foot``, ``top`` or
``foot,top``: each observation's foot (top) point replaced by the projection of the agent's true
axis foot (axis top, the foot plus its height along the up direction) with 1 px noise of its own
(``feet`` 2: the axis is both feet's mean): which observed quantity carries a camera's error.
``--noise-px 0``: noise-free observations (and truth points), the estimator's bias alone
(tapered seeds 0-19, joint: 0.13 / 1.25 degrees; from the true foot and top 0.01-0.19 on its
five steep cameras: the mask's lowest point is on the body's flare, tests/test_plane_bias.py).
``--draws N`` (with ``--verbose``, masks): per camera the joint fits refitted on the camera's
noise-free observations under N fresh draws of the same noise (foot, top and extreme columns),
their RMS / median / max error and share over 1 degree, and per generator the sum of those shares:
the cameras over 1 degree the fit's own spread expects, beside the Cramer-Rao count (which takes
the extents' prior as right, so it understates the spread on bodies far from the prior).

``--scenes``: the independent rendered scenes of tests/indep_scenes.py (people as ellipsoids,
cars as body + cabin + wheel boxes, 320x160, the first ``--frames`` frames: adapt's split of 60),
observations from their ground-truth instance maps as ``adapt`` takes them
(``tracking.observations_from_instances``, straight walkers kept, ``--min-height-px`` 10); per
scene and class set (people, all, vehicles) the joint model's normal error, its bootstrap
uncertainty and their ratio, and the inlier tracks per class.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from plane_generators import GENERATORS, H, W, scene  # noqa: E402

from staticdepth import tracking  # noqa: E402
from staticdepth.errors import InputError  # noqa: E402
from staticdepth.geometry.agent_plane import (AgentPlaneConfig, camera_height_from_prior,  # noqa: E402
                                              fit_agent_plane)
from staticdepth.geometry.agent_plane_gate import camera_height_from_agents, plane_gate  # noqa: E402
from staticdepth.geometry.agent_plane_laplace import (chance_over, cramer_rao_of_fit,  # noqa: E402
                                                      tracks_for)
from staticdepth.geometry.plane import angle_between_deg  # noqa: E402
from staticdepth.geometry.scale import anchor_depth, anchor_pixel  # noqa: E402

CONFIGS = {"paper": AgentPlaneConfig(model="paper", bootstrap=0, classes=None),
           "exact": AgentPlaneConfig(model="exact", bootstrap=0, classes=None),
           "joint": AgentPlaneConfig(bootstrap=0, column_weight=1.0)}
# joint-h: the joint model given the true camera height (a prior on it, known_height_sd apart)
KNOWN_HEIGHT = "joint-h"


def anchor_error(s, normal) -> float:
    """Percent error of the anchor depth (the ground's depth at the bottom row's centre pixel,
    :func:`staticdepth.geometry.scale.anchor_depth`) from the fitted normal and the true camera
    height, against the true plane's."""
    u, v = anchor_pixel(W, H)
    try:
        fit = anchor_depth(s.K, normal, s.height_m, u, v)
    except InputError:          # the anchor above the fitted horizon
        return float("inf")
    return abs(fit / anchor_depth(s.K, s.normal, s.height_m, u, v) - 1) * 100


def with_truth(s, parts: set[str], seed: int, noise_px: float = 1.0):
    """The scene with its observations' foot and/or top points (``parts``) replaced by the
    projections of the agents' true axis foot / axis top, ``noise_px`` noise drawn from
    ``seed``."""
    o = s.obs.copy()
    e = np.random.default_rng([seed, 7]).normal(0.0, noise_px, (4, len(o)))
    up = np.array([s.agent_heights[int(t)] for t in o["track"]])[:, None] * -s.normal
    for name, P, k in (("foot", s.foot_true, 0), ("top", s.foot_true + up, 2)):
        if name in parts:
            q = P @ s.K.T
            cu, cv = ("foot_u", "foot_v") if name == "foot" else ("top_u", "top_v")
            o[cu], o[cv] = q[:, 0] / q[:, 2] + e[k], q[:, 1] / q[:, 2] + e[k + 1]
    if "foot" in parts:
        o["feet"] = 2
    o["height_px"] = o["foot_v"] - o["top_v"]
    return replace(s, obs=o)


def fresh_draw(obs: np.ndarray, noise_px: float, rng) -> np.ndarray:
    """Noise-free mask observations with a new draw of the generators' noise: ``noise_px``
    Gaussian on the foot and top points and on the extreme columns, the pixel height from the
    noisy rows (as ``plane_generators.scene`` makes them)."""
    o = obs.copy()
    for name in ("foot_u", "foot_v", "top_u", "top_v", "left", "right"):
        o[name] = o[name] + rng.normal(0.0, noise_px, len(o))
    o["height_px"] = o["foot_v"] - o["top_v"]
    return o


def draw_errors(K, s0, conf, n_draws: int, noise_px: float, seed: int) -> np.ndarray:
    """The fit's own spread on one camera: the normal error (degrees; NaN: refused) of
    ``n_draws`` refits of its noise-free observations ``s0`` under fresh noise."""
    rng = np.random.default_rng([seed, 99])
    errs = []
    for _ in range(n_draws):
        try:
            p = fit_agent_plane(K, fresh_draw(s0.obs, noise_px, rng), conf)
        except InputError:
            errs.append(np.nan)
            continue
        errs.append(angle_between_deg(p.normal, s0.normal))
    return np.asarray(errs)


def share_over(e: np.ndarray, limit: float = 1.0) -> float:
    """Share of the fitted draws (NaN: refused, left out) over ``limit`` degrees."""
    ok = np.isfinite(e)
    return float(np.mean(e[ok] > limit)) if ok.any() else float("nan")


def draws_text(e: np.ndarray) -> str:
    refused = int(np.isnan(e).sum())
    return (f", {len(e)} fresh draws: RMS {np.sqrt(np.nanmean(e ** 2)):.2f}, median "
            f"{np.nanmedian(e):.2f}, max {np.nanmax(e):.2f} deg, over 1 deg {share_over(e):.0%}"
            + (f" ({refused} refused)" if refused else ""))


def camera_height(plane, model: str, vehicles: bool) -> float:
    try:
        if model in ("joint", KNOWN_HEIGHT):
            return camera_height_from_agents(plane, None if vehicles else (0, -1), bootstrap=0)[0]
        if model == "paper":
            return 1.72 * plane.d_over_agent_height
        return camera_height_from_prior(plane, 1.72)
    except InputError:
        return float("nan")


def uncertainty_cell(s, p, bound, n_tracks: int) -> str:
    """The joint fit's Laplace std (priors in / data only), the Cramer-Rao bound at the truth
    (``bound``: data only / priors in; agent_plane_laplace), the chance that an unbiased fit with
    the bound's RMS is over 1 degree, and the tracks (same frames each) that would make it 5%;
    with the priors, the bound's std of the anchor depth (true camera height) and of the camera
    height."""
    q = p.normal_std_parts
    crb, crb_p = bound.normal_deg, bound.normal_priors_deg
    return (f", Laplace {q.get('laplace_std_deg', np.nan):.2f} / "
            f"{q.get('laplace_data_std_deg', np.nan):.2f}, CRB {crb:.2f} / {crb_p:.2f} "
            f"(P(>1 deg) {chance_over(crb, 1.0, 2):.0%}; 1 deg at 95%: "
            f"{tracks_for(crb, n_tracks) if np.isfinite(crb) else 'no'} tracks), CRB anchor "
            f"{bound.anchor_std(s.K, *anchor_pixel(W, H)) * 100:.2f}%, camera height "
            f"{bound.camera_height_std() * 100:.1f}%")


def scene_table(names: list[str], frames: int, min_height_px: float, bootstrap: int) -> None:
    """Plane error per class set on the independent rendered scenes (see the module doc)."""
    from indep_scenes import SCENES, Scene

    from staticdepth.geometry.camera import normal_from_pitch_roll

    print(f"independent scenes, {frames} frames at 320x160, gt instances; joint model, "
          f"bootstrap {bootstrap}: normal error deg, reported std deg, error / std, inlier tracks")
    sets = {"people": (0, -1), "all": None, "vehicles": (1, 2, 3, 5, 7)}
    for spec in SCENES:
        if spec.name not in names:
            continue
        sc = Scene(spec, 320, 160)
        pairs = [(f["instances"], f["agents"]) for f in (sc.render(i) for i in range(frames))]
        obs = tracking.observations_from_instances(pairs, tracking.TrackingConfig(
            drop_collinear=False, min_height_px=min_height_px))
        truth = normal_from_pitch_roll(spec.pitch_deg, 0.0)
        for name, cls in sets.items():
            try:
                p = fit_agent_plane(sc.camera.K, obs, AgentPlaneConfig(classes=cls,
                                                                        bootstrap=bootstrap))
            except InputError as e:
                print(f"{spec.name:3} {name:8} refused: {e}")
                continue
            err = angle_between_deg(p.normal, truth)
            c = np.asarray(p.extra["classes"])
            per = ", ".join(f"class {k}: {np.count_nonzero(p.inliers & (c == k))}/"
                            f"{np.count_nonzero(c == k)}" for k in np.unique(c))
            q = p.normal_std_parts
            print(f"{spec.name:3} {name:8} error {err:5.2f}  std {p.normal_std_deg:5.2f}  "
                  f"ratio {err / p.normal_std_deg:5.2f}  tracks {per}  (bootstrap "
                  f"{q.get('bootstrap_std_deg', np.nan):.2f}, Laplace "
                  f"{q.get('laplace_std_deg', np.nan):.2f} / data "
                  f"{q.get('laplace_data_std_deg', np.nan):.2f}; gate "
                  f"{'accepts' if plane_gate(p).ok else 'refuses'})", flush=True)


def main() -> None:
    ap_ = argparse.ArgumentParser(description=__doc__)
    ap_.add_argument("--cameras", type=int, default=8)
    ap_.add_argument("--first-camera", type=int, default=0,
                     help="seed of the first camera (e.g. 20 with --cameras 20: cameras held out "
                          "from the ones a rule was chosen on)")
    ap_.add_argument("--outliers", type=float, default=0.0)
    ap_.add_argument("--detection", default="mask",
                     help="mask, box, or mask,box (both per generator: their s per fit compare)")
    ap_.add_argument("--generators", default=",".join(GENERATORS))
    ap_.add_argument("--models", default="paper,exact,joint")
    ap_.add_argument("--bootstrap", type=int, default=0)
    ap_.add_argument("--verbose", action="store_true", help="every camera's error")
    ap_.add_argument("--gate-lines", action="store_true", help="with --bootstrap: per camera the "
                     "joint fit's error, std and its parts, and the gate's verdict")
    ap_.add_argument("--truth", default="", help="foot, top or foot,top: observed points "
                     "replaced by the generator's true axis points (see the module doc)")
    ap_.add_argument("--noise-px", type=float, default=1.0, help="the generators' noise (0: "
                     "noise-free, what is left is the estimator's or the body model's bias)")
    ap_.add_argument("--scenes", default="", help="e.g. i1,i2,i3,i4: the rendered scenes instead")
    ap_.add_argument("--frames", type=int, default=27)
    ap_.add_argument("--min-height-px", type=float, default=10.0)
    ap_.add_argument("--tracks", type=int, default=24, help="tracks per generated camera (a "
                     "longer sequence: more tracks; the issue's figures are at 24)")
    ap_.add_argument("--draws", type=int, default=0, help="with --verbose, masks: per camera "
                     "also the joint fits' spread over this many fresh noise draws of the "
                     "camera's noise-free observations, and per generator the cameras over 1 "
                     "deg that spread expects (see the module doc)")
    args = ap_.parse_args()
    if args.scenes:
        scene_table(args.scenes.split(","), args.frames, args.min_height_px, args.bootstrap)
        return
    models = args.models.split(",")
    if not set(models) <= set(CONFIGS) | {KNOWN_HEIGHT}:
        ap_.error(f"--models: of {', '.join([*CONFIGS, KNOWN_HEIGHT])}, got {args.models}")
    ref = "joint" if "joint" in models else KNOWN_HEIGHT   # the gate's lines
    detections = args.detection.split(",")
    if not set(detections) <= {"mask", "box"}:
        ap_.error(f"--detection: mask, box or mask,box, got {args.detection}")
    truth = set(args.truth.split(",")) if args.truth else set()
    if not truth <= {"foot", "top"} or (truth and detections != ["mask"]):
        ap_.error(f"--truth: foot, top or foot,top, with --detection mask; got {args.truth}")
    if args.draws and (not args.verbose or detections != ["mask"] or truth or args.draws < 2
                       or not args.noise_px > 0):
        ap_.error("--draws N (N >= 2) needs --verbose, --detection mask, no --truth and noise")
    if args.bootstrap:
        CONFIGS["joint"] = replace(CONFIGS["joint"], bootstrap=args.bootstrap)
    print(f"{args.cameras} cameras per generator, detections: {args.detection}, outliers "
          f"{args.outliers:.0%}; normal error deg (median / max), camera height error % "
          "(median / max), anchor depth error % with the true camera height (median / max), "
          "s per fit")
    print(f"{'generator':10}" + "".join(f" | {m:^42}" for m in models))
    for kind, det in ((k, d) for k in args.generators.split(",") for d in detections):
        stats = {m: ([], [], [], []) for m in models}
        refused = {m: 0 for m in models}
        ratios, gate = [], [0, 0, 0, 0]   # accepted over 1 deg, refused under 0.5, of how many
        # --verbose: cameras over 1 deg / 5% camera height / 1% anchor, expected of an unbiased
        # fit at the bound (priors in) and observed, of how many
        expected = {m: [0.0, 0.0, 0.0, 0] for m in models}
        observed = {m: [0, 0, 0] for m in models}
        drawn = {m: [] for m in models}   # --draws: per camera the share of draws over 1 deg
        for seed in range(args.first_camera, args.first_camera + args.cameras):
            try:
                s = scene(kind, seed, detection=det, outliers=args.outliers,
                          noise_px=args.noise_px, n_tracks=args.tracks)
            except ValueError as e:     # the generator could not place a whole agent: no scene
                print(f"  {kind} camera {seed}: no scene ({e}); not counted", flush=True)
                continue
            if truth:
                s = with_truth(s, truth, seed, args.noise_px)
            s0 = (scene(kind, seed, detection=det, outliers=args.outliers, noise_px=0.0,
                        n_tracks=args.tracks) if args.draws else None)
            n_tracks = len(np.unique(s.obs["track"]))
            if n_tracks < 8:     # e.g. a low, steep camera where whole vehicles rarely fit
                print(f"  {kind} camera {seed}: only {n_tracks} tracks in view (the gate refuses "
                      "fewer than 3)", flush=True)
            for m in models:
                conf = (replace(CONFIGS["joint"], known_height_m=s.height_m)
                        if m == KNOWN_HEIGHT else CONFIGS[m])
                t0 = time.perf_counter()
                try:
                    p = fit_agent_plane(s.K, s.obs, conf)
                except InputError as e:          # a refusal (e.g. near-nadir) counts, as NaN
                    print(f"  {kind} camera {seed} {m}: refused: {e}", flush=True)
                    refused[m] += 1
                    continue
                stats[m][2].append(time.perf_counter() - t0)
                stats[m][0].append(angle_between_deg(p.normal, s.normal))
                h = camera_height(p, m, kind == "vehicles")
                stats[m][1].append(abs(h / s.height_m - 1) * 100)
                stats[m][3].append(anchor_error(s, p.normal))
                bound = None
                if args.verbose and m in ("joint", KNOWN_HEIGHT):
                    bound = cramer_rao_of_fit(s.K, s.obs, p, conf, s.normal,
                                              s.agent_heights, s.height_m)
                    a_std = bound.anchor_std(s.K, *anchor_pixel(W, H))
                    for k, (std, lim, dims, err) in enumerate((
                            (bound.normal_priors_deg, 1.0, 2, stats[m][0][-1]),
                            (bound.camera_height_std() * 100, 5.0, 1, stats[m][1][-1]),
                            (a_std * 100, 1.0, 1, stats[m][3][-1]))):
                        expected[m][k] += chance_over(std, lim, dims)
                        observed[m][k] += err > lim
                    expected[m][3] += 1
                spread = ""
                if s0 is not None and m in ("joint", KNOWN_HEIGHT):
                    e_draws = draw_errors(s.K, s0, conf, args.draws, args.noise_px, seed)
                    spread = draws_text(e_draws)
                    drawn[m].append(share_over(e_draws))
                if args.verbose:
                    print(f"  {kind} camera {seed} {m}: {stats[m][0][-1]:.2f} deg, anchor "
                          f"{stats[m][3][-1]:.2f}%, camera height "
                          f"{h / s.height_m * 100 - 100:+.1f}%, "
                          f"{n_tracks} tracks, uncertainty {p.normal_std_deg:.2f}"
                          + (uncertainty_cell(s, p, bound, n_tracks) if bound else "") + spread,
                          flush=True)
                if m == ref and args.bootstrap:
                    ratios.append(stats[m][0][-1] / p.normal_std_deg)
                    ok = plane_gate(p).ok
                    gate[0] += ok and stats[m][0][-1] > 1.0
                    gate[1] += not ok and stats[m][0][-1] < 0.5
                    gate[2] += stats[m][0][-1] > 1.0
                    gate[3] += stats[m][0][-1] < 0.5
                    if args.gate_lines:
                        q = p.normal_std_parts
                        print(f"  gate {kind} {det} camera {seed}: error {stats[m][0][-1]:.2f} "
                              f"std {p.normal_std_deg:.2f} (bootstrap "
                              f"{q.get('bootstrap_std_deg', np.nan):.2f}, class misfit "
                              f"{q.get('class_misfit_deg', np.nan):.2f}, Laplace "
                              f"{q.get('laplace_std_deg', np.nan):.2f} / data "
                              f"{q.get('laplace_data_std_deg', np.nan):.2f}) "
                              f"{'accepts' if ok else 'refuses'}", flush=True)
        cells = []
        for m in models:
            e, h, t, a = (np.asarray(x) for x in stats[m])
            if len(e) == 0:
                cells.append(f"all {refused[m]} refused")
                continue
            cells.append(f"{np.median(e):5.2f} / {np.max(e):5.2f}  {np.nanmedian(h):4.1f} / "
                         f"{np.nanmax(h):4.1f}  {np.median(a):4.2f} / {np.max(a):4.2f}  "
                         f"{np.median(t):4.1f}"
                         + (f" ({refused[m]} refused)" if refused[m] else ""))
        if ratios:
            cells.append(f"error / std {np.nanmedian(ratios):.2f} / {np.nanmax(ratios):.2f}, gate "
                         f"accepts {gate[0]} of {gate[2]} over 1 deg, refuses {gate[1]} of "
                         f"{gate[3]} under 0.5")
        label = f"{kind}/{det}" if len(detections) > 1 else kind
        print(f"{label:10}" + "".join(f" | {c:^42}" for c in cells), flush=True)
        for m in models:
            e, o = expected[m], observed[m]
            if e[3]:
                print(f"{'':10} | {m}, cameras over 1 deg / camera height 5% / anchor 1%: "
                      f"{o[0]} / {o[1]} / {o[2]} of {e[3]}; an unbiased fit at the Cramer-Rao "
                      f"bound (priors in) {e[0]:.1f} / {e[1]:.1f} / {e[2]:.1f}"
                      + (f"; over 1 deg expected of the fit's own spread (fresh draws) "
                         f"{np.nansum(drawn[m]):.1f}" if drawn[m] else ""), flush=True)


if __name__ == "__main__":
    main()
