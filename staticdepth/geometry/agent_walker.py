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
  so their fit is unchanged.
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
