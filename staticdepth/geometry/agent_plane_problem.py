"""The ``joint`` ground-plane model's unknowns and residuals (its robust fit:
:mod:`staticdepth.geometry.agent_plane_joint`).

Unknowns: the normal (pitch, roll), one extent vector per class group present
(:mod:`staticdepth.geometry.agent_shape`: people are foot and head disks ``(e_f, e_h)``,
two-wheelers and vehicles boxes ``(a, b)``; each with a weak Gaussian prior,
``shape_prior_weight`` pixels per prior standard deviation; a group with fewer than 3 tracks
keeps the prior means; people none of whose observations has a top column, i.e. seen as boxes,
have the head extent's prior centred on the fitted foot extent, :data:`HEAD_TIE_SD` apart: the rows
alone drove a 0.3 m cylinder's head to 0.006-0.057 of its height and every track 4-10% too tall;
only where their boxes are rigid by :func:`staticdepth.geometry.agent_gait.box_gait`),
where masks show walkers' feet both apart and overlapping the one-foot
frames' extra foot extent ``e_1`` (:mod:`staticdepth.geometry.agent_walker`), the log of 1 /
camera height (tying every track's height to its class's typical height, robustly: children and
outliers weigh little) and per track ``s_j = H_j / d``.
Residuals: each observation's top row predicted from its foot ray minus the observed one, and
where the top column is known (masks) its column, in pixels; people's over
``sqrt(1 + (kappa h)^2)`` (h: the pixel height; ``relative_noise``; by default kappa is estimated
from the first fit's residuals where the masks show walkers' feet both apart and overlapping,
else 0): a walker is not rigid (it bobs by ~3% of its height, its stride moves the feet), so a
near walker's residuals are larger in pixels, not more informative; at 1 px the robust loss and
the inlier rules cut a near walker's extreme frames and keep a far one's, a bias that grows with
the size in the image, i.e. a pitch bias.

Why the columns: an extent moves the top point along the line of sight, which to first order is
the same as leaning the agent towards the camera, i.e. a change of pitch; from rows alone the
extent and the pitch are nearly degenerate (thin walkers seen from 11.5 m at 48 degrees: the cost
stays flat over +7 degrees of pitch). The line of sight's image passes through the vertical
vanishing point, so the extent does not move the head-foot axis: the columns (the axes meeting at
the image of n) separate the two. A track's foot and head lines meeting on the horizon is implied
by the same row residuals. The columns' weight is scaled by the rows' over the columns' residual
scale (a walker's lowest mask row is often one foot, off the axis); the inlier threshold is at
least ``inlier_px`` and 2.5 robust standard deviations of the rows (a walker's gait moves its
lowest point by +-0.3 m along its heading: several pixels).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from staticdepth.geometry.agent_cylinder import (_BIG, AgentObservations, gauss_newton_track_scales,
                                                 median_track_scales)
from staticdepth.geometry.agent_gait import box_gait
from staticdepth.geometry.agent_plane_sides import WIDTH_SD, anchored, width_tracks
from staticdepth.geometry.agent_shape import (GROUPS, group_of_class, predict_top,
                                              track_headings)
from staticdepth.geometry.agent_walker import (MIN_ONE_FOOT, ONE_FOOT_BOUNDS, ONE_FOOT_PRIOR,
                                               residual_scale)
from staticdepth.geometry.camera import normal_from_pitch_roll

MIN_SHAPE_TRACKS = 3
# people with no top column (seen as boxes): the head extent's prior is centred on the foot's,
# this sd apart (the rows alone drove a 0.3 m cylinder's head to 0.006-0.057 against 0.17),
# where their boxes show no gait (agent_gait.box_gait)
HEAD_TIE_SD = 0.02


def _normal(pitch: float, roll: float) -> np.ndarray:
    return normal_from_pitch_roll(math.degrees(pitch), math.degrees(roll))


class _Problem:
    """The observations with their class groups; packs and unpacks the parameter vector
    ``[pitch, roll, extents of the groups present..., s_1..s_J]``."""

    def __init__(self, K: np.ndarray, obs: AgentObservations, relative_noise: float = 0.0,
                 head_tie: bool | None = None):
        self.K, self.obs, self.kappa = K, obs, relative_noise
        self.J, self.N = len(obs.ids), len(obs.top_v)
        self.track_group = group_of_class(obs.cls)
        self.group = self.track_group[obs.idx]
        self.present = [g for g in range(len(GROUPS)) if np.any(self.group == g)]
        # a group's extents are free with at least MIN_SHAPE_TRACKS tracks, else at the prior
        self.free = [g for g in self.present
                     if np.count_nonzero(self.track_group == g) >= MIN_SHAPE_TRACKS]
        self.slices, k = {}, 2
        for g in self.present:
            m = len(GROUPS[g].prior)
            self.slices[g] = slice(k, k + m)
            k += m
        self.n_shape = k - 2
        # a box's highest mask row is often an edge (its median column between two corners):
        # only the disk outlines' top columns are used
        box_obs = np.array([GROUPS[g].outline == "box" for g in range(len(GROUPS))])[self.group]
        self.top_u = np.where(box_obs, np.nan, obs.top_u)
        self.has_u = np.isfinite(self.top_u)
        # a box outline's extreme columns (a box detection's sides, a mask's extreme columns)
        self.sides = box_obs & np.isfinite(obs.left) & np.isfinite(obs.right)
        self.side_idx = np.flatnonzero(self.sides)
        # people seen as boxes (no top column): their widths, each track's body radius free
        self.width_idx = np.flatnonzero(~box_obs & ~self.has_u & np.isfinite(obs.left)
                                        & np.isfinite(obs.right))
        # people none of whose observations has a top column: the head prior tied to the foot
        # where their boxes show no gait (a walker's box bottom is its front foot, its foot
        # extent holds the stride; agent_gait); a subset of the fit's tracks passes the verdict
        # of every track (``head_tie``) instead of judging its own few
        ppl = ~box_obs & (self.group == 0)
        self.tie_possible = (0 in self.free and bool(ppl.any())
                             and not bool(np.any(self.has_u & ppl)))
        if head_tie is None:
            head_tie = self.tie_possible and box_gait(
                obs.idx[ppl], (obs.right - obs.left)[ppl], obs.h[ppl]) == "rigid"
        self.head_tie = self.tie_possible and bool(head_tie)
        self.k_s = k + 1                  # index of s_1 (k: log of 1 / camera height in metres)
        mh = np.array([GROUPS[g].typical_height for g in self.track_group])
        self.log_h, self.log_sd = np.log(mh[:, 0]), mh[:, 1]
        self.boxes = any(GROUPS[g].outline == "box" for g in self.present)
        # residual scale per observation (1 px + a share of the pixel height: gait, bobbing)
        self.people = np.array([GROUPS[g].outline == "disk" for g in self.group], bool)
        # a walker's one-foot frames (feet overlapping in the image): its nearer foot, half a
        # stride towards the camera; an extent of their own where other frames show two feet
        self.one = self.people & (obs.feet == 1)
        self.sigma = residual_scale(relative_noise, obs.h, self.people, self.one)
        self.one_free = (np.count_nonzero(self.one) >= MIN_ONE_FOOT
                         and np.count_nonzero(self.people & (obs.feet >= 2)) >= MIN_ONE_FOOT)
        # a gait shown (one-foot frames, kept or interpolated, beside two-foot ones): kappa
        self.gait = (np.count_nonzero(self.people & (obs.feet != 0) & (obs.feet != 2))
                     >= MIN_ONE_FOOT and np.count_nonzero(self.people & (obs.feet >= 2))
                     >= MIN_ONE_FOOT)
        self.e1, self._with_one = 0.0, False      # the one-foot extent, fitted or not
        self.width_sd = WIDTH_SD      # the ring radii's spread (agent_plane_sides.width_spread)
        self.extent_s = None          # disks' radii e * s (None) or e * extent_s (in metres)

    def params(self, theta: np.ndarray, e1: float | None = None) -> list:
        out = [np.asarray(GROUPS[g].prior) for g in range(len(GROUPS))]
        for g, sl in self.slices.items():
            out[g] = theta[sl.start - 2:sl.stop - 2]
        e1 = self.e1 if e1 is None else e1
        for g in self.present:
            if GROUPS[g].outline == "disk" and e1 != 0:   # one-foot frames: e_f + e_1
                m = self.group == g
                out[g] = [out[g][0] + e1 * self.one[m], out[g][1]]
        return out

    def prior_theta(self) -> np.ndarray:
        return np.concatenate([GROUPS[g].prior for g in self.present] or [np.zeros(0)])

    def shape_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.concatenate([GROUPS[g].lower for g in self.present] or [np.zeros(0)])
        hi = np.concatenate([GROUPS[g].upper for g in self.present] or [np.zeros(0)])
        return lo, hi

    def headings(self, n: np.ndarray) -> np.ndarray | None:
        if not self.boxes:
            return None
        nr = self.obs.rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            F = self.obs.rays / nr[:, None]
        return track_headings(n, F, self.obs.idx, self.J)[self.obs.idx]

    def anchored(self, n, theta, s, e1=None):
        """(foot rays (N, 3), column residuals of the boxes' sides and the people-as-boxes'
        widths): :func:`staticdepth.geometry.agent_plane_sides.anchored`."""
        return anchored(self, n, theta, s, e1)

    def top(self, n: np.ndarray, theta: np.ndarray, s: np.ndarray, e1=None, rays=None):
        rays = self.anchored(n, theta, s, e1)[0] if rays is None else rays
        return predict_top(self.K, n, rays, s[self.obs.idx], self.group,
                           self.params(theta, e1), self.headings(n), self.extent_s)

    def top_rows(self, n: np.ndarray, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        return self.top(n, theta, s)[1]

    def errors(self, n, theta, s, col_w: float) -> np.ndarray:
        """(N,) the larger of |row| and weighted |column| residual (impossible: _BIG)."""
        u, v = self.top(n, theta, s)
        e = np.abs(np.nan_to_num(v - self.obs.top_v, nan=_BIG))
        if col_w > 0:
            e = np.maximum(e, col_w * np.nan_to_num(np.abs(u - self.top_u), nan=0.0))
        return e / self.sigma

    def residuals(self, x: np.ndarray, prior_w: float, height_w: float,
                  col_w: float, known: tuple[float, float] | None = None) -> np.ndarray:
        n = _normal(x[0], x[1])
        theta, lam, s = x[2:2 + self.n_shape], x[self.k_s - 1], x[self.k_s:self.k_s + self.J]
        e1 = float(x[-1]) if self._with_one else None
        rays, cols = self.anchored(n, theta, s, e1)
        u, v = self.top(n, theta, s, e1, rays)
        r = np.nan_to_num((v - self.obs.top_v) / self.sigma, nan=_BIG)
        if col_w > 0:
            r = np.r_[r, col_w * np.nan_to_num((u - self.top_u)[self.has_u]
                                               / self.sigma[self.has_u], nan=_BIG)]
        r = np.r_[r, cols]
        sd = np.concatenate([GROUPS[g].prior_sd for g in self.present] or [np.zeros(0)])
        mean = self.prior_theta()
        if self.head_tie:      # the head's extent about the foot's (people seen as boxes)
            f = self.slices[0].start - 2
            mean[f + 1], sd = theta[f], sd.copy()
            sd[f + 1] = HEAD_TIE_SD
        # heights: log s_j = log H_class - log d + eps, robust (children, outliers)
        z = (np.log(s) - self.log_h - lam) / self.log_sd
        zr = np.sign(z) * np.sqrt(2.0 * (np.sqrt(1.0 + z * z) - 1.0))
        out = np.r_[r, prior_w * (theta - mean) / np.maximum(sd, 1e-9),
                    height_w * zr]
        if e1 is not None:
            out = np.r_[out, prior_w * (e1 - ONE_FOOT_PRIOR[0]) / ONE_FOOT_PRIOR[1]]
        if known is not None:      # a known camera height: (log 1 / d, its sd)
            out = np.r_[out, height_w * (lam - known[0]) / known[1]]
        return out

    def sparsity(self, col_w: float, with_one: bool = False, known: bool = False):
        ob = np.r_[np.arange(self.N), np.flatnonzero(self.has_u) if col_w > 0 else [],
                   self.side_idx, self.side_idx, self.width_idx,
                   width_tracks(self)[1] if self.width_sd and len(self.width_idx) else []
                   ].astype(int)
        R, n1 = len(ob), int(with_one)
        S = lil_matrix((R + self.n_shape + self.J + n1 + int(known), self.k_s + self.J + n1),
                       dtype=np.int8)
        if known:        # the known camera height's prior row (the last)
            S[R + self.n_shape + self.J + n1, self.k_s - 1] = 1
        if with_one:     # the one-foot extent: the one-foot frames' residuals and its prior
            S[np.flatnonzero(self.one[ob]), self.k_s + self.J] = 1
            S[R + self.n_shape + self.J, self.k_s + self.J] = 1
        rows = np.arange(R)
        S[rows, 0] = 1
        S[rows, 1] = 1
        for g, sl in self.slices.items():
            for c in range(sl.start, sl.stop):
                S[rows[self.group[ob] == g], c] = 1
        S[rows, self.k_s + self.obs.idx[ob]] = 1
        for k in range(self.n_shape):
            S[R + k, 2 + k] = 1
        if self.head_tie:
            S[R + self.slices[0].start - 1, self.slices[0].start] = 1
        tr = R + self.n_shape + np.arange(self.J)
        S[tr, self.k_s - 1] = 1
        S[tr, self.k_s + np.arange(self.J)] = 1
        return S.tocsr()

    def solve_scales(self, n: np.ndarray, theta: np.ndarray, iters: int = 8,
                     huber_px: float = 3.0) -> np.ndarray:
        """Per-track s_j (J,) with the normal and extents fixed: Gauss-Newton per track, the later
        half Huber-reweighted."""
        o = self.obs
        return gauss_newton_track_scales(
            lambda sv: (self.top_rows(n, theta, sv) - o.top_v) / self.sigma, o.idx,
            median_track_scales(self.K, o, n), iters, huber_px)

    def fit(self, conf, starts, theta0=None, loss="linear", max_nfev=200, free_shape=True):
        """Best of several (pitch, roll) starts in degrees: (pitch, roll (rad), theta, s, cost);
        with ``free_shape`` the free groups' extents and, where fitted, the one-foot extent
        (``self.e1``) are unknowns, else fixed."""
        lo_p, hi_p = (math.radians(b) for b in conf.pitch_bounds_deg)
        mr = math.radians(conf.max_roll_deg)
        th0 = self.prior_theta() if theta0 is None else np.asarray(theta0, np.float64)
        t_lo, t_hi = self.shape_bounds()
        th0 = np.clip(th0, t_lo, t_hi)
        fixed = np.ones(len(th0), bool)
        for g in (self.free if free_shape else []):
            fixed[self.slices[g].start - 2:self.slices[g].stop - 2] = False
        t_lo, t_hi = np.where(fixed, th0 - 1e-9, t_lo), np.where(fixed, th0 + 1e-9, t_hi)
        lower = np.r_[lo_p, -mr, t_lo, -10.0, np.full(self.J, 1e-4)]
        upper = np.r_[hi_p, mr, t_hi, 10.0, np.full(self.J, 100.0)]
        with_one = self._with_one = free_shape and conf.one_foot and self.one_free
        if with_one:
            lower, upper = np.r_[lower, ONE_FOOT_BOUNDS[0]], np.r_[upper, ONE_FOOT_BOUNDS[1]]
        elif not (conf.one_foot and self.one_free):
            self.e1 = 0.0
        cw, known = conf.fit_column_weight, conf.known_log
        sparsity, best = self.sparsity(cw, with_one, known is not None), None
        for p0, r0 in starts:
            p0 = float(np.clip(math.radians(p0), lo_p + 1e-3, hi_p - 1e-3))
            r0 = float(np.clip(math.radians(r0), -mr + 1e-3, mr - 1e-3))
            s0 = np.clip(self.solve_scales(_normal(p0, r0), th0, iters=4), 2e-4, 99.0)
            lam0 = float(np.median(np.log(s0) - self.log_h))
            x0 = np.r_[p0, r0, th0, lam0, s0, [self.e1 or ONE_FOOT_PRIOR[0]] if with_one else []]
            x0 = np.clip(x0, lower + 1e-12, upper - 1e-12)
            hw = conf.height_prior_weight
            res = least_squares(lambda x: self.residuals(x, conf.shape_prior_weight, hw, cw,
                                                         known), x0,
                                bounds=(lower, upper), loss=loss, f_scale=conf.f_scale_px,
                                jac_sparsity=sparsity, x_scale="jac", max_nfev=max_nfev)
            if best is None or res.cost < best[4]:
                k = 2 + self.n_shape
                best = (float(res.x[0]), float(res.x[1]), res.x[2:k].copy(),
                        res.x[self.k_s:self.k_s + self.J].copy(), float(res.cost),
                        float(res.x[-1]) if with_one else self.e1)
        self.e1 = best[5]
        return best[:5]

    def take_feet(self, other: "_Problem") -> None:
        """The one-foot extent, the ring radii's spread and the head tie's verdict of ``other`` (a
        problem on a subset of the observations)."""
        self.e1 = other.e1 if self.one_free else 0.0
        self.width_sd = other.width_sd
        self.head_tie = self.tie_possible and other.head_tie
