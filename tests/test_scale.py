"""Metric scale from the camera height (METHOD.md section 5)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.scale import (anchor_depth, anchor_depth_parallel, anchor_pixel,
                                        scale_from_anchor, temporal_scale)
from test_agent_plane import camera_K, people_observations, true_normal


def true_anchor_depth(K, pitch_deg, cam_height, u, v):
    """Intersect the anchor ray with the ground in world coordinates (independent of the library):
    rotate the camera ray by the pitch into a level frame, where the ground is Y = cam_height."""
    t = math.radians(pitch_deg)
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    y_level = y * math.cos(t) + math.sin(t)          # level-frame Y of the ray r = (x, y, 1)
    return cam_height / y_level                      # camera-frame Z of the hit (r_z = 1)


@pytest.mark.parametrize("pitch,height", [(10.0, 3.0), (30.0, 5.5), (45.0, 8.0)])
def test_anchor_depth_from_agents_plane_within_3_percent(pitch, height):
    rng = np.random.default_rng(int(pitch) + 11)
    K, w, h = camera_K(400.0)                        # CARLA's 90 degree field of view at 800 px
    n = true_normal(pitch, 0.0)
    plane = fit_agent_plane(K, people_observations(rng, K, w, h, n, height),
                            AgentPlaneConfig(bootstrap=0))
    u, v = anchor_pixel(w, h)
    truth = true_anchor_depth(K, pitch, height, u, v)
    assert anchor_depth(K, n, height, u, v) == pytest.approx(truth, rel=1e-12)
    est = anchor_depth(K, plane.normal, height, u, v)
    parallel = anchor_depth_parallel(K, height, v)
    print(f"pitch {pitch}: anchor {est:.3f} m, truth {truth:.3f} m, parallel {parallel:.3f} m")
    assert abs(est / truth - 1) < 0.03
    if pitch >= 30:
        assert abs(parallel / truth - 1) > 0.30


def test_level_camera_anchor_equals_the_parallel_baseline():
    K, w, h = camera_K(400.0)
    u, v = anchor_pixel(w, h)
    assert (u, v) == (400.0, 399.0)
    assert anchor_depth(K, [0, 1.0, 0], 5.0, u, v) == pytest.approx(
        anchor_depth_parallel(K, 5.0, v), rel=1e-12)
    assert anchor_depth_parallel(K, 5.0, v) == pytest.approx(400 * 5.0 / 199.5)


def test_scale_from_anchor_patch_skip_and_temporal_median():
    K, w, h = camera_K(400.0, 80, 40)
    n = true_normal(20.0)
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    r = np.stack([(u - K[0, 2]) / 400, (v - K[1, 2]) / 400, np.ones_like(u)], -1)
    truth = (4.0 / (r @ n)).astype(np.float32)
    pred = truth / 7.0
    pred[-1, 40] = 1e3                               # one bad pixel: the patch median ignores it
    a = scale_from_anchor(pred, K, n, 4.0)
    assert a.scale == pytest.approx(7.0, rel=1e-3) and a.skipped is None
    agents = np.zeros((h, w), bool)
    agents[-3:, 38:41] = True
    b = scale_from_anchor(pred, K, n, 4.0, agent_mask=agents)
    assert math.isnan(b.scale) and "agent" in b.skipped
    c = scale_from_anchor(np.full_like(pred, np.nan), K, n, 4.0)
    assert math.isnan(c.scale) and "no valid depth" in c.skipped
    assert temporal_scale([a, b, 6.0, 8.0, 7.5]) == pytest.approx(7.25, rel=1e-3)
    with pytest.raises(InputError, match="no frame gave a scale"):
        temporal_scale([b, c])


def test_scale_errors():
    K, w, h = camera_K(400.0)
    with pytest.raises(InputError, match="above the ground's horizon"):
        anchor_depth(K, true_normal(20.0), 5.0, 400, 0)
    with pytest.raises(InputError, match=r"camera height must be a height in metres in \(0, 1"):
        anchor_depth(K, true_normal(20.0), 0.0, 400, 399)
    with pytest.raises(InputError, match=r"camera height must be a height in metres in \(0, 1"):
        anchor_depth_parallel(K, -1.0, 399)
    with pytest.raises(InputError, match="not below the principal point"):
        anchor_depth_parallel(K, 5.0, 100)
