"""Recording: lossless round trips, segments, every kind of stop, kill safety."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from staticdepth.capture import layout
from staticdepth.capture.record import RecordConfig, Recorder, record
from staticdepth.capture.sources.base import SourceError, StereoFrame, StereoSource
from staticdepth.capture.sources.replay import RecordingSource
from staticdepth.capture.sources.synthetic import SyntheticSource
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig

REPO = Path(__file__).resolve().parents[1]


def assert_lossless(rec: layout.Recording, src: SyntheticSource) -> None:
    """Every listed frame decodes to exactly the synthetic frame it was made from."""
    for f in rec.frames:
        left, right = src.make_pair(f.sequence)
        assert np.array_equal(cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED), left)
        assert np.array_equal(cv2.imread(str(f.right_path), cv2.IMREAD_UNCHANGED), right)


def test_record_and_replay_round_trip_is_lossless(tmp_path):
    rig = StereoRig.rectified(Camera.from_fov(96, 64, 90.0), 0.27)
    src = SyntheticSource(96, 64, 30.0, frames=10)
    root, summary = record(src, tmp_path / "rec", RecordConfig(segment_frames=4), rig=rig)
    assert summary["status"] == "complete" and summary["frames_written"] == 10
    assert summary["achieved_fps"] == pytest.approx(30.0)
    rec = layout.read_recording(root)
    assert [f.frame for f in rec.frames] == list(range(10))
    assert [f.segment for f in rec.frames] == [0] * 4 + [1] * 4 + [2] * 2
    assert [f.timestamp_s for f in rec.frames] == pytest.approx([k / 30 for k in range(10)])
    assert rec.status == "complete" and rec.rig.baseline_m == pytest.approx(0.27)
    assert StereoRig.load(root / "rig.json").left == rig.left
    assert [s["frames"] for s in rec.manifest["segments"]] == [4, 4, 2]
    assert_lossless(rec, SyntheticSource(96, 64, 30.0))
    # Replay yields the same images and timestamps, and carries the rig.
    with RecordingSource(root) as rs:
        frames = list(rs.frames())
        assert rs.rig.baseline_m == pytest.approx(0.27) and rs.nominal_fps == 30.0
    assert len(frames) == 10
    ref = SyntheticSource(96, 64)
    for k, fr in enumerate(frames):
        assert np.array_equal(fr.left, ref.make_pair(k)[0])
        assert fr.timestamp_s == pytest.approx(k / 30)


@pytest.mark.parametrize("preset", ["fast", "zlib1", "compact"])
def test_colour_and_16_bit_frames_are_stored_exactly(tmp_path, preset):
    from staticdepth.capture.record import RECORD_PRESETS

    rng = np.random.default_rng(1)
    frames = [StereoFrame.at(rng.integers(0, 256, (20, 30, 3), dtype=np.uint8),
                             rng.integers(0, 256, (20, 30, 3), dtype=np.uint8), 0.0, 0.001, 0),
              StereoFrame.at(rng.integers(0, 65536, (20, 30), dtype=np.uint16),
                             rng.integers(0, 65536, (20, 30), dtype=np.uint16), 0.1, 0.1, 1)]
    rec = Recorder(layout.create_recording_dir(tmp_path / "r"), RECORD_PRESETS[preset])
    for f in frames:
        rec.write(f)
    assert rec.close()["frames_written"] == 2
    back = layout.read_recording(tmp_path / "r").frames
    for f, b in zip(frames, back):
        assert np.array_equal(cv2.imread(str(b.left_path), cv2.IMREAD_UNCHANGED), f.left)
        assert np.array_equal(cv2.imread(str(b.right_path), cv2.IMREAD_UNCHANGED), f.right)
    assert back[0].timestamp_s == pytest.approx(0.0005) and back[0].right_timestamp_s == 0.001


def test_disk_full_stops_cleanly_with_earlier_frames_intact(tmp_path):
    def write_bytes(path: str, data: bytes) -> None:
        if "00000007" in path:
            raise OSError(errno.ENOSPC, "No space left on device", path)
        with open(path, "wb") as f:
            f.write(data)

    src = SyntheticSource(64, 32, 30.0, frames=40)
    root, summary = record(src, tmp_path / "rec", RecordConfig(queue_frames=8),
                           write_bytes=write_bytes)
    assert summary["status"] == "disk_full" and "No space left" in summary["detail"]
    assert summary["frames_written"] == 7
    rec = layout.read_recording(root)
    assert rec.status == "disk_full" and [f.frame for f in rec.frames] == list(range(7))
    assert_lossless(rec, SyntheticSource(64, 32))
    # Frames written after the failure were removed: only committed frames are on disk.
    for side in ("left", "right"):
        assert sorted(os.listdir(root / "seg_0000" / side)) == [layout.frame_name(k)
                                                                for k in range(7)]


class _ShortWrites:
    """A CSV file object whose writes stop half-way (a disk filling up in the middle of a line)."""

    def __init__(self, f):
        self.f = f

    def write(self, data):
        return self.f.write(data[: len(data) // 2])

    def __getattr__(self, name):
        return getattr(self.f, name)


def test_torn_timestamp_row_is_cut_back_to_the_last_whole_line(tmp_path):
    img = np.zeros((8, 8), np.uint8)
    rec = Recorder(layout.create_recording_dir(tmp_path / "r"))
    rec.write(StereoFrame.at(img, img, 0.0, 0.0, 0))
    while rec.committed < 1:
        time.sleep(0.01)
    rec._csv = _ShortWrites(rec._csv)
    rec.write(StereoFrame.at(img, img, 0.1, 0.1, 1))
    s = rec.close()
    assert s["status"] == "disk_full" and "short write" in s["detail"]
    text = (tmp_path / "r" / "seg_0000" / "timestamps.csv").read_text()
    assert text.endswith("\n") and text.count("\n") == 2          # header + frame 0
    assert [f.frame for f in layout.read_recording(tmp_path / "r").frames] == [0]
    assert not (tmp_path / "r" / "seg_0000" / "left" / layout.frame_name(1)).exists()


def test_source_lost_mid_run_keeps_every_received_frame(tmp_path):
    root, summary = record(SyntheticSource(64, 32, frames=None, lost_after=6), tmp_path / "rec")
    assert summary["status"] == "source_lost" and "lost after 6" in summary["detail"]
    rec = layout.read_recording(root)
    assert len(rec.frames) == 6 and rec.status == "source_lost"
    assert_lossless(rec, SyntheticSource(64, 32))


def test_stop_event_and_limits(tmp_path):
    stop = threading.Event()

    def on_frame(n, rec):
        if n == 5:
            stop.set()

    _, s = record(SyntheticSource(64, 32), tmp_path / "a", stop=stop, on_frame=on_frame)
    assert s["status"] == "stopped" and s["frames_written"] == 5
    _, s = record(SyntheticSource(64, 32), tmp_path / "b", max_frames=3)
    assert s["status"] == "frame_limit" and s["frames_written"] == 3
    _, s = record(SyntheticSource(64, 32, fps=100, realtime=True), tmp_path / "c",
                  duration_s=0.15)
    assert s["status"] == "time_limit" and 10 <= s["frames_written"] <= 20


def test_recordings_are_never_overwritten(tmp_path):
    root, _ = record(SyntheticSource(32, 16, frames=2), tmp_path / "rec")
    with pytest.raises(InputError, match="never overwritten"):
        record(SyntheticSource(32, 16, frames=2), root)
    assert len(layout.read_recording(root).frames) == 2
    a, _ = record(SyntheticSource(32, 16, frames=1), tmp_path / "many", numbered=True)
    b, _ = record(SyntheticSource(32, 16, frames=1), tmp_path / "many", numbered=True)
    assert (a.name, b.name) == ("rec_0000", "rec_0001")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        layout.create_recording_dir(tmp_path / "file")


class _NoDevice(StereoSource):
    def open(self):
        raise SourceError("no device found within 1.0 s")

    def frames(self):
        yield from ()

    def close(self):
        pass


def test_source_that_cannot_open_leaves_no_folder(tmp_path):
    with pytest.raises(SourceError, match="no device"):
        record(_NoDevice(), tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_sequence_gaps_and_timestamp_gaps_are_summarised(tmp_path):
    img = np.zeros((8, 8), np.uint8)
    rec = Recorder(layout.create_recording_dir(tmp_path / "r"), nominal_fps=10.0)
    for seq in (0, 1, 2, 5, 6):  # device lost frames 3 and 4
        rec.write(StereoFrame.at(img, img, seq / 10, seq / 10, seq))
    s = rec.close()
    assert s["sequence_gaps"] == 2 and s["gaps"] == 1 and s["missing_frames_estimate"] == 2
    assert s["largest_gaps"][0]["frame"] == 3
    assert s["largest_gaps"][0]["gap_s"] == pytest.approx(0.3)


@pytest.mark.parametrize("kw, msg", [({"png_compression": 10}, "0-9"),
                                     ({"png_strategy": "lzma"}, "png_strategy"),
                                     ({"png_filter": "median"}, "png_filter"),
                                     ({"workers": 0}, "at least 1")])
def test_record_config_rejects_bad_values(kw, msg):
    with pytest.raises(InputError, match=msg):
        RecordConfig(**kw)


def _write_manifest(root: Path, **kw) -> None:
    root.mkdir(parents=True, exist_ok=True)
    (root / "manifest.json").write_text(json.dumps({"format": layout.RECORDING_FORMAT, **kw}))


def test_reader_ignores_a_torn_last_line_and_rejects_bad_files(tmp_path):
    root = tmp_path / "r"
    _write_manifest(root)
    seg = root / "seg_0000"
    seg.mkdir()
    (seg / "timestamps.csv").write_text(layout.CSV_HEADER + "\n0,0.0,0.0,0.0,0\n1,0.03,0.0")
    rec = layout.read_recording(root)
    assert [f.frame for f in rec.frames] == [0] and rec.status == "unknown"
    (seg / "timestamps.csv").write_text(layout.CSV_HEADER + "\n0,zero,0.0,0.0,0\n")
    with pytest.raises(InputError, match="line 2 is malformed"):
        layout.read_recording(root)
    (seg / "timestamps.csv").write_text("a,b\n")
    with pytest.raises(InputError, match="unexpected header"):
        layout.read_recording(root)
    (seg / "timestamps.csv").write_text(layout.CSV_HEADER + "\n1,0,0,0,0\n0,0,0,0,0\n")
    with pytest.raises(InputError, match="not increasing"):
        layout.read_recording(root)
    _write_manifest(root, format="other/1")
    with pytest.raises(InputError, match="unknown recording format"):
        layout.read_recording(root)
    with pytest.raises(InputError, match="file not found"):
        layout.read_recording(tmp_path)           # a folder without manifest.json
    with pytest.raises(InputError, match="not found"):
        layout.read_recording(tmp_path / "nope")


def _start_capture(out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "staticdepth.cli", "capture", "--source",
                             "synthetic", "--size", "320x200", "--fps", "30", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO,
                            text=True)


def _wait_rows(out: Path, n: int, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    csv = out / "seg_0000" / "timestamps.csv"
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if csv.exists() and csv.read_text().count("\n") > n:
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.kill()
    pytest.fail("capture subprocess wrote no frames in time")


def test_killed_recording_reads_back_to_its_last_complete_frame(tmp_path):
    out = tmp_path / "rec"
    proc = _start_capture(out)
    _wait_rows(out, 15, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    rec = layout.read_recording(out)
    assert rec.status == "recording"                     # never closed
    n = len(rec.frames)
    assert n >= 15 and [f.frame for f in rec.frames] == list(range(n))
    assert_lossless(rec, SyntheticSource(320, 200))
    with RecordingSource(out) as rs:                     # replay reads all of them
        assert sum(1 for _ in rs.frames()) == n


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_sigterm_and_ctrl_c_close_the_recording_cleanly(tmp_path, sig):
    out = tmp_path / "rec"
    proc = _start_capture(out)
    _wait_rows(out, 10, proc)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    rec = layout.read_recording(out)
    assert rec.status == "stopped" and "stopped" in stdout
    assert rec.manifest["summary"]["frames_written"] == len(rec.frames) >= 10
    assert_lossless(rec, SyntheticSource(320, 200))
