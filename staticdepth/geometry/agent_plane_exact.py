"""The fixed-shape exact model of :mod:`staticdepth.geometry.agent_plane` (``model="exact"``):
fit, RANSAC over tracks, robust refinement and the bootstrap over tracks (shared with the Eq. 1
models).

Each agent is an upright cylinder (:mod:`staticdepth.geometry.agent_cylinder`) with a foot disk of
``conf.radius_m`` and a head disk of ``conf.head_radius_m`` relative to ``conf.agent_height_m``;
unknowns are the normal (pitch, roll) and per track ``s_j = H_j / d``; residuals are the top
point's row and, with ``conf.column_weight`` > 0, its column, in pixels. ``conf`` is an
:class:`~staticdepth.geometry.agent_plane.AgentPlaneConfig`.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from staticdepth.errors import InputError
from staticdepth.geometry.agent_cylinder import (_BIG, AgentObservations, head_residuals,
                                                 head_rows, observation_residual,
                                                 solve_track_scales)
from staticdepth.geometry.agent_plane_linear import fit_linear, plane_affine
from staticdepth.geometry.camera import normal_from_pitch_roll, pitch_roll_from_normal
from staticdepth.geometry.plane import angle_between_deg


def _ratio(conf) -> tuple[float, float]:
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


def _fit_exact(K, obs: AgentObservations, conf,
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


def _observation_error(K, obs: AgentObservations, n, s, conf) -> np.ndarray:
    """(N,) the larger of |row| and |column| residual per observation (columns when used)."""
    r_v, r_u = head_residuals(K, obs, n, s, _ratio(conf))
    if conf.fit_column_weight <= 0:
        r_u = np.full_like(r_u, np.nan)
    return observation_residual(r_v, r_u)


def _inlier_tracks(obs: AgentObservations, good: np.ndarray) -> np.ndarray:
    """(J,) bool: tracks with at least half of their observations good."""
    J = len(obs.ids)
    return np.bincount(obs.idx, good, minlength=J) / np.bincount(obs.idx, minlength=J) >= 0.5


def _ransac(K, obs: AgentObservations, conf,
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


def fit_robust(K, obs: AgentObservations, conf, rng):
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



def bootstrap_normal(K, obs: AgentObservations, conf, n: np.ndarray,
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
