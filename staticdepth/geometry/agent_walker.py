"""Walkers in the joint ground-plane fit: one-foot frames and the residual scale of a gait.

A walker is not rigid. Two of its effects bias the plane if the fit treats it as a rigid disk
(:mod:`staticdepth.geometry.agent_plane_joint`), both measured on the ellipsoid walkers of
``tests/plane_generators.py`` (legs swinging +-20 degrees, 20 cameras):

- *One-foot frames.* Where the mask shows both feet apart, the foot point is their mean
  (:func:`staticdepth.tracking.walker_foot`, ``feet`` = 2): 0.05 m from the body's axis towards
  the camera, a foot's size. Where they overlap in the image (the stride along the line of
  sight, 23-44% of the frames, more on steep cameras) the mask's lowest point is the nearer foot,
  half a stride nearer: 0.22-0.28 m towards the camera on average, +-0.2 m with the stride's
  phase. One foot extent for both kinds of frame makes the plane's pitch take the difference (up
  to 2.9 degrees on a camera 11.5 m high at 48 degrees). The one-foot frames get an extent of
  their own, ``e_f + e_1`` (a share of the height, :data:`ONE_FOOT_PRIOR`), fitted where a class
  group has at least :data:`MIN_ONE_FOOT` frames of each kind; rigid bodies never show two feet,
  so their fit is unchanged. Where a track's frames are numbered (``frame``), the one-foot frames
  between two of its two-foot frames take the interpolated foot instead
  (:func:`interpolate_one_foot`, before the fit), those outside them are left out: the stride's
  phase spreads the nearer foot over 0-0.17 of the height, far walkers' feet merge in the mask
  more often, so one extent leaves a distance-dependent bias (20 ellipsoid cameras, seeds 0-19:
  0.21 / 0.71 degrees median / max and camera height 1.3 / 4.4% against 0.22 / 1.29 and 1.6 /
  5.1% with the extent alone; seeds 20-39: 0.43 / 1.41 and 1.4 / 4.7% against 0.42 / 1.64 and
  2.1 / 3.8%: the maximum above 1 degree is not solved). The frames still one-foot get a kappa
  of their own (:func:`relative_noise_split`).
- *Residual scale.* A walker bobs by up to 3% of its height (its legs' swing lowers the hip) and
  its foot point moves with the stride: a near walker's residuals are larger in pixels. With 1 px
  residual scales, the inlier rules and the robust loss cut a near walker's extreme frames and
  keep a far one's, a bias that grows with the size in the image, i.e. a pitch bias (2.5 degrees
  on a camera 3.4 m high at 43 degrees with the true foot points; 0.5 without the bobbing). The
  people's residuals are scaled by ``sqrt(1 + (kappa h)^2)`` (h: pixel height), kappa estimated
  from the residuals (:func:`relative_noise`; 0.01-0.04 for the walkers) where the masks show a
  gait (the one-foot extent's condition); rigid bodies keep 1 px.
"""
from __future__ import annotations

import numpy as np
from scipy.special import erf

MIN_ONE_FOOT = 5               # one- and two-foot frames a group needs for the one-foot extent
ONE_FOOT_PRIOR = (0.08, 0.08)  # its prior mean and sd (share of the height; half a stride ~0.1)
ONE_FOOT_BOUNDS = (0.0, 0.3)
KAPPA_GRID = np.r_[0.0, np.geomspace(1e-3, 0.1, 81)]


def relative_noise(r: np.ndarray, h: np.ndarray, trim_px: float = 3.0,
                   trim: float = 0.1) -> float:
    """kappa of the residual scale ``sqrt(1 + (kappa h)^2)`` px: the maximum likelihood over
    :data:`KAPPA_GRID` of the residuals ``r`` (pixels) of agents ``h`` pixels tall, Gaussian and
    truncated at ``T = trim_px + trim h``: residuals beyond T are left out (an occluded foot or a
    cut head moves a point by 15-50% of h, which would read as relative noise) and the
    likelihood accounts for the cut. The base is the fit's own 1 px (a rigid body's residuals,
    about 1.4 px with 1 px noise on the foot and on the top, give kappa 0.002-0.009). 0 with
    fewer than 10 residuals."""
    r, h = np.asarray(r, np.float64), np.asarray(h, np.float64)
    T = trim_px + trim * h
    ok = np.abs(np.nan_to_num(r, nan=np.inf)) <= T
    r, h, T = r[ok], h[ok], T[ok]
    if len(r) < 10:
        return 0.0
    var = 1.0 + (KAPPA_GRID[:, None] * h[None]) ** 2
    nll = (0.5 * np.log(var) + 0.5 * r[None] ** 2 / var
           + np.log(np.maximum(erf(T[None] / np.sqrt(2 * var)), 1e-300))).sum(1)
    return float(KAPPA_GRID[int(np.argmin(nll))])


def relative_noise_split(r: np.ndarray, h: np.ndarray, one: np.ndarray) -> tuple[float, float]:
    """(kappa of the two-foot frames, kappa of the one-foot frames): :func:`relative_noise` on
    each kind of frame apart. A one-foot frame's foot is the nearer foot, ahead of the axis by
    0-0.17 of the height with the stride's phase: the extent ``e_1`` takes the mean, the phase
    leaves a spread of 3-6% of the height (ellipsoid walkers), which the one-foot frames' own
    kappa weighs down. The one-foot kappa is never below the two-foot one; with fewer than 10
    one-foot residuals it is the two-foot one."""
    one = np.asarray(one, bool)
    k2 = relative_noise(r[~one], h[~one])
    k1 = relative_noise(r[one], h[one]) if np.count_nonzero(one) >= 10 else k2
    return k2, max(k1, k2)


def residual_scale(kappa, h: np.ndarray, people: np.ndarray, one: np.ndarray) -> np.ndarray:
    """(N,) residual scale in pixels, ``sqrt(1 + (kappa h)^2)`` for people (1 px for rigid
    bodies); ``kappa`` one value, or (two-foot, one-foot) values for the two kinds of frame."""
    k2, k1 = (kappa, kappa) if np.isscalar(kappa) else kappa
    k = np.where(one, k1, k2) * people
    return np.sqrt(1.0 + (k * h) ** 2)


INTERPOLATED = 3    # ``feet`` of a one-foot frame whose foot point was interpolated
MIN_TWO_FOOT_SHARE = 1 / 3   # a track's two-foot frames needed to interpolate its one-foot ones
MAX_GAP = 2         # frame numbers between the two-foot frames a foot is interpolated between
#                     (the sequence's own numbering; the generator's walkers advance a fifth
#                     of a gait cycle per frame)


def interpolate_one_foot(obs: np.ndarray) -> np.ndarray:
    """The observation table with each walker's one-foot frames (``feet`` 1) that lie between
    two of its track's two-foot frames (``feet`` 2) given the foot point interpolated linearly
    in the frame number between its two-foot neighbours (``height_px`` moved with the foot row,
    the top kept) and ``feet`` :data:`INTERPOLATED`, where those are at most :data:`MAX_GAP`
    frame numbers apart; its other one-foot frames (before the first or after the last two-foot
    frame, or in a longer gap) are left out (a turning walker's foot drifts from the line:
    extrapolated, 0.47 / 3.05 degrees median / max on the 20 cameras; interpolated across gaps
    up to 4 frames, 0.31 / 1.76; up to 2, 0.21 / 0.71, and 0.43 / 1.41 against 0.40 / 1.87 on
    20 other cameras, seeds 20-39). Only tracks whose masks show the gait, at least two
    two-foot frames and :data:`MIN_TWO_FOOT_SHARE` of their frames, are changed; the others
    keep their one-foot frames (the extent ``e_1``): on the real vtest.avi's rough YOLOX masks
    7% of the frames show two feet, and interpolating between those, leaving the rest out,
    moved a half's roll by 6 degrees. The interpolation is linear in the image (the
    perspective-correct one, depths ~ 1 / pixel height, measured 0.23 / 0.77 against 0.21 /
    0.71 on the 20 cameras: the gaps are short). A two-foot frame's foot is the body's axis (both
    feet's mean); a one-foot frame's is the nearer foot, 0-0.17 of the height ahead with
    the stride's phase, an offset that no one extent describes (far walkers' feet merge in the
    mask more often than near ones', so the one-foot frames' mean offset varies with distance:
    a pitch bias). A table without ``frame`` and ``feet`` columns is returned as it is."""
    names = obs.dtype.names or ()
    if not {"frame", "feet", "track"} <= set(names) or not np.any(obs["feet"] == 1):
        return obs
    out = obs.copy()
    feet, frame, track = out["feet"], out["frame"].astype(np.float64), out["track"]
    drop = np.zeros(len(out), bool)
    for t in np.unique(track[feet == 1]):
        rows = np.flatnonzero(track == t)
        two, one = rows[feet[rows] == 2], rows[feet[rows] == 1]
        if len(two) < max(2, MIN_TWO_FOOT_SHARE * len(rows)):
            continue
        two = two[np.argsort(frame[two], kind="stable")]
        f2 = frame[two]
        k = np.searchsorted(f2, frame[one])
        inside = (k > 0) & (k < len(f2))
        inside[inside] = (f2[k[inside]] - f2[k[inside] - 1]) <= MAX_GAP
        drop[one[~inside]] = True
        one = one[inside]
        top = out["foot_v"][one] - out["height_px"][one]
        for c in ("foot_u", "foot_v"):
            out[c][one] = np.interp(frame[one], f2, out[c][two].astype(np.float64))
        out["height_px"][one] = out["foot_v"][one] - top
        out["feet"][one] = INTERPOLATED
    return out[~drop]

