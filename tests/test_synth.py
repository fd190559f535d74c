"""The synthetic scene against geometry computed independently in the test."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_DTYPE, COCO
from staticdepth.dataset.synth import PRESETS, SceneConfig, SyntheticScene, preset
from staticdepth.dataset.synth.agents import HEAD_RADIUS_RATIO
from staticdepth.dataset.synth.layout import TAG
from staticdepth.errors import InputError

SMALL = dict(width=320, height=160)


@pytest.fixture(scope="module")
def demo():
    return SyntheticScene(preset("demo", seed=3))


def _rays(K, w, h):
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)


def _project(K, P):
    return P[..., 0] / P[..., 2] * K[0, 0] + K[0, 2], P[..., 1] / P[..., 2] * K[1, 1] + K[1, 2]


def test_presets_and_camera():
    c1 = SyntheticScene(PRESETS["c1"])
    assert c1.camera.fx == pytest.approx(400.0) and c1.camera.size == (800, 400)
    assert c1.rig.baseline_m == pytest.approx(0.27) and c1.rig.is_rectified()
    n, d = c1.ground_plane
    t = math.radians(25.0)
    np.testing.assert_allclose(n, [0.0, math.cos(t), math.sin(t)], atol=1e-12)
    assert d == pytest.approx(5.4) and c1.rig.mounting.height_m == pytest.approx(5.4)
    # the world's down direction seen from the camera is the ground normal, with roll too
    r2 = SyntheticScene(preset("r2", **SMALL))
    np.testing.assert_allclose(r2.cam_from_world_R @ [0, 0, -1], r2.ground_plane[0], atol=1e-12)
    for name in ("street", "c2", "c3", "demo"):
        assert PRESETS[name].name == name


def test_ground_depth_is_the_closed_form(demo):
    for scene in (demo, SyntheticScene(preset("r2", seed=1, **SMALL))):
        fr = scene.render(5)
        n, d = scene.ground_plane
        nr = _rays(scene.camera.K, *scene.camera.size) @ n
        g = fr["ground_mask"]
        assert g.sum() > 0.3 * g.size
        np.testing.assert_allclose(fr["depth"][g], (d / nr)[g], rtol=2e-6)
        # depth is NaN exactly on the sky, finite and positive elsewhere
        sky = fr["semantic"] == TAG["sky"]
        assert np.array_equal(np.isnan(fr["depth"]), sky)
        assert np.all(fr["depth"][~sky] > 0)
        assert np.all(nr[sky] <= 0)  # the sky is seen only above the horizon


@pytest.mark.parametrize("height_m,pitch_deg,roll_deg", [(5.0, 25.0, 0.0), (8.0, 40.0, 0.0),
                                                         (3.0, 15.0, 3.0)])
def test_agent_rows_are_the_cylinder_silhouette_extremes(height_m, pitch_deg, roll_deg):
    scene = SyntheticScene(preset("demo", seed=7, camera_height_m=height_m, pitch_deg=pitch_deg,
                                  roll_deg=roll_deg, n_agents=10, agent_mix=(1, 0, 0),
                                  accessory_prob=0.0))
    K = scene.camera.K
    n, _ = scene.ground_plane
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    a = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    ring = np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2    # unit circle in the ground plane
    checked = 0
    for i in range(0, 400, 25):
        fr = scene.render(i)
        w, h = scene.camera.size
        for row in fr["agents"][fr["visibility"] == 1.0]:
            if not (2 < row["top_v"] and row["foot_v"] < h - 3 and row["class_id"] == 0):
                continue
            mask = fr["instances"] == row["instance_id"]
            cols = np.nonzero(mask.any(0))[0]
            if cols[0] < 2 or cols[-1] > w - 3:
                continue
            foot = np.array([row["foot_x"], row["foot_y"], row["foot_z"]], dtype=float)
            head = np.array([row["head_x"], row["head_y"], row["head_z"]], dtype=float)
            # upright: the axis points along -n, as long as the height; the foot is on the ground
            np.testing.assert_allclose(head - foot, -row["height_m"] * n, atol=1e-5)
            assert foot @ n == pytest.approx(height_m, abs=1e-5)
            r = float(row["radius_m"])
            _, v_foot = _project(K, foot + r * ring)
            _, v_head = _project(K, head + HEAD_RADIUS_RATIO * r * ring)
            assert abs(row["foot_v"] - v_foot.max()) <= 1.0
            assert abs(row["top_v"] - v_head.min()) <= 1.0
            # not the body axis: the near foot edge is lower, the far head edge higher
            assert v_foot.max() > _project(K, foot)[1] and v_head.min() < _project(K, head)[1]
            checked += 1
    assert checked >= 5


def test_right_view_matches_disparity(demo):
    fr = demo.render(12)
    f, B = demo.camera.fx, demo.rig.baseline_m
    h, w = fr["depth"].shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))

    def warp_error(disp):
        xs = u - disp
        right = cv2.remap(fr["right"].astype(np.float32), xs, v, cv2.INTER_LINEAR)
        zr = cv2.remap(fr["depth_right"], xs, v, cv2.INTER_NEAREST)
        ok = (np.isfinite(fr["depth"]) & (xs > 1) & (xs < w - 2)
              & (np.abs(zr - fr["depth"]) < 0.02 * fr["depth"]))
        return np.median(np.abs(right - fr["left"].astype(np.float32))[ok]), ok.mean()

    disp = f * B / np.nan_to_num(fr["depth"], nan=np.inf)
    err, share = warp_error(disp)
    assert share > 0.7 and err < 4.0
    worse, _ = warp_error(disp + 2.0)
    assert worse > 3 * err


def test_deterministic_from_seed():
    a = SyntheticScene(preset("demo", seed=11, **SMALL)).render(30)
    b = SyntheticScene(preset("demo", seed=11, **SMALL)).render(30)
    c = SyntheticScene(preset("demo", seed=12, **SMALL)).render(30)
    for k in ("left", "right", "depth", "instances", "agents"):
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["left"], c["left"])
    assert a["agents"].dtype == AGENT_DTYPE and a["timestamp"] == pytest.approx(3.0)


def test_agents_enter_leave_and_occlude(demo):
    tracks, occluded = [], None
    for i in range(0, 1600, 40):
        fr = demo.render(i)
        tracks.append(set(fr["agents"]["track_id"].tolist()))
        if occluded is None:
            hidden = np.nonzero(fr["visibility"] < 0.7)[0]
            if len(hidden):
                occluded = (i, fr["agents"][hidden[0]], fr)
    assert all(len(t) == len(set(t)) for t in tracks)
    first = tracks[0]
    assert any(t - first for t in tracks) and any(first - t for t in tracks)
    assert sum(bool(t) for t in tracks) > 0.8 * len(tracks)
    # the occluded agent alone would cover more pixels than it shows in the full frame
    assert occluded is not None
    i, row, fr = occluded
    obj = next(o for o in demo.agents_at(i) if o.track_id == row["track_id"])
    from staticdepth.dataset.synth.render import Canvas, draw
    blank = Canvas(np.zeros_like(fr["left"]), np.full(fr["depth"].shape, np.inf, np.float32),
                   np.zeros_like(fr["instances"]), np.zeros_like(fr["semantic"]))
    draw(demo.views[0], blank, obj, demo.camera.fx)
    alone = np.count_nonzero(blank.instances == row["instance_id"])
    shown = np.count_nonzero(fr["instances"] == row["instance_id"])
    assert shown < 0.7 * alone


def test_agent_kinds_and_instances(demo):
    classes, rider_and_bike = set(), False
    for i in range(0, 1200, 30):
        fr = demo.render(i)
        ids = fr["agents"]["instance_id"]
        assert len(set(ids.tolist())) == len(ids)
        present = set(np.unique(fr["instances"]).tolist()) - {0}
        assert present == set(ids.tolist())
        classes |= set(fr["agents"]["class_id"].tolist())
        tags = {int(fr["semantic"][fr["instances"] == k][0]) for k in ids}
        rider_and_bike |= TAG["rider"] in tags and TAG["bicycle"] in tags
    assert {COCO["person"], COCO["car"]} <= classes
    assert classes & ACCESSORY_CLASSES and rider_and_bike


def test_bad_config_raises():
    with pytest.raises(InputError, match="unknown setting"):
        preset("demo", camera_hieght_m=3)
    with pytest.raises(InputError, match="unknown scene preset"):
        preset("c9")
    with pytest.raises(InputError, match="camera_height_m"):
        SceneConfig(camera_height_m=-1)
    with pytest.raises(InputError, match="expects int"):
        preset("demo", width="wide")
    with pytest.raises(InputError, match="agent_mix"):
        preset("demo", agent_mix="1,0")
    with pytest.raises(InputError, match="sees no ground"):
        SyntheticScene(preset("demo", pitch_deg=-10, hfov_deg=20, max_range_m=5))
    with pytest.raises(InputError, match="frame index"):
        SyntheticScene(preset("demo", **SMALL)).render(-1)
    # --set values arrive as strings
    cfg = preset("demo", camera_height_m="6", width="320", agent_mix="0.5,0.5,0")
    assert (cfg.camera_height_m, cfg.width, cfg.agent_mix) == (6.0, 320, (0.5, 0.5, 0.0))
    assert preset("c1").focal == pytest.approx(400.0) and preset("c1", focal_px=500).focal == 500


def test_fast_path_equals_full_frame_reference():
    scene = SyntheticScene(preset("c1", seed=1, width=200, height=100))
    for i in (0, 33):
        fast, ref = scene.render(i), scene.render(i, full_frame=True)
        for k in ("left", "right", "depth", "instances", "semantic", "agents", "visibility"):
            np.testing.assert_array_equal(fast[k], ref[k])


def test_synth_command_writes_a_sequence(tmp_path):
    from staticdepth.cli import main
    from staticdepth.dataset.h5 import SequenceReader

    out = tmp_path / "s.h5"
    assert main(["synth", "--preset", "demo", "--frames", "3", "--set", "width=96",
                 "--set", "height=48", "--set", "camera_height_m=6", "--out", str(out)]) == 0
    with SequenceReader(out) as r:
        assert len(r) == 3 and r.camera.size == (96, 48)
        scene = SyntheticScene(preset("demo", width=96, height=48, camera_height_m=6))
        np.testing.assert_array_equal(r.depth(2), scene.render(2)["depth"])
    assert main(["synth", "--preset", "demo", "--set", "nope=1", "--out",
                 str(tmp_path / "t.h5")]) == 2


def test_top_u_is_the_median_column_of_the_highest_mask_row():
    from staticdepth.dataset.synth import SyntheticScene, preset

    fr = SyntheticScene(preset("demo", seed=3)).render(5)
    checked = 0
    for r in fr["agents"]:
        m = fr["instances"] == r["instance_id"]
        rows = np.nonzero(m.any(1))[0]
        if len(rows) == 0:
            continue
        assert r["top_v"] == rows[0]
        assert r["top_u"] == pytest.approx(np.median(np.nonzero(m[rows[0]])[0]))
        checked += 1
    assert checked >= 3
