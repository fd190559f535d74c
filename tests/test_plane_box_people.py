"""People seen as boxes (issue 13): no top column, the box's sides give each observation's width.

The width is the hull of the foot disk, the head disk and a shoulder ring
(:func:`staticdepth.geometry.agent_shape.person_columns`, each circle's extreme columns in closed
form); the fits below are on the independent generators of ``tests/plane_generators.py`` (boxes
with +-2 px jitter), bounded against their true planes and the anchor depth from the true camera
height (:func:`staticdepth.geometry.scale.anchor_depth`)."""
from __future__ import annotations

import math

import numpy as np

from plane_generators import H, W, scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_shape import _ground_basis, person_columns
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import angle_between_deg
from staticdepth.geometry.scale import anchor_depth, anchor_pixel

FAST = AgentPlaneConfig(bootstrap=0, column_weight=1.0)


def _dense_columns(K, n, F, s, radii, heights, k=20000):
    """Extreme columns of circles (centres F - h s n, the given radii) by projecting k points
    each: the brute-force truth for the closed form."""
    e1, e2 = _ground_basis(n)
    a = np.linspace(0, 2 * math.pi, k, endpoint=False)
    lo, hi = np.inf, -np.inf
    for r, h in zip(radii, heights):
        P = F - h * s * n + r * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
        u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]
        lo, hi = min(lo, u.min()), max(hi, u.max())
    return lo, hi


def test_person_columns_are_the_circles_extreme_columns():
    """Thin (no disks), wide foot, wide head, ring-dominated bodies off the image centre, the
    camera pitched 35 deg and rolled 4: the closed form's left and right columns within 0.01 px
    of 20000 projected points per circle (measured up to 0.003 px: the library places a wide
    foot disk by 3 fixed-point steps, the truth by 30)."""
    K = np.array([[700.0, 0, 479.5], [0, 700.0, 269.5], [0, 0, 1]])
    n = normal_from_pitch_roll(35.0, 4.0)
    rays = np.array([[-0.5, 0.3, 1.0], [0.4, 0.45, 1.0], [0.05, 0.6, 1.0], [0.6, 0.2, 1.0]])
    s = np.array([0.3, 0.25, 0.4, 0.2])
    for e_f, e_h, ring in ((0.0, 0.0, 0.0), (0.2, 0.05, 0.01), (0.03, 0.2, 0.02),
                           (0.03, 0.03, 0.06)):
        lo, hi = person_columns(K, n, rays, s, e_f, e_h, np.full(4, ring))
        sc = s
        for i in range(4):
            F = rays[i] / (rays[i] @ n)
            A = _foot_centre(K, n, F, e_f * sc[i])
            want = _dense_columns(K, n, A, s[i], (e_f * sc[i], e_h * sc[i], ring),
                                  (0.0, 1.0, 0.75))
            assert abs(lo[i] - want[0]) < 0.01 and abs(hi[i] - want[1]) < 0.01, (i, lo[i], hi[i],
                                                                                  want)


def _foot_centre(K, n, F, rho, k=20000):
    """The centre A of a horizontal circle of radius rho whose lowest image point is F, by
    fixed-point iteration on densely sampled circles."""
    e1, e2 = _ground_basis(n)
    a = np.linspace(0, 2 * math.pi, k, endpoint=False)
    A = F.copy()
    for _ in range(30):
        P = A + rho * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
        low = P[np.argmax(P[:, 1] / P[:, 2])]
        A = A + (F - low)
    return A


def _fit_errors(kind: str, seed: int) -> tuple[float, float]:
    """(normal error deg, anchor depth error % from the true camera height) of the joint fit of
    one generator camera's boxes."""
    s = scene(kind, seed, detection="box")
    assert np.all(np.isnan(s.obs["top_u"])) and np.all(s.obs["right"] > s.obs["left"])
    p = fit_agent_plane(s.K, s.obs, FAST)
    u, v = anchor_pixel(W, H)
    a = anchor_depth(s.K, p.normal, s.height_m, u, v)
    truth = anchor_depth(s.K, s.normal, s.height_m, u, v)
    return angle_between_deg(p.normal, s.normal), abs(a / truth - 1) * 100


def test_tapered_people_as_boxes():
    """The tapered body (widest at 0.4 of its height, not at the shoulder ring's 0.75) on the
    camera that was its worst of 8 (3: 1.56 deg when the ring started inside the foot disk, which
    then stood in for it; measured 0.54 deg now, anchor 0.11%): within 0.6 deg, anchor within
    0.5%."""
    err, anchor = _fit_errors("tapered", 3)
    assert err < 0.6 and anchor < 0.5, (err, anchor)


def test_the_fit_does_not_jump_between_minima_under_tiny_moves():
    """The robust cost has shallow local minima: before the fit's restarts
    (agent_plane_joint._restarts) moving every foot 1e-9 px took this camera from 0.69 to 1.40
    deg. The normal must be a continuous function of the
    observations: moves of 1e-9 to 1e-4 px change it by less than 0.02 deg."""
    s = scene("tapered", 3, detection="box")
    normals = []
    for eps in (0.0, 1e-9, 1e-6, 1e-4):
        obs = s.obs.copy()
        obs["foot_v"] = obs["foot_v"] + eps
        normals.append(fit_agent_plane(s.K, obs, FAST).normal)
    for n in normals[1:]:
        assert angle_between_deg(n, normals[0]) < 0.02


def test_wide_cylinders_as_boxes():
    """0.3 m cylinders seen at 46 deg (camera 7: 2.10 deg with 16-gon columns and the narrow
    start only, measured 0.34 deg now, anchor 0.13%): the closed-form columns and the wide start
    put it within 0.6 deg, the anchor within 0.5%."""
    err, anchor = _fit_errors("cylinder", 7)
    assert err < 0.6 and anchor < 0.5, (err, anchor)


def test_far_small_people_as_boxes():
    """Tapered people far and small (camera 9: 10 m high at 21.5 deg, 30-90 px tall, +-2 px
    boxes): the ring radii's spread estimated from the tracks (one body width: the floor,
    0.053) ties their depths together; measured 0.84 deg, anchor 1.38% (1.37 deg, 1.99% with the
    fixed spread 0.15): within 1 deg, anchor within 1.6%."""
    err, anchor = _fit_errors("tapered", 9)
    assert err < 1.0 and anchor < 1.6, (err, anchor)
