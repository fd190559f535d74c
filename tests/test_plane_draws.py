"""bench_agent_plane.py --draws: fresh noise on a camera's noise-free observations (issue 13)."""
from __future__ import annotations

import os
import sys

import numpy as np

from plane_generators import scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.plane import angle_between_deg

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
from bench_agent_plane import draw_errors, fresh_draw, share_over  # noqa: E402


def test_fresh_draw_adds_the_generators_noise_and_keeps_the_rest():
    s0 = scene("thin", 3, noise_px=0.0)
    o = fresh_draw(s0.obs, 1.5, np.random.default_rng(0))
    names = ("foot_u", "foot_v", "top_u", "top_v", "left", "right")
    d = np.stack([o[name] - s0.obs[name] for name in names])     # (6, 161)
    assert abs(np.std(d) / 1.5 - 1) < 0.1 and abs(np.mean(d)) < 0.15
    assert np.all(np.std(d, axis=1) > 1.0)      # every column drawn
    assert abs(np.corrcoef(d)[np.triu_indices(6, 1)]).max() < 0.3    # each its own draw
    np.testing.assert_allclose(o["height_px"], o["foot_v"] - o["top_v"])
    for name in ("frame", "track", "class_id", "feet"):
        np.testing.assert_array_equal(o[name], s0.obs[name])
    # the same seed, the same scene: noise-free and noisy scenes share their geometry
    s1 = scene("thin", 3)
    assert np.abs(s1.obs["foot_v"] - s0.obs["foot_v"]).max() < 6
    np.testing.assert_array_equal(s1.obs["track"], s0.obs["track"])


def test_draws_without_noise_repeat_the_noise_free_fit():
    s0 = scene("tapered", 5, noise_px=0.0, n_tracks=12)
    conf = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    bias = angle_between_deg(fit_agent_plane(s0.K, s0.obs, conf).normal, s0.normal)
    e = draw_errors(s0.K, s0, conf, 2, 1e-9, 5)
    np.testing.assert_allclose(e, bias, atol=0.006)
    assert share_over(e) == (1.0 if bias > 1 else 0.0)
    assert share_over(np.array([0.5, np.nan, 1.5, 2.0])) == 2 / 3     # refusals left out
