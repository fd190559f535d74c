"""Stereo pipeline: exact answers on a synthetic ground plane, formats, fill, CLI, bad input."""
from __future__ import annotations

import cv2
import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig, normal_from_pitch_roll
from staticdepth.geometry.plane import plane_depth_map
from staticdepth.stereo.fill import fill_from_background, trim_foreground_edges
from staticdepth.stereo.io import read_disparity, read_pfm, write_disparity, write_pfm
from staticdepth.stereo.match import create_matcher, num_disparities_for
from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline
from staticdepth.stereo.rectify import check_rectified

CAM = Camera.from_intrinsics(400.0, 400.0, 199.5, 99.5, 400, 200)
BASELINE = 0.27


def ground_pair(camera=CAM, height_m=3.0, pitch=25.0, seed=0):
    """Left/right views of a textured ground plane (world texture: same point, same colour)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur((rng.random((2048, 2048, 3)) * 255).astype(np.float32), (0, 0), 1.5)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    n = normal_from_pitch_roll(pitch, 0.0)
    depth = plane_depth_map(camera.K, n, height_m, camera.width, camera.height)
    e1 = np.cross(n, [0, 0, 1.0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    views = []
    for shift in (0.0, BASELINE):   # right camera centre at +B along x (P_r = P_l - (B, 0, 0))
        rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy,
                         np.ones(u.shape)], -1)
        z = height_m / np.maximum(rays @ n, 1e-9)
        P = rays * z[..., None] + np.array([shift, 0, 0])
        mx = (P @ e1 * 60 + 1024).astype(np.float32)     # 60 texture px per metre
        my = (P @ e2 * 60 + 1024).astype(np.float32)
        views.append(cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
    return views[0], views[1], depth


def test_ground_plane_depth_matches_truth():
    left, right, depth = ground_pair()
    rig = StereoRig.rectified(CAM, BASELINE)
    pipe = StereoPipeline(rig, StereoConfig(min_depth_m=2.0))
    assert pipe.num_disparities == num_disparities_for(400.0, BASELINE, 2.0) == 64
    res = pipe.process(left, right)
    m = np.isfinite(res.depth) & (depth < 20)
    assert m.sum() > 0.5 * (depth < 20).sum()
    absrel = np.mean(np.abs(res.depth[m] - depth[m]) / depth[m])
    assert absrel < 0.05
    assert res.depth.dtype == np.float32 and res.disparity.dtype == np.float32
    assert np.allclose(res.depth[m], 400 * BASELINE / res.disparity[m], rtol=1e-5)
    assert np.all(res.depth[np.isfinite(res.depth)] <= 80.0)
    dense = StereoPipeline(rig, StereoConfig(min_depth_m=2.0, fill=True)).process(left, right)
    assert np.isfinite(dense.disparity).all()



@pytest.mark.parametrize("border, absrel_max", [("half", 0.03), ("full", 0.015)])
def test_left_border_is_matched(border, absrel_max):
    """SGBM leaves the first num_disparities columns empty; both border modes fill them truly."""
    left, right, depth = ground_pair()
    rig = StereoRig.rectified(CAM, BASELINE)
    res = StereoPipeline(rig, StereoConfig(min_depth_m=2.0, options={"border": border})).process(
        left, right)
    z, truth = res.depth[:, :64], depth[:, :64]        # 64 disparities at min_depth_m = 2
    m = np.isfinite(z) & (truth < 20)
    assert m.sum() > 0.7 * (truth < 20).sum()
    assert np.mean(np.abs(z[m] - truth[m]) / truth[m]) < absrel_max
    none = StereoPipeline(rig, StereoConfig(min_depth_m=2.0, options={"border": "none"}))
    empty = none.process(left, right)
    assert np.isnan(empty.disparity[:, :64]).all()
    if border == "half":      # the interior comes from the same unpadded match (trim: 3 px)
        assert np.array_equal(empty.disparity[:, 67:], res.disparity[:, 67:], equal_nan=True)

def test_calibrated_rig_rectifies_and_triangulates():
    """A rig with a small rotation: rectify its raw views and recover the plane's depth."""
    left, right, depth = ground_pair()
    rig = StereoRig.rectified(CAM, BASELINE)
    pipe = StereoPipeline(rig, StereoConfig(num_disparities=64))
    assert pipe.rectifier.maps is None and pipe.camera == CAM
    rot = StereoRig(CAM, CAM, cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0], [-BASELINE, 0, 0])
    p2 = StereoPipeline(rot, StereoConfig(num_disparities=64))
    assert p2.rectifier.maps is not None
    assert p2.baseline_m == pytest.approx(BASELINE, rel=1e-6)


def test_pipeline_pickles_and_reports_provenance():
    import pickle

    left, right, _ = ground_pair()
    pipe = StereoPipeline(StereoRig.rectified(CAM, BASELINE), StereoConfig(num_disparities=64))
    again = pickle.loads(pickle.dumps(pipe))
    assert np.array_equal(again.process(left, right).depth, pipe.process(left, right).depth,
                          equal_nan=True)
    prov = pipe.provenance()
    assert prov["matcher"]["block_size"] == 3 and prov["num_disparities"] == 64
    assert StereoConfig.from_dict(prov["stereo"]) == pipe.config


def test_fill_and_trim_exact():
    d = np.array([[5, np.nan, np.nan, 9, np.nan], [np.nan] * 5, [np.nan, 2, np.nan, 7, 7]],
                 np.float32)
    f = fill_from_background(d, median_rows=1)
    assert np.array_equal(f[0], [5, 5, 5, 9, 9])
    assert np.array_equal(f[2], [2, 2, 2, 7, 7])
    assert np.array_equal(f[1], f[2])         # an empty row takes its nearest row (tie: below)
    t = trim_foreground_edges(np.array([[1, 1, 9, 9, 9, 9]], np.float32), radius_px=2)
    assert np.array_equal(np.isnan(t[0]), [False, False, True, True, False, False])


def test_disparity_files_round_trip(tmp_path):
    d = np.array([[1.5, np.nan], [200.25, 3.0]], np.float32)
    for ext in (".pfm", ".npy", ".png"):
        write_disparity(tmp_path / f"d{ext}", d)
        assert np.array_equal(read_disparity(tmp_path / f"d{ext}"), d, equal_nan=True)
    assert np.isinf(read_pfm(tmp_path / "d.pfm")[0, 1])   # Middlebury: invalid = inf
    raw = (tmp_path / "d.pfm").read_bytes()
    assert raw.startswith(b"Pf\n2 2\n-1.0\n")
    assert np.frombuffer(raw[-16:], "<f4")[0] == 200.25   # rows stored bottom to top
    write_pfm(tmp_path / "c.pfm", np.ones((2, 3, 3)))
    assert read_pfm(tmp_path / "c.pfm").shape == (2, 3, 3)
    with pytest.raises(InputError, match="255.99"):
        write_disparity(tmp_path / "x.png", np.array([[300.0]]))
    with pytest.raises(InputError, match=".pfm, .png or .npy"):
        write_disparity(tmp_path / "x.tif", d)
    (tmp_path / "bad.pfm").write_bytes(b"P6\n1 1\n")
    with pytest.raises(InputError, match="not a PFM"):
        read_pfm(tmp_path / "bad.pfm")


def test_matcher_and_config_errors():
    with pytest.raises(InputError, match="unknown matcher"):
        create_matcher("nope", num_disparities=64, image_size=(400, 200))
    with pytest.raises(InputError, match="multiple of 16"):
        create_matcher("sgbm", num_disparities=60, image_size=(400, 200))
    with pytest.raises(InputError, match="not below the image width"):
        create_matcher("sgbm", num_disparities=400, image_size=(400, 200))
    with pytest.raises(InputError, match="unknown setting"):
        create_matcher("sgbm", num_disparities=64, image_size=(400, 200),
                       options={"uniquness": 3})
    with pytest.raises(InputError, match="unknown sgbm preset"):
        create_matcher("sgbm", num_disparities=64, image_size=(400, 200),
                       options={"preset": "x"})
    with pytest.raises(InputError, match="sgbm border"):
        create_matcher("sgbm", num_disparities=64, image_size=(400, 200),
                       options={"border": "left"})
    with pytest.raises(InputError, match="min_depth_m"):
        StereoConfig(min_depth_m=100.0)
    with pytest.raises(InputError, match="num_disparities"):
        StereoConfig(num_disparities=10)
    pipe = StereoPipeline(StereoRig.rectified(CAM, BASELINE), StereoConfig(num_disparities=64))
    with pytest.raises(InputError, match="calibrated for 400x200"):
        pipe.process(np.zeros((100, 100, 3), np.uint8), np.zeros((100, 100, 3), np.uint8))


def test_not_rectified_is_refused(shared_data):
    img = cv2.imread(str(shared_data / "middlebury" / "Art" / "view1.png"))[..., ::-1]
    shifted = np.ascontiguousarray(np.roll(img, 12, axis=0))
    with pytest.raises(InputError, match="not rectified"):
        check_rectified(img, shifted)
    right = cv2.imread(str(shared_data / "middlebury" / "Art" / "view5.png"))[..., ::-1]
    assert check_rectified(img, np.ascontiguousarray(right)).offset_px < 1.0


def test_cli_rectified_pair(shared_data, tmp_path, capsys):
    d = shared_data / "middlebury" / "Art"
    out = tmp_path / "disp.pfm"
    rc = main(["stereo", "--rectified", "--left", str(d / "view1.png"), "--right",
               str(d / "view5.png"), "--max-disparity", "75", "--disparity-out", str(out)])
    assert rc == 0
    disp = read_disparity(out)
    gt = cv2.imread(str(d / "disp1.png"), cv2.IMREAD_UNCHANGED) / 3.0
    m = np.isfinite(disp) & (gt > 0)
    assert np.median(np.abs(disp[m] - gt[m])) < 0.5
    rc = main(["stereo", "--rectified", "--left", str(d / "view1.png"), "--right",
               str(d / "view5.png"), "--max-disparity", "75", "--fill",
               "--disparity-out", str(tmp_path / "dense.npy")])
    assert rc == 0 and np.isfinite(np.load(tmp_path / "dense.npy")).all()
    shifted = tmp_path / "shifted.png"
    cv2.imwrite(str(shifted), np.roll(cv2.imread(str(d / "view5.png")), 15, axis=0))
    rc = main(["stereo", "--rectified", "--left", str(d / "view1.png"), "--right", str(shifted),
               "--max-disparity", "75", "--disparity-out", str(out)])
    assert rc == 2 and "exists already; pass --overwrite" in capsys.readouterr().err
    rc = main(["stereo", "--rectified", "--left", str(d / "view1.png"), "--right", str(shifted),
               "--max-disparity", "75", "--disparity-out", str(out), "--overwrite"])
    assert rc == 2 and "not rectified" in capsys.readouterr().err
    rc = main(["stereo", "--rectified", "--left", str(d / "view1.png"), "--right",
               str(d / "view5.png"), "--disparity-out", str(out)])
    assert rc == 2 and "--max-disparity" in capsys.readouterr().err


def _write_frames(folder, frames):
    folder.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:04d}.png"), f[..., ::-1])


def _interrupted_on_third_pair(args) -> int:
    """``main(args)`` with Ctrl-C arriving while the third pair is matched."""
    calls = {"n": 0}
    real = StereoPipeline.process

    def crash_on_third(self, L, R):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(self, L, R)

    StereoPipeline.process = crash_on_third
    try:
        return main(args)
    finally:
        StereoPipeline.process = real


def test_cli_sequence_resume_and_errors(tmp_path, capsys):
    frames = [ground_pair(seed=s) for s in range(3)]
    _write_frames(tmp_path / "L", [f[0] for f in frames])
    _write_frames(tmp_path / "R", [f[1] for f in frames])
    rig = tmp_path / "rig.json"
    StereoRig.rectified(CAM, BASELINE).save(rig)
    out = tmp_path / "seq.h5"
    args = ["stereo", "--rig", str(rig), "--left", str(tmp_path / "L"), "--right",
            str(tmp_path / "R"), "--out", str(out), "--min-depth", "2"]
    from staticdepth.stereo import cli as stereo_cli

    assert _interrupted_on_third_pair(args) == 130
    assert (tmp_path / "seq.h5.partial").exists() and not out.exists()
    assert main(args + ["--resume"]) == 0 and "(2 resumed)" in capsys.readouterr().out
    with h5py.File(out) as f:
        assert f["depth"].shape == (3, 200, 400) and f.attrs["gt_kind"] == "stereo"
        depth = f["depth"][2]
    truth = frames[2][2]
    m = np.isfinite(depth) & (truth < 20)
    assert np.mean(np.abs(depth[m] - truth[m]) / truth[m]) < 0.05
    assert stereo_cli is not None

    (tmp_path / "R" / "0002.png").unlink()
    rc = main(args[:-4] + ["--out", str(tmp_path / "x.h5")])
    assert rc == 2 and "3 left frames but 2 right frames" in capsys.readouterr().err
    StereoRig.rectified(Camera.from_intrinsics(400, 400, 320, 240, 640, 480), BASELINE).save(rig)
    _write_frames(tmp_path / "R2", [f[1] for f in frames])
    rc = main(["stereo", "--rig", str(rig), "--left", str(tmp_path / "L"), "--right",
               str(tmp_path / "R2"), "--out", str(tmp_path / "y.h5")])
    assert rc == 2 and "calibrated for 640x480" in capsys.readouterr().err


def test_cli_sequence_from_two_videos_resumes(tmp_path, capsys):
    """Left and right videos (lossless FFV1) give the sequence the same pairs as image folders
    give, frame for frame; an interrupted run resumes from its third frame (the video is read
    forward to it)."""
    frames = [ground_pair(seed=s) for s in range(3)]
    for side, k in (("L", 0), ("R", 1)):
        out = cv2.VideoWriter(str(tmp_path / f"{side}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 5,
                              (frames[0][k].shape[1], frames[0][k].shape[0]))
        for f in frames:
            out.write(np.ascontiguousarray(f[k][..., ::-1]))
        out.release()
    _write_frames(tmp_path / "L", [f[0] for f in frames])
    _write_frames(tmp_path / "R", [f[1] for f in frames])
    rig = tmp_path / "rig.json"
    StereoRig.rectified(CAM, BASELINE).save(rig)
    common = ["--rig", str(rig), "--min-depth", "2"]
    assert main(["stereo", *common, "--left", str(tmp_path / "L"), "--right",
                 str(tmp_path / "R"), "--out", str(tmp_path / "folders.h5")]) == 0
    args = ["stereo", *common, "--left", str(tmp_path / "L.avi"), "--right",
            str(tmp_path / "R.avi"), "--out", str(tmp_path / "videos.h5")]
    assert _interrupted_on_third_pair(args) == 130
    assert main(args + ["--resume"]) == 0 and "(2 resumed)" in capsys.readouterr().out
    with h5py.File(tmp_path / "videos.h5") as v, h5py.File(tmp_path / "folders.h5") as f:
        assert v["depth"].shape == f["depth"].shape == (3, 200, 400)
        np.testing.assert_array_equal(v["left"][:], f["left"][:])
        np.testing.assert_array_equal(v["depth"][:], f["depth"][:])


def _sequence_args(tmp_path, out="seq.h5"):
    return ["stereo", "--rig", str(tmp_path / "rig.json"), "--left", str(tmp_path / "L"),
            "--right", str(tmp_path / "R"), "--out", str(tmp_path / out), "--min-depth", "2"]


@pytest.fixture
def three_pairs(tmp_path):
    frames = [ground_pair(seed=s) for s in range(3)]
    _write_frames(tmp_path / "L", [f[0] for f in frames])
    _write_frames(tmp_path / "R", [f[1] for f in frames])
    StereoRig.rectified(CAM, BASELINE).save(tmp_path / "rig.json")
    return frames


def test_cli_bad_files_are_refused_before_any_work(tmp_path, three_pairs, capsys):
    bad = tmp_path / "R" / "0002.png"
    good = bad.read_bytes()
    bad.write_bytes(b"not an image")                    # unreadable: found by the header check
    assert main(_sequence_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert "corrupt or unreadable image" in err and "0002.png" in err and err.count("\n") == 1
    assert not (tmp_path / "seq.h5.partial").exists() and not (tmp_path / "seq.h5").exists()
    cv2.imwrite(str(bad), np.zeros((200, 300, 3), np.uint8))   # another size than the rig's
    assert main(_sequence_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert "0002.png" in err and "300x200" in err and "calibrated for 400x200" in err
    # data truncated after a valid header: found when frame 2 is decoded; frames 0-1 are kept
    bad.write_bytes(good[:len(good) // 2])
    assert main(_sequence_args(tmp_path)) == 2
    assert "0002.png" in capsys.readouterr().err
    assert (tmp_path / "seq.h5.partial").exists()
    bad.write_bytes(good)
    assert main(_sequence_args(tmp_path)) == 2          # a partial is never resumed unasked
    assert "--resume continues it" in capsys.readouterr().err
    assert main(_sequence_args(tmp_path) + ["--resume"]) == 0
    assert "(2 resumed)" in capsys.readouterr().out


def test_cli_refuses_a_16_bit_pair_instead_of_darkening_it(tmp_path, three_pairs, capsys):
    # stereo reads through the toolkit's one image reader: a 16-bit frame (here 12-bit sensor data)
    # is refused with its name, where OpenCV's colour decode divided it by 256 into 0-15
    bad = tmp_path / "R" / "0002.png"
    grey = cv2.cvtColor(cv2.imread(str(bad)), cv2.COLOR_BGR2GRAY).astype(np.uint16) * 16
    cv2.imwrite(str(bad), grey)
    assert main(_sequence_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert "0002.png: expected an 8-bit image, got uint16" in err and err.count("\n") == 1
    with h5py.File(tmp_path / "seq.h5.partial", "r") as f:     # the frames before it are kept
        assert f["left"].shape[0] == 2


def test_one_image_reader_for_every_command(tmp_path):
    from staticdepth import fileio
    from staticdepth.capture.sources import replay
    from staticdepth.dataset import pack
    from staticdepth.stereo import io as stereo_io

    assert stereo_io.read_rgb is pack.read_rgb is fileio.read_rgb
    rgb = np.random.default_rng(0).integers(0, 256, (6, 5, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "c.png"), rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / "a.png"), np.dstack([rgb[..., ::-1], np.full((6, 5), 7, np.uint8)]))
    cv2.imwrite(str(tmp_path / "g.png"), rgb[..., 0])
    cv2.imwrite(str(tmp_path / "w.png"), rgb[..., 0].astype(np.uint16) * 256)
    np.testing.assert_array_equal(fileio.read_rgb(tmp_path / "c.png"), rgb)
    np.testing.assert_array_equal(fileio.read_rgb(tmp_path / "a.png"), rgb)       # alpha dropped
    np.testing.assert_array_equal(fileio.read_rgb(tmp_path / "g.png"),
                                  np.repeat(rgb[..., :1], 3, axis=2))
    with pytest.raises(InputError, match="w.png: expected an 8-bit image, got uint16"):
        fileio.read_rgb(tmp_path / "w.png")
    # capture's replay keeps 16-bit as recorded, through the same decoder
    assert replay.read_image(tmp_path / "w.png").dtype == np.uint16
    (tmp_path / "x.png").write_bytes(b"")
    for f in ("x.png", "missing.png"):
        with pytest.raises(InputError, match=f"{f}: (corrupt or unreadable image|file not found)"):
            fileio.read_rgb(tmp_path / f)


def test_cli_unrectified_sequence_and_size_mismatch(tmp_path, three_pairs, capsys):
    for f in (tmp_path / "R").iterdir():              # right view moved down by 12 rows
        cv2.imwrite(str(f), np.roll(cv2.imread(str(f)), 12, axis=0))
    assert main(_sequence_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert "not rectified" in err and "rig.json" in err
    assert not (tmp_path / "seq.h5.partial").exists()
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 200, 3), np.uint8))
    assert main(["stereo", "--rectified", "--left", str(tmp_path / "L" / "0000.png"), "--right",
                 str(small), "--max-disparity", "64", "--disparity-out",
                 str(tmp_path / "d.pfm")]) == 2
    assert "left is 400x200 but right is 200x100" in capsys.readouterr().err


def test_cli_stereo_on_a_capture_recording(tmp_path, capsys):
    from staticdepth.capture.layout import read_recording
    from staticdepth.capture.record import record
    from staticdepth.capture.sources.synthetic import SyntheticSource
    from staticdepth.dataset.h5 import SequenceReader

    cam = Camera.from_intrinsics(100.0, 100.0, 79.5, 39.5, 160, 80)
    rig = StereoRig.rectified(cam, 0.1)
    root, _ = record(SyntheticSource(160, 80, fps=10, frames=3, disparity_px=16, seed=3),
                     tmp_path / "cap", rig=rig)
    out = tmp_path / "rec.h5"
    args = ["stereo", "--recording", str(root), "--out", str(out), "--max-disparity", "20",
            "--set", "border=none"]
    assert main([*args[:3], "--left", "x", *args[3:]]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(args) == 0                               # the recording's own rig
    rec = read_recording(root)
    with SequenceReader(out) as r:
        assert len(r) == 3 and r.meta.gt_kind == "stereo"
        np.testing.assert_allclose(r.timestamps(), [f.timestamp_s for f in rec.frames])
        assert r.meta.provenance["input_rig"]["T"] == pytest.approx([-0.1, 0, 0])
        left, right = SyntheticSource(160, 80, disparity_px=16, seed=3).make_pair(1)
        grey3 = [np.repeat(a[..., None], 3, axis=2) for a in (left, right)]
        conf = StereoConfig(num_disparities=32, options={"border": "none"})
        ref = StereoPipeline(rig, conf).process(*grey3)
        np.testing.assert_array_equal(r.depth(1), ref.depth)
        d = ref.disparity[np.isfinite(ref.disparity)]
        assert np.median(d) == pytest.approx(16, abs=0.5)   # the source's true disparity
    (root / "manifest.json").write_text((root / "manifest.json").read_text()
                                        .replace('"rig": {', '"rig_": {'))
    assert main([*args[:3], "--out", str(tmp_path / "x.h5")]) == 2
    assert "pass --rig" in capsys.readouterr().err


def test_synthetic_scene_depth_matches_rendered_truth():
    """Issue 3: on the generator's 800x400 scenes, stereo depth within 20 m has AbsRel < 0.05."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    scene = SyntheticScene(preset("c1", seed=0))
    fr = scene.render(10)
    res = StereoPipeline(scene.rig, StereoConfig()).process(fr["left"], fr["right"])
    near = np.isfinite(fr["depth"]) & (fr["depth"] < 20)
    m = near & np.isfinite(res.depth)
    assert m.sum() > 0.9 * near.sum()
    assert np.mean(np.abs(res.depth[m] - fr["depth"][m]) / fr["depth"][m]) < 0.05


def test_ply_holds_the_finite_points_and_colours(tmp_path):
    from staticdepth.stereo.io import write_ply

    P = np.array([[[0.5, -1.0, 2.0], [np.nan, 0, 1]], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]]])
    C = np.array([[[255, 0, 1], [9, 9, 9]], [[2, 3, 4], [5, 6, 7]]], np.uint8)
    assert write_ply(tmp_path / "p.ply", P, C) == 3
    raw = (tmp_path / "p.ply").read_bytes()
    head, body = raw.split(b"end_header\n")
    assert b"element vertex 3" in head and b"property uchar red" in head
    rows = np.frombuffer(body, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"),
                                ("g", "u1"), ("b", "u1")])
    assert rows["z"].tolist() == [2.0, 3.0, 6.5] and rows["r"].tolist() == [255, 2, 5]
