"""A walker's foot point from its mask (tracking.walker_foot) and the generators' imitation of it.

The generators of tests/plane_generators.py do not import the library; they take the foot point
from the bottom profile of their bodies' convex pieces the way tracking takes it from a mask. This
checks both against closed-form masks and against each other on rasterised generator bodies.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import ConvexHull

import plane_generators as G
from staticdepth.tracking import detections_from_instances, walker_foot


def _pixels(m):
    v, u = np.nonzero(m)
    return u, v


def test_two_feet_give_their_mean_and_one_blob_its_lowest_point():
    m = np.zeros((80, 60), bool)
    m[5:30, 12:25] = True                     # torso
    m[30:61, 12:16] = True                    # near leg: lowest row 60, columns 12..15
    m[30:53, 21:25] = True                    # far leg: lowest row 52, columns 21..24
    assert walker_foot(*_pixels(m)) == (18.0, 56.0, 2)      # ((13.5 + 22.5) / 2, (60 + 52) / 2)
    m[53:61, 16:21] = True                    # feet joined: one convex bottom, one peak
    assert walker_foot(*_pixels(m)) == (16.0, 60.0, 1)
    far = np.zeros_like(m)
    far[5:30, 12:25] = far[30:61, 12:16] = far[30:35, 21:25] = True   # other foot lifted high
    assert walker_foot(*_pixels(far)) == (13.5, 60.0, 1)    # beyond FOOT_BAND: lowest foot only


def test_person_detection_uses_the_walker_foot_and_other_classes_the_lowest_point():
    m = np.zeros((80, 60), np.uint16)
    m[5:30, 12:25] = 3
    m[30:61, 12:16] = 3
    m[30:53, 21:25] = 3
    d = detections_from_instances(m, np.array([[3, 0, 0.9]]))
    assert (d["foot_u"][0], d["foot_v"][0], d["feet"][0]) == (18.0, 56.0, 2)
    car = detections_from_instances(m, np.array([[3, 2, 0.9]]))
    assert (car["foot_u"][0], car["foot_v"][0], car["feet"][0]) == (13.5, 60.0, 0)


def _rasterise(pieces, shape):
    """Union of the convex hulls of projected pieces [(u, v)] sampled at pixel centres."""
    vv, uu = np.mgrid[:shape[0], :shape[1]]
    q = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1)
    m = np.zeros(uu.size, bool)
    for u, v in pieces:
        eq = ConvexHull(np.stack([u, v], 1)).equations
        m |= np.all(q @ eq.T <= 1e-9, axis=1)
    return m.reshape(shape)


def test_generator_foot_matches_tracking_on_the_rasterised_walker():
    """The ellipsoid walker at several stride phases, seen at 30 and 50 degrees: the generator's
    foot point (bottom profile of the hulls) and tracking's (pixels of the rasterised mask) agree
    within a pixel, and at wide strides both take the two feet's mean (not the lowest point)."""
    two = 0
    for pitch in (30.0, 50.0):
        t = math.radians(pitch)
        n = np.array([0.0, math.cos(t), math.sin(t)])
        e1 = np.cross(n, [1.0, 0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        K = np.array([[700.0, 0, 160], [0, 700.0, 100], [0, 0, 1]])
        pos = np.linalg.solve(K, [160.0, 200.0, 1.0])
        pos *= 6.0 / (pos @ n)
        for frame in range(5):
            fwd = math.cos(0.4) * e1 + math.sin(0.4) * e2
            side = np.cross(-n, fwd)
            pieces = []
            for P in G.parts("ellipsoid", 1.7, frame, 0.3):
                X = pos + P[:, :1] * fwd + P[:, 1:2] * side - P[:, 2:3] * n
                pieces.append(G._project(K, X))
            top = min(v.min() for _, v in pieces)
            bottom = max(v.max() for _, v in pieces)
            shape = (int(bottom) + 5, 320)
            u, v = (np.concatenate(x) for x in zip(*pieces))
            gen = G._walker_foot(u, v, *G._bottom_profile(pieces))
            trk = walker_foot(*_pixels(_rasterise(pieces, shape)))
            assert abs(gen[0] - trk[0]) <= 1.0 and abs(gen[1] - trk[1]) <= 1.0, (gen, trk)
            assert gen[2] == trk[2]
            two += (gen[2] == 2) and gen[1] < bottom - 1.0
    assert two >= 3
