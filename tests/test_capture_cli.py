"""``staticdepth capture`` in process: recording, replay, and one-line errors with exit code 2."""
from __future__ import annotations

import json

import pytest

from staticdepth.capture import layout
from staticdepth.cli import main
from staticdepth.geometry.camera import Camera, StereoRig


def test_capture_synthetic_then_replay_with_rig(tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["capture", "--source", "synthetic", "--size", "64x32", "--fps", "60",
                 "--frames", "5", "--out", str(out), "--set", "segment_frames=2",
                 "--summary-json", str(tmp_path / "s.json")]) == 0
    assert "frames 5" in capsys.readouterr().out
    rec = layout.read_recording(out)
    assert len(rec.frames) == 5 and rec.manifest["record"]["segment_frames"] == 2
    assert json.loads((tmp_path / "s.json").read_text())["frames_written"] == 5
    rig_path = tmp_path / "rig.json"
    StereoRig.rectified(Camera.from_fov(64, 32, 80.0), 0.27).save(rig_path)
    assert main(["capture", "--source", "replay", "--input", str(out), "--out", str(tmp_path),
                 "--numbered", "--rig", str(rig_path), "--record-preset", "compact"]) == 0
    again = layout.read_recording(tmp_path / "rec_0000")
    assert len(again.frames) == 5 and again.rig.baseline_m == pytest.approx(0.27)
    assert [f.timestamp_s for f in again.frames] == [f.timestamp_s for f in rec.frames]


@pytest.mark.parametrize("argv, msg", [
    (["--source", "replay"], "needs --input"),
    (["--source", "synthetic", "--size", "64by32"], "WIDTHxHEIGHT"),
    (["--source", "synthetic", "--frames", "0"], "at least 1"),
    (["--source", "synthetic", "--record-preset", "tiny"], "unknown record preset"),
    (["--source", "synthetic", "--set", "png_compression=11"], "0-9"),
    (["--source", "synthetic", "--set", "colour=1"], "unknown record setting"),
    (["--source", "uvc", "--device", "0,1,2"], "expects LEFT,RIGHT"),
    (["--source", "sbs", "--device", "0,1"], "expects one camera"),
    (["--source", "depthai", "--preset", "oak-x"], "unknown depthai preset"),
    (["--source", "depthai", "--set", "exposure_us=abc"], "exposure_us"),
])
def test_capture_errors_are_one_line_exit_2(tmp_path, capsys, argv, msg):
    assert main(["capture", *argv, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and err.count("\n") == 0 and err.startswith("staticdepth capture: error:")
    assert not (tmp_path / "x").exists()


def test_existing_recording_is_refused(tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["capture", "--source", "synthetic", "--size", "32x16", "--frames", "1",
                 "--out", str(out)]) == 0
    assert main(["capture", "--source", "synthetic", "--size", "32x16", "--frames", "1",
                 "--out", str(out)]) == 2
    assert "never overwritten" in capsys.readouterr().err
