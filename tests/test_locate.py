"""locate: contact points in metres, ground frame, speeds and pairwise distances against known
geometry (closed forms, an independent generator in tests/upright_scene.py, the synthetic
renderer), and the command's outputs."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.geometry.ground_frame import (GroundFrame, contact_points, ground_points,
                                               track_speeds)
from staticdepth.geometry.plane import plane_depth_at_pixels
from staticdepth.locate import LocateConfig, locate, pairs

from upright_scene import UprightScene


def test_level_camera_closed_form():
    f, H, cy = 200.0, 4.0, 80.0
    K = np.array([[f, 0, 160.0], [0, f, cy], [0, 0, 1]])
    n = np.array([0.0, 1.0, 0.0])
    v = np.array([100.0, 120.0, 150.0])
    P = ground_points(K, n, H, np.full(3, 160.0), v)
    assert np.allclose(P[:, 2], f * H / (v - cy)) and np.allclose(P[:, 1], H)
    Q = contact_points(K, n, H, np.full(3, 160.0), v, 0.25)       # the axis is 0.25 m further
    assert np.allclose(Q[:, 2], f * H / (v - cy) + 0.25)
    g = GroundFrame.from_plane(n, H).to_ground(Q)
    assert np.allclose(g[:, 1], Q[:, 2]) and np.allclose(g[:, 0], 0.0)
    assert np.isnan(ground_points(K, n, H, [160.0], [cy - 5])).all()   # above the horizon


def test_ground_frame_tilted_camera():
    scene = UprightScene(pitch_deg=35, roll_deg=4, height_m=6.0)
    gf = GroundFrame.from_plane(scene.normal, scene.height_m)
    assert np.allclose(gf.origin, scene.cam_from_world([0, 0, 0]))      # under the camera
    pts_w = np.array([[1.0, 5.0, 0.0], [-2.0, 9.0, 0.0], [3.0, 12.0, 0.0]])
    # the world frame of the generator is the ground frame up to the camera's roll about its axis
    g = gf.to_ground(scene.cam_from_world(pts_w))
    d_true = np.linalg.norm(pts_w[:, None, :2] - pts_w[None, :, :2], axis=-1)
    d_est = np.linalg.norm(g[:, None] - g[None], axis=-1)
    assert np.allclose(d_est, d_true, atol=1e-9)
    assert np.allclose(np.linalg.norm(g, axis=1), np.linalg.norm(pts_w[:, :2], axis=1))
    assert np.all(g[:, 1] > 0)                                           # ahead of the camera
    assert np.allclose(gf.to_camera(g), scene.cam_from_world(pts_w))


def test_track_speeds_line():
    rng = np.random.default_rng(0)
    t = np.arange(40) / 10.0
    xy = np.stack([1.3 * t, 0.4 * t], 1) + rng.normal(0, 0.02, (40, 2))
    s = track_speeds(t, xy, window_s=1.0)
    assert abs(np.nanmedian(s) - np.hypot(1.3, 0.4)) < 0.03
    assert np.isnan(track_speeds(t[:2], xy[:2])).all()


def _errors(pos, truth_of, visible=lambda row: True):
    """Relative contact errors of visible contacts (not flagged, and ``visible`` by the truth),
    and pairwise distance errors within 20 m."""
    rel, pair_err = [], []
    for f in np.unique(pos["frame"]):
        p = pos[(pos["frame"] == f) & ~pos["occluded"] & ~pos["rider"] & (pos["class_id"] == 0)]
        est, tru = [], []
        for row in p:
            T = truth_of(int(f), int(row["track"]))
            if T is None or not visible(row):
                continue
            P = np.array([row["X"], row["Y"], row["Z"]])
            rel.append(np.linalg.norm(P - T) / np.linalg.norm(T))
            est.append(P), tru.append(T)
        for a in range(len(est)):
            for b in range(a + 1, len(est)):
                if max(np.linalg.norm(tru[a]), np.linalg.norm(tru[b])) <= 20:
                    pair_err.append(abs(np.linalg.norm(est[a] - est[b])
                                        - np.linalg.norm(tru[a] - tru[b])))
    return np.array(rel), np.array(pair_err)


@pytest.mark.parametrize("cam", [dict(seed=0, height_m=5.0, pitch_deg=30, roll_deg=0),
                                 dict(seed=1, height_m=3.5, pitch_deg=18, roll_deg=-4),
                                 dict(seed=2, height_m=8.0, pitch_deg=42, roll_deg=3,
                                      focal_px=300)])
def test_locate_on_independent_scenes(tmp_path, cam):
    scene = UprightScene(n_people=9, **cam)
    seq = str(tmp_path / "up.h5")
    truth = scene.write(seq, frames=12)
    pos = locate(seq, scene.normal, scene.height_m, LocateConfig())
    assert set(np.unique(pos["source"])) <= {"plane"}
    rel, pair_err = _errors(pos, lambda f, t: truth[f][t])
    assert len(rel) >= 30 and len(pair_err) >= 30
    assert np.median(rel) <= 0.02 and rel.max() <= 0.05, (np.median(rel), rel.max())
    assert np.median(pair_err) <= 0.2, np.median(pair_err)
    # speeds: every person walks straight at a constant speed
    true_speed = np.linalg.norm(scene.velocity, axis=1)
    got = []
    for t in range(scene.n_people):
        s = pos["speed_mps"][(pos["track"] == t) & ~pos["occluded"]]
        got.append(np.median(s[np.isfinite(s)]) if np.isfinite(s).any() else np.nan)
    ok = np.isfinite(got)
    assert ok.sum() >= 5
    assert np.median(np.abs(np.array(got)[ok] - true_speed[ok]) / true_speed[ok]) < 0.1
    # an occluded contact is flagged, never silently counted as visible
    assert pos["occluded"].any() or len(pos) == len(np.concatenate(truth))


def test_locate_on_synthetic_scene(tmp_path):
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.synth_io import render_to_file

    seq = str(tmp_path / "demo.h5")
    render_to_file(seq, preset_name="demo", n_frames=24, seed=3)
    with SequenceReader(seq) as r:
        m, agents, K = r.meta.mounting, r.agents(), r.camera.K
        depth = [r.depth(i) for i in range(len(r))]
    key = {(int(a["frame"]), int(a["track_id"])): a for a in agents}

    def visible(row):
        """The true depth 2 rows under the contact is the ground's: nothing (a bench, a kerb:
        static objects are not instances) hides the feet."""
        u, v = int(round(row["u"])), int(row["v"]) + 2
        if v >= depth[0].shape[0]:
            return False
        zp = plane_depth_at_pixels(K, m.normal, m.height_m, u, v)
        return bool(abs(depth[int(row["frame"])][v, u] / zp - 1) < 0.03)

    def truth_of(f, t):
        a = key.get((f, t))
        return None if a is None else np.array([a["foot_x"], a["foot_y"], a["foot_z"]], float)

    pos = locate(seq, m.normal, m.height_m, LocateConfig())
    rel, pair_err = _errors(pos, truth_of, visible)
    assert len(rel) >= 20
    assert np.median(rel) <= 0.02 and rel.max() <= 0.05, (np.median(rel), rel.max())
    if len(pair_err):
        assert np.median(pair_err) <= 0.2
    pr = pairs(pos, close_m=2.0)
    assert all(p["close"] == int(p["distance_m"] < 2.0) for p in pr)


def test_locate_command_outputs(tmp_path):
    scene = UprightScene(n_people=6, seed=4)
    seq = tmp_path / "up.h5"
    scene.write(str(seq), frames=8)
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"normal": scene.normal.tolist()}))
    out = tmp_path / "pos.csv"
    argv = ["locate", str(seq), "--plane", str(plane), "--out", str(out),
            "--pairs", str(tmp_path / "pairs.csv"), "--bev", str(tmp_path / "bev.png"),
            "--annotate", str(tmp_path / "frames.gif"), "--annotate-frames", "3"]
    assert main(argv) == 2                                   # no camera height anywhere
    assert main(argv + ["--camera-height", str(scene.height_m)]) == 0
    rows = list(csv.DictReader(out.open()))
    for col in ("frame", "track", "class", "u", "v", "X", "Y", "Z", "ground_x", "ground_y",
                "distance_m", "source", "speed_mps"):
        assert col in rows[0]
    assert {r["class"] for r in rows} == {"person"}
    assert all(r["source"] == "plane" for r in rows)
    d = np.array([float(r["distance_m"]) for r in rows])
    xyz = np.array([[float(r[k]) for k in "XYZ"] for r in rows])
    assert np.allclose(d, np.linalg.norm(xyz, axis=1), atol=2e-3)
    prs = list(csv.DictReader((tmp_path / "pairs.csv").open()))
    assert prs and set(prs[0]) >= {"frame", "track_a", "track_b", "distance_m", "close"}
    for name in ("bev.png", "frames.gif", "frames_sheet.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert main(argv + ["--camera-height", "5", "--close-m", "0", "--overwrite"]) == 2


def test_hidden_feet_use_the_metric_map(tmp_path):
    """A static box (no instance) hides a person's feet: the plane alone places it too far; a
    metric depth map (here the scene's true depth, stored as adapt's prediction) flags the contact
    as hidden and locates the person from its own depth (source 'depth')."""
    from staticdepth.dataset.h5 import add_prediction

    scene = UprightScene(n_people=3, seed=5, bench=True)
    seq = str(tmp_path / "bench.h5")
    truth = scene.write(seq, frames=1)
    T = truth[0][0]
    pos = locate(seq, scene.normal, scene.height_m, LocateConfig(), depth_pred=None)
    p0 = pos[pos["track"] == 0][0]
    err_plane = np.linalg.norm([p0["X"] - T[0], p0["Y"] - T[1], p0["Z"] - T[2]]) / np.linalg.norm(T)
    assert not p0["occluded"] and err_plane > 0.05        # nothing in the instances shows it
    add_prediction(seq, "ft-align-metric", [scene.render(0)["depth"].astype(np.float32)],
                   {"metric": True})
    pos = locate(seq, scene.normal, scene.height_m, LocateConfig())
    p0 = pos[pos["track"] == 0][0]
    assert p0["occluded"] and p0["source"] == "depth"
    err = np.linalg.norm([p0["X"] - T[0], p0["Y"] - T[1], p0["Z"] - T[2]]) / np.linalg.norm(T)
    assert err < 0.05, (err, err_plane)
    others = pos[pos["track"] != 0]
    assert np.all(others["source"] == "plane")            # visible feet keep the plane
    assert main(["locate", seq, "--plane", str(_plane_json(tmp_path, scene)), "--camera-height",
                 "5", "--depth", "nothing", "--out", str(tmp_path / "p.csv")]) == 2


def _plane_json(tmp_path, scene):
    path = tmp_path / "plane.json"
    path.write_text(json.dumps({"normal": scene.normal.tolist()}))
    return path


def test_locate_with_the_motion_detector(tmp_path):
    """No instances in the file: the motion detector finds the people, the tracker links them,
    and their visible contacts land where the truth is."""
    from staticdepth.dataset.h5 import SequenceReader, SequenceWriter

    scene = UprightScene(n_people=5, seed=6)
    full = str(tmp_path / "full.h5")
    truth = scene.write(full, frames=16)
    seq = str(tmp_path / "video.h5")               # the same frames, as a video would give them
    with SequenceReader(full) as r:
        meta = r.meta
        with SequenceWriter(seq, meta, streams=("left",)) as w:
            for i in range(len(r)):
                w.append(left=r.left(i), timestamp=float(r.timestamps()[i]))
    pos = locate(seq, scene.normal, scene.height_m, LocateConfig(), detector="motion")
    vis = pos[~pos["occluded"]]
    assert len(vis) >= 30
    rel = []
    for p in vis:
        P = np.array([p["X"], p["Y"], p["Z"]])
        T = truth[int(p["frame"])][np.argmin(np.linalg.norm(truth[int(p["frame"])] - P, axis=1))]
        rel.append(np.linalg.norm(P - T) / np.linalg.norm(T))
    assert np.median(rel) <= 0.02, np.median(rel)
    # tracks: a person keeps one id over most of its frames
    assert len(np.unique(pos["track"])) <= 2 * scene.n_people


def test_locate_parquet_tables(tmp_path, monkeypatch, capsys):
    """--out/--pairs .parquet: the CSV's columns at full precision; without pyarrow a one-line
    error before any work, and nothing written."""
    import sys

    pq = pytest.importorskip("pyarrow.parquet", reason="pyarrow is the optional extra "
                             "staticdepth[parquet] (installed by setup.sh)")
    scene = UprightScene(n_people=5, seed=6)
    seq = tmp_path / "up.h5"
    scene.write(str(seq), frames=6)
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"normal": scene.normal.tolist()}))
    base = ["locate", str(seq), "--plane", str(plane), "--camera-height", str(scene.height_m)]
    assert main(base + ["--out", str(tmp_path / "p.csv"), "--pairs", str(tmp_path / "q.csv")]) == 0
    assert main(base + ["--out", str(tmp_path / "p.parquet"),
                        "--pairs", str(tmp_path / "q.parquet")]) == 0
    rows = list(csv.DictReader((tmp_path / "p.csv").open()))
    t = pq.read_table(tmp_path / "p.parquet").to_pydict()
    assert list(t) == list(rows[0]) and len(t["frame"]) == len(rows) > 0
    assert t["class"] == [r["class"] for r in rows] and t["source"] == [r["source"] for r in rows]
    for col in ("X", "Y", "Z", "ground_x", "ground_y", "distance_m"):
        assert np.allclose(t[col], [float(r[col]) for r in rows], atol=6e-4)
    sp = [np.nan if v is None else v for v in t["speed_mps"]]
    assert np.allclose(sp, [float(r["speed_mps"] or "nan") for r in rows], atol=6e-4,
                       equal_nan=True)
    prs = list(csv.DictReader((tmp_path / "q.csv").open()))
    tq = pq.read_table(tmp_path / "q.parquet").to_pydict()
    assert len(tq["distance_m"]) == len(prs) > 0
    assert np.allclose(tq["distance_m"], [float(r["distance_m"]) for r in prs], atol=6e-4)
    monkeypatch.setitem(sys.modules, "pyarrow", None)           # as if it were not installed
    assert main(base + ["--out", str(tmp_path / "n.parquet")]) == 2
    err = capsys.readouterr().err
    assert "needs pyarrow" in err and len(err.strip().splitlines()) == 1
    assert main(base + ["--out", str(tmp_path / "n.csv"),
                        "--pairs", str(tmp_path / "n.parquet")]) == 2
    assert not (tmp_path / "n.parquet").exists() and not (tmp_path / "n.csv").exists()


def test_riders_on_a_synthetic_scene(tmp_path):
    """Riders stay people (the tracking's rider merge is for the ground plane) and sit on their
    vehicle: the direction of their own silhouette, the distance of the vehicle's contact. The
    nearest footprint point alone, as before, was 3.7% off at the median (0.3 m sideways)."""
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.synth_io import render_to_file

    seq = str(tmp_path / "bikes.h5")
    render_to_file(seq, preset_name="demo", n_frames=12, seed=2,
                   overrides={"agent_mix": (0.3, 0.1, 0.6), "n_agents": 20})
    with SequenceReader(seq) as r:
        m, agents = r.meta.mounting, r.agents()
    key = {(int(a["frame"]), int(a["track_id"])): a for a in agents}
    pos = locate(seq, m.normal, m.height_m, LocateConfig())
    riders = pos[pos["rider"]]
    assert np.all(riders["class_id"] == 0) and len(np.unique(riders["track"])) >= 3
    rel, lateral = [], []
    for row in riders:
        a = key[(int(row["frame"]), int(row["track"]))]
        T = np.array([a["foot_x"], a["foot_y"], a["foot_z"]], float)
        P = np.array([row["X"], row["Y"], row["Z"]])
        rel.append(np.linalg.norm(P - T) / np.linalg.norm(T))
        side = np.cross(T / np.linalg.norm(T), m.normal)              # horizontal, across the view
        lateral.append(abs((P - T) @ side / np.linalg.norm(side)))
    assert np.median(rel) <= 0.02 and np.median(lateral) <= 0.05, (np.median(rel),
                                                                    np.median(lateral))


@pytest.mark.parametrize("extra, msg", [
    (["--annotate", "a.gif", "--annotate-frames", "0"],
     "--annotate-frames must be at least 1, got 0"),
    (["--person-radius", "-1"], "--person-radius must be a body radius from 0 to 1 m, got -1"),
    (["--person-radius", "50"], "--person-radius must be a body radius from 0 to 1 m, got 50"),
    (["--depth", "base"], "prediction 'base' is not metric depth (metric ones: ft-align-metric;"),
    # a table path of another kind got CSV under its name
    (["--pairs", "pairs.json"], "pairs.json: a table is written as .csv or .parquet"),
    # refused only after the table was written: the corrected rerun was 'exists already'
    (["--annotate", "a.png"], "a.png: annotated frames are written as .gif or .mp4"),
    (["--annotate", "nodir/a.gif"], "nodir: output's parent does not exist"),
    (["--bev", "nodir/bev.png"], "nodir: output's parent does not exist"),
    (["--bev", "bev.xyz"], "bev.xyz: --bev: cannot write an image of this kind"),
    (["--pairs", "nodir/q.csv"], "nodir: output's parent does not exist")])
def test_locate_refuses_bad_options_before_writing(tmp_path, capsys, monkeypatch, extra, msg):
    """--annotate-frames 0 (crashed in pick_frames after the CSV was written), a body radius out
    of range (-1 and 50 m ran), a relative --depth map (base, used as metres) and outputs that
    cannot be written (another kind, a missing folder: refused after the CSV was written) are
    refused in one line, exit 2, before any output; the metric map and a radius of 0 are
    taken."""
    from staticdepth.dataset.h5 import add_prediction

    monkeypatch.chdir(tmp_path)
    scene = UprightScene(n_people=3, seed=5, bench=True)
    seq = str(tmp_path / "bench.h5")
    scene.write(seq, frames=2)
    depth = [scene.render(i)["depth"].astype(np.float32) for i in range(2)]
    add_prediction(seq, "base", [d / 7.0 for d in depth], {"metric": False})
    add_prediction(seq, "ft-align-metric", depth, {"metric": True})
    out = tmp_path / "p.csv"
    base = ["locate", seq, "--plane", str(_plane_json(tmp_path, scene)), "--camera-height",
            str(scene.height_m), "--out", str(out)]
    assert main(base + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err
    assert not out.exists() and not (tmp_path / "a.gif").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.h5", "bench.h5.lock",
                                                          "bench.h5.pred", "plane.json"]
    assert main(base + ["--depth", "ft-align-metric", "--person-radius", "0"]) == 0
    assert "depth" in {r["source"] for r in csv.DictReader(out.open())}   # the bench's feet
