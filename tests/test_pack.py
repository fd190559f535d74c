"""Packing stereo recordings: stored depth equals the stereo pipeline's, executors agree, resume."""

import os

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.executors import ProcessExecutor, SerialExecutor, make_executor
from staticdepth.dataset.h5 import SequenceMeta, SequenceReader
from staticdepth.dataset.pack import LoadedFrame, pack_recording, write_frames
from staticdepth.errors import InputError
from staticdepth.geometry import Camera, StereoRig


@pytest.fixture(scope="module")
def plain_recording(tmp_path_factory):
    """Four synthetic frames (known depth) in the plain layout, with timestamps and a rig file."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    d = tmp_path_factory.mktemp("rec")
    scene = SyntheticScene(preset("demo", width=192, height=96, seed=1))
    frames = [scene.render(i) for i in range(4)]
    for sub in ("left", "right"):
        (d / sub).mkdir()
    for i, fr in enumerate(frames):
        cv2.imwrite(str(d / "left" / f"{i:04d}.png"), fr["left"][..., ::-1])
        cv2.imwrite(str(d / "right" / f"{i:04d}.png"), fr["right"][..., ::-1])
    (d / "timestamps.csv").write_text("frame,timestamp_s\n" + "".join(
        f"{i},{fr['timestamp']}\n" for i, fr in enumerate(frames)))
    scene.rig.save(d / "rig.json")
    return d, scene, frames


def _pack(rec, out, *extra):
    return main(["pack", "--recording", str(rec), "--rig", str(rec / "rig.json"),
                 "--camera-height", "5.0", "--adapt-frames", "2", "--out", str(out),
                 "--set", "num_disparities=32", *extra])


def _assert_same_file(a, b):
    with SequenceReader(a) as ra, SequenceReader(b) as rb:
        assert len(ra) == len(rb)
        for i in range(len(ra)):
            for s in ra.streams():
                np.testing.assert_array_equal(ra.read(s, i), rb.read(s, i))
        np.testing.assert_array_equal(ra.timestamps(), rb.timestamps())


def test_pack_cli_stores_the_pipeline_depth(plain_recording, tmp_path, capsys):
    from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline

    rec, scene, frames = plain_recording
    out = tmp_path / "R.h5"
    assert _pack(rec, out) == 0
    assert "wrote 4 frames" in capsys.readouterr().out
    pipe = StereoPipeline(scene.rig, StereoConfig(num_disparities=32))
    with SequenceReader(out) as r:
        assert len(r) == 4 and r.streams() == ["left", "right", "depth"]
        assert r.meta.gt_kind == "stereo" and r.split("adapt") == range(2)
        assert r.meta.camera_height_m == 5.0 and r.meta.mounting.pitch_deg == pytest.approx(25)
        assert r.meta.rig.baseline_m == pytest.approx(0.27)
        prov = r.meta.provenance
        assert prov["matcher"] == "sgbm" and prov["stereo_config"]["num_disparities"] == 32
        assert prov["pipeline"]["matcher"]  # the matcher's resolved parameters
        assert r.attrs["toolkit_version"]
        np.testing.assert_allclose(r.timestamps(), [f["timestamp"] for f in frames])
        errs = []
        for i, fr in enumerate(frames):
            res = pipe.process(fr["left"], fr["right"])
            np.testing.assert_array_equal(r.depth(i), res.depth)  # NaN where the check failed
            np.testing.assert_array_equal(r.left(i), fr["left"])
            ok = np.isfinite(res.depth) & np.isfinite(fr["depth"])
            errs.append(np.median(np.abs(res.depth[ok] - fr["depth"][ok]) / fr["depth"][ok]))
            assert np.isnan(r.depth(i)).any() and ok.mean() > 0.5
        assert np.median(errs) < 0.1  # against the scene's true depth (disparities of 1-5 px)


def test_process_pool_and_ray_give_the_same_file(plain_recording, tmp_path):
    rec, _, _ = plain_recording
    assert _pack(rec, tmp_path / "serial.h5") == 0
    assert _pack(rec, tmp_path / "pool.h5", "--workers", "2") == 0
    _assert_same_file(tmp_path / "serial.h5", tmp_path / "pool.h5")
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install ray)")
    assert _pack(rec, tmp_path / "ray.h5", "--executor", "ray", "--workers", "2") == 0
    _assert_same_file(tmp_path / "serial.h5", tmp_path / "ray.h5")


def test_capture_layout_recording(tmp_path):
    from staticdepth.capture.record import record
    from staticdepth.capture.sources.synthetic import SyntheticSource

    cam = Camera.from_intrinsics(100.0, 100.0, 79.5, 39.5, 160, 80)
    rig = StereoRig.rectified(cam, 0.1)
    root, _ = record(SyntheticSource(160, 80, fps=10, frames=3, disparity_px=16, seed=3),
                     tmp_path / "cap", rig=rig)
    rep = pack_recording(root, None, tmp_path / "C.h5", camera_height_m=4.0,
                         overrides={"num_disparities": "32"})
    assert rep.frames == 3
    with SequenceReader(tmp_path / "C.h5") as r:
        np.testing.assert_allclose(r.timestamps(), [0, 0.1, 0.2])
        from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline

        pipe = StereoPipeline(rig, StereoConfig(num_disparities=32))
        left, right = SyntheticSource(160, 80, disparity_px=16, seed=3).make_pair(1)
        res = pipe.process(*(np.repeat(a[..., None], 3, axis=2) for a in (left, right)))
        np.testing.assert_array_equal(r.depth(1), res.depth)  # grey frames read as RGB
        assert r.meta.camera_height_m == 4.0 and r.meta.mounting is None


class _Counting:
    """A loader that records calls and can fail once at a given task (a simulated kill)."""

    def __init__(self, fail_at=None):
        self.calls, self.fail_at = [], fail_at

    def __call__(self, t):
        if t == self.fail_at:
            self.fail_at = None
            raise KeyboardInterrupt
        if t == 3:
            raise InputError("corrupt or unreadable image", f"/x/{t}.png")
        self.calls.append(t)
        img = np.full((8, 16, 3), t, np.uint8)
        return LoadedFrame({"left": img, "depth": np.full((8, 16), t + 1.0, np.float32)},
                           timestamp=t / 10)


def test_resume_after_interruption_loads_only_the_rest(tmp_path):
    meta = SequenceMeta(name="x", camera=Camera.from_fov(16, 8, 90), adapt_frames=1)
    tasks = list(range(8))
    first = _Counting(fail_at=5)
    with pytest.raises(KeyboardInterrupt):
        write_frames(tmp_path / "x.h5", meta, ("left", "depth"), tasks, first, skip_bad=True)
    assert not (tmp_path / "x.h5").exists() and (tmp_path / "x.h5.partial").exists()
    second = _Counting()
    rep = write_frames(tmp_path / "x.h5", meta, ("left", "depth"), tasks, second, skip_bad=True,
                       resume=True)
    assert first.calls == [0, 1, 2, 4] and second.calls == [5, 6, 7]  # 3 was a bad frame
    assert rep.frames == 7 and rep.resumed_from == 4 and [s["frame"] for s in rep.skipped] == ["3"]
    with SequenceReader(tmp_path / "x.h5") as r:
        assert [int(r.left(i)[0, 0, 0]) for i in range(7)] == [0, 1, 2, 4, 5, 6, 7]
        assert r.meta.provenance["skipped"][0]["error"] == "/x/3.png: corrupt or unreadable image"
        assert r.meta.provenance["frames_in_input"] == 8


def test_executors_keep_order():
    items = list(range(20))
    assert list(SerialExecutor().map(abs, items)) == items
    ex = ProcessExecutor(2, window=3)
    try:
        assert list(ex.map(abs, [-i for i in items])) == items
    finally:
        ex.close()
    with pytest.raises(InputError, match="unknown executor"):
        make_executor("dask")
    with pytest.raises(InputError, match="--workers must be within 1..256"):
        make_executor("process", 0)
    with pytest.raises(InputError, match="only used with --executor ray"):
        make_executor("serial", 1, "ray://x:10001")


def test_pack_bad_input(plain_recording, tmp_path, capsys):
    rec0, _, _ = plain_recording
    rec = tmp_path / "rec"
    for sub in ("left", "right"):
        (rec / sub).mkdir(parents=True)
        for p in sorted((rec0 / sub).iterdir()):
            (rec / sub / p.name).write_bytes(p.read_bytes())
    (rec / "rig.json").write_text((rec0 / "rig.json").read_text())
    out = tmp_path / "R.h5"
    (rec / "right" / "0002.png").write_bytes(b"broken")
    assert _pack(rec, out) == 2
    assert "right/0002.png: corrupt or unreadable image" in capsys.readouterr().err
    assert _pack(rec, out) == 2                                         # nothing was interrupted
    assert capsys.readouterr().err.strip().endswith(
        f"{out}.partial: an earlier run stopped before finishing (interrupted, or by a bad input) "
        "and left this file: --resume continues it (add --skip-bad to pass a bad frame that "
        "stopped it), --restart starts over")
    assert _pack(rec, out, "--skip-bad", "--resume") == 0
    assert "skipped 1 bad frame" in capsys.readouterr().out
    with SequenceReader(out) as r:
        assert len(r) == 3
    # a pair of the wrong size for the rig
    small = cv2.imread(str(rec0 / "left" / "0000.png"))[:48]
    cv2.imwrite(str(rec / "right" / "0002.png"), small)
    with pytest.raises(InputError, match="but the rig was calibrated for 192x96") as e:
        pack_recording(rec, rec / "rig.json", tmp_path / "x.h5", overrides={"num_disparities": 32})
    assert e.value.path.endswith("left/0002.png")
    (rec / "right" / "0002.png").unlink()
    with pytest.raises(InputError, match="mismatched frame counts"):
        pack_recording(rec, rec / "rig.json", tmp_path / "x.h5", overrides={"num_disparities": 32})
    (rec / "left" / "0002.png").unlink()
    (rec / "timestamps.csv").write_text("0,0.0\n1,0.1\n")
    with pytest.raises(InputError, match="2 timestamps for 3 frames"):
        pack_recording(rec, rec / "rig.json", tmp_path / "x.h5", overrides={"num_disparities": 32})
    (rec / "timestamps.csv").unlink()
    with pytest.raises(InputError, match="has no rig"):
        pack_recording(rec, None, tmp_path / "x.h5", overrides={"num_disparities": 32})
    with pytest.raises(InputError, match="unknown setting"):
        pack_recording(rec, rec / "rig.json", tmp_path / "x.h5", overrides={"bogus": "1"})
    with pytest.raises(InputError, match=r"--camera-height must be a height in metres.*got -1.0"):
        pack_recording(rec, rec / "rig.json", tmp_path / "x.h5", camera_height_m=-1.0,
                       overrides={"num_disparities": 32})
    with pytest.raises(InputError, match="recording folder not found"):
        pack_recording(tmp_path / "none", rec / "rig.json", tmp_path / "x.h5")


def test_mounting_of_a_calibrated_rig_is_kept_in_the_rectified_frame(plain_recording, tmp_path):
    """``mount`` stores the ground normal in the rectified left frame: pack must not rotate it."""
    from staticdepth.geometry.camera import Mounting, normal_from_pitch_roll

    rec, scene, _ = plain_recording
    cam = scene.rig.left
    n = normal_from_pitch_roll(30.0, 2.0)
    rig = StereoRig(cam, cam, cv2.Rodrigues(np.array([0.0, 0.02, 0.01]))[0], [-0.27, 0, 0],
                    mounting=Mounting(4.5, n))
    assert not rig.is_rectified()
    rig.save(tmp_path / "rig.json")
    pack_recording(rec, tmp_path / "rig.json", tmp_path / "M.h5", camera_height_m=5.0,
                   overrides={"num_disparities": "32"})
    with SequenceReader(tmp_path / "M.h5") as r:
        np.testing.assert_allclose(r.meta.mounting.normal, n, atol=1e-12)
        assert r.meta.camera_height_m == 5.0


def render_recording(d, frames: int, width: int, height: int, swap: bool = False):
    """A ``left/``, ``right/``, ``rig.json`` recording of the demo scene (seed 1) in folder
    ``d``; ``swap`` exchanges the views. Returns the scene."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    scene = SyntheticScene(preset("demo", width=width, height=height, seed=1))
    views = ("right", "left") if swap else ("left", "right")
    for sub in ("left", "right"):
        (d / sub).mkdir()
    for i in range(frames):
        fr = scene.render(i)
        for sub, view in zip(("left", "right"), views):
            cv2.imwrite(str(d / sub / f"{i:04d}.png"), fr[view][..., ::-1])
    scene.rig.save(d / "rig.json")
    return scene


@pytest.fixture(scope="module")
def swapped_recording(tmp_path_factory):
    """Two 320x160 frames of the demo scene with the left and right views exchanged."""
    d = tmp_path_factory.mktemp("swapped")
    return d, render_recording(d, 2, 320, 160, swap=True)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_pack_refuses_swapped_views(swapped_recording, tmp_path, capsys):
    rec, _ = swapped_recording
    argv = ["pack", "--recording", str(rec), "--rig", str(rec / "rig.json"),
            "--set", "num_disparities=32", "--out", str(tmp_path / "S.h5")]
    assert main(argv) == 2
    assert _one_error_line(capsys).endswith(
        f"{rec}/left/0000.png: the views look swapped: 100% of the matched features have a "
        "negative disparity (the right image matches better as the left); exchange the "
        "recording's left and right images, or pass --skip-rectification-check")
    assert not (tmp_path / "S.h5").exists() and not (tmp_path / "S.h5.partial").exists()
    assert main(argv + ["--skip-rectification-check"]) == 0  # the way out the message names
    with SequenceReader(tmp_path / "S.h5") as r:
        assert len(r) == 2


def test_pack_accepts_the_skip_rectification_check_its_error_suggests(swapped_recording,
                                                                       tmp_path, capsys):
    rec, scene = swapped_recording
    cam = scene.rig.left
    tilted = StereoRig(cam, cam, cv2.Rodrigues(np.array([0.04, 0.0, 0.0]))[0],
                       [-scene.rig.baseline_m, 0, 0])  # rows 7 px apart after rectifying
    tilted.save(tmp_path / "tilted.json")
    argv = ["pack", "--recording", str(rec), "--rig", str(tmp_path / "tilted.json"),
            "--set", "num_disparities=32", "--out", str(tmp_path / "T.h5")]
    assert main(argv) == 2
    line = _one_error_line(capsys)
    assert "images are not rectified: matched features are 7.0 px apart vertically" in line
    assert line.endswith("or pass --skip-rectification-check")
    assert not (tmp_path / "T.h5").exists()
    assert main(argv + ["--skip-rectification-check"]) == 0
    assert "wrote 2 frames" in capsys.readouterr().out


def test_plain_recording_frames_are_in_numeric_order(tmp_path):
    """left/1.png, 2.png, 10.png are packed as frames 1, 2, 10 (plain sorting gave 1, 10, 2),
    paired with their timestamps in that order."""
    from staticdepth.dataset.pack import recording_tasks

    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for i in (10, 1, 2):
            (tmp_path / side / f"{i}.png").write_bytes(b"")
    (tmp_path / "timestamps.csv").write_text("frame,timestamp_s\n1,0.1\n2,0.2\n10,1.0\n")
    tasks, labels, _ = recording_tasks(tmp_path)
    assert labels == ["1", "2", "10"]
    assert [os.path.basename(t.left) for t in tasks] == ["1.png", "2.png", "10.png"]
    assert [t.timestamp for t in tasks] == [0.1, 0.2, 1.0]


_WRITERS = {"pack": ["pack", "--recording", "{d}/rec"], "import-kitti": [
    "import-kitti", "--root", "{d}/kitti", "--drives", "2011_09_26_drive_0001"],
    "import-carla": ["import-carla", "{d}/carla"]}


@pytest.mark.parametrize("command", sorted(_WRITERS))
@pytest.mark.parametrize("workers, executor", [("0", "serial"), ("-5", "serial"),
                                               ("100000", "serial"), ("0", "process"),
                                               ("300", "ray")])
def test_workers_rule_is_one_line_before_any_work(command, workers, executor, tmp_path, capsys):
    """--workers 0, -5 ran serially and 100000 was taken; one rule for every executor, checked
    before the input is even looked at (the inputs here do not exist)."""
    args = [a.format(d=tmp_path) for a in _WRITERS[command]]
    assert main(args + ["--out", str(tmp_path / "o.h5"), "--workers", workers,
                        "--executor", executor]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        f"--workers must be within 1..256 (local worker processes), got {workers}"), err
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("command", sorted(_WRITERS) + ["import-video"])
@pytest.mark.parametrize("n", ["0", "-3"])
def test_adapt_frames_rule_is_the_same_for_every_importer(command, n, tmp_path, capsys):
    """import-kitti/-carla and pack took --adapt-frames 0 (and -3) where import-video refused
    it: one rule, one wording (only what leaving it out means differs), before any work."""
    args = ([a.format(d=tmp_path) for a in _WRITERS[command]] if command in _WRITERS
            else ["import-video", str(tmp_path / "v.avi")])
    assert main(args + ["--out", str(tmp_path / "o.h5"), "--adapt-frames", n]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    left_out = "all of them" if command == "import-video" else "none: every frame is for evaluation"
    assert len(err) == 1 and err[0].endswith(
        f"--adapt-frames must be >= 1 (the first frames, which adapt learns from; leave it out "
        f"for {left_out}), got {n}"), err
    assert os.listdir(tmp_path) == []


def test_a_recording_without_png_pairs_names_its_folder_and_what_it_holds(tmp_path, capsys):
    """A folder of .jpg pairs gave 'R1.h5: no frames to write', naming the output."""
    for side in ("left", "right"):
        (tmp_path / "rec" / side).mkdir(parents=True)
    out = tmp_path / "R1.h5"
    assert main(["pack", "--recording", str(tmp_path / "rec"), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().endswith(
        f"error: {tmp_path / 'rec' / 'left'}: holds no .png files (empty)")
    for side in ("left", "right"):
        for i in range(2):
            cv2.imwrite(str(tmp_path / "rec" / side / f"{i}.jpg"), np.zeros((8, 8), np.uint8))
    (tmp_path / "rec" / "left" / "notes.txt").write_text("x")
    assert main(["pack", "--recording", str(tmp_path / "rec"), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().endswith(
        f"error: {tmp_path / 'rec' / 'left'}: holds no .png files (it holds 2 .jpg, 1 .txt "
        "files)")
    assert not out.exists()
