"""Ground plane from agents (METHOD.md section 2) on physically correct synthetic observations.

The generator below is independent of the library: people are upright cylinders standing on the
true plane, their silhouette's lowest and highest rows found by densely sampling and projecting the
foot and head rims.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry.agent_plane import (AgentPlane, AgentPlaneConfig, camera_height_from_prior,
                                              fit_agent_plane, head_pixels, head_rows,
                                              plane_affine, plane_paper)
from staticdepth.geometry.plane import angle_between_deg

OBS = [("frame", "i4"), ("track", "i4"), ("class_id", "i2"), ("foot_u", "f8"), ("foot_v", "f8"),
       ("height_px", "f8"), ("top_v", "f8"), ("top_u", "f8"), ("score", "f4")]


def camera_K(f: float = 600.0, w: int = 800, h: int = 400) -> tuple[np.ndarray, int, int]:
    return np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]]), w, h


def true_normal(pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Rz(roll) (0, cos t, sin t), built here independently of the library."""
    t, r = math.radians(pitch_deg), math.radians(roll_deg)
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return Rz @ np.array([0.0, math.cos(t), math.sin(t)])


def _project(K, P):
    uvw = P @ K.T
    return uvw[..., 0] / uvw[..., 2], uvw[..., 1] / uvw[..., 2]


def people_observations(rng, K, w, h, n, cam_height, n_tracks=40, frames=(5, 12), radius=0.2,
                        noise_px=1.0, max_depth=40.0, heights=(1.7, 0.07),
                        turn_sd=0.35, head_radius=0.12) -> np.ndarray:
    """Tracks of upright cylinders (foot disk ``radius``, head disk ``head_radius``, metres)
    walking on ``n . P = cam_height``; observation table rows with the silhouette's lowest point
    (foot_u, foot_v) and highest point (top_u, top_v), plus Gaussian pixel noise on all four.
    ``turn_sd`` (rad) is the heading's random walk per step (0 = straight walkers)."""
    e1 = np.cross(n, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    phi = np.linspace(0, 2 * math.pi, 2881)[:-1]
    rim = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    rows, track = [], 0
    while track < n_tracks:
        u0, v0 = rng.uniform(40, w - 40), rng.uniform(0.3 * h, h - 10)
        r = np.linalg.solve(K, [u0, v0, 1.0])
        if r @ n <= 1e-6 or (r * cam_height / (r @ n))[2] > max_depth:
            continue
        A = r * cam_height / (r @ n)
        H = rng.normal(*heights)
        heading = rng.uniform(0, 2 * math.pi)
        out = []
        for i in range(rng.integers(frames[0], frames[1] + 1)):
            heading += rng.normal(0, turn_sd) if turn_sd > 0 else 0.0
            A = A + 0.8 * (math.cos(heading) * e1 + math.sin(heading) * e2)
            foot, head = A + radius * rim, A - H * n + head_radius * rim
            if foot[:, 2].min() <= 0.1 or head[:, 2].min() <= 0.1:
                break
            fu, fv = _project(K, foot)
            hu, hv = _project(K, head)
            ib, it = np.argmax(fv), np.argmin(hv)
            if (min(fu.min(), hu.min()) < 1 or max(fu.max(), hu.max()) > w - 2 or hv.min() < 1
                    or fv[ib] > h - 2):
                continue
            out.append((track, i, fu[ib], fv[ib], hv[it], hu[it]))
        if len(out) >= 3:
            rows += out
            track += 1
    a = np.array(rows)
    noise = rng.normal(0, noise_px, (len(a), 3))
    obs = np.zeros(len(a), OBS)
    obs["track"], obs["frame"], obs["class_id"], obs["score"] = a[:, 0], a[:, 1], 0, 1
    obs["foot_u"], obs["foot_v"] = a[:, 2] + noise[:, 0], a[:, 3] + noise[:, 1]
    obs["top_v"] = a[:, 4] + noise[:, 2]
    obs["top_u"] = a[:, 5] + rng.normal(0, noise_px, len(a))
    obs["height_px"] = obs["foot_v"] - obs["top_v"]
    return obs


def shrink_heights(rng, obs: np.ndarray, fraction: float = 0.2) -> np.ndarray:
    """Bad detections: ``fraction`` of the heights shrunk to 40-70% (sitting people, cut boxes)."""
    o = obs.copy()
    bad = rng.random(len(o)) < fraction
    o["height_px"][bad] *= rng.uniform(0.4, 0.7, bad.sum())
    o["top_v"] = o["foot_v"] - o["height_px"]
    return o


# (f, pitch, roll, camera height): pitched 10-45 degrees, 3-8 m up
CAMERAS = [(450.0, 12.0, 2.0, 3.5), (600.0, 25.0, -3.0, 7.5), (700.0, 35.0, 1.0, 5.0),
           (520.0, 44.0, -1.5, 6.5)]


def test_head_rows_match_dense_projection():
    """The closed-form extreme rim rows equal the generator's densely sampled silhouette."""
    rng = np.random.default_rng(3)
    K, w, h = camera_K(550.0)
    n = true_normal(38.0, 4.0)
    for head_r, ratio in ((0.2, 0.2 / 1.7), (0.12, (0.2 / 1.7, 0.12 / 1.7))):
        obs = people_observations(rng, K, w, h, n, 6.0, n_tracks=8, noise_px=0.0,
                                  heights=(1.7, 0.0), head_radius=head_r)
        rays = np.linalg.solve(K, np.stack([obs["foot_u"], obs["foot_v"], np.ones(len(obs))])).T
        s = np.full(len(obs), 1.7 / 6.0)
        v = head_rows(K, n, rays, s, ratio)
        assert np.max(np.abs(v - obs["top_v"])) < 0.05
        u, v2 = head_pixels(K, n, rays, s, ratio)
        np.testing.assert_array_equal(v2, v)
        assert np.max(np.abs(u - obs["top_u"])) < 0.05
    thin = head_rows(K, n, rays, s, 0.0)        # ignoring the body's thickness biases the rows
    assert np.max(np.abs(thin - obs["top_v"])) > 1.0
    # a head as wide as the body moves the top point's column by pixels
    u_wide, _ = head_pixels(K, n, rays, s, 0.2 / 1.7)
    assert np.max(np.abs(u_wide - obs["top_u"])) > 1.0


@pytest.mark.parametrize("f,pitch,roll,height", CAMERAS)
def test_exact_model_recovers_normal_and_camera_height(f, pitch, roll, height):
    rng = np.random.default_rng(int(pitch))
    K, w, h = camera_K(f)
    n = true_normal(pitch, roll)
    obs = people_observations(rng, K, w, h, n, height)
    plane = fit_agent_plane(K, obs, AgentPlaneConfig(model="exact", bootstrap=0, column_weight=1.0))
    paper = fit_agent_plane(K, obs, AgentPlaneConfig(model="paper", bootstrap=0))
    rows_only = fit_agent_plane(K, obs[[c for c in obs.dtype.names if c != "top_u"]],
                                AgentPlaneConfig(model="exact", bootstrap=0))       # boxes: no top column
    # the default ignores the column (unbiased only on exact cylinders like these)
    default = fit_agent_plane(K, obs, AgentPlaneConfig(model="exact", bootstrap=0))
    assert np.allclose(default.normal, rows_only.normal, atol=1e-9)
    err, err_paper = angle_between_deg(plane.normal, n), angle_between_deg(paper.normal, n)
    err_rows = angle_between_deg(rows_only.normal, n)
    cam_h = camera_height_from_prior(plane, 1.7)
    print(f"pitch {pitch}: exact {err:.2f} deg (rows only {err_rows:.2f}), paper "
          f"{err_paper:.2f} deg, height {100 * (cam_h / height - 1):+.1f}%")
    assert err < 0.5              # head rows and columns
    assert err_rows < 1.0         # head rows only
    assert abs(cam_h / height - 1) < 0.05
    assert plane.inliers.mean() > 0.9
    # the horizon line is where n . K^-1 [u, v, 1] = 0
    a, b, c = plane.horizon
    assert abs(np.hypot(a, b) - 1) < 1e-9
    if pitch > 30:   # Eq. 1 is biased for a tilted camera (METHOD.md section 2)
        assert err_paper > 3.0


@pytest.mark.parametrize("f,pitch,roll,height", CAMERAS[1:])
def test_exact_model_survives_20_percent_bad_detections(f, pitch, roll, height):
    rng = np.random.default_rng(100 + int(pitch))
    K, w, h = camera_K(f)
    n = true_normal(pitch, roll)
    obs = shrink_heights(rng, people_observations(rng, K, w, h, n, height))
    plane = fit_agent_plane(K, obs, AgentPlaneConfig(model="exact", bootstrap=0))
    assert angle_between_deg(plane.normal, n) < 2.0
    assert abs(camera_height_from_prior(plane, 1.7) / height - 1) < 0.05


def test_eq1_models_exact_on_eq1_data():
    """Data that follow Eq. 1 exactly (h = f_y H (n . r) / d): both linear forms recover n, d/H."""
    rng = np.random.default_rng(1)
    K = np.array([[520.0, 0, 401.0], [0, 480.0, 198.0], [0, 0, 1]])   # fx != fy
    n = true_normal(27.0, 6.0)
    u, v = rng.uniform(0, 800, 50), rng.uniform(150, 400, 50)
    r = np.linalg.solve(K, np.stack([u, v, np.ones(50)])).T
    d_over_h = 4.2 / 1.7
    hpx = K[1, 1] * (r @ n) / d_over_h
    for fit in (plane_paper, plane_affine):
        n_fit, dh = fit(K, u, v, hpx)
        assert angle_between_deg(n_fit, n) < 1e-6
        assert dh == pytest.approx(d_over_h, rel=1e-9)


def test_thin_model_on_thin_agents_and_bootstrap():
    rng = np.random.default_rng(7)
    K, w, h = camera_K(500.0)
    n = true_normal(30.0, -2.0)
    obs = people_observations(rng, K, w, h, n, 5.0, n_tracks=25, radius=0.0, head_radius=0.0)
    plane = fit_agent_plane(K, obs, AgentPlaneConfig(model="exact", radius_m=0.0, head_radius_m=0.0, bootstrap=8))
    err = angle_between_deg(plane.normal, n)
    assert err < 1.0
    assert 0.0 < plane.normal_std_deg < 2.0
    assert 0.0 < plane.d_over_h_std < 0.5
    assert abs(plane.d_over_agent_height * 1.7 / 5.0 - 1) < 0.05
    back = AgentPlane.from_dict(plane.to_dict())
    assert np.allclose(back.normal, plane.normal) and np.array_equal(back.inliers, plane.inliers)
    assert back.normal_std_deg == pytest.approx(plane.normal_std_deg)


def test_straight_walkers_still_fix_the_plane():
    """Tracks that walk straight lines (each one collinear on its own) constrain the exact model."""
    rng = np.random.default_rng(11)
    K, w, h = camera_K(600.0)
    n = true_normal(30.0, 2.0)
    obs = people_observations(rng, K, w, h, n, 6.0, n_tracks=25, turn_sd=0.0)
    for t in np.unique(obs["track"]):             # each track's feet lie on one line (up to noise)
        uv = np.stack([obs["foot_u"], obs["foot_v"]], 1)[obs["track"] == t]
        assert np.linalg.svd(uv - uv.mean(0), compute_uv=False)[1] / math.sqrt(len(uv)) < 2.0
    plane = fit_agent_plane(K, obs, AgentPlaneConfig(model="exact", bootstrap=0))
    assert angle_between_deg(plane.normal, n) < 1.0


def test_degenerate_inputs_raise():
    K, w, h = camera_K()
    obs = np.zeros(2, OBS)
    obs["foot_u"], obs["foot_v"], obs["height_px"] = [100, 200], [300, 310], [50, 55]
    with pytest.raises(InputError, match="at least 3 usable"):
        fit_agent_plane(K, obs)
    line = np.zeros(12, OBS)
    line["track"] = np.arange(12) // 4
    line["foot_u"] = np.linspace(100, 700, 12)
    line["foot_v"] = 0.2 * line["foot_u"] + 150
    line["height_px"] = 60
    with pytest.raises(InputError, match="collinear"):
        fit_agent_plane(K, line)
    # nadir camera: every agent has the same pixel height, wherever it stands
    rng = np.random.default_rng(0)
    flat = np.zeros(30, OBS)
    flat["track"] = np.arange(30) // 5
    flat["foot_u"], flat["foot_v"] = rng.uniform(0, 800, 30), rng.uniform(0, 400, 30)
    flat["height_px"] = 80.0
    for model in ("affine", "paper"):
        with pytest.raises(InputError):
            fit_agent_plane(K, flat, AgentPlaneConfig(model=model, bootstrap=0))
    missing = np.zeros(5, [("foot_u", "f8"), ("foot_v", "f8"), ("height_px", "f8")])
    with pytest.raises(InputError, match="'track'"):
        fit_agent_plane(K, missing)
    # observations that are not usable (no height, not finite) do not count
    few = np.zeros(6, OBS)
    few["track"] = np.arange(6)
    few["foot_u"], few["foot_v"] = [1, 50, 90, 9, 9, 9], [5, 80, 30, 9, 9, 9]
    few["height_px"] = [40, 50, 45, 0, -3, np.nan]
    with pytest.raises(InputError, match=r"at least 3 usable observations .*got 2"):
        fit_agent_plane(K, few[[0, 1, 3, 4, 5]])
    # every track seen once: each observation only fixes its own track's height
    once = np.zeros(10, OBS)
    once["track"] = np.arange(10)
    once["foot_u"], once["foot_v"] = rng.uniform(0, 800, 10), rng.uniform(200, 400, 10)
    once["height_px"] = 60
    with pytest.raises(InputError, match="seen in several frames"):
        fit_agent_plane(K, once, AgentPlaneConfig(bootstrap=0))
    # a real nadir camera (people seen from straight above) with the exact model
    n_nadir = true_normal(90.0)
    nadir = people_observations(np.random.default_rng(0), K, w, h, n_nadir, 6.0, n_tracks=12)
    with pytest.raises(InputError, match="nadir"):
        fit_agent_plane(K, nadir, AgentPlaneConfig(model="exact", bootstrap=0))


def test_config_and_prior_errors():
    with pytest.raises(InputError, match="unknown ground-plane model"):
        AgentPlaneConfig(model="magic")
    with pytest.raises(InputError):
        AgentPlaneConfig(radius_m=-1.0)
    with pytest.raises(InputError, match="head_radius_m must be a finite number >= 0"):
        AgentPlaneConfig(head_radius_m=-0.1)
    with pytest.raises(InputError, match="column weight"):
        AgentPlaneConfig(column_weight=-0.5)
    plane = AgentPlane(true_normal(20), np.array([0, 1.0, -10]), 3.0, np.array([1, 2]),
                       np.array([0.3, 0.3]), np.array([False, False]), 1.0, "exact", 10)
    with pytest.raises(InputError, match="no inlier person track"):
        camera_height_from_prior(plane, 1.7)
    with pytest.raises(InputError, match="agent height must be positive"):
        camera_height_from_prior(plane, 0.0)
    for bad in (float("nan"), float("inf")):      # were taken: a NaN or infinite camera height
        with pytest.raises(InputError, match="agent height must be positive and finite"):
            camera_height_from_prior(plane, bad)
        with pytest.raises(InputError, match="plane.agent_height_m must be a finite number > 0"):
            AgentPlaneConfig(agent_height_m=bad)
        with pytest.raises(InputError, match="radius"):
            AgentPlaneConfig(radius_m=bad)
    with pytest.raises(InputError, match="column weight"):   # was a scipy traceback
        AgentPlaneConfig(column_weight=float("inf"))
    with pytest.raises(InputError, match="less than the agent height"):
        AgentPlaneConfig(radius_m=2.0)
    with pytest.raises(InputError, match="bootstrap must be a finite number within 0..10000"):
        AgentPlaneConfig(bootstrap=-1)
    with pytest.raises(InputError, match=r"camera height \(given\) must be a height in metres"):
        plane.with_camera_height(-2.0, "given")
    with pytest.raises(InputError, match="missing the key 'normal'"):
        AgentPlane.from_dict({"horizon": [0, 1, 0]}, "p.json")
    with pytest.raises(InputError, match="finite non-zero"):
        AgentPlane.from_dict({"normal": [0, 0, 0], "horizon": [0, 1, 0]}, "p.json")


def test_only_the_modelled_classes_enter_the_fit():
    """People (and rows of unknown class) by default; boxes of other classes only on request."""
    rng = np.random.default_rng(5)
    K, w, h = camera_K(600.0)
    n = true_normal(30.0, 1.0)
    people = people_observations(rng, K, w, h, n, 6.0, n_tracks=20)
    cars = people_observations(rng, K, w, h, n, 6.0, n_tracks=10, radius=0.9, head_radius=0.9,
                               heights=(1.5, 0.05))
    cars["class_id"], cars["track"] = 2, cars["track"] + 100
    both = np.concatenate([people, cars])
    plane = fit_agent_plane(K, both, AgentPlaneConfig(model="exact", bootstrap=0))
    assert plane.n_observations == len(people)
    assert set(plane.track_ids.tolist()) == set(np.unique(people["track"]).tolist())
    every = fit_agent_plane(K, both, AgentPlaneConfig(model="exact", bootstrap=0, classes=None))
    assert every.n_observations == len(both)
    with pytest.raises(InputError, match="no observation of the classes"):
        fit_agent_plane(K, cars, AgentPlaneConfig(model="exact"))
    unknown = people.copy()
    unknown["class_id"] = -1                      # a CSV without classes: taken as people
    conf = AgentPlaneConfig(model="exact", bootstrap=0)
    assert fit_agent_plane(K, unknown, conf).n_observations == len(people)
