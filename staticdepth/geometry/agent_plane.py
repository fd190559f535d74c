"""The ground plane from moving agents' foot points and pixel heights (METHOD.md section 2).

Three models, selectable by name:
- ``paper``: the paper's Eq. 1 least squares ``[x_i, y_i, -h_i] . [a, b, k] = -f`` (c = 1);
- ``affine``: the equivalent, better-conditioned regression ``h = alpha x + beta y + gamma``;
- ``exact`` (default): the exact projective model. Unknowns are the unit normal (pitch, roll) and
  per track ``s_j = H_j / d``; each agent is an upright cylinder whose radius is ``radius_m /
  agent_height_m`` of its height, so the observed bottom row is the lowest point of the foot disk
  and the top row the highest point of the head disk. Residuals are head-row reprojection errors
  in pixels; RANSAC over tracks, then a robust (soft-L1) refinement on the inliers and a bootstrap
  over tracks for the uncertainty.

Everything is in the camera frame (OpenCV), in units of the camera height d (plane ``n . P = 1``).
Observations are the table of :data:`staticdepth.tracking.OBS_DTYPE` (or any structured array
with ``track``, ``foot_u``, ``foot_v``, ``height_px`` fields, ``class_id`` optional).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from staticdepth.errors import InputError
from staticdepth.geometry.camera import normal_from_pitch_roll, pitch_roll_from_normal
from staticdepth.geometry.plane import angle_between_deg, horizon_line
from staticdepth.geometry.projection import rays_from_pixels

MODELS = ("exact", "affine", "paper")
PERSON_CLASSES = (0, -1)  # COCO person, or unknown class (a CSV without classes)


@dataclass(frozen=True)
class AgentPlaneConfig:
    """How to fit the ground plane from agents; see :data:`PRESETS`."""

    model: str = "exact"
    radius_m: float = 0.2            # body radius of the cylinder model (0 = thin axis)
    agent_height_m: float = 1.7      # only sets the radius/height ratio of the cylinder model
    inlier_px: float = 3.0           # RANSAC: observation inlier threshold on the head row
    ransac_iters: int = 60           # upper bound; stops early at 99% confidence
    loss: str = "soft_l1"            # robust refinement loss (scipy least_squares)
    f_scale_px: float = 1.5
    pitch_starts_deg: tuple[float, ...] = (10.0, 25.0, 40.0, 60.0)
    pitch_bounds_deg: tuple[float, float] = (0.0, 89.0)
    max_roll_deg: float = 30.0
    bootstrap: int = 20              # resamples over tracks (0 = no uncertainty)
    seed: int = 0

    def __post_init__(self):
        if self.model not in MODELS:
            raise InputError(f"unknown ground-plane model {self.model!r} (use {', '.join(MODELS)})")
        if self.radius_m < 0 or self.agent_height_m <= 0:
            raise InputError("agent radius must be >= 0 and agent height > 0")


PRESETS: dict[str, AgentPlaneConfig] = {
    "exact": AgentPlaneConfig(),
    "exact-thin": AgentPlaneConfig(radius_m=0.0),
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

    @property
    def pitch_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[0]

    @property
    def roll_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[1]

    def with_camera_height(self, height_m: float, source: str) -> "AgentPlane":
        if not (math.isfinite(height_m) and height_m > 0):
            raise InputError(f"camera height must be positive, got {height_m}")
        return replace(self, camera_height_m=float(height_m), camera_height_source=source)

    def to_dict(self) -> dict[str, Any]:
        d = {"normal": self.normal.tolist(), "horizon": self.horizon.tolist(),
             "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg,
             "d_over_agent_height": self.d_over_agent_height, "model": self.model,
             "inliers": [int(t) for t in self.track_ids[self.inliers]],
             "tracks": {str(int(t)): float(s) for t, s in zip(self.track_ids, self.track_scale)},
             "rms_px": self.rms_px, "n_observations": self.n_observations,
             "uncertainty": {"normal_std_deg": _num(self.normal_std_deg),
                             "d_over_agent_height_std": _num(self.d_over_h_std)}}
        if self.camera_height_m is not None:
            d["camera_height_m"] = self.camera_height_m
            d["camera_height_source"] = self.camera_height_source
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
                       None if h is None else float(h), d.get("camera_height_source"))
        except KeyError as e:
            raise InputError(f"plane is missing the key {e.args[0]!r}", source) from None
        except (TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(f"plane is malformed: {e}", source) from None


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


# -- Eq. 1: the paper's least squares and the affine regression -------------------------------
def _centered(K: np.ndarray, u, v) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets from the principal point in row pixels: x = (u - cx) fy/fx, y = v - cy."""
    r = rays_from_pixels(K, u, v)
    return r[:, 0] * K[1, 1], r[:, 1] * K[1, 1]


def plane_paper(K: np.ndarray, u, v, h) -> tuple[np.ndarray, float]:
    """The paper's Eq. 1 with c = 1: solve ``[x, y, -h] . [a, b, k] = -f``; returns (n, d/H).

    u, v, h: (N,) foot pixels and pixel heights. n = (a, b, 1)/|.|, d/H = k / |(a, b, 1)|.
    """
    x, y = _centered(K, u, v)
    A = np.stack([x, y, -np.asarray(h, dtype=np.float64)], axis=1)
    sol, *_ = np.linalg.lstsq(A, -np.full(len(x), K[1, 1]), rcond=None)
    a, b, k = sol
    s = math.sqrt(a * a + b * b + 1.0)
    return np.array([a, b, 1.0]) / s, float(k / s)


def plane_affine(K: np.ndarray, u, v, h) -> tuple[np.ndarray, float]:
    """Regression ``h = alpha x + beta y + gamma``; n ∝ (alpha fx/fy, beta, gamma/fy) (in row
    pixels x is already scaled by fy/fx, so n ∝ (alpha, beta, gamma/fy)); returns (n, d/H)."""
    x, y = _centered(K, u, v)
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    (al, be, ga), *_ = np.linalg.lstsq(A, np.asarray(h, dtype=np.float64), rcond=None)
    m = np.array([al, be, ga / K[1, 1]])
    s = float(np.linalg.norm(m))
    if s < 1e-12:
        raise InputError("pixel heights do not vary with position: no ground plane")
    return m / s, 1.0 / s


# -- the exact projective model --------------------------------------------------------------
def _extreme_rim(C: np.ndarray, n: np.ndarray, rho: np.ndarray, lowest: bool) -> np.ndarray:
    """Point of each horizontal circle (centre C (N,3), radius rho (N,), axis n) with the largest
    (``lowest``) or smallest image row, i.e. extreme Y/Z; closed form of d(Y/Z)/dphi = 0."""
    ex = np.array([1.0, 0.0, 0.0])
    e1 = ex - n[0] * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    p, q = np.array([e1[1], e2[1]]), np.array([e1[2], e2[2]])
    g = C[:, 2:3] * p - C[:, 1:2] * q                         # (N, 2)
    k = p[1] * q[0] - p[0] * q[1]
    R = np.maximum(np.hypot(g[:, 0], g[:, 1]), 1e-300)
    alpha = np.arctan2(g[:, 0], g[:, 1])
    acos = np.arccos(np.clip(-rho * k / R, -1.0, 1.0))
    best = None
    for sign in (1.0, -1.0):
        phi = sign * acos - alpha
        P = C + rho[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        if best is None:
            best = P
        else:
            ratio_new, ratio_old = P[:, 1] / P[:, 2], best[:, 1] / best[:, 2]
            take = ratio_new > ratio_old if lowest else ratio_new < ratio_old
            best = np.where(take[:, None], P, best)
    return best


def head_rows(K: np.ndarray, n: np.ndarray, rays: np.ndarray, s: np.ndarray,
              radius_ratio: float) -> np.ndarray:
    """Predicted top rows (N,) of upright cylinders whose lowest image point is on ``rays`` (N,3).

    n: unit ground normal; s: (N,) agent height over camera height; radius = radius_ratio * s.
    NaN where a foot ray does not meet the ground (n . r <= 0).
    """
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        F = rays / nr[:, None]
    rho = radius_ratio * s
    A = F.copy()
    if radius_ratio > 0:
        for _ in range(3):                      # axis foot A such that the lowest rim point is F
            A = A + (F - _extreme_rim(A, n, rho, lowest=True))
    T = _extreme_rim(A - s[:, None] * n, n, rho, lowest=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = K[1, 1] * T[:, 1] / T[:, 2] + K[1, 2]
    v[~(nr > 1e-9) | ~(T[:, 2] > 1e-9)] = np.nan
    return v


@dataclass(frozen=True)
class _Obs:
    """Observations prepared for the fit: rays, observed top rows, track index 0..J-1."""

    rays: np.ndarray
    top_v: np.ndarray
    h: np.ndarray
    u: np.ndarray
    v: np.ndarray
    idx: np.ndarray
    ids: np.ndarray
    cls: np.ndarray

    def subset(self, tracks: np.ndarray) -> "_Obs":
        """Observations of the given track indices (duplicates become separate tracks)."""
        parts = [np.flatnonzero(self.idx == t) for t in tracks]
        sel = np.concatenate(parts)
        new_idx = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
        return _Obs(self.rays[sel], self.top_v[sel], self.h[sel], self.u[sel], self.v[sel],
                    new_idx, self.ids[tracks], self.cls[tracks])

    def select(self, keep: np.ndarray) -> "_Obs":
        """The observations where ``keep`` (N,) is true; tracks left without any are dropped."""
        tracks, idx = np.unique(self.idx[keep], return_inverse=True)
        return _Obs(self.rays[keep], self.top_v[keep], self.h[keep], self.u[keep], self.v[keep],
                    idx, self.ids[tracks], self.cls[tracks])


def _residuals(K, obs: _Obs, pitch, roll, s, ratio) -> np.ndarray:
    n = normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))
    r = head_rows(K, n, obs.rays, s[obs.idx], ratio) - obs.top_v
    return np.where(np.isfinite(r), r, 1e3)


def solve_track_scales(K, obs: _Obs, n: np.ndarray, ratio: float, s0: np.ndarray | None = None,
                       iters: int = 6, huber_px: float = 3.0) -> np.ndarray:
    """Per-track s_j with the normal fixed: Gauss-Newton on each track's head-row residuals, the
    later half of the iterations Huber-reweighted (``huber_px``) against bad detections."""
    J = len(obs.ids)
    nr = obs.rays @ n
    if s0 is None:                              # thin, untilted start: h = fy s (n . r)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_obs = obs.h / (K[1, 1] * nr)
        s = np.array([np.nanmedian(s_obs[obs.idx == j]) if np.any(obs.idx == j) else 0.3
                      for j in range(J)])
        s = np.where(np.isfinite(s) & (s > 0), s, 0.3)
    else:
        s = s0.copy()
    for it in range(iters):
        r0 = head_rows(K, n, obs.rays, s[obs.idx], ratio) - obs.top_v
        eps = 1e-4 * np.maximum(s, 1e-3)
        r1 = head_rows(K, n, obs.rays, (s + eps)[obs.idx], ratio) - obs.top_v
        jac = (r1 - r0) / eps[obs.idx]
        ok = np.isfinite(r0) & np.isfinite(jac)
        wt = np.ones_like(r0)
        if it >= iters // 2:
            wt = np.minimum(1.0, huber_px / np.maximum(np.abs(np.nan_to_num(r0)), 1e-12))
        num = np.bincount(obs.idx[ok], (wt * r0 * jac)[ok], minlength=J)
        den = np.bincount(obs.idx[ok], (wt * jac * jac)[ok], minlength=J)
        step = np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)
        s = np.clip(s - step, 1e-4, 100.0)
    return s


def _fit_exact(K, obs: _Obs, conf: AgentPlaneConfig, starts: list[tuple[float, float]],
               loss: str = "linear", max_nfev: int = 200) -> tuple[float, float, np.ndarray, float]:
    """Best of several starts (pitch, roll in degrees): returns pitch, roll (rad), s, cost."""
    ratio = conf.radius_m / conf.agent_height_m
    J, N = len(obs.ids), len(obs.top_v)
    rows = np.repeat(np.arange(N), 3)
    cols = np.stack([np.zeros(N, int), np.ones(N, int), 2 + obs.idx], axis=1).ravel()
    sparsity = csr_matrix((np.ones(3 * N), (rows, cols)), shape=(N, J + 2))
    lo_p, hi_p = (math.radians(b) for b in conf.pitch_bounds_deg)
    mr = math.radians(conf.max_roll_deg)
    lower = np.r_[lo_p, -mr, np.full(J, 1e-4)]
    upper = np.r_[hi_p, mr, np.full(J, 100.0)]
    best = None
    for p0, r0 in starts:
        p0 = float(np.clip(math.radians(p0), lo_p + 1e-3, hi_p - 1e-3))
        r0 = float(np.clip(math.radians(r0), -mr + 1e-3, mr - 1e-3))
        n0 = normal_from_pitch_roll(math.degrees(p0), math.degrees(r0))
        s0 = np.clip(solve_track_scales(K, obs, n0, ratio), 2e-4, 99.0)
        res = least_squares(lambda x: _residuals(K, obs, x[0], x[1], x[2:], ratio),
                            np.r_[p0, r0, s0], bounds=(lower, upper), loss=loss,
                            f_scale=conf.f_scale_px, jac_sparsity=sparsity, x_scale="jac",
                            max_nfev=max_nfev)
        if best is None or res.cost < best[3]:
            best = (float(res.x[0]), float(res.x[1]), res.x[2:].copy(), float(res.cost))
    return best


def _prepare(K: np.ndarray, obs: np.ndarray) -> _Obs:
    for f in ("track", "foot_u", "foot_v", "height_px"):
        if obs.dtype.names is None or f not in obs.dtype.names:
            raise InputError(f"observations need a {f!r} column")
    u, v, h = (np.asarray(obs[f], dtype=np.float64) for f in ("foot_u", "foot_v", "height_px"))
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(h) & (h > 0)
    obs = obs[ok]
    if len(obs) < 3:
        raise InputError(f"the ground plane needs at least 3 usable observations, got {len(obs)}")
    uv = np.stack([obs["foot_u"], obs["foot_v"]], axis=1).astype(np.float64)
    sv = np.linalg.svd(uv - uv.mean(0), compute_uv=False)
    if sv[1] / math.sqrt(len(uv)) < 1.0:
        raise InputError("the agents' foot points are collinear: the ground plane is undetermined"
                         " (need agents at positions off one line)")
    ids, idx = np.unique(np.asarray(obs["track"]), return_inverse=True)
    cls = np.full(len(ids), -1)
    if "class_id" in obs.dtype.names:
        cls[idx] = obs["class_id"]
    u, v, h = uv[:, 0], uv[:, 1], np.asarray(obs["height_px"], dtype=np.float64)
    return _Obs(rays_from_pixels(K, u, v), v - h, h, u, v, idx, ids, cls)


def _ransac(K, obs: _Obs, conf: AgentPlaneConfig, rng) -> tuple[np.ndarray, np.ndarray]:
    """Hypotheses from 3 tracks; returns (best normal, inlier track mask)."""
    J = len(obs.ids)
    ratio = conf.radius_m / conf.agent_height_m
    best_n, best_inl, best_key = None, None, None
    need, it = conf.ransac_iters, 0
    while it < min(need, conf.ransac_iters):
        it += 1
        sample = rng.choice(J, 3, replace=False)
        sub = obs.subset(sample)
        try:
            n0, _ = plane_affine(K, sub.u, sub.v, sub.h)
            p0, r0 = pitch_roll_from_normal(n0)
        except InputError:
            p0, r0 = 30.0, 0.0
        pitch, roll, _, _ = _fit_exact(K, sub, conf, [(p0, r0)], max_nfev=40)
        n = normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))
        s = solve_track_scales(K, obs, n, ratio, iters=8, huber_px=conf.inlier_px)
        res = np.abs(head_rows(K, n, obs.rays, s[obs.idx], ratio) - obs.top_v)
        good = np.nan_to_num(res, nan=np.inf) < conf.inlier_px
        frac = np.bincount(obs.idx, good, minlength=J) / np.bincount(obs.idx, minlength=J)
        inl = frac >= 0.5
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
    (lowest silhouette point, px), ``height_px`` (foot row - top row), optional ``class_id``.
    Raises InputError for fewer than 3 usable observations, collinear feet or a nadir camera.
    """
    K = np.asarray(K, dtype=np.float64)
    obs = _prepare(K, np.asarray(observations))
    rng = np.random.default_rng(conf.seed)
    if conf.model in ("paper", "affine"):
        n, d_over_h = _fit_linear(K, obs, conf.model)
        inl = np.ones(len(obs.ids), bool)
        s = np.full(len(obs.ids), 1.0 / d_over_h)
        res = K[1, 1] * (obs.rays @ n) / d_over_h - obs.h
    else:
        n, s, inl, res = _fit_robust(K, obs, conf, rng)
        d_over_h = 1.0 / float(np.median(s[inl]))
    _check_nadir(n, conf)
    rms = float(np.sqrt(np.mean(res[inl[obs.idx]] ** 2)))
    std_n, std_dh = _bootstrap(K, obs, conf, n, inl, rng) if conf.bootstrap > 0 else (np.nan,) * 2
    return AgentPlane(n, horizon_line(K, n), d_over_h, obs.ids.copy(), s, inl, rms, conf.model,
                      len(obs.top_v), std_n, std_dh, extra={"classes": obs.cls})


def _fit_linear(K, obs: _Obs, model: str) -> tuple[np.ndarray, float]:
    fit = plane_paper if model == "paper" else plane_affine
    n, d_over_h = fit(K, obs.u, obs.v, obs.h)
    if d_over_h < 0:
        n, d_over_h = -n, -d_over_h
    if d_over_h == 0 or not np.isfinite(d_over_h):
        raise InputError("pixel heights do not vary with position: no ground plane")
    return n, d_over_h


def _fit_robust(K, obs: _Obs, conf: AgentPlaneConfig, rng):
    ratio = conf.radius_m / conf.agent_height_m
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
    n = normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))
    res = np.abs(head_rows(K, n, sub.rays, s[sub.idx], ratio) - sub.top_v)
    keep = np.nan_to_num(res, nan=np.inf) < conf.inlier_px
    if keep.sum() >= 3:
        p_deg, r_deg = math.degrees(pitch), math.degrees(roll)
        pitch, roll, _, _ = _fit_exact(K, sub.select(keep), conf, [(p_deg, r_deg)])
        n = normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))
    s = solve_track_scales(K, obs, n, ratio, iters=8, huber_px=conf.inlier_px)
    res = head_rows(K, n, obs.rays, s[obs.idx], ratio) - obs.top_v
    good = np.abs(np.nan_to_num(res, nan=np.inf)) < conf.inlier_px
    inl = np.bincount(obs.idx, good, minlength=J) / np.bincount(obs.idx, minlength=J) >= 0.5
    if inl.sum() == 0:
        inl = np.ones(J, bool)
    return n, s, inl, np.nan_to_num(res, nan=1e3)


def _check_nadir(n: np.ndarray, conf: AgentPlaneConfig) -> None:
    if pitch_roll_from_normal(n)[0] >= conf.pitch_bounds_deg[1] - 0.5 or math.hypot(n[0], n[1]) < 1e-6:
        raise InputError("the camera looks straight down (nadir): pixel heights cannot fix the "
                         "ground plane's tilt")


def _bootstrap(K, obs: _Obs, conf: AgentPlaneConfig, n: np.ndarray, inl: np.ndarray, rng):
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
            nb = normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))
            dhb = 1.0 / float(np.median(s))
        else:
            try:
                nb, dhb = _fit_linear(K, sub, conf.model)
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
