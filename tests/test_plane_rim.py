"""The people's raised foot rim (issue 13): a body flaring above its sole shows, seen from above,
the flare's near edge as its lowest point, so the observed foot's offset from the axis grows with
the viewing angle. Truth: dense points on the two rims (closed-form geometry, independent of the
library's stationary-point formulas) and the independent generators of tests/plane_generators.py.
"""
from __future__ import annotations

import math

import numpy as np

from plane_generators import scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_shape import foot_centres
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import angle_between_deg


def _lowest_of_rims(n, A, s, e_f, delta, z):
    """The lowest image point (as a 3D point) of the two rims' 720 points each, per centre A."""
    up = -n
    e1 = np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    a = np.linspace(0, 2 * math.pi, 720, endpoint=False)
    circ = np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2
    out = []
    for c, sc in zip(A, s):
        P = np.r_[c + e_f * sc * circ, c + z * sc * up + (e_f + delta) * sc * circ]
        out.append(P[np.argmax(P[:, 1] / P[:, 2])])
    return np.array(out)


def test_foot_centres_recover_the_axis_under_either_rim():
    # camera 1 unit above the ground pitched 45 deg; agents near (steep: the raised rim is the
    # lowest point) and far (shallow: the sole is); s = 0.3 (1.7 m seen from 5.7 m)
    n = normal_from_pitch_roll(45.0, 2.0)
    rng = np.random.default_rng(0)
    e1 = np.cross(n, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    A = np.array([n + x * e1 + y * e2 for x, y in rng.uniform([-1, -1.5], [1, 4], (40, 2))])
    s = np.full(len(A), 0.3)
    e_f, delta, z = 0.025, 0.04, 0.05
    low = _lowest_of_rims(n, A, s, e_f, delta, z)
    rays = low / np.linalg.norm(low, axis=1)[:, None]
    got = foot_centres(n, rays, s, e_f, (delta, z))
    assert np.max(np.linalg.norm(got - A, axis=1)) < 2e-4      # 720-gon: ~1e-4 of the radius
    # both cases occur, and the sole-only model (no rim) misses the near ones by centimetres
    sole = foot_centres(n, rays, s, e_f)
    miss = np.linalg.norm(sole - A, axis=1)
    assert np.sum(miss > 1e-2) >= 20 and np.sum(miss < 2e-4) >= 3


def test_tapered_steep_camera_without_noise():
    # camera 8 (pitch 49.5 deg): 1.25 degrees with the sole disk alone (the flare's near rim is
    # the mask's lowest point), 0.18 with the raised rim; thin camera 15 keeps its exact plane
    conf = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    s = scene("tapered", 8, noise_px=0.0)
    p = fit_agent_plane(s.K, s.obs, conf)
    assert angle_between_deg(p.normal, s.normal) < 0.4
    rim = p.extra["extents"]["people"][2]
    assert 0.01 < rim < 0.06          # the flare: 4 cm sole, 10.7 cm at 5% of 1.72 m
    t = scene("thin", 15, noise_px=0.0)
    assert angle_between_deg(fit_agent_plane(t.K, t.obs, conf).normal, t.normal) < 0.05
