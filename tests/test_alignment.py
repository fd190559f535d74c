"""Scene alignment (METHOD.md section 4) on a synthetic scene with known geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from staticdepth.errors import InputError
from staticdepth.geometry.alignment import (align_depth, depth_from_inverse, fit_predicted_plane,
                                            ground_mask_from_feet)

W, H = 160, 80


def scene(pitch_deg: float = 30.0, cam_height: float = 5.0, f: float = 100.0):
    """True depth of a pitched camera over a ground plane, with a 2 m tall wall on it and sky.

    Returns K, n, true depth (H, W), ground mask (pixels that see the ground), wall mask.
    """
    K = np.array([[f, 0, W / 2 - 0.5], [0, f, H / 2 - 0.5], [0, 0, 1.0]])
    t = math.radians(pitch_deg)
    n = np.array([0.0, math.cos(t), math.sin(t)])
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    r = np.stack([(u - K[0, 2]) / f, (v - K[1, 2]) / f, np.ones_like(u)], -1)
    nr = r @ n
    with np.errstate(divide="ignore"):
        z_ground = np.where(nr > 1e-9, cam_height / nr, np.inf)
    # a wall facing the camera: the plane Z_world-forward = 12 m (distance along the ground)
    fwd = np.array([0.0, -math.sin(t), math.cos(t)])      # horizontal forward direction
    with np.errstate(divide="ignore"):
        z_wall = np.where(r @ fwd > 1e-9, 12.0 / (r @ fwd), np.inf)
    up = -(r * z_wall[..., None]) @ n + cam_height        # height of the wall point over ground
    wall = (z_wall < z_ground) & (up < 2.0) & (np.abs(u - W / 2) < 30)
    depth = np.where(wall, z_wall, z_ground)
    sky = ~np.isfinite(depth)
    depth[sky] = 200.0
    ground = ~wall & ~sky & (z_ground < 60)
    return K, n, depth.astype(np.float32), ground, wall


def dpt_failure(depth: np.ndarray, s: float = 3.0, t: float = 0.08) -> np.ndarray:
    """The failure the paper describes: inverse depth with unknown scale and shift, D = s/Z + t."""
    return (s / depth + t).astype(np.float32)


def explicit_reprojection(Z, K, n_p, d_p, n_g, d_g):
    """Eq. 2 written out, then re-projection (x', y') and the agents' plane depth (Eq. 1)."""
    a, b, c = n_p
    u, v = np.meshgrid(np.arange(Z.shape[1], dtype=float), np.arange(Z.shape[0], dtype=float))
    X = Z * (u - K[0, 2]) / K[0, 0]
    Y = Z * (v - K[1, 2]) / K[1, 1]
    s = a * a + b * b
    Xg = (a * d_p - a * c * Z - a * b * Y + b * b * X) / s
    Yg = (b * d_p - b * c * Z - a * b * X + a * a * Y) / s
    x2, y2 = Xg / Z, Yg / Z                  # normalised coordinates of the re-projected pixel
    return d_g / (n_g[0] * x2 + n_g[1] * y2 + n_g[2])


def test_alignment_fixes_the_tilted_ground():
    K, n, depth, ground, wall = scene()
    Z = depth_from_inverse(dpt_failure(depth))
    before = np.mean(np.abs(Z * np.median(depth[ground] / Z[ground]) - depth)[ground] / depth[ground])
    res = align_depth(Z, K, n, 5.0, ground)
    absrel = np.mean(np.abs(res.depth - depth)[ground] / depth[ground])
    assert before > 0.03            # the shifted inverse depth tilts the ground
    assert absrel < 0.01
    assert not res.skipped and np.all(np.isfinite(res.depth))


def test_closed_form_equals_explicit_reprojection():
    K, n, depth, ground, wall = scene(pitch_deg=22.0)
    Z = depth_from_inverse(dpt_failure(depth, 2.0, 0.05)).astype(np.float64)
    n_p, d_p = fit_predicted_plane(Z, K, ground)
    n_g = n + np.array([0.01, -0.02, 0.015])
    n_g /= np.linalg.norm(n_g)
    res = align_depth(Z, K, n_g, 4.0, ground)
    ref = explicit_reprojection(Z, K, n_p, d_p, n_g, 4.0)
    ok = res.depth > 0
    ok &= np.isfinite(ref) & (ref > 0) & (np.abs(ref) < 1e4)
    both = ok & (wall | ground)
    assert both.sum() > 1000
    np.testing.assert_allclose(res.depth[both], ref[both], rtol=2e-4)


def test_same_plane_is_a_pure_rescale():
    K, n, depth, ground, wall = scene()
    Z = depth / 7.0
    res = align_depth(Z, K, n, 5.0, ground)
    ratio = res.depth / Z
    assert np.nanstd(ratio[depth < 100]) / np.nanmean(ratio[depth < 100]) < 1e-3
    assert np.median(ratio) == pytest.approx(7.0, rel=1e-3)


@settings(max_examples=15, deadline=None)
@given(k=st.floats(1e-2, 1e2), t=st.floats(0.0, 0.2))
def test_alignment_is_invariant_to_global_scale(k, t):
    K, n, depth, ground, _ = scene()
    Z = depth_from_inverse(dpt_failure(depth, 3.0, t))
    a = align_depth(Z, K, n, 5.0, ground).depth
    b = align_depth(Z * np.float32(k), K, n, 5.0, ground).depth
    np.testing.assert_allclose(a, b, rtol=2e-3)


def test_fallback_above_the_agents_horizon_and_no_nan():
    K, n, depth, ground, _ = scene(pitch_deg=15.0)
    Z = depth_from_inverse(dpt_failure(depth))
    # an agents' plane less pitched than the predicted one: far depth slices land above its horizon
    n_g = np.array([0.0, math.cos(math.radians(5)), math.sin(math.radians(5))])
    res = align_depth(Z, K, n_g, 5.0, ground)
    assert res.n_fallback > 0
    assert np.all(np.isfinite(res.depth))
    sky = depth == 200.0
    np.testing.assert_allclose(res.depth[sky], Z[sky] * res.fallback_ratio, rtol=1e-5)


def test_near_plane_option_only_rescales_far_objects():
    K, n, depth, ground, wall = scene()
    Z = depth_from_inverse(dpt_failure(depth))
    res = align_depth(Z, K, n, 5.0, ground, near_plane_rel=0.02)
    np.testing.assert_allclose(res.depth[wall & (depth < 12.5)] / Z[wall & (depth < 12.5)],
                               res.fallback_ratio, rtol=1e-5)
    full = align_depth(Z, K, n, 5.0, ground)
    np.testing.assert_allclose(res.depth[ground], full.depth[ground], rtol=1e-5)


def test_agent_pixels_are_removed_from_the_ground_and_unknowns_stay_unknown():
    K, n, depth, ground, wall = scene()
    Z = depth_from_inverse(dpt_failure(depth))
    Z[0, :5] = np.nan
    res = align_depth(Z, K, n, 5.0, ground | wall, agent_mask=wall)
    g = ground & np.isfinite(Z)
    assert np.mean(np.abs(res.depth - depth)[g] / depth[g]) < 0.01
    assert np.all(np.isnan(res.depth[0, :5])) and np.isfinite(res.depth[1:]).all()


def test_nadir_prediction_is_skipped_and_rescaled():
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 39.5], [0, 0, 1]])
    Z = np.full((H, W), 2.0, np.float32)            # a flat floor straight below
    res = align_depth(Z, K, [0, 0, 1.0], 6.0, np.ones((H, W), bool))
    assert res.skipped
    np.testing.assert_allclose(res.depth, 6.0, rtol=1e-6)


def test_ground_mask_from_feet_is_the_eroded_hull():
    feet = np.array([[40, 20], [120, 20], [120, 70], [40, 70], [80, 45]], float)
    m = ground_mask_from_feet(feet, W, H, erode_px=5)
    vs, us = np.nonzero(m)
    assert (us.min(), us.max(), vs.min(), vs.max()) == (45, 115, 25, 65)
    with pytest.raises(InputError, match="collinear"):
        ground_mask_from_feet(np.array([[0, 0], [10, 10], [20, 20.0]]), W, H)
    with pytest.raises(InputError, match="at least 3"):
        ground_mask_from_feet(np.array([[0, 0], [10, 10.0]]), W, H)
    with pytest.raises(InputError, match="leaves no ground"):
        ground_mask_from_feet(feet, W, H, erode_px=60)


def test_alignment_errors():
    K, n, depth, ground, _ = scene()
    with pytest.raises(InputError, match="2-D"):
        align_depth(depth[None], K, n, 5.0, ground)
    with pytest.raises(InputError, match="shape"):
        align_depth(depth, K, n, 5.0, ground[:10])
    with pytest.raises(InputError, match="valid predicted depths"):
        align_depth(np.full_like(depth, np.nan), K, n, 5.0, ground)
    # a ground mask entirely above the agents' horizon cannot be aligned
    with pytest.raises(InputError, match="horizon"):
        align_depth(depth, K, -n, 5.0, ground)
    np.testing.assert_allclose(depth_from_inverse(np.array([2.0, 0.0, -1.0]), eps=1e-3),
                               [0.5, 1e3, 1e3], rtol=1e-6)


def _inside_even_odd(poly: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Independent reference: even-odd ray casting (a horizontal ray to +u crosses edges)."""
    inside = np.zeros(u.shape, bool)
    for (u1, v1), (u2, v2) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (v1 > v) != (v2 > v)
        with np.errstate(divide="ignore", invalid="ignore"):
            u_at = u1 + (v - v1) * (u2 - u1) / (v2 - v1)
        inside ^= crosses & (u < u_at)
    return inside


def test_ground_mask_from_polygon_matches_an_independent_point_in_polygon_test():
    from staticdepth.geometry.alignment import ground_mask_from_polygon
    rect = [(39.5, 19.5), (120.5, 19.5), (120.5, 70.5), (39.5, 70.5)]
    vs, us = np.nonzero(ground_mask_from_polygon(rect, W, H))
    assert (us.min(), us.max(), vs.min(), vs.max(), len(us)) == (40, 120, 20, 70, 81 * 51)
    # a concave polygon reaching outside the image, against an even-odd ray-casting test
    poly = np.array([[-20.3, 75.2], [60.7, 5.1], [90.2, 50.6], [130.4, 3.3], [175.1, 78.9]])
    m = ground_mask_from_polygon(poly, W, H)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    ref = _inside_even_odd(poly, u.astype(float), v.astype(float))
    assert m.sum() > 3000 and np.array_equal(m, ref)
    with pytest.raises(InputError, match="at least 3"):
        ground_mask_from_polygon([(0, 0), (5, 5)], W, H)
    with pytest.raises(InputError, match="no area"):
        ground_mask_from_polygon([(0, 0), (5, 5), (10, 10)], W, H)
    with pytest.raises(InputError, match="covers no pixel"):
        ground_mask_from_polygon([(500, 500), (600, 500), (600, 600)], W, H)
    with pytest.raises(InputError, match="pairs"):
        ground_mask_from_polygon([(1, 2, 3), (4, 5, 6), (7, 8, 9), (1, 1, 1), (0, 0, 0)], W, H)


def test_ground_mask_from_semantics_and_alignment_with_it():
    from staticdepth.geometry.alignment import ground_mask_from_semantics
    K, n, depth, ground, wall = scene()
    labels = np.where(ground, 7, np.where(wall, 3, 0)).astype(np.uint8)   # 7 = road, 3 = wall
    G = ground_mask_from_semantics(labels, ground_labels=(7,))
    assert np.array_equal(G, ground)
    assert np.array_equal(ground_mask_from_semantics(ground), ground)      # a boolean map
    res = align_depth(depth_from_inverse(dpt_failure(depth)), K, n, 5.0, G)
    assert np.mean(np.abs(res.depth - depth)[ground] / depth[ground]) < 0.01
    with pytest.raises(InputError, match="no ground pixel"):
        ground_mask_from_semantics(labels, ground_labels=(9,))
    with pytest.raises(InputError, match="2-D"):
        ground_mask_from_semantics(labels[None])


def test_degenerate_alignment_inputs_raise_instead_of_nan_maps():
    K, n, depth, ground, wall = scene()
    Z = depth_from_inverse(dpt_failure(depth))
    with pytest.raises(InputError, match="the ground mask is empty$"):
        align_depth(Z, K, n, 5.0, np.zeros_like(ground))
    with pytest.raises(InputError, match="empty once the agents' pixels are removed"):
        align_depth(Z, K, n, 5.0, wall, agent_mask=wall)
    with pytest.raises(InputError, match="agent mask shape"):
        align_depth(Z, K, n, 5.0, ground, agent_mask=wall[:5])
    with pytest.raises(InputError, match="finite non-zero"):
        align_depth(Z, K, [0, 0, 0], 5.0, ground)
    with pytest.raises(InputError, match="finite non-zero"):
        align_depth(Z, K, [np.nan, 1, 0], 5.0, ground)
    for d_g in (0.0, -5.0, float("nan")):
        with pytest.raises(InputError, match="must be positive"):
            align_depth(Z, K, n, d_g, ground)
    # a non-unit normal is normalised: same result as the unit one
    np.testing.assert_allclose(align_depth(Z, K, 3 * n, 5.0, ground).depth,
                               align_depth(Z, K, n, 5.0, ground).depth, rtol=1e-6)
