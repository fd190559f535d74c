"""``staticdepth capture`` refuses impossible rates and durations, camera options on a replay and a
rig of another size, in one line with exit code 2, before anything is written."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.capture import layout
from staticdepth.capture.sources.base import SourceError
from staticdepth.capture.sources.replay import FolderSource, open_replay
from staticdepth.cli import main
from staticdepth.geometry.camera import Camera, StereoRig


@pytest.fixture
def folders(tmp_path):
    """Three tiny grey pairs, 48x32, as left/ and right/ image folders."""
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for k in range(3):
            cv2.imwrite(str(tmp_path / side / f"{k:03d}.png"),
                        rng.integers(0, 255, (32, 48), dtype=np.uint8))
    return tmp_path


def _replay(folders, *extra):
    return ["capture", "--source", "replay", "--input", str(folders / "left"), "--right",
            str(folders / "right"), "--out", str(folders / "rec"), *extra]


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err.strip()
    assert err.startswith("staticdepth capture: error:") and "\n" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("fps", ["-5", "0", "nan", "inf", "1e9", "1000.5"])
def test_non_positive_or_non_finite_fps_is_refused(folders, capsys, fps):
    # 1e9 recorded its frames and reported 1.8 million missing between them
    assert main(_replay(folders, "--fps", fps)) == 2
    _one_line_error(capsys, "--fps", "frames per second in (0, 1000]")
    assert not (folders / "rec").exists()


def test_fps_zero_is_not_turned_into_30_by_the_library(folders):
    with pytest.raises(SourceError, match="positive"):
        open_replay(str(folders / "left"), str(folders / "right"), fps=0.0)
    with pytest.raises(SourceError, match="positive"):
        FolderSource(str(folders / "left"), str(folders / "right"), fps=-5.0)


def test_positive_fps_stamps_forward(folders):
    assert main(_replay(folders, "--fps", "5")) == 0
    times = [f.timestamp_s for f in layout.read_recording(folders / "rec").frames]
    assert times == pytest.approx([0.0, 0.2, 0.4])


@pytest.mark.parametrize("duration", ["-1", "0", "nan"])
def test_non_positive_duration_is_refused(folders, capsys, duration):
    assert main(_replay(folders, "--duration", duration)) == 2
    _one_line_error(capsys, "--duration", "positive")
    assert not (folders / "rec").exists()


@pytest.mark.parametrize("option", [["--size", "100x100"], ["--color"], ["--device", "0"],
                                    ["--fourcc", "YUYV"]])
def test_camera_options_are_refused_on_replay(folders, capsys, option):
    assert main(_replay(folders, *option)) == 2
    _one_line_error(capsys, option[0], "replay")
    assert not (folders / "rec").exists()


def test_replay_keeps_the_inputs_pixels(tmp_path):
    """Replay records what it reads: colour stays colour (the help says so), grey stays grey."""
    rng = np.random.default_rng(1)
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        cv2.imwrite(str(tmp_path / side / "0.png"), rng.integers(0, 255, (16, 24, 3), np.uint8))
    assert main(["capture", "--source", "replay", "--input", str(tmp_path), "--out",
                 str(tmp_path / "rec")]) == 0
    frame = layout.read_recording(tmp_path / "rec").frames[0]
    assert cv2.imread(str(frame.left_path), cv2.IMREAD_UNCHANGED).shape == (16, 24, 3)


def test_fps_on_a_recording_is_refused(folders, capsys):
    assert main(_replay(folders)) == 0
    capsys.readouterr()
    assert main(["capture", "--source", "replay", "--input", str(folders / "rec"), "--out",
                 str(folders / "copy"), "--fps", "3"]) == 2
    _one_line_error(capsys, "own timestamps", "--fps")
    assert not (folders / "copy").exists()


def test_rig_of_another_size_is_refused(folders, capsys):
    rig = folders / "rig640.json"
    StereoRig.rectified(Camera.from_fov(640, 480, 60.0), 0.1).save(rig)
    assert main(_replay(folders, "--rig", str(rig))) == 2
    _one_line_error(capsys, str(rig), "640x480", "48x32")
    assert not (folders / "rec").exists()
    good = folders / "rig48.json"
    StereoRig.rectified(Camera.from_fov(48, 32, 60.0), 0.1).save(good)
    assert main(_replay(folders, "--rig", str(good))) == 0
    rec = layout.read_recording(folders / "rec")
    assert len(rec.frames) == 3 and rec.rig.left.size == (48, 32)


def test_side_by_side_video_with_a_rig_of_another_size(tmp_path, capsys):
    """A 96x32 side-by-side video holds 48x32 views; a 640x480 rig is refused, naming its file."""
    video = tmp_path / "sbs.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 32))
    for k in range(3):
        writer.write(np.full((32, 96, 3), 40 * k, np.uint8))
    writer.release()
    rig = tmp_path / "rig.json"
    StereoRig.rectified(Camera.from_fov(640, 480, 60.0), 0.1).save(rig)
    assert main(["capture", "--source", "replay", "--input", str(video), "--side-by-side",
                 "--rig", str(rig), "--out", str(tmp_path / "rec")]) == 2
    _one_line_error(capsys, str(rig), "48x32")
    assert not (tmp_path / "rec").exists()
