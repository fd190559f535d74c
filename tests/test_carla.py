"""CARLA export import: encodings, camera and mounting, agents, ground mask, bad input."""
import json
import math

import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.carla import (carla_rgb_from_depth, depth_from_carla_rgb, import_carla,
                                       instance_rgb_from_tags_ids, mounting_from_transform,
                                       tags_ids_from_instance_rgb, ue_rotation, write_carla_frame)
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError
from staticdepth.geometry import fit_plane, normal_from_pitch_roll, points_from_depth

W, H, FOV, Z_M, PITCH = 160, 80, 90.0, 5.0, -30.0


def _scene(i, legacy=False):
    """A camera 5 m up, pitched 30 degrees down, over flat road (closed-form depth), sky above the
    horizon, and three agents drawn as rectangles that move one pixel per frame."""
    f = W / 2 / math.tan(math.radians(FOV) / 2)
    t = math.radians(-PITCH)
    v = np.arange(H)[:, None] - H / 2
    denom = math.cos(t) * v / f + math.sin(t)  # n . r for n = (0, cos t, sin t), r = (x, y, 1)
    depth = np.where(denom > 1e-6, Z_M / np.maximum(denom, 1e-6), np.nan) * np.ones((1, W))
    tags = np.where(np.isfinite(depth), 7 if legacy else 1, 13 if legacy else 11).astype(np.uint8)
    tags[:5, :20] = 3 if not legacy else 1  # a building corner
    ids = np.zeros((H, W), np.uint16)
    person, car = (4, 10) if legacy else (12, 14)
    for tag, iid, (v0, v1, u0, u1) in ((person, 300, (40, 61, 30 + i, 36 + i)),
                                       (car, 7, (50, 70, 100, 131)),
                                       (13 if not legacy else person, 1025, (30, 45, 60, 66))):
        tags[v0:v1, u0:u1] = tag
        ids[v0:v1, u0:u1] = iid
    tags[70, 100:110], ids[70, 100:110] = car, 7  # the car's lowest row is narrower: foot_u = 104.5
    rng = np.random.default_rng(i)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    return rgb, depth.astype(np.float32), tags, ids


def _export(folder, n=4, legacy=False, right=False, **sensor):
    for i in range(n):
        rgb, depth, tags, ids = _scene(i, legacy)
        write_carla_frame(folder, i, rgb, depth, tags, ids, right=rgb[:, ::-1] if right else None)
    meta = {"image_size_x": W, "image_size_y": H, "fov": FOV, "sensor_tick": 0.05,
            "transform": {"location": {"x": 10.0, "y": -3.0, "z": Z_M},
                          "rotation": {"pitch": PITCH, "yaw": 90.0, "roll": 0.0}}, **sensor}
    (folder / "sensor.json").write_text(json.dumps(meta))
    return folder


def test_depth_encoding_round_trip_and_formula():
    # CARLA's formula on a hand-made pixel: R=1, G=2, B=3 -> (1 + 512 + 196608)/(2^24-1)*1000 m
    assert depth_from_carla_rgb(np.array([[[1, 2, 3]]], np.uint8))[0, 0] == pytest.approx(
        (1 + 2 * 256 + 3 * 65536) / (256 ** 3 - 1) * 1000, rel=1e-6)
    d = np.random.default_rng(0).uniform(0.5, 900, (20, 30)).astype(np.float32)
    d[0, 0] = np.nan
    back = depth_from_carla_rgb(carla_rgb_from_depth(d))
    assert np.isnan(back[0, 0])
    np.testing.assert_allclose(back[1:], d[1:], atol=1000 / (256 ** 3 - 1))
    tags, ids = np.array([[12, 1]], np.uint8), np.array([[300, 65535]], np.uint16)
    rgb = instance_rgb_from_tags_ids(tags, ids)
    assert rgb[0, 0].tolist() == [12, 300 % 256, 1]  # id = G + 256 B
    t2, i2 = tags_ids_from_instance_rgb(rgb)
    np.testing.assert_array_equal(t2, tags)
    np.testing.assert_array_equal(i2, ids)


@pytest.mark.parametrize("pitch,roll", [(-30, 0), (-12, 7), (-45, -20), (0, 0)])
def test_mounting_matches_pitch_roll_convention(pitch, roll):
    m = mounting_from_transform(6.0, pitch, 33.0, roll)  # yaw does not matter
    np.testing.assert_allclose(m.normal, normal_from_pitch_roll(-pitch, -roll), atol=1e-12)
    assert m.height_m == 6.0
    R = ue_rotation(pitch, 33.0, roll)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert R[0, 2] == pytest.approx(math.sin(math.radians(pitch)))  # forward axis up for pitch > 0


def test_positive_unreal_roll_brings_the_right_side_down():
    # Unreal: positive roll turns the right axis downward, so the ground on the right is nearer.
    from staticdepth.geometry import plane_depth_at_pixels
    from staticdepth.geometry.camera import Camera

    m = mounting_from_transform(5.0, -20.0, 0.0, 10.0)
    K = Camera.from_fov(W, H, FOV).K
    left, right = plane_depth_at_pixels(K, m.normal, m.height_m, np.array([5.0, W - 5.0]),
                                        np.array([70.0, 70.0]))
    assert right < left


def test_import_carla_cli(tmp_path, capsys):
    src = _export(tmp_path / "C", n=4, right=True, baseline_m=0.27)
    out = tmp_path / "C.h5"
    assert main(["import-carla", str(src), "--adapt-frames", "2", "--out", str(out)]) == 0
    assert "wrote 4 frames" in capsys.readouterr().out
    with SequenceReader(out) as r:
        assert len(r) == 4 and r.streams() == ["left", "right", "depth", "instances"]
        assert r.meta.gt_kind == "synthetic" and r.split("eval") == range(2, 4)
        assert r.camera.fx == pytest.approx(80.0) and r.camera.cx == 80 and r.camera.cy == 40
        assert r.meta.camera_height_m == Z_M and r.meta.mounting.pitch_deg == pytest.approx(30)
        assert r.meta.rig.baseline_m == pytest.approx(0.27)
        np.testing.assert_allclose(r.timestamps(), [0, 0.05, 0.1, 0.15])
        rgb, depth, tags, ids = _scene(2)
        np.testing.assert_array_equal(r.left(2), rgb)
        np.testing.assert_array_equal(r.right(2), rgb[:, ::-1])
        got = r.depth(2)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(depth))  # sky -> NaN
        np.testing.assert_allclose(got[~np.isnan(depth)], depth[~np.isnan(depth)], atol=1e-4)
        inst = r.instances(2)
        assert set(np.unique(inst)) == {0, 7, 300, 1025}
        assert not inst[tags == 1].any()  # road pixels carry no instance
        ag = r.agents(2)
        by = {int(a["instance_id"]): a for a in ag}
        assert by[300]["class_id"] == schema.COCO["person"] and by[300]["foot_v"] == 60
        assert by[300]["top_v"] == 40 and by[300]["foot_u"] == pytest.approx(np.median(
            np.arange(32, 38)))
        assert by[7]["class_id"] == schema.COCO["car"] and by[7]["foot_v"] == 70
        assert by[7]["foot_u"] == 104.5
        assert by[1025]["class_id"] == schema.COCO["person"]  # a rider is a person (riding)
        assert by[1025]["track_id"] == 1025
        # The ground mask and the decoded depth recover the plane of the transform.
        with h5py.File(out) as f:
            ground = f["aux/ground"][2]
        assert f is not None
        np.testing.assert_array_equal(ground, tags == 1)
        P = points_from_depth(got, r.camera.K)[ground]
        n, d = fit_plane(P)
        np.testing.assert_allclose(n, r.meta.mounting.normal, atol=1e-4)
        assert d == pytest.approx(Z_M, rel=1e-4)
        assert r.meta.provenance["sensor"]["fov"] == FOV


def test_legacy_tags_and_timestamps_csv(tmp_path):
    src = _export(tmp_path / "C", n=3, legacy=True)
    (src / "timestamps.csv").write_text("frame,timestamp_s\n0,10.5\n1,10.6\n2,10.75\n")
    out = tmp_path / "C.h5"
    import_carla(src, out, legacy_tags=True)
    with SequenceReader(out) as r:
        np.testing.assert_allclose(r.timestamps(), [10.5, 10.6, 10.75])
        cls = {int(a["instance_id"]): int(a["class_id"]) for a in r.agents(0)}
        assert cls == {300: 0, 7: 2, 1025: 0}
        with h5py.File(out) as f:
            assert f["aux/ground"][0].sum() == np.count_nonzero(_scene(0, True)[2] == 7)
    # Read with the wrong numbering, the legacy tags mean nothing: no person, no car.
    import_carla(src, tmp_path / "D.h5")
    with SequenceReader(tmp_path / "D.h5") as r:
        assert len(r.agents()) == 0
    (src / "timestamps.csv").write_text("0,1.0\n1,x\n")
    with pytest.raises(InputError, match="line 2"):
        import_carla(src, tmp_path / "E.h5")


def test_bad_input(tmp_path, capsys):
    src = _export(tmp_path / "C", n=3)
    out = tmp_path / "C.h5"
    # corrupt instance PNG: error naming it, or a counted skip
    bad = src / "instance" / "000001.png"
    bad.write_bytes(b"not a png")
    assert main(["import-carla", str(src), "--out", str(out)]) == 2
    assert "instance/000001.png: corrupt or unreadable image" in capsys.readouterr().err
    assert not out.exists()
    assert main(["import-carla", str(src), "--out", str(out)]) == 2      # nothing was interrupted
    assert capsys.readouterr().err.strip().endswith(
        "an earlier run stopped before finishing (interrupted, or by a bad input) and left this "
        "file: --resume continues it (add --skip-bad to pass a bad frame that stopped it), "
        "--restart starts over")
    assert main(["import-carla", str(src), "--out", str(out), "--skip-bad", "--resume"]) == 0
    assert "skipped 1 bad frame" in capsys.readouterr().out
    with SequenceReader(out) as r:
        assert len(r) == 2 and r.meta.provenance["skipped"][0]["frame"] == "000001"
    # a depth image of the wrong size
    rgb, depth, tags, ids = _scene(0)
    write_carla_frame(tmp_path / "small", 1, rgb[:40], depth[:40], tags[:40], ids[:40])
    (src / "depth" / "000001.png").write_bytes((tmp_path / "small/depth/000001.png").read_bytes())
    write_carla_frame(src, 1, rgb, depth, tags, ids)
    (src / "depth" / "000001.png").write_bytes((tmp_path / "small/depth/000001.png").read_bytes())
    with pytest.raises(InputError, match="expected a 160x80 8-bit image"):
        import_carla(src, tmp_path / "x.h5")
    write_carla_frame(src, 1, rgb, depth, tags, ids)
    # a frame's depth image missing: a bad frame naming it (tests/test_import_missing_files.py)
    (src / "depth" / "000002.png").unlink()
    with pytest.raises(InputError, match="depth/000002.png: file not found"):
        import_carla(src, tmp_path / "x.h5", restart=True)
    write_carla_frame(src, 2, rgb, depth, tags, ids)
    # right/ without a baseline
    write_carla_frame(tmp_path / "r", 0, rgb, depth, tags, ids, right=rgb)
    for k in range(3):
        (src / "right").mkdir(exist_ok=True)
        (src / "right" / f"{k:06d}.png").write_bytes((tmp_path / "r/right/000000.png").read_bytes())
    with pytest.raises(InputError, match="no baseline_m"):
        import_carla(src, tmp_path / "x.h5")
    # sensor.json problems
    meta = json.loads((src / "sensor.json").read_text())
    del meta["fov"]
    (src / "sensor.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="missing 'fov'"):
        import_carla(src, tmp_path / "x.h5")
    meta["fov"] = 200
    (src / "sensor.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="fov must be within"):
        import_carla(src, tmp_path / "x.h5")
    meta["fov"] = 90
    meta["transform"]["location"]["z"] = -1
    (src / "sensor.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"location.z must be a height in metres.*got -1.0"):
        import_carla(src, tmp_path / "x.h5")
    (src / "sensor.json").unlink()
    with pytest.raises(InputError, match="file not found") as e:
        import_carla(src, tmp_path / "x.h5")
    assert e.value.path.endswith("sensor.json")
    with pytest.raises(InputError, match="folder not found"):
        import_carla(tmp_path / "nowhere", tmp_path / "x.h5")


def test_import_of_the_synthetic_generators_carla_export(tmp_path):
    """The scene generator writes CARLA's encodings from a known scene; the import recovers it."""
    from staticdepth.dataset.synth import SyntheticScene, preset
    from staticdepth.dataset.synth.carla_export import write_carla_export

    scene = SyntheticScene(preset("demo", width=192, height=96, seed=2, roll_deg=4.0))
    write_carla_export(scene, tmp_path / "c", n_frames=3)
    rep = import_carla(tmp_path / "c", tmp_path / "c.h5", adapt_frames=1)
    assert rep.frames == 3
    with SequenceReader(tmp_path / "c.h5") as r, h5py.File(tmp_path / "c.h5") as f:
        assert r.camera == scene.camera
        np.testing.assert_allclose(r.meta.mounting.normal, scene.mounting.normal, atol=1e-9)
        assert r.meta.rig.baseline_m == pytest.approx(scene.rig.baseline_m)
        np.testing.assert_allclose(r.timestamps(), [0.0, 0.1, 0.2])
        for i in range(3):
            fr = scene.render(i)
            np.testing.assert_array_equal(r.left(i), fr["left"])
            np.testing.assert_array_equal(r.right(i), fr["right"])
            d, t = r.depth(i), fr["depth"]
            np.testing.assert_array_equal(np.isnan(d), ~np.isfinite(t))
            assert np.nanmax(np.abs(d - t)) < 1000 / (256 ** 3 - 1)  # CARLA's depth step
            np.testing.assert_array_equal(f["aux/ground"][i], fr["ground_mask"])
            truth = {int(a["instance_id"]): a for a in fr["agents"]
                     if a["class_id"] in schema.AGENT_CLASSES}
            got = r.agents(i)
            assert sorted(truth) == sorted(int(x) for x in got["instance_id"])
            np.testing.assert_array_equal(r.instances(i), np.where(
                np.isin(fr["instances"], list(truth)), fr["instances"], 0))
            for a in got:
                b = truth[int(a["instance_id"])]
                for k in ("class_id", "foot_u", "foot_v", "top_v"):
                    assert a[k] == b[k], (k, a[k], b[k])


def test_default_name_is_the_outputs_stem_and_adapt_frames_is_checked_first(tmp_path, capsys):
    src = _export(tmp_path / "carla", n=4)
    out = tmp_path / "C1.h5"
    assert main(["import-carla", str(src), "--adapt-frames", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "--adapt-frames must be within 1..4 (the input's frames), got 5")
    assert not out.exists() and not (tmp_path / "C1.h5.partial").exists()
    assert main(["import-carla", str(src), "--out", str(out)]) == 0
    assert main(["import-carla", str(src), "--name", "site 3", "--out", str(tmp_path / "C2.h5")]
                ) == 0
    with SequenceReader(out) as a, SequenceReader(tmp_path / "C2.h5") as b:
        assert (a.meta.name, b.meta.name) == ("C1", "site 3")


def test_legacy_tags_on_newer_data_warn_in_one_line(tmp_path, capsys):
    """--legacy-tags on data from CARLA 0.9.14+ gave 0 agents without a word."""
    src = _export(tmp_path / "C", n=4)  # 0.9.14+ numbering: 3 agents a frame
    out = tmp_path / "C.h5"
    assert main(["import-carla", str(src), "--legacy-tags", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln for ln in lines if ln.startswith("warning")] == [
        f"warning: {src}: --legacy-tags (pre-0.9.14: Pedestrian 4, Vehicle 10) finds no agents "
        "in 4 sampled frames, the 0.9.14+ numbering finds 12: data from CARLA 0.9.14 or later "
        "needs no --legacy-tags"]
    with SequenceReader(out) as r:
        assert len(r.agents()) == 0
        assert r.meta.provenance["legacy_tags_check"] == {
            "sampled_frames": 4, "agents_legacy": 0, "agents_current": 12}
    # legacy data read with --legacy-tags: its agents, no warning
    old = _export(tmp_path / "L", n=3, legacy=True)
    assert main(["import-carla", str(old), "--legacy-tags", "--out", str(tmp_path / "L.h5")]) == 0
    assert "warning" not in capsys.readouterr().out
    with SequenceReader(tmp_path / "L.h5") as r:
        assert len(r.agents()) == 9
        assert r.meta.provenance["legacy_tags_check"]["agents_legacy"] == 9


def test_a_file_given_as_the_export_folder_is_said_to_be_a_file(tmp_path, capsys):
    """import-carla vtest.avi said 'folder not found' though the path exists (as a file)."""
    f = tmp_path / "clip.avi"
    f.write_bytes(b"x")
    assert main(["import-carla", str(f), "--out", str(tmp_path / "c.h5")]) == 2
    assert capsys.readouterr().err.strip().endswith(
        f"error: {f}: is a file, not a CARLA export folder (rgb/, depth/, instance/, sensor.json)")
    assert main(["import-carla", str(tmp_path / "none"), "--out", str(tmp_path / "c.h5")]) == 2
    assert capsys.readouterr().err.strip().endswith("none: folder not found")
