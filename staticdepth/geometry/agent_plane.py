"""The ground plane from moving agents' foot points and pixel heights (METHOD.md section 2).

Four models, selectable by name:
- ``joint`` (default): plane, per-track heights and per-class extents fitted together, every
  agent class (people as disks, two-wheelers and vehicles as boxes), head rows and columns
  (:mod:`staticdepth.geometry.agent_plane_joint`, :mod:`staticdepth.geometry.agent_shape`);
- ``paper`` and ``affine``: Eq. 1 (:mod:`staticdepth.geometry.agent_plane_linear`);
- ``exact``: the fixed-shape exact projective model (:mod:`staticdepth.geometry.agent_cylinder`).
  Unknowns are the unit normal (pitch, roll) and per track ``s_j = H_j / d``; each agent is an
  upright cylinder with a foot disk of ``radius_m`` and a head disk of ``head_radius_m`` (both
  relative to ``agent_height_m``), so the observed bottom point is the lowest point of the foot
  disk's rim and the top point the highest point of the head disk's rim. Residuals are the top
  point's reprojection errors in pixels: its row, and optionally (``column_weight`` > 0) its
  column where the table has ``top_u``. RANSAC over tracks, a robust (soft-L1) refinement of the
  normal and all s_j jointly on the inliers, least squares on the inlier observations, and a
  bootstrap over tracks for the uncertainty.

For ``exact`` only the classes the body model describes enter the fit (``classes="auto"``:
people, and rows of unknown class). Cars, buses, trucks and two-wheelers are boxes, not upright
cylinders: on the synthetic scenes they pull that model's normal by degrees when few people are
seen; ``joint`` models them and takes every class by default.

Why the head column is off by default for ``exact`` (``joint`` uses it, weighted by the rows'
over the columns' residual scale, since its extents are fitted): the column of the top of a mask moves with the head's
radius and with where the mask's top row cuts the head (its midpoint is not the rim's extreme
point), and the tilt it implies is tiny (about 0.003 px per pixel off-centre per degree of
pitch), so a 1 px systematic column error at the image edge is a degree of pitch. Measured on the
rendered scenes (c1, c2, c3, demo, 400 frames, 400x200 and 800x400, benchmarks/
bench_plane_on_synth.py): pitch errors of 3.8-6.2 degrees with ``column_weight`` 1 and a head as
wide as the body, 0.0-0.15 degrees with rows only and ``head_radius_m`` 0.12 (c2 at 400x200,
7 people 10-20 px tall: 0.5-1.8).

Everything is in the camera frame (OpenCV), in units of the camera height d (plane ``n . P = 1``).
Observations are the table of :data:`staticdepth.tracking.OBS_DTYPE` (or any structured array
with ``track``, ``foot_u``, ``foot_v``, ``height_px`` fields; ``top_u`` and ``class_id``
optional). The Eq. 1 solvers and the cylinder model's functions are re-exported here; the
exact model's fit is in :mod:`staticdepth.geometry.agent_plane_exact`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from staticdepth.config import check_ranges, check_seed
from staticdepth.errors import InputError
from staticdepth.geometry.agent_cylinder import (_BIG, AgentObservations, extreme_rim,  # noqa: F401
                                                 head_pixels, head_residuals, head_rows,
                                                 observation_residual, solve_track_scales)
from staticdepth.geometry.agent_plane_checks import check_fitted_plane, check_nadir
from staticdepth.geometry.agent_plane_exact import bootstrap_normal, fit_robust
from staticdepth.geometry.agent_plane_joint import fit_joint
from staticdepth.geometry.agent_plane_linear import (LINEAR_MODELS, fit_linear,  # noqa: F401
                                                     plane_affine, plane_paper,
                                                     vertical_from_axes)
from staticdepth.geometry.agent_walker import interpolate_one_foot
from staticdepth.geometry.camera import check_camera_height, pitch_roll_from_normal
from staticdepth.geometry.plane import horizon_line
from staticdepth.geometry.projection import rays_from_pixels

MODELS = ("joint", "exact", "affine", "paper")
PERSON_CLASSES = (0, -1)  # COCO person, or unknown class (a CSV without classes)
# the normal's uncertainty, part by part (joint model; agent_plane_boot, agent_plane_laplace)
UNCERTAINTY_PARTS = ("bootstrap_std_deg", "class_misfit_deg", "laplace_std_deg",
                     "laplace_data_std_deg", "boxed_share", "pitch_std_deg", "roll_std_deg",
                     "pitch_roll_corr")


@dataclass(frozen=True)
class AgentPlaneConfig:
    """How to fit the ground plane from agents; see :data:`PRESETS`."""

    model: str = "joint"
    radius_m: float = 0.2            # body (foot disk) radius of the cylinder model (0 = thin axis)
    head_radius_m: float = 0.12      # head disk radius: the top of the silhouette (0 = thin)
    agent_height_m: float = 1.7      # only sets the radius/height ratio of the cylinder model
    inlier_px: float = 3.0           # RANSAC: observation inlier threshold on the head point
    column_weight: float | None = None   # weight of the head-column residuals (0 = rows only;
    #                                  None: 1 for ``joint``, 0 for ``exact``, see the module doc)
    classes: tuple[int, ...] | None | str = "auto"   # class ids that enter the fit (None = all;
    #                                  "auto": all for ``joint``, people for the other models)
    ransac_iters: int = 60           # upper bound; stops early at 99% confidence
    loss: str = "soft_l1"            # robust refinement loss (scipy least_squares)
    f_scale_px: float = 1.5
    pitch_starts_deg: tuple[float, ...] = (10.0, 25.0, 40.0, 60.0)
    pitch_bounds_deg: tuple[float, float] = (0.0, 89.0)
    max_roll_deg: float = 30.0
    max_pitch_deg: float = 65.0      # refuse a (near-)nadir camera above it (see check_nadir;
    #                                  the fitted pitch for joint and exact, not for Eq. 1, whose
    #                                  bias reaches 30 degrees)
    bootstrap: int = 20              # resamples over tracks (0 = no uncertainty)
    seed: int = 0
    shape_prior_weight: float = 1.0  # joint: pixels of residual per prior sd of an extent
    height_prior_weight: float = 1.0  # joint: pixels per sd of a track's height from its class
    relative_noise: float | None = None   # joint: people's residuals over sqrt(1 + (this *
    #                                  pixel height)^2): gait and bobbing move a walker's extremes
    #                                  by a share of its size (None: estimated from the residuals)
    one_foot: bool = True            # joint: people's one-foot frames (masks whose feet overlap,
    #                                  where others show two) take the foot interpolated between
    #                                  their track's two-foot frames, else a foot extent of their
    #                                  own (agent_walker)
    max_class_misfit_deg: float | None = 2.0   # joint: a minority class group whose leaving-out
    #                                  moves the normal by more than this disagrees with the rest:
    #                                  the plane is refit without it (None: never)
    known_height_m: float | None = None   # joint: the camera height when known (a measured rig,
    #                                  the sequence's): a prior on log 1 / d, ``known_height_sd``
    #                                  apart, beside the tracks' height priors (None: free)
    known_height_sd: float = 0.04    # joint: that prior's sd in log units: the height's own
    #                                  error with the agents' mean height's (a population, shoes,
    #                                  a mask's top below the crown: a few %), in quadrature

    def __post_init__(self):
        if isinstance(self.classes, str) and self.classes != "auto":
            raise InputError(f"classes must be a tuple of class ids, None or 'auto', got "
                             f"{self.classes!r}")
        if self.model not in MODELS:
            raise InputError(f"unknown ground-plane model {self.model!r} (use {', '.join(MODELS)})")
        check_seed(self.seed, "plane.seed")
        check_ranges(self, "plane.", {
            "radius_m": ">=0", "head_radius_m": ">=0", "agent_height_m": ">0",
            "bootstrap": "0..10000",     # each resample is a plane fit (ground_plane's range)
            "inlier_px": ">0", "ransac_iters": ">=1", "f_scale_px": ">0", "max_roll_deg": ">0",
            "shape_prior_weight": ">=0", "height_prior_weight": ">=0", "relative_noise": ">=0",
            "max_class_misfit_deg": ">0|inf"})
        if max(self.radius_m, self.head_radius_m) >= self.agent_height_m:
            raise InputError(f"agent radius and head radius must be less than the agent height "
                             f"({self.agent_height_m} m), got {self.radius_m} and "
                             f"{self.head_radius_m}")
        if not isinstance(self.bootstrap, (int, np.integer)):
            raise InputError(f"plane.bootstrap must be a whole number >= 0 (0 = no uncertainty), "
                             f"got {self.bootstrap}")
        if self.max_roll_deg > 90:
            raise InputError(f"plane.max_roll_deg must be at most 90, got {self.max_roll_deg}")
        if not 0 < self.max_pitch_deg < 90:
            raise InputError(f"max_pitch_deg must be in (0, 90), got {self.max_pitch_deg}")
        if not (self.fit_column_weight >= 0 and math.isfinite(self.fit_column_weight)):
            raise InputError(f"column weight must be >= 0, got {self.column_weight}")
        if self.known_height_m is not None:
            check_camera_height(self.known_height_m, "plane.known_height_m")
        if not (math.isfinite(self.known_height_sd) and self.known_height_sd > 0):
            raise InputError(f"known_height_sd must be > 0, got {self.known_height_sd}")

    def with_known_height(self, height_m: float | None) -> "AgentPlaneConfig":
        """These settings with ``known_height_m = height_m`` where a height is given and none is
        set (a set one wins)."""
        if height_m is None or self.known_height_m is not None:
            return self
        return replace(self, known_height_m=height_m)

    @property
    def known_log(self) -> tuple[float, float] | None:
        """(log 1 / known camera height, its sd) for the joint fit's prior, or None."""
        if self.known_height_m is None:
            return None
        return -math.log(self.known_height_m), self.known_height_sd

    # "auto" settings are resolved when used, not stored resolved: a config built from another
    # (``--set plane.model=exact`` over the joint defaults) then gets the new model's defaults.
    @property
    def fit_classes(self) -> tuple[int, ...] | None:
        if isinstance(self.classes, str):  # "auto"
            return None if self.model == "joint" else PERSON_CLASSES
        return self.classes

    @property
    def fit_column_weight(self) -> float:
        if self.column_weight is None:
            return 1.0 if self.model == "joint" else 0.0
        return self.column_weight


PRESETS: dict[str, AgentPlaneConfig] = {
    "joint": AgentPlaneConfig(),
    "exact": AgentPlaneConfig(model="exact"),
    "exact-thin": AgentPlaneConfig(model="exact", radius_m=0.0, head_radius_m=0.0),
    "exact-columns": AgentPlaneConfig(model="exact", column_weight=1.0),
    "exact-all-classes": AgentPlaneConfig(model="exact", classes=None),
    "affine": AgentPlaneConfig(model="affine"),
    "paper": AgentPlaneConfig(model="paper"),
}


@dataclass(frozen=True, eq=False)
class AgentPlane:
    """The ground plane seen by the agents, in units of the camera height d.

    ``normal`` (3,) unit, camera frame, pointing to the ground; ``horizon`` (a, b, c) with
    ``a u + b v + c = 0`` (positive on the ground side); ``d_over_agent_height`` = d / H of a
    typical agent (1 / median s_j over the inlier tracks); ``track_ids`` (J,), ``track_scale``
    (J,) = s_j = H_j / d; ``inliers`` (J,) bool; ``normal_std_deg`` (the gate's; joint: the
    bootstrap, class misfit and Laplace std in quadrature, their parts in ``normal_std_parts``)
    and ``d_over_h_std`` (NaN when the bootstrap was not run); ``camera_height_m`` when a height
    prior or a height was given.
    """

    normal: np.ndarray
    horizon: np.ndarray
    d_over_agent_height: float
    track_ids: np.ndarray
    track_scale: np.ndarray
    inliers: np.ndarray
    rms_px: float
    model: str
    n_observations: int
    normal_std_deg: float = float("nan")
    d_over_h_std: float = float("nan")
    camera_height_m: float | None = None
    camera_height_source: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    camera_height_std_m: float = float("nan")
    normal_std_parts: Mapping[str, float] = field(default_factory=dict)   # UNCERTAINTY_PARTS

    @property
    def pitch_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[0]

    @property
    def roll_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[1]

    def with_camera_height(self, height_m: float, source: str,
                           std_m: float = float("nan")) -> "AgentPlane":
        height_m = check_camera_height(height_m, f"the camera height ({source})")
        return replace(self, camera_height_m=height_m, camera_height_source=source,
                       camera_height_std_m=float(std_m))

    def to_dict(self) -> dict[str, Any]:
        d = {"normal": self.normal.tolist(), "horizon": self.horizon.tolist(),
             "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg,
             "d_over_agent_height": self.d_over_agent_height, "model": self.model,
             "inliers": [int(t) for t in self.track_ids[self.inliers]],
             "tracks": {str(int(t)): float(s) for t, s in zip(self.track_ids, self.track_scale)},
             "rms_px": self.rms_px, "n_observations": self.n_observations,
             "uncertainty": {"normal_std_deg": _num(self.normal_std_deg),
                             "d_over_agent_height_std": _num(self.d_over_h_std),
                             "camera_height_std_m": _num(self.camera_height_std_m),
                             **{k: _num(v) for k, v in self.normal_std_parts.items()}}}
        if self.camera_height_m is not None:
            d["camera_height_m"] = self.camera_height_m
            d["camera_height_source"] = self.camera_height_source
        if "extents" in self.extra:
            d["extents"] = {k: list(v) for k, v in self.extra["extents"].items()}
        if "left_out" in self.extra:      # a class group that disagreed with the rest
            d["left_out"] = dict(self.extra["left_out"])
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "AgentPlane":
        try:
            n = np.asarray(d["normal"], dtype=np.float64)
            if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
                raise InputError("plane 'normal' must be a finite non-zero 3-vector", source)
            tracks = {int(k): float(v) for k, v in d.get("tracks", {}).items()}
            ids = np.array(sorted(tracks), dtype=np.int64)
            inl = set(int(t) for t in d.get("inliers", []))
            unc = d.get("uncertainty", {})
            h = d.get("camera_height_m")
            return cls(n / np.linalg.norm(n), np.asarray(d["horizon"], dtype=np.float64),
                       float(d.get("d_over_agent_height", float("nan"))), ids,
                       np.array([tracks[t] for t in ids]), np.array([t in inl for t in ids], bool),
                       float(d.get("rms_px", float("nan"))), str(d.get("model", "exact")),
                       int(d.get("n_observations", 0)),
                       float(unc.get("normal_std_deg") or float("nan")),
                       float(unc.get("d_over_agent_height_std") or float("nan")),
                       None if h is None else check_camera_height(h, "camera_height_m", source),
                       d.get("camera_height_source"),
                       {"extents": d["extents"]} if "extents" in d else {},
                       float(unc.get("camera_height_std_m") or float("nan")),
                       {k: float(unc[k]) for k in UNCERTAINTY_PARTS if unc.get(k) is not None})
        except KeyError as e:
            raise InputError(f"plane is missing the key {e.args[0]!r}", source) from None
        except (TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(f"plane is malformed: {e}", source) from None


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _prepare(K: np.ndarray, obs: np.ndarray, model: str = "exact",
             classes: tuple[int, ...] | None = None) -> AgentObservations:
    """Validate the observation table, keep the rows of ``classes`` (when the table has a
    ``class_id`` column) and turn it into rays and track indices."""
    for f in ("track", "foot_u", "foot_v", "height_px"):
        if obs.dtype.names is None or f not in obs.dtype.names:
            raise InputError(f"observations need a {f!r} column")
    if classes is not None and "class_id" in obs.dtype.names and len(obs):
        of_class = np.isin(np.asarray(obs["class_id"]), list(classes))
        if not of_class.any():
            raise InputError(f"no observation of the classes selected (class ids "
                             f"{', '.join(map(str, classes))}; the table has "
                             f"{', '.join(map(str, np.unique(obs['class_id'])))}): use "
                             "--classes all (classes=None) to fit every class")
        obs = obs[of_class]
    u, v, h = (np.asarray(obs[f], dtype=np.float64) for f in ("foot_u", "foot_v", "height_px"))
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(h) & (h > 0)
    obs, u, v, h = obs[ok], u[ok], v[ok], h[ok]
    if len(obs) < 3:
        raise InputError(f"the ground plane needs at least 3 usable observations (finite foot "
                         f"point, height_px > 0), got {len(obs)}")
    uv = np.stack([u, v], axis=1)
    sv = np.linalg.svd(uv - uv.mean(0), compute_uv=False)
    ids, idx = np.unique(np.asarray(obs["track"]), return_inverse=True)
    if sv[1] / math.sqrt(len(uv)) < 1.0:
        raise InputError(f"the agents' foot points are collinear ({len(obs)} observations of "
                         f"{len(ids)} track(s){' of the classes selected' if classes else ''}): "
                         "the ground plane is undetermined (need agents at positions off one "
                         "line: more tracks, or tracks that turn)")
    if model in ("exact", "joint") and len(obs) - len(ids) < 2:
        raise InputError(f"{len(obs)} observations of {len(ids)} track(s): the exact model needs "
                         "tracks seen in several frames (each track's first observation only "
                         "fixes its own height; at least 2 more are needed)")
    cls = np.full(len(ids), -1)
    if "class_id" in obs.dtype.names:
        cls[idx] = obs["class_id"]
    top_u = feet = None
    if "top_u" in obs.dtype.names:
        top_u = np.asarray(obs["top_u"], dtype=np.float64)
    if "feet" in obs.dtype.names:
        feet = np.asarray(obs["feet"], dtype=np.int64)
    sides = [np.asarray(obs[c], dtype=np.float64) if c in obs.dtype.names else None
             for c in ("left", "right")]
    return AgentObservations(rays_from_pixels(K, u, v), v - h, h, u, v, idx, ids, cls, top_u,
                             feet, *sides)


def fit_agent_plane(K: np.ndarray, observations: np.ndarray,
                    conf: AgentPlaneConfig = AgentPlaneConfig(), steps=None) -> AgentPlane:
    """Fit the ground plane to agents' observations (see module doc).

    K: (3, 3) intrinsics; observations: structured (N,) with ``track``, ``foot_u``, ``foot_v``
    (lowest silhouette point, continuous pixel coordinates), ``height_px`` (its row minus the
    highest silhouette point's row), optional ``top_u`` (column of the highest silhouette point,
    NaN = unknown) and ``class_id`` (only ``conf.classes`` are used).
    Raises InputError for a table without those columns, without rows of ``conf.classes``,
    fewer than 3 usable observations or tracks, collinear feet (all tracks together) or a
    (near-)nadir camera: the people's head-foot axes' vanishing point (where top columns are
    known) or, for ``joint`` and ``exact``, the fitted normal above ``conf.max_pitch_deg`` or a
    fit that puts over 5% of the inlier feet above its horizon.
    ``steps`` (optional) wraps the ``joint`` model's bootstrap resamples, e.g. in a progress bar
    (``staticdepth.progress.progress``); the math itself prints nothing.
    """
    K = np.asarray(K, dtype=np.float64)
    observations = np.asarray(observations)
    if conf.model == "joint" and conf.one_foot:
        observations = interpolate_one_foot(observations)
    obs = _prepare(K, observations, conf.model, conf.fit_classes)
    rng = np.random.default_rng(conf.seed)
    # people's lowest and highest points are near their axis (a vehicle's are corners)
    ppl = np.isin(obs.cls[obs.idx], PERSON_CLASSES)
    axes_n = vertical_from_axes(K, np.stack([obs.u, obs.v], 1)[ppl],
                                np.stack([obs.top_u, obs.top_v], 1)[ppl])
    if axes_n is not None:
        check_nadir(axes_n, conf, "the head-foot axes' vanishing point")
    if conf.model in LINEAR_MODELS:
        n, d_over_h = fit_linear(K, obs.u, obs.v, obs.h, conf.model)
        inl = np.ones(len(obs.ids), bool)
        s = np.full(len(obs.ids), 1.0 / d_over_h)
        res = K[1, 1] * (obs.rays @ n) / d_over_h - obs.h
    elif conf.model == "joint":
        n, s, inl, res, extents, boot = fit_joint(K, obs, conf, rng, steps)
        left_out = _disagreeing_group(boot, conf)
        if left_out is not None:
            return _without_group(K, observations, obs, conf, left_out, boot, steps)
        check_fitted_plane(n, conf, obs, inl)
        d_over_h = 1.0 / float(np.median(s[inl]))
        rms = float(np.sqrt(np.mean(res[inl[obs.idx]] ** 2)))
        return AgentPlane(n, horizon_line(K, n), d_over_h, obs.ids.copy(), s, inl, rms,
                          conf.model, len(obs.top_v), boot.get("normal_std_deg", float("nan")),
                          boot.get("d_over_h_std", float("nan")),
                          extra={"classes": obs.cls, "extents": extents,
                                 "column_weight": boot.get("column_weight", 0.0),
                                 "inlier_px": boot.get("inlier_px", conf.inlier_px),
                                 "class_misfit_deg": boot.get("class_misfit_deg", float("nan")),
                                 "relative_noise": boot.get("relative_noise", 0.0),
                                 "relative_noise_one_foot": boot.get("relative_noise_one_foot",
                                                                     0.0)},
                          normal_std_parts={k: boot[k] for k in UNCERTAINTY_PARTS if k in boot})
    else:
        n, s, inl, res = fit_robust(K, obs, conf, rng)
        d_over_h = 1.0 / float(np.median(s[inl]))
        check_fitted_plane(n, conf, obs, inl)
    if conf.model in LINEAR_MODELS and (math.hypot(n[0], n[1]) < 1e-6 or pitch_roll_from_normal(
            n)[0] >= conf.pitch_bounds_deg[1] - 0.5):
        raise InputError("the camera looks straight down (nadir): pixel heights cannot fix the "
                         "ground plane's tilt")
    rms = float(np.sqrt(np.mean(res[inl[obs.idx]] ** 2)))
    std_n, std_dh = (bootstrap_normal(K, obs, conf, n, inl, rng) if conf.bootstrap > 0
                      else (np.nan,) * 2)
    return AgentPlane(n, horizon_line(K, n), d_over_h, obs.ids.copy(), s, inl, rms, conf.model,
                      len(obs.top_v), std_n, std_dh, extra={"classes": obs.cls})


def _disagreeing_group(boot: dict, conf: AgentPlaneConfig) -> tuple[int, ...] | None:
    """The class groups (indices in ``GROUPS``) whose leaving-out moved the normal by more than
    ``conf.max_class_misfit_deg``, else None. Not against the bootstrap's spread: a few tracks of
    a disagreeing class inflate it too (demo scene: one bus among 10 tracks, bootstrap 3.5 deg,
    leaving the bus out 4.4 deg)."""
    misfit, g = boot.get("class_misfit_deg", 0.0), boot.get("class_misfit_group", ())
    if conf.max_class_misfit_deg is None or not g:
        return None
    return g if misfit > conf.max_class_misfit_deg else None


def _without_group(K, observations, obs, conf: AgentPlaneConfig, gs: tuple[int, ...],
                   boot: dict, steps=None):
    """The joint fit again without class groups ``gs`` (recorded in ``extra["left_out"]``)."""
    from staticdepth.geometry.agent_shape import GROUPS

    out = [c for g in gs for c in GROUPS[g].classes]
    keep = tuple(int(c) for c in np.unique(obs.cls) if c not in out)
    plane = fit_agent_plane(K, observations, replace(conf, classes=keep,
                                                     max_class_misfit_deg=None), steps)
    plane.extra["left_out"] = {"group": ", ".join(GROUPS[g].name for g in gs),
                               "misfit_deg": boot["class_misfit_deg"],
                               "bootstrap_std_deg": boot.get("bootstrap_std_deg")}
    return plane


def camera_height_from_prior(plane: AgentPlane, agent_height_m: float = 1.7) -> float:
    """Camera height d = H_prior / s_j, median over the inlier person tracks (all inlier tracks
    when no class is known). Raises when no such track exists."""
    if not (math.isfinite(agent_height_m) and agent_height_m > 0):
        raise InputError(f"agent height must be positive and finite (metres), got "
                         f"{agent_height_m}")
    cls = np.asarray(plane.extra.get("classes", np.full(len(plane.track_ids), -1)))
    use = plane.inliers & np.isin(cls, PERSON_CLASSES)
    if not use.any():
        raise InputError("no inlier person track to scale the camera height with")
    return float(np.median(agent_height_m / plane.track_scale[use]))
