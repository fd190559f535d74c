"""Is a boxed person a walker or a rigid body? A test on the boxes alone, before any plane fit.

A walker's box is as wide as its open legs: seen from the side its width opens and closes with
every step (the ellipsoid walkers of ``tests/plane_generators.py``: 0.3-0.7 m at 1.7 m), while a
rigid body's width changes only slowly, with its distance and viewing angle. Its height moves
with the same distance but hardly with the gait (the head bobs by a few per cent). So per track
both series are detrended by a straight line in time, which takes the slow change, and what is
left of the width is compared with what is left of the height: the ratio is scale free (both in
the track's pixels) and needs no jitter level (the height's residual is the detector's own
jitter, whatever its size). Pooled over the tracks of a class with medians (a cut top or an
occluded foot moves a few rows' height, not the median).

Why the class, not the track: a walker seen head-on swings its legs along the ray and its box
width hardly changes, so a single track cannot tell; a class of people walking in several
directions can. The verdict gates the head tie of people seen as boxes
(:data:`staticdepth.geometry.agent_plane_problem.HEAD_TIE_SD`): a walker's box bottom is its
front foot, so its foot extent holds the stride and must not carry the head.
"""
from __future__ import annotations

import numpy as np

MIN_FRAMES = 5       # a track's residuals need a few frames beyond its straight line
MIN_TRACKS = 3       # a class verdict needs a few tracks (walking in several directions)
# pooled width / height residual ratio: rigid below RIGID_BELOW, walkers above WALKER_ABOVE,
# unknown between (chosen on the generators' seeds 0-19, benchmarks/bench_agent_gait.py)
RIGID_BELOW = 1.6
WALKER_ABOVE = 1.6


def detrended(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Residuals of ``y`` after a least-squares parabola in ``t``."""
    A = np.vander(t - t.mean(), 3)
    return y - A @ np.linalg.lstsq(A, y, rcond=None)[0]


def gait_residuals(idx: np.ndarray, width: np.ndarray, height: np.ndarray,
                   time: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Per row of the tracks with at least :data:`MIN_FRAMES` finite boxes, the width's and the
    height's residual after each track's straight line in time, over the track's median height.

    idx: (N,) track index per row; width, height: (N,) box sides in pixels; time: (N,) frame
    numbers (default: the rows' order within the track). Also the number of tracks used."""
    idx, width, height = np.asarray(idx), np.asarray(width, float), np.asarray(height, float)
    ok = np.isfinite(width) & np.isfinite(height) & (height > 0)
    rw, rh = [], []
    for j in np.unique(idx[ok]):
        sel = np.flatnonzero(ok & (idx == j))
        if len(sel) < MIN_FRAMES:
            continue
        t = np.arange(len(sel), dtype=float) if time is None else np.asarray(time, float)[sel]
        scale = np.median(height[sel])
        rw.append(detrended(t, width[sel] / height[sel]))
        rh.append(detrended(t, height[sel] / scale))
    if not rw:
        return np.zeros(0), np.zeros(0), 0
    return np.concatenate(rw), np.concatenate(rh), len(rw)


def gait_ratio(idx, width, height, time=None) -> tuple[float, int]:
    """(median |width residual| / median |height residual| over the tracks' rows, tracks used);
    NaN when no track has :data:`MIN_FRAMES` boxes. About 1 for rigid bodies with equal jitter on
    rows and columns (below 1 for narrow ones), several for walkers seen from the side."""
    rw, rh, used = gait_residuals(idx, width, height, time)
    if not used:
        return float("nan"), 0
    den = np.median(np.abs(rh))
    return float(np.median(np.abs(rw)) / den) if den > 0 else float("inf"), used


def box_gait(idx, width, height, time=None) -> str:
    """``"rigid"``, ``"walker"`` or ``"unknown"`` (fewer than :data:`MIN_TRACKS` tracks of
    :data:`MIN_FRAMES` boxes, or a ratio between the two limits) for one class's boxes."""
    g, used = gait_ratio(idx, width, height, time)
    if used < MIN_TRACKS or not np.isfinite(g):
        return "unknown"
    if g < RIGID_BELOW:
        return "rigid"
    return "walker" if g > WALKER_ABOVE else "unknown"
