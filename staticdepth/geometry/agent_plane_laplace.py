"""The joint ground plane's data-only uncertainty (Laplace) and what the data allow (Cramer-Rao).

The bootstrap (:mod:`staticdepth.geometry.agent_plane_boot`) resamples tracks and refits from the
solution: it sees how much the plane depends on which agents passed, not the pixel noise that
each track's frames average only partly, nor a bias the priors share (seeds 40-59: it accepted
cameras 1.3-2.2 degrees off with a std of 0.4-1.0). This module reads the uncertainty off the
fit's own curvature instead.

Laplace: the Gauss-Newton information ``J^T W J`` of the joint model's residuals
(:meth:`staticdepth.geometry.agent_plane_problem._Problem.residuals`) at the solution, on the
observations the final fit kept. The robust loss's rows weigh by ``psi'`` and the residual scale
is Huber's M-estimator factor from the fit's own residuals, ``sum psi^2 / (n - p) / mean psi'``
(for least squares: ``sum r^2 / (n - p)``), so a model that describes the data worse than the
noise model says (gait, body shape) reports a larger uncertainty. The normal's 2x2 block of the
inverse marginalises the extents, the camera-height term and every track's height; its RMS angle
(``sqrt`` of the trace, the same measure as the bootstrap's RMS) is reported with the priors
(shape and height priors as Gaussian information) and without (data only).

The rows and their scale are already the kept ones (inlier tracks, rows within the fit's
threshold). With 20% outliers, other choices changed no gate verdict: the rows within
``inlier_px`` only, or the relative noise re-estimated on the kept rows (seeds 0-19 masks, 80
cameras: the std within 7%); a MAD scale, or one trimmed at 3 MAD (seeds 0-19 thin, 20-39 thin,
tapered, cylinder). The Laplace grows with outliers (ellipsoid: 1.5-2x) because the fit's
relative noise (kappa) and threshold grow (kappa +12-50%, threshold 3.0 -> 3.3-4.4), which weigh
the near walkers down; the gate's over-caution there is the bootstrap's (with the Laplace at 0
it still refuses 18 of 59 cameras under 0.5 degrees, against 22). Its cost is 1% of a fit
(``benchmarks/bench_laplace_cost.py``), so it runs on every joint fit.

Cramer-Rao: the same information at the *true* plane and heights, unweighted, unit scale (the
noise model's pixels): the smallest normal std any unbiased estimator gets from these
observations. With 1 px noise and 24 tracks it says which cameras cannot reach 1 degree, and
(the std falls as ``1 / sqrt(tracks)``) how many tracks would.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from staticdepth.geometry.agent_cylinder import _BIG
from staticdepth.geometry.agent_plane_problem import _Problem
from staticdepth.geometry.agent_walker import ONE_FOOT_BOUNDS
from staticdepth.geometry.camera import pitch_roll_from_normal

# the normal's RMS angle must stay below the limit / this for 95% of its errors to: a 2-D
# isotropic Gaussian's angle exceeds ``a`` with probability ``exp(-(a / rms)^2)``
RMS_FOR_95 = math.sqrt(math.log(20.0))


def _state(prob: _Problem, n, theta, s, lam: float, with_one: bool) -> np.ndarray:
    p, r = (math.radians(a) for a in pitch_roll_from_normal(n))
    return np.r_[p, r, theta, lam, s, [prob.e1] if with_one else []]


def _height_offset(prob: _Problem, s: np.ndarray) -> float:
    """The fitted log(1 / camera height) given the tracks' s: the robust (pseudo-Huber) centre of
    ``log s_j - log H_class`` in units of the class spreads (IRLS)."""
    y = np.log(np.maximum(s, 1e-9)) - prob.log_h
    lam = float(np.median(y))
    for _ in range(20):
        z = (y - lam) / prob.log_sd
        w = 1.0 / (np.sqrt(1.0 + z * z) * prob.log_sd ** 2)
        lam = float(np.sum(w * y) / np.sum(w))
    return lam


def _jacobian(fun, x: np.ndarray, sparsity, k_s: int, J: int) -> tuple[np.ndarray, np.ndarray]:
    """(residuals, dense Jacobian) by central differences: one column at a time, the tracks'
    s_j all at once (each residual row depends on one track's s, ``sparsity`` says which)."""
    r0 = fun(x)
    D = np.zeros((len(r0), len(x)))
    cols = [[c] for c in range(len(x)) if not k_s <= c < k_s + J] + [list(range(k_s, k_s + J))]
    S = sparsity.tocsc()[:, k_s:k_s + J].tocsr()
    for c in cols:
        h = 1e-6 * np.maximum(1.0, np.abs(x[c]))
        xp, xm = x.copy(), x.copy()
        xp[c] += h
        xm[c] -= h
        d = (fun(xp) - fun(xm))
        if len(c) == 1:
            D[:, c[0]] = d / (2 * h[0])
            continue
        rows, tracks = S.nonzero()
        D[rows, k_s + tracks] = d[rows] / (2 * h[tracks])
    return r0, D


def _normal_jacobian(n) -> np.ndarray:
    """(3, 2) derivative of the unit normal by (pitch, roll), radians."""
    p, r = (math.radians(a) for a in pitch_roll_from_normal(n))
    return np.array([[math.sin(r) * math.sin(p), -math.cos(r) * math.cos(p)],
                     [-math.cos(r) * math.sin(p), -math.sin(r) * math.cos(p)],
                     [math.cos(p), 0.0]])


def _angle_std_deg(n, cov_pr: np.ndarray) -> float:
    """RMS angle (deg) of the normal for a (pitch, roll) covariance (rad^2)."""
    G = _normal_jacobian(n)
    var = float(np.trace(G @ cov_pr @ G.T))
    return math.degrees(math.sqrt(var)) if var >= 0 else float("inf")


def _inverse_block(info: np.ndarray, idx) -> np.ndarray:
    """The ``idx`` block of the inverse, unknowns without information (the camera-height term
    when its prior is off) left out; ``idx`` must have information."""
    d = np.diag(info)
    use = d > 1e-12 * d.max()
    use[list(idx)] = True
    pos = np.cumsum(use) - 1
    try:
        return np.linalg.inv(info[np.ix_(use, use)])[np.ix_(pos[idx], pos[idx])]
    except np.linalg.LinAlgError:
        return np.full((len(idx), len(idx)), np.inf)


def _normal_block(info: np.ndarray) -> np.ndarray:
    """The (pitch, roll) block of the inverse (see :func:`_inverse_block`)."""
    return _inverse_block(info, [0, 1])


def _information(prob: _Problem, conf, x: np.ndarray, with_one: bool, at_bound=None):
    """(data rows' (residuals, Jacobian), prior rows' Jacobian, the camera-height term's column)
    at ``x``, over the free unknowns: not the groups fixed at their prior for lack of tracks, nor
    those ``at_bound`` (x's length, bool; an extent the fit holds at its bound, e.g. a thin
    body's zero extents: the constrained optimum's curvature)."""
    prob._with_one = with_one
    cw, known = conf.fit_column_weight, conf.known_log
    r, D = _jacobian(lambda v: prob.residuals(v, conf.shape_prior_weight,
                                              conf.height_prior_weight, cw, known),
                     x, prob.sparsity(cw, with_one, known is not None), prob.k_s, prob.J)
    n_prior = prob.n_shape + prob.J + int(with_one) + int(known is not None)
    n_data = len(r) - n_prior
    keep = np.r_[0, 1, [2 + k for g in prob.free
                        for k in range(prob.slices[g].start - 2, prob.slices[g].stop - 2)],
                 prob.k_s - 1, prob.k_s + np.arange(prob.J),
                 [prob.k_s + prob.J] if with_one else []].astype(int)
    if at_bound is not None:
        keep = keep[~at_bound[keep]]
    D = D[:, keep]
    ok = np.abs(r[:n_data]) < 0.5 * _BIG
    lam_col = int(np.flatnonzero(keep == prob.k_s - 1)[0])
    return (r[:n_data][ok], D[:n_data][ok]), D[n_data:], lam_col


def _at_bound(prob: _Problem, x: np.ndarray, with_one: bool) -> np.ndarray:
    """(len(x),) the extents (and one-foot extent) the fit holds at a bound."""
    lo, hi = prob.shape_bounds()
    out = np.zeros(len(x), bool)
    th = x[2:2 + prob.n_shape]
    out[2:2 + prob.n_shape] = (th <= lo + 1e-6) | (th >= hi - 1e-6)
    if with_one:
        out[-1] = not ONE_FOOT_BOUNDS[0] + 1e-6 < x[-1] < ONE_FOOT_BOUNDS[1] - 1e-6
    return out


def _std_pair(n, data, prior_D, lam_col: int, conf, robust: bool
              ) -> tuple[float, float, float, np.ndarray]:
    """(RMS angle deg with the priors, without them, residual scale, the (pitch, roll) covariance
    with the priors in deg^2) from the rows; ``lam_col``: the camera-height term's column."""
    r, D = data
    if robust and conf.loss == "soft_l1":
        z = 1.0 + (r / conf.f_scale_px) ** 2
        psi, dpsi = r / np.sqrt(z), z ** -1.5
    else:
        psi, dpsi = r, np.ones_like(r)
    p = D.shape[1]
    scale = (float(np.sum(psi ** 2)) / max(len(r) - p, 1) / float(np.mean(dpsi))
             if robust else 1.0)
    A = (D * dpsi[:, None]).T @ D / scale
    cov = _normal_block(A + prior_D.T @ prior_D)
    with_p = _angle_std_deg(n, cov)
    # without priors the camera-height term (in the height rows only) has no information
    drop = np.ones(p, bool)
    drop[lam_col] = False
    no_p = _angle_std_deg(n, _normal_block(A[np.ix_(drop, drop)]))
    return with_p, no_p, math.sqrt(scale), np.degrees(np.degrees(cov))


def laplace_uncertainty(K, prob: _Problem, conf, n, theta, s, inl, thr: float) -> dict:
    """``laplace_std_deg`` (priors in), ``laplace_data_std_deg`` (data only),
    ``laplace_scale`` (residual scale in noise-model units) and ``laplace_cov_pr_deg2`` (the
    (pitch, roll) covariance with the priors, deg^2) of the joint fit's solution, on the
    observations of inlier tracks within ``thr``; empty with fewer than 3 inlier tracks."""
    keep = inl[prob.obs.idx] & (prob.errors(n, theta, s, 0.0) < thr)
    if np.count_nonzero(inl) < 3 or keep.sum() < 3:
        return {}
    sub = _Problem(K, prob.obs.select(keep), prob.kappa)
    sub.take_feet(prob)
    tracks = np.unique(prob.obs.idx[keep])
    with_one = bool(conf.one_foot and sub.one_free)
    s_sub = s[tracks]
    x = _state(sub, n, theta, s_sub, _height_offset(sub, s_sub), with_one)
    data, prior_D, lam_col = _information(sub, conf, x, with_one, _at_bound(sub, x, with_one))
    with_p, no_p, scale, cov = _std_pair(n, data, prior_D, lam_col, conf, robust=True)
    return {"laplace_std_deg": with_p, "laplace_data_std_deg": no_p, "laplace_scale": scale,
            "laplace_cov_pr_deg2": cov}


@dataclass(frozen=True)
class CramerRao:
    """What no unbiased fit of one camera's observations beats (unit noise in the model's
    pixels), at the true plane and heights: the normal's RMS angle from the data alone and with
    the shape and height priors, and with the priors the covariance of (pitch, roll, log(1 / d))
    (rad, rad, and the camera height's relative error: d = exp(-lam)), from which the anchor
    depth's and the camera height's relative std follow to first order."""

    normal_deg: float
    normal_priors_deg: float
    cov: np.ndarray
    normal: np.ndarray

    def camera_height_std(self) -> float:
        """Relative std of the camera height from the people's height priors (1 = 100%)."""
        return math.sqrt(self.cov[2, 2])

    def anchor_std(self, K, u: float, v: float) -> float:
        """Relative std of the ground's depth at pixel (u, v) given the true camera height,
        ``d / (n . r)``: its log moves by ``-(r . dn) / (n . r)``."""
        r = np.linalg.solve(np.asarray(K, float), [u, v, 1.0])
        g = r @ _normal_jacobian(self.normal) / float(r @ self.normal)
        return math.sqrt(float(g @ self.cov[:2, :2] @ g))


def chance_over(std: float, limit: float, dims: int = 1) -> float:
    """P(error > ``limit``) for a zero-mean Gaussian error of RMS ``std``: one value (``dims``
    1, |e|), or an isotropic 2-D one's length (``dims`` 2, e.g. the normal's angle)."""
    if not std > 0:
        return 0.0
    if dims == 2:
        return math.exp(-(limit / std) ** 2)
    return math.erfc(limit / (std * math.sqrt(2.0)))


def cramer_rao_std(K, obs, conf, n_true, s_true, height_m: float, theta, kappa=0.0,
                   e1: float = 0.0, max_residual: float = 5.0) -> CramerRao:
    """The bound for ``obs`` (AgentObservations): the joint model's information at the true
    normal ``n_true``, true ``s_true`` (J,) = H_j / d and extents ``theta`` (the body's true
    extents, or the fit's where the body is not the model's), unit noise in the model's pixels;
    rows more than ``max_residual`` off at the truth (outliers, impossible) left out."""
    prob = _Problem(K, obs, kappa)
    prob.e1 = e1
    with_one = bool(conf.one_foot and prob.one_free)
    x = _state(prob, n_true, np.asarray(theta, float), np.asarray(s_true, float),
               -math.log(height_m), with_one)
    (r, D), prior_D, lam_col = _information(prob, conf, x, with_one)
    ok = np.abs(r) < max_residual
    with_p, no_p, _, _ = _std_pair(n_true, (r[ok], D[ok]), prior_D, lam_col, conf, robust=False)
    A = D[ok].T @ D[ok] + prior_D.T @ prior_D
    return CramerRao(no_p, with_p, _inverse_block(A, [0, 1, lam_col]),
                     np.asarray(n_true, float))


def cramer_rao_of_fit(K, observations: np.ndarray, plane, conf, n_true, agent_heights: dict,
                      height_m: float) -> CramerRao:
    """:func:`cramer_rao_std` for an observation table that ``plane`` (a joint AgentPlane) was
    fitted to with ``conf``: its noise scales, one-foot and body extents; the truth: ``n_true``,
    the tracks' heights (track id -> m) and the camera height (m)."""
    from staticdepth.geometry.agent_plane import _prepare
    from staticdepth.geometry.agent_shape import GROUPS, group_of_class
    from staticdepth.geometry.agent_walker import interpolate_one_foot

    table = interpolate_one_foot(observations) if conf.one_foot else observations
    obs = _prepare(K, table, "joint", conf.fit_classes)
    ext = plane.extra["extents"]
    theta = np.concatenate([ext.get(GROUPS[g].name, GROUPS[g].prior)
                            for g in np.unique(group_of_class(obs.cls))])
    kappa = (plane.extra.get("relative_noise", 0.0), plane.extra.get("relative_noise_one_foot",
                                                                      0.0))
    s_true = np.array([agent_heights[int(t)] for t in obs.ids]) / height_m
    return cramer_rao_std(K, obs, conf, n_true, s_true, height_m, theta, kappa,
                          ext.get("people one-foot", [0.0])[0])


def tracks_for(std_deg: float, tracks: int, limit_deg: float = 1.0) -> int:
    """Tracks (like these) for 95% of the normal's errors to stay within ``limit_deg`` when its
    RMS is ``std_deg`` over ``tracks``: the RMS falls as ``1 / sqrt(tracks)``."""
    return int(math.ceil(tracks * (std_deg * RMS_FOR_95 / limit_deg) ** 2))
