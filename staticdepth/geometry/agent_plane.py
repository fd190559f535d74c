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
optional). The Eq. 1 solvers and the cylinder model's functions are re-exported here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from staticdepth.errors import InputError
from staticdepth.geometry.agent_cylinder import (_BIG, AgentObservations, extreme_rim,  # noqa: F401
                                                 head_pixels, head_residuals, head_rows,
                                                 observation_residual, solve_track_scales)
from staticdepth.geometry.agent_plane_joint import fit_joint
from staticdepth.geometry.agent_plane_linear import (LINEAR_MODELS, fit_linear,  # noqa: F401
                                                     plane_affine, plane_paper)
from staticdepth.geometry.camera import normal_from_pitch_roll, pitch_roll_from_normal
from staticdepth.geometry.plane import angle_between_deg, horizon_line
from staticdepth.geometry.projection import rays_from_pixels

MODELS = ("joint", "exact", "affine", "paper")
PERSON_CLASSES = (0, -1)  # COCO person, or unknown class (a CSV without classes)


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
    bootstrap: int = 20              # resamples over tracks (0 = no uncertainty)
    seed: int = 0
    shape_prior_weight: float = 1.0  # joint: pixels of residual per prior sd of an extent
    height_prior_weight: float = 1.0  # joint: pixels per sd of a track's height from its class

    def __post_init__(self):
        if isinstance(self.classes, str) and self.classes != "auto":
            raise InputError(f"classes must be a tuple of class ids, None or 'auto', got "
                             f"{self.classes!r}")
        if self.model not in MODELS:
            raise InputError(f"unknown ground-plane model {self.model!r} (use {', '.join(MODELS)})")
        if self.radius_m < 0 or self.head_radius_m < 0 or self.agent_height_m <= 0:
            raise InputError("agent radius and head radius must be >= 0 and agent height > 0")
        if not self.fit_column_weight >= 0:
            raise InputError(f"column weight must be >= 0, got {self.column_weight}")

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
    (J,) = s_j = H_j / d; ``inliers`` (J,) bool; ``normal_std_deg`` and ``d_over_h_std`` from the
    bootstrap (NaN when not run); ``camera_height_m`` when a height prior or a height was given.
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

    @property
    def pitch_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[0]

    @property
    def roll_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[1]

    def with_camera_height(self, height_m: float, source: str,
                           std_m: float = float("nan")) -> "AgentPlane":
        if not (math.isfinite(height_m) and height_m > 0):
            raise InputError(f"camera height must be positive, got {height_m}")
        return replace(self, camera_height_m=float(height_m), camera_height_source=source,
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
                             "camera_height_std_m": _num(self.camera_height_std_m)}}
        if self.camera_height_m is not None:
            d["camera_height_m"] = self.camera_height_m
            d["camera_height_source"] = self.camera_height_source
        if "extents" in self.extra:
            d["extents"] = {k: list(v) for k, v in self.extra["extents"].items()}
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
                       None if h is None else float(h), d.get("camera_height_source"),
                       {"extents": d["extents"]} if "extents" in d else {},
                       float(unc.get("camera_height_std_m") or float("nan")))
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
    if sv[1] / math.sqrt(len(uv)) < 1.0:
        raise InputError("the agents' foot points are collinear: the ground plane is undetermined"
                         " (need agents at positions off one line)")
    ids, idx = np.unique(np.asarray(obs["track"]), return_inverse=True)
    if model in ("exact", "joint") and len(obs) - len(ids) < 2:
        raise InputError(f"{len(obs)} observations of {len(ids)} track(s): the exact model needs "
                         "tracks seen in several frames (each track's first observation only "
                         "fixes its own height; at least 2 more are needed)")
    cls = np.full(len(ids), -1)
    if "class_id" in obs.dtype.names:
        cls[idx] = obs["class_id"]
    top_u = None
    if "top_u" in obs.dtype.names:
        top_u = np.asarray(obs["top_u"], dtype=np.float64)
    return AgentObservations(rays_from_pixels(K, u, v), v - h, h, u, v, idx, ids, cls, top_u)


# -- the exact cylinder model: fit, RANSAC, refinement, bootstrap ----------------------------
_Obs = AgentObservations      # the former private name


def _ratio(conf: AgentPlaneConfig) -> tuple[float, float]:
    """(foot, head) disk radius over the agent height."""
    return conf.radius_m / conf.agent_height_m, conf.head_radius_m / conf.agent_height_m


def _normal(pitch_rad: float, roll_rad: float) -> np.ndarray:
    return normal_from_pitch_roll(math.degrees(pitch_rad), math.degrees(roll_rad))


def _residuals(K, obs: AgentObservations, pitch, roll, s, ratio, col_w: float) -> np.ndarray:
    """Row residuals (N,), then weighted column residuals of the observations with a known top
    column; impossible predictions count as ``_BIG`` pixels."""
    r_v, r_u = head_residuals(K, obs, _normal(pitch, roll), s, ratio)
    r = np.nan_to_num(r_v, nan=_BIG)
    if col_w > 0:
        r = np.concatenate([r, col_w * np.nan_to_num(r_u[obs.has_u], nan=_BIG)])
    return r


def _fit_exact(K, obs: AgentObservations, conf: AgentPlaneConfig,
               starts: list[tuple[float, float]], loss: str = "linear",
               max_nfev: int = 200) -> tuple[float, float, np.ndarray, float]:
    """Best of several starts (pitch, roll in degrees): returns pitch, roll (rad), s, cost.

    Unknowns: pitch and roll (bounded, so every foot ray keeps n . r > 0 near the solution) and
    the per-track s_j, solved jointly with a sparse Jacobian."""
    ratio = _ratio(conf)
    J, N = len(obs.ids), len(obs.top_v)
    col = np.flatnonzero(obs.has_u) if conf.fit_column_weight > 0 else np.zeros(0, int)
    res_obs = np.r_[np.arange(N), col]                        # observation of each residual
    R = len(res_obs)
    rows = np.repeat(np.arange(R), 3)
    cols = np.stack([np.zeros(R, int), np.ones(R, int), 2 + obs.idx[res_obs]], axis=1).ravel()
    sparsity = csr_matrix((np.ones(3 * R), (rows, cols)), shape=(R, J + 2))
    lo_p, hi_p = (math.radians(b) for b in conf.pitch_bounds_deg)
    mr = math.radians(conf.max_roll_deg)
    lower = np.r_[lo_p, -mr, np.full(J, 1e-4)]
    upper = np.r_[hi_p, mr, np.full(J, 100.0)]
    best = None
    for p0, r0 in starts:
        p0 = float(np.clip(math.radians(p0), lo_p + 1e-3, hi_p - 1e-3))
        r0 = float(np.clip(math.radians(r0), -mr + 1e-3, mr - 1e-3))
        s0 = np.clip(solve_track_scales(K, obs, _normal(p0, r0), ratio), 2e-4, 99.0)
        res = least_squares(
            lambda x: _residuals(K, obs, x[0], x[1], x[2:], ratio, conf.fit_column_weight),
            np.r_[p0, r0, s0], bounds=(lower, upper), loss=loss, f_scale=conf.f_scale_px,
            jac_sparsity=sparsity, x_scale="jac", max_nfev=max_nfev)
        if best is None or res.cost < best[3]:
            best = (float(res.x[0]), float(res.x[1]), res.x[2:].copy(), float(res.cost))
    return best


def _observation_error(K, obs: AgentObservations, n, s, conf: AgentPlaneConfig) -> np.ndarray:
    """(N,) the larger of |row| and |column| residual per observation (columns when used)."""
    r_v, r_u = head_residuals(K, obs, n, s, _ratio(conf))
    if conf.fit_column_weight <= 0:
        r_u = np.full_like(r_u, np.nan)
    return observation_residual(r_v, r_u)


def _inlier_tracks(obs: AgentObservations, good: np.ndarray) -> np.ndarray:
    """(J,) bool: tracks with at least half of their observations good."""
    J = len(obs.ids)
    return np.bincount(obs.idx, good, minlength=J) / np.bincount(obs.idx, minlength=J) >= 0.5


def _ransac(K, obs: AgentObservations, conf: AgentPlaneConfig,
            rng) -> tuple[np.ndarray, np.ndarray]:
    """Hypotheses from 3 tracks; returns (best normal, inlier track mask)."""
    J = len(obs.ids)
    ratio = _ratio(conf)
    best_n, best_inl, best_key = None, None, None
    need, it = conf.ransac_iters, 0
    while it < min(need, conf.ransac_iters):
        it += 1
        sample = rng.choice(J, 3, replace=False)
        sub = obs.subset(sample)
        try:
            p0, r0 = pitch_roll_from_normal(plane_affine(K, sub.u, sub.v, sub.h)[0])
        except InputError:
            p0, r0 = 30.0, 0.0
        pitch, roll, _, _ = _fit_exact(K, sub, conf, [(p0, r0)], max_nfev=40)
        n = _normal(pitch, roll)
        s = solve_track_scales(K, obs, n, ratio, iters=8, huber_px=conf.inlier_px)
        res = _observation_error(K, obs, n, s, conf)
        good = res < conf.inlier_px
        inl = _inlier_tracks(obs, good)
        key = (int(good[inl[obs.idx]].sum()), -float(np.sum(np.minimum(res, conf.inlier_px))))
        if best_key is None or key > best_key:
            best_n, best_inl, best_key = n, inl, key
            w = max(inl.mean(), 1e-3)
            need = math.ceil(math.log(0.01) / math.log(max(1.0 - w ** 3, 1e-12)))
            need = max(need, 8)
    return best_n, best_inl


def fit_agent_plane(K: np.ndarray, observations: np.ndarray,
                    conf: AgentPlaneConfig = AgentPlaneConfig()) -> AgentPlane:
    """Fit the ground plane to agents' observations (see module doc).

    K: (3, 3) intrinsics; observations: structured (N,) with ``track``, ``foot_u``, ``foot_v``
    (lowest silhouette point, continuous pixel coordinates), ``height_px`` (its row minus the
    highest silhouette point's row), optional ``top_u`` (column of the highest silhouette point,
    NaN = unknown) and ``class_id`` (only ``conf.classes`` are used).
    Raises InputError for a table without those columns, without rows of ``conf.classes``,
    fewer than 3 usable observations or tracks, collinear feet (all tracks together) or a nadir
    camera.
    """
    K = np.asarray(K, dtype=np.float64)
    obs = _prepare(K, np.asarray(observations), conf.model, conf.fit_classes)
    rng = np.random.default_rng(conf.seed)
    if conf.model in LINEAR_MODELS:
        n, d_over_h = fit_linear(K, obs.u, obs.v, obs.h, conf.model)
        inl = np.ones(len(obs.ids), bool)
        s = np.full(len(obs.ids), 1.0 / d_over_h)
        res = K[1, 1] * (obs.rays @ n) / d_over_h - obs.h
    elif conf.model == "joint":
        n, s, inl, res, extents, boot = fit_joint(K, obs, conf, rng)
        _check_nadir(n, conf)
        d_over_h = 1.0 / float(np.median(s[inl]))
        rms = float(np.sqrt(np.mean(res[inl[obs.idx]] ** 2)))
        return AgentPlane(n, horizon_line(K, n), d_over_h, obs.ids.copy(), s, inl, rms,
                          conf.model, len(obs.top_v), boot.get("normal_std_deg", float("nan")),
                          boot.get("d_over_h_std", float("nan")),
                          extra={"classes": obs.cls, "extents": extents,
                                 "column_weight": boot.get("column_weight", 0.0),
                                 "inlier_px": boot.get("inlier_px", conf.inlier_px)})
    else:
        n, s, inl, res = _fit_robust(K, obs, conf, rng)
        d_over_h = 1.0 / float(np.median(s[inl]))
    _check_nadir(n, conf)
    rms = float(np.sqrt(np.mean(res[inl[obs.idx]] ** 2)))
    std_n, std_dh = _bootstrap(K, obs, conf, n, inl, rng) if conf.bootstrap > 0 else (np.nan,) * 2
    return AgentPlane(n, horizon_line(K, n), d_over_h, obs.ids.copy(), s, inl, rms, conf.model,
                      len(obs.top_v), std_n, std_dh, extra={"classes": obs.cls})


def _fit_robust(K, obs: AgentObservations, conf: AgentPlaneConfig, rng):
    """RANSAC over tracks, a robust (``conf.loss``) fit on the inlier tracks from several starts,
    then least squares on their observations within ``inlier_px``; s_j of every track last."""
    ratio = _ratio(conf)
    J = len(obs.ids)
    if J >= 4:
        n_h, inl = _ransac(K, obs, conf, rng)
        if inl.sum() < 3:
            inl = np.ones(J, bool)
    else:
        n_h, inl = None, np.ones(J, bool)
    sub = obs.subset(np.flatnonzero(inl))
    starts = [(p, 0.0) for p in conf.pitch_starts_deg]
    try:
        starts.insert(0, pitch_roll_from_normal(plane_affine(K, sub.u, sub.v, sub.h)[0]))
    except InputError:
        pass
    if n_h is not None:
        starts.insert(0, pitch_roll_from_normal(n_h))
    pitch, roll, s, _ = _fit_exact(K, sub, conf, starts, loss=conf.loss)
    # least squares on the inlier observations: a soft-L1 loss alone keeps a bias from one-sided
    # outliers (shrunk heights)
    keep = _observation_error(K, sub, _normal(pitch, roll), s, conf) < conf.inlier_px
    if keep.sum() >= 3:
        p_deg, r_deg = math.degrees(pitch), math.degrees(roll)
        pitch, roll, _, _ = _fit_exact(K, sub.select(keep), conf, [(p_deg, r_deg)])
    n = _normal(pitch, roll)
    s = solve_track_scales(K, obs, n, ratio, iters=8, huber_px=conf.inlier_px)
    res = head_rows(K, n, obs.rays, s[obs.idx], ratio) - obs.top_v
    inl = _inlier_tracks(obs, _observation_error(K, obs, n, s, conf) < conf.inlier_px)
    if inl.sum() == 0:
        inl = np.ones(J, bool)
    return n, s, inl, np.nan_to_num(res, nan=_BIG)


def _check_nadir(n: np.ndarray, conf: AgentPlaneConfig) -> None:
    near_bound = pitch_roll_from_normal(n)[0] >= conf.pitch_bounds_deg[1] - 0.5
    if near_bound or math.hypot(n[0], n[1]) < 1e-6:
        raise InputError("the camera looks straight down (nadir): pixel heights cannot fix the "
                         "ground plane's tilt")


def _bootstrap(K, obs: AgentObservations, conf: AgentPlaneConfig, n: np.ndarray,
               inl: np.ndarray, rng):
    """Std of the normal angle (deg) and of d/H over resamples of the inlier tracks."""
    tracks = np.flatnonzero(inl)
    if len(tracks) < 3:
        return float("nan"), float("nan")
    p0, r0 = pitch_roll_from_normal(n)
    angles, dh = [], []
    for _ in range(conf.bootstrap):
        sub = obs.subset(rng.choice(tracks, len(tracks), replace=True))
        if conf.model == "exact":
            pitch, roll, s, _ = _fit_exact(K, sub, conf, [(p0, r0)], loss=conf.loss)
            nb, dhb = _normal(pitch, roll), 1.0 / float(np.median(s))
        else:
            try:
                nb, dhb = fit_linear(K, sub.u, sub.v, sub.h, conf.model)
            except InputError:
                continue
        angles.append(angle_between_deg(nb, n))
        dh.append(dhb)
    if len(angles) < 2:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(np.square(angles)))), float(np.std(dh, ddof=1))


def camera_height_from_prior(plane: AgentPlane, agent_height_m: float = 1.7) -> float:
    """Camera height d = H_prior / s_j, median over the inlier person tracks (all inlier tracks
    when no class is known). Raises when no such track exists."""
    if not agent_height_m > 0:
        raise InputError(f"agent height must be positive, got {agent_height_m}")
    cls = np.asarray(plane.extra.get("classes", np.full(len(plane.track_ids), -1)))
    use = plane.inliers & np.isin(cls, PERSON_CLASSES)
    if not use.any():
        raise InputError("no inlier person track to scale the camera height with")
    return float(np.median(agent_height_m / plane.track_scale[use]))
