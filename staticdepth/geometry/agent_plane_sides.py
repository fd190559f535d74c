"""Column residuals of the joint ground-plane model (:mod:`staticdepth.geometry.agent_plane_joint`)
where an observation's sides are known: box detections and box-class masks (``left``, ``right``
of :data:`staticdepth.tracking.OBS_DTYPE`).

- Box outlines (two-wheelers, cars, buses/trucks): the projected box's extreme columns against
  the observed sides, the box's lowest corner slid along the foot row to centre it between them.
- People seen as boxes (no top column): the width of the hull of the foot disk, the head disk and
  a shoulder ring (:func:`staticdepth.geometry.agent_shape.person_columns`, extreme columns in
  closed form), the axis slid along the foot row likewise. Each track's ring radius is solved
  inside the residuals (Gauss-Newton), starting where the ring alone spans the box and never
  inside the widest disk: from a narrow start the hull's width does not move with the ring, and
  the fit widened the foot disk instead (tapered bodies 1.56 deg off). The radii share a prior
  about their median whose spread is estimated from the tracks after the first fit
  (:func:`width_spread`, at most :data:`WIDTH_SD`): bodies alike in width tie the tracks' depths
  together as their heights do, which far, small people need (tapered camera 9, 10 m high at
  21.5 deg, 30-90 px tall: 1.37 deg with the fixed 0.15, 0.84 with the estimated 0.053). Ring
  and disks explain a wide body alike, so the joint fit also starts from disks as wide as the
  boxes (:func:`wide_start`) and keeps the lower cost. Generators' boxes (+-2 px, 8 cameras,
  benchmarks/bench_agent_plane.py) went from 0.29-1.08 / 0.97-1.56 deg (median / max) to
  0.17-0.59 / 0.40-0.91 (box6); on 20 cameras the estimated spread took tapered, cylinder and
  ellipsoid from 1.37 / 1.17 / 1.49 deg max to 0.84 / 0.77 / 1.38.
"""
from __future__ import annotations

import numpy as np

from staticdepth.geometry.agent_cylinder import _BIG, track_medians
from staticdepth.geometry.agent_shape import (WIDTH_AT, box_columns, disk_columns,
                                              foot_centres, ring_columns)
from staticdepth.geometry.projection import rays_from_pixels

# people seen as boxes: the largest spread (log sd) of their widest ring's radius about the
# tracks' median, the prior's until width_spread estimates it (0 = each track's own, unrelated)
WIDTH_SD = 0.15


def anchored(prob, n, theta, s, dev=None, iters: int = 3):
    """(foot rays (N, 3), residuals over the noise model of the box outlines' left and right
    columns (2 x len(side_idx)) and of the people-as-boxes' widths (len(width_idx))).

    A box's lowest mask row is an edge as often as a corner, and a box detection's foot
    column is its centre, so the foot column says little where the sides are known: the
    outline's lowest point keeps the foot row and slides along it until the outline's
    projection is centred between the observed sides (Newton steps of slope 1: the
    projection moves with its anchor). People seen as boxes
    (:func:`~staticdepth.geometry.agent_shape.person_columns`) have a shoulder radius per
    track (Gauss-Newton per track); a body's width does not foreshorten with the viewing
    angle, its height does: the width along a track measures the viewing angle that rows
    alone trade against the foot and head extents."""
    rays = prob.obs.rays.copy()
    out = []
    k = prob.side_idx
    if len(k):
        params, heading = prob.params(theta, dev), prob.headings(n)[k]
        mid = 0.5 * (prob.obs.left[k] + prob.obs.right[k])
        u, sk, grp = prob.obs.u[k].copy(), s[prob.obs.idx[k]], prob.group[k]
        for it in range(iters + 1):
            rays[k] = rays_from_pixels(prob.K, u, prob.obs.v[k])
            left, right = box_columns(prob.K, n, rays[k], sk, grp, params, heading)
            if it < iters:
                u = u - np.nan_to_num(0.5 * (left + right) - mid)
        out += [(left - prob.obs.left[k]) / prob.sigma[k],
                (right - prob.obs.right[k]) / prob.sigma[k]]
    k = prob.width_idx
    if len(k):
        rays[k], wres = _people_widths(prob, n, theta, s, dev)[:2]
        out.append(wres)
    return rays, np.nan_to_num(np.concatenate(out), nan=_BIG) if out else np.zeros(0)

def _people_widths(prob, n, theta, s, dev, iters: int = 1):
    """(foot rays, width residuals) of the people seen as boxes; see :func:`anchored`."""
    k = prob.width_idx
    e_f, e_h = prob.params(theta, dev)[0]   # people (the disk group): foot, head extents
    if np.ndim(e_f):                          # per observation of the group (striding)
        e_f = np.asarray(e_f)[(np.cumsum(prob.group == 0) - 1)[k]]
    j, sk = prob.obs.idx[k], s[prob.obs.idx[k]]
    obs_w = prob.obs.right[k] - prob.obs.left[k]
    mid = 0.5 * (prob.obs.left[k] + prob.obs.right[k])
    u, sig = prob.obs.u[k].copy(), prob.sigma[k]
    tracks = width_tracks(prob)[0]

    def cols(d_lo, d_hi, A, r):
        lo, hi = ring_columns(prob.K, n, A, sk, r)
        return (np.nan_to_num(np.fmin(d_lo, lo), nan=-_BIG),
                np.nan_to_num(np.fmax(d_hi, hi), nan=_BIG))

    for it in range(iters + 1):
        rays = rays_from_pixels(prob.K, u, prob.obs.v[k])
        A = foot_centres(n, rays, sk, e_f)
        d_lo, d_hi = disk_columns(prob.K, n, A, sk, e_f, e_h)
        if it == 0:       # the ring that alone spans the box, never inside the widest disk
            r_lo = np.bincount(j, np.maximum(e_f, e_h) * sk, minlength=prob.J) \
                / np.maximum(np.bincount(j, minlength=prob.J), 1)
            radius = np.maximum(_ring_start(prob, n, rays, sk, obs_w, j), r_lo)
        for _ in range(1 if it else 2):
            lo, hi = cols(d_lo, d_hi, A, radius[j])
            lo2, hi2 = cols(d_lo, d_hi, A, radius[j] + 1e-3)
            w, dw = (hi - lo) / sig, (hi2 - lo2 - hi + lo) / 1e-3 / sig
            num = np.bincount(j, dw * (w - obs_w / sig), minlength=prob.J)
            den = np.bincount(j, dw * dw, minlength=prob.J)
            if prob.width_sd:     # the shared-width prior's Gauss-Newton terms
                pr, dpr = _width_prior(radius, tracks, prob.width_sd)
                num[tracks] += pr * dpr
                den[tracks] += dpr * dpr
            radius = np.clip(radius - np.where(den > 0, num / np.maximum(den, 1e-300), 0.0),
                             r_lo, 0.2)
        lo, hi = cols(d_lo, d_hi, A, radius[j])
        if it < iters:
            u = u - (0.5 * (lo + hi) - mid)
    out = (hi - lo - obs_w) / sig
    if prob.width_sd:
        out = np.r_[out, _width_prior(radius, tracks, prob.width_sd)[0]]
    return rays, out, radius


def width_tracks(prob) -> tuple[np.ndarray, np.ndarray]:
    """(tracks with people-as-box widths, one observation index of each): the rows of the
    shared-width prior's residuals, in the order :func:`anchored` returns them."""
    j = prob.obs.idx[prob.width_idx]
    tracks, first = np.unique(j, return_index=True)
    return tracks, prob.width_idx[first]


def _width_prior(radius: np.ndarray, tracks: np.ndarray, sd: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(residuals, their derivatives in the radius) of the tracks' ring radii about their
    median, in log units over ``sd``."""
    r = np.maximum(radius[tracks], 1e-6)
    z = (np.log(r) - np.median(np.log(r))) / sd
    return z, 1.0 / (r * sd)


def width_spread(prob, n, theta, s, inl, floor: float) -> float:
    """The spread (log sd) of the inlier tracks' ring radii about their median (1.4826 MAD),
    between ``floor`` and :data:`WIDTH_SD`: people of one class alike in width have a tight prior,
    walkers seen from their side and from their front a loose one."""
    tracks = width_tracks(prob)[0]
    tracks = tracks[inl[tracks]]
    if len(tracks) < 5 or not prob.width_sd:
        return prob.width_sd
    r = np.log(np.maximum(_people_widths(prob, n, theta, s, None)[2][tracks], 1e-6))
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return float(np.clip(mad, floor, WIDTH_SD))


def _ring_start(prob, n, rays, sk, obs_w, j) -> np.ndarray:
    """(J,) per track the median radius (units of d) of a ring at :data:`WIDTH_AT` of the height
    whose projection is as wide as the observed box: ``w Z / (2 fx)``, Z the ring centre's
    depth. The hull's width does not move with the ring while the foot or head disk is wider, so
    a start below them would leave those disks to explain the widths."""
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = rays[:, 2] / nr - WIDTH_AT * sk * n[2]
        r = obs_w * z / (2.0 * prob.K[0, 0])
    ok = np.isfinite(r) & (r > 0)
    return np.clip(track_medians(r[ok], j[ok], prob.J, 0.02), 0.0, 0.2)


def wide_start(prob) -> np.ndarray | None:
    """A second start for the extents where people are seen as boxes (None otherwise): their
    foot and head disks as wide as the boxes (half the median width over the height). From the
    prior's narrow head alone the fit of a wide body (a 0.3 m cylinder seen at 46 deg) stayed in a
    valley 2 deg off, the shoulder ring standing in for the head: its cost is far above the true
    plane's, so the lower cost of the two fits decides."""
    k = prob.width_idx
    if len(k) < 3 or 0 not in prob.slices:
        return None
    w = (prob.obs.right[k] - prob.obs.left[k]) / np.maximum(prob.obs.h[k], 1e-9)
    e = float(np.clip(0.5 * np.median(w), 0.0, 0.3))
    theta = prob.prior_theta().copy()
    sl = prob.slices[0]
    theta[sl.start - 2:sl.stop - 2] = e
    return theta
