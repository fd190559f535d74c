"""The walker test on boxes (issue 13; staticdepth/geometry/agent_gait.py), on closed-form box
tracks: a rigid body's box (width and height f W / Z, f H / Z at a depth Z(t) that changes
smoothly as it walks past the camera) against a walker's, whose width opens and closes with its
legs by a known amount, each side and row jittered by U(-2, 2) px as the generators' boxes are."""
from __future__ import annotations

import math

import numpy as np

from staticdepth.geometry.agent_gait import (BOX_JITTER_PX, RIGID_BELOW, WALKER_ABOVE, box_gait,
                                             gait_ratio)

F = 700.0


def _tracks(rng, n_tracks=8, frames=9, spread_m=0.0, gait=1.3, jitter=BOX_JITTER_PX,
            width_m=0.45, height_m=1.7):
    """(idx, width, height) of ``n_tracks`` tracks walking past the camera at 0.7 m a frame
    (depth 4-12 m, sideways offset -4..4 m), a box of ``width_m`` plus ``spread_m`` x |sin| of
    the leg phase (``gait`` radians a frame) by ``height_m``, each side jittered."""
    idx, w, h = [], [], []
    for j in range(n_tracks):
        z0, x0 = rng.uniform(4, 12), rng.uniform(-4, 4)
        head, phase = rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi)
        for t in range(frames):
            x, z = x0 + 0.7 * t * math.cos(head), z0 + 0.7 * t * math.sin(head)
            z = max(z, 2.0)
            wm = width_m + spread_m * abs(math.sin(phase + gait * t))
            e = rng.uniform(-jitter, jitter, 4)
            idx.append(j)
            w.append(F * wm / z + e[0] - e[1])
            h.append(F * height_m / z + e[2] - e[3])
    return np.array(idx), np.array(w), np.array(h)


def test_jitter_alone_is_about_one():
    """A box of constant size, only the +-2 px jitter: the statistic is the jitter's own scale,
    1 within sampling (200 tracks of 9 frames: 1.00 +- 0.1), so rigid."""
    rng = np.random.default_rng(0)
    idx = np.repeat(np.arange(200), 9)
    e = rng.uniform(-2, 2, (4, len(idx)))
    w, h = 40.0 + e[0] - e[1], 100.0 + e[2] - e[3]
    g, used = gait_ratio(idx, w, h)
    assert used == 200 and abs(g - 1.0) < 0.1, g
    assert box_gait(idx, w, h) == "rigid"


def test_rigid_box_moving_past_the_camera_is_rigid():
    """Rigid bodies (a 0.45 m and a 0.6 m wide box, and the thin axis: width only jitter), 60
    tracks of 12 frames walking past the camera: their boxes change size smoothly with depth,
    which the ratio and the second differences take out; rigid. Over 200 draws the statistic is
    1.06-1.07 median (the larger of two lags' medians sits above 1), 1.17-1.20 at the 99th
    percentile; with the generators' 24 tracks of 9 frames 1.08-1.10 median, 1.28 at the 95th:
    about one rigid class in ten is left unknown there (no tie: the fit as without the test)."""
    for seed in range(5):
        for width in (0.0, 0.45, 0.6):
            rng = np.random.default_rng(seed)
            idx, w, h = _tracks(rng, n_tracks=60, frames=12, width_m=width)
            g, _ = gait_ratio(idx, np.abs(w), h)
            assert g < RIGID_BELOW and box_gait(idx, np.abs(w), h) == "rigid", (seed, width, g)


def test_walkers_swinging_legs_are_walkers():
    """Legs opening 0.4 m (the box 0.45 -> 0.85 m wide, 24-48 px at 10 m against 2 px jitter),
    at the generators' gait (a step every 2.4 frames) and at slower ones (0.9 and 0.5 rad a
    frame: 3.5 and 6.3 frames a step): walkers, far above the jitter."""
    for gait in (1.3, 0.9, 0.5):
        rng = np.random.default_rng(1)
        idx, w, h = _tracks(rng, spread_m=0.4, gait=gait, frames=10)
        g, _ = gait_ratio(idx, w, h)
        assert g > WALKER_ABOVE and box_gait(idx, w, h) == "walker", (gait, g)


def test_noisier_boxes_than_assumed_are_not_rigid():
    """Boxes jittered by +-4 px (twice the assumed): the statistic about 2, never rigid (a
    detector noisier than assumed must not pass as rigid bodies)."""
    rng = np.random.default_rng(2)
    idx, w, h = _tracks(rng, jitter=4.0, n_tracks=12)
    g, _ = gait_ratio(idx, w, h)
    assert g > 1.6 and box_gait(idx, w, h) != "rigid", g


def test_short_tracks_and_few_tracks_are_unknown():
    """Tracks of 4 frames (no second differences to pool), or 2 tracks (one direction of walking
    cannot tell): unknown."""
    rng = np.random.default_rng(3)
    idx, w, h = _tracks(rng, frames=4)
    assert box_gait(idx, w, h) == "unknown" and math.isnan(gait_ratio(idx, w, h)[0])
    idx, w, h = _tracks(rng, n_tracks=2, spread_m=0.4)
    assert box_gait(idx, w, h) == "unknown"
