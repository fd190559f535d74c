"""The ``joint`` ground-plane model's robust fit: plane, per-track heights and per-class extent
fitted together (the unknowns and residuals: :mod:`staticdepth.geometry.agent_plane_problem`).

Robust pipeline: RANSAC over tracks (3 tracks, extents at their prior means, every other track's
``s_j`` solved with the normal fixed, observations within ``inlier_px`` counted), a soft-L1 fit of
all unknowns on the inlier tracks from the RANSAC and the affine (Eq. 1) normals (people seen as
boxes: each also with disks as wide as the boxes, the lowest cost kept), the residual scales,
then a fit on the inlier observations; the per-track heights last, with the people's disks in
metres (:func:`_metric_scales`); its uncertainty (:mod:`staticdepth.geometry.agent_plane_boot`)
refits from that solution.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.agent_cylinder import _BIG, AgentObservations
from staticdepth.geometry.agent_plane_linear import plane_affine
from staticdepth.geometry.agent_plane_problem import MIN_SHAPE_TRACKS, _normal, _Problem
from staticdepth.geometry.agent_plane_sides import wide_start, width_spread
from staticdepth.geometry.agent_shape import GROUPS
from staticdepth.geometry.agent_walker import relative_noise_split
from staticdepth.geometry.camera import pitch_roll_from_normal

__all__ = ["fit_joint", "_Problem", "_normal", "_expand"]   # _Problem, _normal: for the bootstrap


def _track_inliers(idx: np.ndarray, good: np.ndarray, J: int) -> np.ndarray:
    return np.bincount(idx, good, minlength=J) / np.maximum(np.bincount(idx, minlength=J), 1) >= 0.5


def _affine_start(K, obs: AgentObservations) -> tuple[float, float] | None:
    try:
        return pitch_roll_from_normal(plane_affine(K, obs.u, obs.v, obs.h)[0])
    except InputError:
        return None


def _ransac(K, prob: _Problem, conf, rng):
    J, obs = prob.J, prob.obs
    theta0 = prob.prior_theta()
    best, need, it = None, conf.ransac_iters, 0
    while it < min(need, conf.ransac_iters):
        it += 1
        sub = _Problem(K, obs.subset(rng.choice(J, 3, replace=False)), prob.kappa,
                       head_tie=prob.head_tie)              # the verdict of every track
        sub.width_idx = sub.width_idx[:0]     # rows (and box sides) only: the widths are slow
        start = _affine_start(K, sub.obs) or (30.0, 0.0)
        p, r, _, _, _ = sub.fit(conf, [start], sub.prior_theta(), max_nfev=30, free_shape=False)
        n = _normal(p, r)
        s = prob.solve_scales(n, theta0, huber_px=conf.inlier_px)
        res = prob.errors(n, theta0, s, 0.0)
        good = res < conf.inlier_px
        inl = _track_inliers(obs.idx, good, J)
        key = (int(good[inl[obs.idx]].sum()), -float(np.sum(np.minimum(res, conf.inlier_px))))
        if best is None or key > best[0]:
            best = (key, n, inl)
            w = max(inl.mean(), 1e-3)
            need = max(8, math.ceil(math.log(0.01) / math.log(max(1.0 - w ** 3, 1e-12))))
    return best[1], best[2]


RESTARTS_DEG = ((0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0))   # (pitch, roll) offsets


def _restarts(sub: _Problem, conf, best: tuple, theta0) -> tuple:
    """The robust fit's cost has shallow local minima (boxes: no head columns, the roll is
    weakly held): from the best solution, fits started 1 deg away in roll and in pitch
    (:data:`RESTARTS_DEG`) replace it when they end lower. Without them 1e-9 px on the feet
    moved a tapered-boxes camera from 0.69 to 1.40 deg (two minima); with them both end at
    0.54 (tests/test_plane_box_people.py). ``sub.e1`` (the one-foot extent) stays the winner's."""
    p, r = math.degrees(best[0]), math.degrees(best[1])
    e1 = sub.e1
    for dp, dr in RESTARTS_DEG:
        alt = sub.fit(conf, [(p + dp, r + dr)], theta0, loss=conf.loss, max_nfev=100)
        if alt[4] < best[4]:
            best, e1 = alt, sub.e1
    sub.e1 = e1
    return best


def _main_fit(sub: _Problem, conf, starts) -> tuple:
    """The robust fit from ``starts`` with its restarts and, for people as boxes, the same from
    disks as wide as the boxes (:func:`wide_start`); the lower cost wins, and ``sub.e1`` (the
    one-foot extent, which every fit rewrites) is the winner's: it had kept the wide fit's even
    when that fit lost."""
    best = _restarts(sub, conf, sub.fit(conf, starts, loss=conf.loss, max_nfev=100), None)
    e1 = sub.e1
    wide = wide_start(sub)
    if wide is not None:
        alt = _restarts(sub, conf, sub.fit(conf, starts, wide, loss=conf.loss, max_nfev=100),
                        wide)
        if alt[4] < best[4]:
            best, e1 = alt, sub.e1
    sub.e1 = e1
    return best


def fit_joint(K: np.ndarray, obs: AgentObservations, conf, rng, steps=None):
    """Fit the joint model. Returns (n, s (J,), inliers (J,), row residuals (N,), extents
    {group name: list}, bootstrap {normal_std_deg, d_over_h_std, ...}); ``steps`` wraps the
    bootstrap's resamples (a progress bar)."""
    auto_noise = conf.relative_noise is None
    prob = _Problem(K, obs, 0.0 if auto_noise else conf.relative_noise)
    J = prob.J
    starts = [(p, 0.0) for p in conf.pitch_starts_deg]
    if J >= 4:
        n_h, inl = _ransac(K, prob, conf, rng)
        if inl.sum() < 3:
            inl = np.ones(J, bool)
        starts = [pitch_roll_from_normal(n_h)]
    else:
        inl = np.ones(J, bool)
    sub = _Problem(K, obs.subset(np.flatnonzero(inl)), prob.kappa,
                   head_tie=prob.head_tie)                  # the gait verdict of every track
    aff = _affine_start(K, sub.obs)
    if aff is not None:
        starts.insert(1, aff)
    p, r, theta, s, cost = _main_fit(sub, conf, starts)
    # the rows' noise scale (gait, rough masks) sets the inlier threshold, never below inlier_px
    n = _normal(p, r)
    theta_all = _expand(prob, sub, theta)
    prob.take_feet(sub)
    s = prob.solve_scales(n, theta_all, huber_px=conf.inlier_px)
    if auto_noise and (prob.gait or len(prob.width_idx)):   # walkers' gait (or boxes' widths)
        kappa = relative_noise_split(*_people_residuals(prob, n, theta_all, s, inl))
        e1, prob = prob.e1, _Problem(K, obs, kappa)
        prob.e1 = e1
        s = prob.solve_scales(n, theta_all, huber_px=conf.inlier_px)
    if len(prob.width_idx):     # people as boxes: the spread of their widths
        prob.width_sd = width_spread(prob, n, theta_all, s, inl,
                                     GROUPS[0].typical_height[1])
    thr, inl, keep = kept_rows(obs.idx, prob.errors(n, theta_all, s, 0.0), J, conf.inlier_px)
    conf = _column_weight(conf, prob, n, theta_all, s, keep)
    fine = _Problem(K, obs.select(keep), prob.kappa) if keep.sum() >= 3 else sub
    if fine.present == sub.present:
        p, r, theta, _ = _fine_fit(fine, prob, conf, p, r, theta_all)
        theta_all = _expand(prob, fine, theta)
        prob.take_feet(fine)
    n = _normal(p, r)
    s = prob.solve_scales(n, theta_all, huber_px=thr)
    res = np.nan_to_num(prob.top_rows(n, theta_all, s) - obs.top_v, nan=_BIG)
    inl = _track_inliers(obs.idx, prob.errors(n, theta_all, s, 0.0) < thr, J)
    if inl.sum() == 0:
        inl = np.ones(J, bool)
    s_fit, s = s, _metric_scales(prob, n, theta_all, s, inl, thr)
    extents = {GROUPS[g].name: [float(v) for v in theta_all[sl.start - 2:sl.stop - 2]]
               for g, sl in prob.slices.items()}
    if prob.e1:
        extents["people one-foot"] = [prob.e1]     # e_1: added to e_f in one-foot frames
    from staticdepth.geometry.agent_plane_boot import joint_uncertainty

    # the Laplace part at the fit's own heights (its optimum), not the metric ones
    boot = joint_uncertainty(K, prob, conf, n, theta_all, inl, rng, s_fit, thr, steps)
    boot["column_weight"] = conf.fit_column_weight
    boot["inlier_px"] = thr
    k2, k1 = (prob.kappa, prob.kappa) if np.isscalar(prob.kappa) else prob.kappa
    boot["relative_noise"], boot["relative_noise_one_foot"] = float(k2), float(k1)
    return n, s, inl, res, extents, boot


def _metric_scales(prob: _Problem, n, theta, s, inl, thr: float) -> np.ndarray:
    """Per-track heights s_j with the people's disks fixed in metres at the fitted extents of a
    typical (median inlier) person: a head's and a foot's width hardly grow with stature, so
    radii scaled with each track's height make a child's too narrow and its height too large
    (0.3 m cylinders: +6-9% per child, the adults' heights pulled down where children are many).
    The normal and extents stay those of the scaled model's fit."""
    people = inl & (prob.track_group == 0)
    if people.sum() < MIN_SHAPE_TRACKS:
        return s
    prob.extent_s = float(np.median(s[people]))
    try:
        return prob.solve_scales(n, theta, huber_px=thr)
    finally:
        prob.extent_s = None


def _people_residuals(prob: _Problem, n, theta, s, inl):
    """(row and column residuals, pixel heights, one-foot frames) of the people on inlier
    tracks."""
    u, v = prob.top(n, theta, s)
    keep = inl[prob.obs.idx] & prob.people
    h, one = prob.obs.h[keep], prob.one[keep]
    return (np.r_[(v - prob.obs.top_v)[keep], (u - prob.top_u)[keep]], np.r_[h, h],
            np.r_[one, one])


def kept_rows(idx: np.ndarray, err: np.ndarray, J: int, inlier_px: float):
    """The fit's second step's rows, from the first fit's row errors ``err`` (px / sigma): the
    threshold (``inlier_px``, or 2.5 robust sigmas where the errors are larger), the inlier
    tracks (J,) and the kept rows (N,) (the bootstrap's replicates take the same step)."""
    thr = max(inlier_px, 2.5 * 1.4826 * float(np.median(err)))
    inl = _track_inliers(idx, err < thr, J)
    return thr, inl, inl[idx] & (err < thr)


def _fine_fit(fine: _Problem, prob: _Problem, conf, p, r, theta_all):
    """The fit on the inlier observations (pitch, roll, theta, track scales), the one-foot extent
    from the first fit's."""
    fine.take_feet(prob)
    fit = fine.fit(conf, [(math.degrees(p), math.degrees(r))], _expand(fine, prob, theta_all),
                   loss=conf.loss if conf.fit_column_weight > 0 else "linear", max_nfev=60)
    return fit[0], fit[1], fit[2], fit[3]


def _column_weight(conf, prob: _Problem, n, theta, s, keep):
    """``conf`` with the column weight scaled by the rows' over the columns' residual scale
    (MAD on the kept observations), never above the configured one: a real mask's lowest row is
    often one foot of a walker, its column pixels off the axis."""
    if conf.fit_column_weight <= 0:
        return conf
    u, v = prob.top(n, theta, s)
    ru, rv = (u - prob.top_u)[keep], (v - prob.obs.top_v)[keep]
    ru = ru[np.isfinite(ru)]
    if len(ru) < 5:
        return conf
    mad = lambda x: 1.4826 * float(np.median(np.abs(x - np.median(x))))  # noqa: E731
    ratio = mad(rv[np.isfinite(rv)]) / max(mad(ru), 1e-9)
    return replace(conf, column_weight=conf.fit_column_weight * min(1.0, ratio))


def _expand(full: _Problem, sub: _Problem, theta: np.ndarray) -> np.ndarray:
    """Extents of ``sub``'s groups placed into ``full``'s vector (prior means for groups that
    only the outlier tracks have)."""
    out = full.prior_theta().copy()
    for g, sl in full.slices.items():
        if g in sub.slices:
            ss = sub.slices[g]
            out[sl.start - 2:sl.stop - 2] = theta[ss.start - 2:ss.stop - 2]
    return out
