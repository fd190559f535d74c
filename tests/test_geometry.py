"""Geometry core against closed-form answers and round trips."""
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from staticdepth.errors import InputError
from staticdepth.geometry import (Camera, Mounting, StereoRig, angle_between_deg, fit_plane,
                                  horizon_line, load_camera, normal_from_pitch_roll,
                                  pitch_roll_from_normal, plane_depth_at_pixels, plane_depth_map,
                                  points_from_depth, project_points, rays_from_pixels,
                                  depth_from_disparity, disparity_from_depth, point_plane_distance)

CAM = Camera.from_intrinsics(500.0, 480.0, 401.5, 199.0, 800, 400)


def test_level_camera_ground_row_depth_closed_form():
    # A level camera at height H sees ground row v at depth Z = fy H / (v - cy).
    H = 1.6
    n = normal_from_pitch_roll(0.0)
    depth = plane_depth_map(CAM.K, n, H, CAM.width, CAM.height)
    v = np.arange(CAM.height)
    expected = np.where(v > CAM.cy, CAM.fy * H / np.where(v > CAM.cy, v - CAM.cy, 1), np.nan)
    for col in (0, 333, 799):
        np.testing.assert_allclose(depth[:, col], expected, rtol=1e-6, equal_nan=True)
    assert np.isnan(depth[:199]).all()


def test_pitched_camera_ground_depth_matches_ray_plane_intersection():
    n = normal_from_pitch_roll(30.0, 4.0)
    H = 5.0
    u, v = 123.0, 350.0
    r = rays_from_pixels(CAM.K, u, v)
    Z = plane_depth_at_pixels(CAM.K, n, H, u, v)
    P = Z * r
    assert P[2] == pytest.approx(Z)
    assert float(P @ n) == pytest.approx(H, rel=1e-12)  # the point lies on the plane


def test_pitch_roll_round_trip_and_known_normals():
    np.testing.assert_allclose(normal_from_pitch_roll(0, 0), [0, 1, 0], atol=1e-15)
    t = math.radians(30)
    np.testing.assert_allclose(normal_from_pitch_roll(30, 0), [0, math.cos(t), math.sin(t)])
    for pitch, roll in [(10, 0), (45, -12), (80, 25)]:
        p, r = pitch_roll_from_normal(normal_from_pitch_roll(pitch, roll))
        assert p == pytest.approx(pitch) and r == pytest.approx(roll)


def test_project_unproject_round_trip(rng):
    depth = rng.uniform(1, 50, size=(CAM.height, CAM.width)).astype(np.float32)
    P = points_from_depth(depth, CAM.K)
    uv, z = project_points(P, CAM.K)
    u, v = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    np.testing.assert_allclose(uv[..., 0], u, atol=1e-6)
    np.testing.assert_allclose(uv[..., 1], v, atol=1e-6)
    np.testing.assert_allclose(z, depth, rtol=1e-6)


def test_disparity_depth_closed_form():
    f, B = 400.0, 0.27
    Z = np.array([[1.0, 10.0, np.nan, 0.0]], np.float32)
    d = disparity_from_depth(Z, f, B)
    np.testing.assert_allclose(d[0, :2], [108.0, 10.8], rtol=1e-6)
    assert np.isnan(d[0, 2:]).all()
    back = depth_from_disparity(d, f, B)
    np.testing.assert_allclose(back[0, :2], [1.0, 10.0], rtol=1e-6)
    capped = depth_from_disparity(np.array([1.0, 0.5, -1.0]), f, B, max_depth_m=150)
    assert capped[0] == pytest.approx(108.0) and np.isnan(capped[1:]).all()


@settings(max_examples=40, deadline=None)
@given(pitch=st.floats(0, 80), roll=st.floats(-30, 30), d=st.floats(0.5, 20),
       seed=st.integers(0, 1000))
def test_fit_plane_recovers_plane_from_noisy_points(pitch, roll, d, seed):
    g = np.random.default_rng(seed)
    n = normal_from_pitch_roll(pitch, roll)
    a = np.cross(n, [1.0, 0, 0]) if abs(n[0]) < 0.9 else np.cross(n, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    s, t = g.uniform(-5, 5, (2, 500))
    P = d * n + s[:, None] * a + t[:, None] * b + g.normal(0, 1e-3, (500, 3))
    n_fit, d_fit = fit_plane(P)
    assert angle_between_deg(n_fit, n) < 0.1
    assert d_fit == pytest.approx(d, abs=5e-3)
    assert np.abs(point_plane_distance(P, n_fit, d_fit)).max() < 5e-3


def test_fit_plane_degenerate_inputs():
    with pytest.raises(InputError, match="at least 3"):
        fit_plane(np.zeros((2, 3)))
    with pytest.raises(InputError, match="collinear"):
        fit_plane(np.outer(np.arange(10.0), [1, 2, 3]))


def test_horizon_line_separates_ground_from_sky():
    n = normal_from_pitch_roll(20.0, 5.0)
    a, b, c = horizon_line(CAM.K, n)
    depth = plane_depth_map(CAM.K, n, 5.0, CAM.width, CAM.height)
    u, v = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    side = a * u + b * v + c
    assert np.all(np.isfinite(depth[side > 1e-6]))
    assert np.all(np.isnan(depth[side < -1e-6]))
    with pytest.raises(InputError, match="nadir"):
        horizon_line(CAM.K, [0, 0, 1])


def test_camera_scaled_keeps_pixel_centres():
    c = Camera.from_intrinsics(100, 100, 49.5, 24.5, 100, 50)  # centre of a 100x50 image
    s = c.scaled(2.0)
    assert (s.width, s.height) == (200, 100)
    assert s.cx == pytest.approx(99.5) and s.cy == pytest.approx(49.5) and s.fx == 200


def test_rig_json_round_trip(tmp_path):
    left = Camera.from_intrinsics(700, 701, 600, 180, 1242, 375, dist=[0.1, -0.2, 0, 0, 0.01])
    right = Camera.from_intrinsics(702, 703, 605, 182, 1242, 375)
    R = np.array([[1, 0, 0], [0, math.cos(0.01), -math.sin(0.01)], [0, math.sin(0.01), math.cos(0.01)]])
    rig = StereoRig(left, right, R, [-0.27, 0.001, 0.002],
                    rectification={"P1": np.eye(3, 4), "Q": np.eye(4)},
                    mounting=Mounting.from_pitch_roll(5.0, 30.0, -2.0, source="board"),
                    rms_reprojection_px=0.41, extra={"device": "OAK-FFC"})
    path = tmp_path / "rig.json"
    rig.save(path)
    back = StereoRig.load(path)
    assert back.left == left and back.right == right
    np.testing.assert_array_equal(back.R, rig.R)
    np.testing.assert_array_equal(back.T, rig.T)
    assert back.baseline_m == pytest.approx(math.sqrt(0.27 ** 2 + 0.001 ** 2 + 0.002 ** 2))
    assert back.mounting == rig.mounting
    assert back.mounting.pitch_deg == pytest.approx(30.0)
    assert back.rms_reprojection_px == 0.41 and back.extra["device"] == "OAK-FFC"
    np.testing.assert_array_equal(back.rectification["Q"], np.eye(4))
    assert not back.is_rectified()
    assert StereoRig.rectified(CAM, 0.27).is_rectified()


def test_load_camera_accepts_bare_intrinsics_and_rig(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"fx": 400, "fy": 410, "cx": 399.5, "cy": 199.5}))
    c = load_camera(p)
    assert (c.fx, c.fy, c.width, c.height) == (400, 410, 800, 400)
    StereoRig.rectified(CAM, 0.27).save(tmp_path / "rig.json")
    assert load_camera(tmp_path / "rig.json") == CAM


@pytest.mark.parametrize("content, match", [
    ("{not json", "not valid JSON"),
    ('{"fx": 1, "fy": 1, "cx": 1}', "missing the key 'cy'"),
    ('[1, 2]', "expected a JSON object"),
    ('{"fx": -1, "fy": 1, "cx": 1, "cy": 1}', "focal lengths must be positive"),
])
def test_bad_camera_files_name_the_file(tmp_path, content, match):
    p = tmp_path / "cam.json"
    p.write_text(content)
    with pytest.raises(InputError, match=match) as e:
        load_camera(p)
    assert str(p) in str(e.value)


def test_bad_geometry_values():
    with pytest.raises(InputError):
        Camera(np.eye(2), 10, 10)
    with pytest.raises(InputError):
        Mounting(-1.0, [0, 1, 0])
    with pytest.raises(InputError):
        StereoRig.rectified(CAM, 0.0)
    with pytest.raises(InputError, match="file not found"):
        load_camera("/nonexistent/cam.json")
