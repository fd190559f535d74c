"""Is a boxed person a walker or a rigid body? A test on the boxes alone, before any plane fit.

A walker's box is as wide as its open legs: seen from the side its width opens and closes with
every step (the ellipsoid walkers of ``tests/plane_generators.py``: 0.3-0.7 m at 1.7 m), while a
rigid body's width changes only slowly, with its distance and viewing angle. The width over the
height (free of the distance) is differenced twice in time, over one frame and over two (a step
every 2.4 frames, or a slower gait, e.g. a real walker at 10 frames a second), which takes the
slow change out and leaves the box jitter and the gait. Each difference is divided by the one a
box jittered by :data:`BOX_JITTER_PX` on every side would give at that size (scale free), and the
class's statistic is the larger of the two lags' pooled median over its expected median: about 1
for rigid bodies boxed at that jitter, above :data:`RIGID_BELOW` for walkers and for boxes noisier
than assumed, which must not count as rigid (YOLOX boxes of the real vtest.avi's pedestrians,
150-frame windows: 1.32-2.1 at 10 frames a second, 1.48 and up at every 2nd, 1.69 at every 4th).

Why the class, not the track: a walker seen head-on swings its legs along the ray and its box
width hardly changes, so one track cannot tell; a class of people walking in several directions
can. The verdict gates the head tie of people seen as boxes
(:data:`staticdepth.geometry.agent_plane_problem.HEAD_TIE_SD`): a walker's box bottom is its
front foot, so its foot extent holds the stride and must not carry the head.
Measured by ``benchmarks/bench_agent_gait.py`` (generators and vtest.avi).
"""
from __future__ import annotations

import numpy as np

BOX_JITTER_PX = 2.0  # each box side and row within +-this (uniform) of the silhouette's
MIN_FRAMES = 5       # a track's lag-1 second differences need a few frames (lag 2: 2 more)
MIN_TRACKS = 3       # a class verdict needs a few tracks (walking in several directions)
# the statistic: rigid below (under every real vtest.avi window, 1.32, and the generators'
# walkers at any gait, 1.45; on seeds 0-19 1.25 kept tapered's camera height max at 3.4%, 1.4 made
# it 4.3%), walkers above (the generators' walkers: 1.45-25)
RIGID_BELOW = 1.25
WALKER_ABOVE = 1.8
_MEDIAN_ABS = 0.6745  # median |z| of a unit normal


def gait_scores(idx: np.ndarray, width: np.ndarray, height: np.ndarray,
                lag: int = 1) -> tuple[np.ndarray, int]:
    """Per row of the tracks with :data:`MIN_FRAMES` + 2 (lag - 1) finite boxes, the lag-``lag``
    second difference of width / height in units of its standard deviation under the assumed box
    jitter alone, and the number of tracks used. idx, width, height: (N,) track index, box width
    and height in pixels, a track's rows in frame order (consecutive rows: consecutive frames)."""
    idx, width, height = np.asarray(idx), np.asarray(width, float), np.asarray(height, float)
    ok = np.isfinite(width) & np.isfinite(height) & (height > 0)
    k, z = lag, []
    for j in np.unique(idx[ok]):
        sel = np.flatnonzero(ok & (idx == j))
        if len(sel) < MIN_FRAMES + 2 * (k - 1):
            continue
        h = height[sel]
        r = width[sel] / h
        d2 = r[2 * k:] - 2 * r[k:-k] + r[:-2 * k]
        # w = right - left, each side U(-J, J): var(d2 w) = var(d2 h) = 6 * 2 J^2 / 3
        sd = 2.0 * BOX_JITTER_PX * np.sqrt(1.0 + r[k:-k] ** 2) / h[k:-k]
        z.append(d2 / sd)
    return (np.concatenate(z), len(z)) if z else (np.zeros(0), 0)


def gait_ratio(idx, width, height) -> tuple[float, int]:
    """(the larger of lags 1 and 2's median |score| over its value under jitter alone, tracks
    used at lag 1); NaN when no track has :data:`MIN_FRAMES` boxes."""
    z1, used = gait_scores(idx, width, height, 1)
    if not used:
        return float("nan"), 0
    z2, _ = gait_scores(idx, width, height, 2)
    g = [np.median(np.abs(z)) / _MEDIAN_ABS for z in (z1, z2) if len(z)]
    return float(max(g)), used


def box_gait(idx, width, height) -> str:
    """``"rigid"``, ``"walker"`` or ``"unknown"`` (fewer than :data:`MIN_TRACKS` tracks of
    :data:`MIN_FRAMES` boxes, or a statistic between the two limits) for one class's boxes."""
    g, used = gait_ratio(idx, width, height)
    if used < MIN_TRACKS or not np.isfinite(g):
        return "unknown"
    if g < RIGID_BELOW:
        return "rigid"
    return "walker" if g > WALKER_ABOVE else "unknown"
