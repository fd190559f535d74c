"""Disparity post-filters (pure numpy/OpenCV): edge trimming, hole filling from the background.

Conventions: disparity maps are float32 (H, W) in pixels, NaN = invalid; larger disparity = nearer.
"""
from __future__ import annotations

import numpy as np
import cv2
from scipy import ndimage


def trim_foreground_edges(disparity: np.ndarray, radius_px: int, jump_px: float = 2.0,
                          copy: bool = True) -> np.ndarray:
    """Invalidate pixels within ``radius_px`` (along the row) of a neighbour ``jump_px`` farther.

    Block matching and SGM smear the foreground's disparity over the background beside it
    ("foreground fattening"); those wrong pixels carry the foreground's disparity and sit next to
    the true background, so removing foreground pixels that have a much smaller disparity nearby
    removes them (at the cost of ``radius_px`` true pixels along each depth edge). With
    ``copy=False`` a float32 input is modified in place (and returned).
    """
    d = np.asarray(disparity, dtype=np.float32)
    if radius_px <= 0:
        return d.copy()
    far = np.where(np.isnan(d), np.float32(np.inf), d)
    nearest_far = cv2.erode(far, np.ones((1, 2 * radius_px + 1), np.uint8),
                            borderType=cv2.BORDER_REPLICATE)
    out = d.copy() if copy or d is not disparity else d
    out[d - nearest_far > jump_px] = np.nan
    return out


def lr_consistent(disp_left: np.ndarray, disp_right: np.ndarray, tol_px: float) -> np.ndarray:
    """True where the right view's disparity at ``u - d`` agrees with ``d`` within ``tol_px``.

    Both maps (H, W) hold positive disparities in their own view (NaN = invalid): a left pixel u
    with disparity d sees right pixel round(u - d), whose disparity should again be d.
    """
    h, w = disp_left.shape
    u = np.arange(w, dtype=np.float32)[None, :]
    ur = np.round(u - np.nan_to_num(disp_left, nan=-1e6)).astype(np.int64)
    inside = (ur >= 0) & (ur < w)
    dr = np.take_along_axis(disp_right, np.clip(ur, 0, w - 1), axis=1)
    return inside & (np.abs(dr - disp_left) <= tol_px)


def _forward_fill(d: np.ndarray) -> np.ndarray:
    """Each NaN takes the last valid value to its left in its row (NaN where there is none)."""
    h, w = d.shape
    valid = ~np.isnan(d)
    idx = np.where(valid, np.arange(w)[None, :], -1)
    idx = np.maximum.accumulate(idx, axis=1)
    out = np.take_along_axis(d, np.clip(idx, 0, None), axis=1)
    out[idx < 0] = np.nan
    return out


def fill_from_background(disparity: np.ndarray, median_rows: int = 21) -> np.ndarray:
    """A dense disparity map: holes take the background (smaller) of their row neighbours.

    Each invalid pixel gets ``min(nearest valid to the left, nearest valid to the right)`` in its
    row (holes in rectified stereo are occlusions beside a foreground object, so the farther side
    is the right guess); then the filled pixels (only those) are replaced by the median over
    ``median_rows`` rows of the filled map, which removes streaks copied from a single wrong
    neighbour. Rows without any valid pixel take the nearest filled row (the one below on a tie);
    an all-invalid map is 0. A disparity <= 0 (infinite depth: a match at the end of the search
    range, no depth at all) is a hole too, so every filled pixel has a positive disparity.
    Returns float32 (H, W) without NaN.
    """
    d = np.asarray(disparity, dtype=np.float32)
    holes = ~(d > 0)
    if not holes.any():
        return d.copy()
    if holes.all():
        return np.zeros_like(d)
    d = np.where(holes, np.float32(np.nan), d)
    left = _forward_fill(d)
    right = _forward_fill(d[:, ::-1])[:, ::-1]
    filled = np.where(holes, np.fmin(left, right), d)
    empty_rows = np.isnan(filled).any(axis=1)
    if empty_rows.any():
        rows = np.flatnonzero(~empty_rows)
        nearest = rows[np.clip(np.searchsorted(rows, np.arange(len(d))), 0, len(rows) - 1)]
        below = rows[np.clip(np.searchsorted(rows, np.arange(len(d))) - 1, 0, len(rows) - 1)]
        pick = np.where(np.abs(nearest - np.arange(len(d))) <= np.abs(below - np.arange(len(d))),
                        nearest, below)
        filled[empty_rows] = filled[pick[empty_rows]]
    if median_rows > 1:
        smooth = ndimage.median_filter(filled, size=(median_rows, 1), mode="nearest")
        filled = np.where(holes, smooth, filled)
    return filled.astype(np.float32, copy=False)
