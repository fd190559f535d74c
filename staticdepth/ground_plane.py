"""Stage: the ground plane from agents' observations (``staticdepth ground-plane``).

Reads an observation CSV (columns ``frame, track, foot_u, foot_v, height_px``, optional
``class_id``, ``score``, ``top_u`` (the column of the agent's highest pixel), ``feet`` and the
images' ``image_width, image_height``, to which the intrinsics are fitted), fits
:func:`staticdepth.geometry.agent_plane.fit_agent_plane` and writes the plane as JSON
(``normal``, ``horizon``, ``d_over_agent_height``, ``inliers``, ``uncertainty``,
``camera_height_m`` when an agent height or a camera height is given).
"""
from __future__ import annotations

import argparse
import csv
import os
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry import load_camera
from staticdepth.geometry.agent_plane_gate import (CLASS_SETS, GATE_STD_DEG, class_set,
                                                   plane_gate, with_camera_height_from_agents)

if TYPE_CHECKING:  # the fit imports scipy: loaded when a plane is fitted, not for --help
    from staticdepth.geometry.agent_plane import AgentPlane, AgentPlaneConfig

# geometry.agent_plane.MODELS, named here so that `ground-plane --help` does not import scipy
# (tests/test_cli_startup.py checks that the two agree).
MODELS = ("joint", "exact", "affine", "paper")
# --bootstrap's range: each resample is a plane fit (20, the default, take most of a fit's time);
# plane.bootstrap (AgentPlaneConfig) has the same
BOOTSTRAP_RANGE = "0..10000"

REQUIRED_COLUMNS = ("frame", "track", "foot_u", "foot_v", "height_px")


def read_observations_csv(path: str | os.PathLike
                          ) -> tuple[np.ndarray, tuple[int, int] | None]:
    """(the observation table (:data:`~staticdepth.tracking.OBS_DTYPE`), the ``(width, height)``
    of the images it was measured on, or None) from a CSV with a header; the size comes from the
    optional ``image_width``, ``image_height`` columns (``staticdepth observations`` writes them),
    one size for every row."""
    from staticdepth.observations import SIZE_COLUMNS
    from staticdepth.tracking import OBS_DTYPE

    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read: {e}", path) from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise InputError("empty file (expected a header with "
                         f"{', '.join(REQUIRED_COLUMNS)})", path)
    header = [c.strip() for c in rows[0]]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (header: {', '.join(header)})",
                         path)
    cols = {c: header.index(c) for c in header}
    sized = [c in cols for c in SIZE_COLUMNS]
    if any(sized) and not all(sized):
        raise InputError(f"has one of the columns {' and '.join(SIZE_COLUMNS)} without the other",
                         path)
    out = np.zeros(len(rows) - 1, OBS_DTYPE)
    out["class_id"] = -1
    out["score"] = 1.0
    out["top_u"] = np.nan
    out["left"] = out["right"] = np.nan
    sizes = np.zeros((len(out), 2))
    for i, r in enumerate(rows[1:]):
        if len(r) != len(header):
            raise InputError(f"line {i + 2}: {len(r)} fields, the header has {len(header)}", path)
        for name in ("frame", "track", "foot_u", "foot_v", "height_px", "class_id", "score",
                     "top_u", "feet") + SIZE_COLUMNS:
            if name not in cols:
                continue
            text = r[cols[name]].strip()
            try:
                val = float(text)
            except ValueError:
                raise InputError(f"line {i + 2}: column {name!r} is not a number: {text!r}",
                                 path) from None
            if not np.isfinite(val):
                raise InputError(f"line {i + 2}: column {name!r} is not finite: {text!r}", path)
            if name in SIZE_COLUMNS:
                sizes[i, SIZE_COLUMNS.index(name)] = val
            else:
                out[name][i] = val
    out["top_v"] = out["foot_v"] - out["height_px"]
    usable = int(np.sum(out["height_px"] > 0))
    if usable < 3:
        raise InputError(f"{usable} usable observation(s) (height_px > 0); the ground plane needs "
                         "at least 3", path)
    return out, (_image_size(sizes, path) if all(sized) else None)


def _image_size(sizes: np.ndarray, path) -> tuple[int, int]:
    """The one image size of every row."""
    distinct = np.unique(sizes, axis=0)
    if len(distinct) > 1:
        raise InputError(f"rows of {len(distinct)} image sizes ("
                         + ", ".join(f"{int(w)}x{int(h)}" for w, h in distinct[:3])
                         + "): the observations of one camera have one size", path)
    w, h = distinct[0]
    if w < 1 or h < 1 or w != int(w) or h != int(h):
        raise InputError(f"image size {w:g}x{h:g} is not a size in pixels", path)
    return int(w), int(h)


#: how far (share of the image's size) observations may lie beyond the camera's image: a camera
#: JSON without ``width``/``height`` gets a size from its principal point (``2 c + 1``)
OUTSIDE_TOLERANCE = 0.2


def check_in_image(obs: np.ndarray, camera, obs_path, camera_path) -> None:
    """One line when the observations reach beyond the camera's image by more than
    :data:`OUTSIDE_TOLERANCE` of its size: observations taken at another resolution than the
    intrinsics (a video's full frames against the imported sequence's camera) would put every
    ray, and so the plane, wrong without any other sign."""
    pts = [("foot_u", camera.width), ("top_u", camera.width), ("foot_v", camera.height),
           ("top_v", camera.height)]
    for col, size in pts:
        x = obs[col][np.isfinite(obs[col])]
        if not len(x):
            continue
        lo, hi = float(x.min()), float(x.max())
        if hi > (1 + OUTSIDE_TOLERANCE) * size or lo < -OUTSIDE_TOLERANCE * size:
            raise InputError(f"{col} spans {lo:g} to {hi:g}, beyond the {camera.width}x"
                             f"{camera.height} image of {os.fspath(camera_path)}: observations and "
                             f"intrinsics of different resolutions?", obs_path)


def bootstrap_bar(resamples: int):
    """A progress bar over the plane fit's bootstrap resamples (most of the fit's time: 10 of
    14 s on 1.8k observations), for :func:`fit_agent_plane`'s ``steps``."""
    from staticdepth.progress import progress

    return lambda it: progress(it, total=resamples, desc="ground plane (bootstrap)",
                               unit="resample")


def estimate_ground_plane(observations: np.ndarray, K: np.ndarray,
                          conf: AgentPlaneConfig | None = None, *,
                          agent_height_m: float | None = None,
                          camera_height_m: float | None = None, steps=None) -> AgentPlane:
    """Fit the plane and attach a camera height: the given one, else from one agent height (the
    median over person tracks), else from the classes' height distributions (people when the
    plane has person tracks, else every class; with its uncertainty); none when that fails.
    A given camera height also enters the joint fit, as a prior ``conf.known_height_sd`` apart.
    ``conf`` None = the default :class:`AgentPlaneConfig`; ``steps`` wraps the bootstrap's
    resamples (a progress bar)."""
    from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane

    conf = (AgentPlaneConfig() if conf is None else conf).with_known_height(camera_height_m)
    plane = fit_agent_plane(K, observations, conf, steps)
    if camera_height_m is not None:
        return plane.with_camera_height(camera_height_m, "given")
    try:
        return with_camera_height_from_agents(plane, agent_height_m, seed=conf.seed)
    except InputError:
        return plane


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON atomically (:mod:`staticdepth.fileio`)."""
    from staticdepth.fileio import atomic_write_json
    atomic_write_json(path, obj)


def summary(plane: AgentPlane) -> str:
    lines = [f"ground plane ({plane.model}): pitch {plane.pitch_deg:.2f} deg, roll "
             f"{plane.roll_deg:.2f} deg, normal {np.round(plane.normal, 4).tolist()}",
             f"  d / agent height {plane.d_over_agent_height:.3f}, inlier tracks "
             f"{int(plane.inliers.sum())}/{len(plane.inliers)}, {plane.n_observations} "
             f"observations, rms {plane.rms_px:.2f} px"]
    if np.isfinite(plane.normal_std_deg):
        q = plane.normal_std_parts
        axes = (f" (pitch {q['pitch_std_deg']:.2f}, roll {q['roll_std_deg']:.2f})"
                if "pitch_std_deg" in q else "")
        lines.append(f"  uncertainty: normal {plane.normal_std_deg:.2f} deg{axes}, d/H "
                     f"{plane.d_over_h_std:.3f}")
    if plane.camera_height_m is not None:
        sd = (f" +- {plane.camera_height_std_m:.3f}" if np.isfinite(plane.camera_height_std_m)
              else "")
        lines.append(f"  camera height {plane.camera_height_m:.3f}{sd} m "
                     f"({plane.camera_height_source})")
    ext = plane.extra.get("extents")
    if ext:
        lines.append("  extents (ratio to height): " + ", ".join(
            f"{k} {'/'.join(f'{v:.3f}' for v in vals)}" for k, vals in ext.items()))
    return "\n".join(lines)


def register(sub) -> None:
    p = sub.add_parser("ground-plane", help="ground plane from agents' foot points and heights",
                       description="Fit the ground plane (normal, horizon, d/H, camera height) to "
                                   "tracked agents' observations (METHOD.md section 2).")
    p.add_argument("--observations", required=True,
                   help="CSV with columns frame, track, foot_u, foot_v, height_px (pixels); "
                        "optional class_id, score, top_u (column of the highest pixel)")
    p.add_argument("--intrinsics", required=True, help="JSON with fx, fy, cx, cy (or a camera/rig)")
    p.add_argument("--agent-height", type=float,
                   help="one agent height in metres that gives the camera height (the median "
                        "over person tracks; default: none, the camera height comes from the "
                        "per-class height distributions, people's inlier tracks else every "
                        "class's); it also sets the exact model's radius-to-height ratio "
                        "(default 1.7 there); ignored for the height with --camera-height")
    p.add_argument("--camera-height", type=float, help="known camera height in metres")
    p.add_argument("--model", choices=MODELS, default="joint",
                   help="joint (default): plane, per-class extents and track heights together; "
                        "exact: fixed-radius cylinders; paper/affine: Eq. 1")
    p.add_argument("--classes", choices=tuple(CLASS_SETS),
                   help="agent classes that enter the fit (default: all for joint, people for "
                        "the other models)")
    p.add_argument("--max-normal-std", type=float, default=GATE_STD_DEG,
                   help="refuse a plane whose normal uncertainty (degrees) is larger (default "
                        f"{GATE_STD_DEG:.2f}: 1 degree of error is then 1.4 std)")
    p.add_argument("--accept-uncertain", action="store_true",
                   help="write the plane even when it fails the uncertainty gate")
    p.add_argument("--radius", type=float, help="agent body radius in metres (default 0.2, 0 = "
                                                "thin axis)")
    p.add_argument("--bootstrap", type=int,
                   help="resamples for the uncertainty (default 20, at most 10000)")
    p.add_argument("--column-weight", type=float,
                   help="weight of the head-column residuals (0: rows only; default 1 for "
                        "joint, scaled down by the columns' noise, 0 for exact)")
    p.add_argument("--out", required=True, help="plane JSON to write")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)
    p.set_defaults(func=_ground_plane_cmd)


def _ground_plane_cmd(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing
    from staticdepth.fileio import check_writable
    from staticdepth.geometry.agent_plane import PRESETS
    from staticdepth.geometry.camera import check_camera_height

    check_writable(args.out)
    refuse_existing(args.out, overwrite=args.overwrite)
    from staticdepth.config import check_ranges

    # the options as given, before any file is read (the config checks its settings again)
    check_ranges(args, "", {"radius": ">=0", "agent_height": ">0", "column_weight": ">=0",
                            "bootstrap": BOOTSTRAP_RANGE, "max_normal_std": ">0|inf"},
                 options=True)
    if args.camera_height is not None:
        check_camera_height(args.camera_height, "--camera-height")
    if args.agent_height is not None and args.camera_height is not None:
        print("warning: --camera-height is given: --agent-height does not set the camera height "
              "(it only sets the exact model's body-to-height ratio)")
    conf = PRESETS[args.model]
    changes = {k: v for k, v in (("radius_m", args.radius), ("bootstrap", args.bootstrap),
                                 ("column_weight", args.column_weight),
                                 ("agent_height_m", args.agent_height)) if v is not None}
    if args.classes is not None:
        changes["classes"] = class_set(args.classes)
    conf = replace(conf, **changes)     # the options checked before any file is read
    camera = load_camera(args.intrinsics)
    obs, size = read_observations_csv(args.observations)
    if size is not None:        # the intrinsics scaled to the observations' images, or refused
        camera = camera.fitted_to(*size, what=f"the images of {os.fspath(args.observations)}",
                                  source=args.intrinsics)
    check_in_image(obs, camera, args.observations, args.intrinsics)
    print(f"fitting the {conf.model} ground plane to {len(obs)} observations of "
          f"{len(np.unique(obs['track']))} tracks ({conf.bootstrap} bootstrap resamples)",
          flush=True)
    try:
        plane = estimate_ground_plane(obs, camera.K, conf, agent_height_m=args.agent_height,
                                      camera_height_m=args.camera_height,
                                      steps=bootstrap_bar(conf.bootstrap))
    except InputError as e:
        raise InputError(e.problem, args.observations) from None
    print(summary(plane))
    if conf.bootstrap == 0:         # the user turned the uncertainty off: nothing to gate
        write_json(args.out, plane.to_dict())
        print("warning: --bootstrap 0: the plane's uncertainty is unknown and not checked")
        return 0
    gate = plane_gate(plane, args.max_normal_std)
    if not gate.ok and not args.accept_uncertain:
        raise InputError(f"{gate.message} (--accept-uncertain writes it anyway)",
                         args.observations)
    write_json(args.out, {**plane.to_dict(), "gate": gate.to_dict()})
    print(("" if gate.ok else "warning: ") + gate.message)
    return 0
