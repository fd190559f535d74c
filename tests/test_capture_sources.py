"""UVC sources with fake OpenCV cameras, and replay of folders, videos and real sample data."""
from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from staticdepth.capture import layout
from staticdepth.capture.record import record
from staticdepth.capture.sources.base import SourceError, SourceLost
from staticdepth.capture.sources.opencv_source import OpenCVStereoSource, SideBySideSource
from staticdepth.capture.sources.replay import FolderSource, VideoSource, open_replay
from staticdepth.capture.sources.synthetic import SyntheticSource

P = 1 / 30


class FakeCamera:
    """A cv2.VideoCapture stand-in: given timestamps and images; ``grab`` fails after the last
    frame (an unplugged camera), or blocks (``stall=True``, a hung driver)."""

    def __init__(self, times_s, values, size=(24, 16), opened=True, stall=False, sbs=False):
        self.times_s, self.values, self.size = list(times_s), list(values), size
        self.opened, self.stall, self.sbs = opened, stall, sbs
        self.i = -1
        self.released = threading.Event()
        self.props: dict[int, float] = {}

    def isOpened(self):
        return self.opened

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(self.size[0])
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.size[1])
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.times_s[self.i] * 1000.0
        return 0.0

    def grab(self):
        if self.i + 1 >= len(self.times_s):
            if self.stall:
                self.released.wait(5.0)
            return False
        self.i += 1
        time.sleep(0.001)
        return True

    def retrieve(self):
        w, h = self.size
        img = np.full((h, w, 3), self.values[self.i], np.uint8)
        if self.sbs:
            img[:, w // 2:] = self.values[self.i] + 100
        return True, img

    def release(self):
        self.released.set()


def _factory(cams):
    return lambda dev: cams[dev]


def _pairs(root):
    rec = layout.read_recording(root)
    out = []
    for f in rec.frames:
        left = cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED)
        right = cv2.imread(str(f.right_path), cv2.IMREAD_UNCHANGED)
        assert left.ndim == 2  # grey by default
        out.append((int(left[0, 0]), int(right[0, 0]) - 100))
    return rec, out


def test_uvc_pairs_out_of_sync_cameras_by_nearest_timestamp(tmp_path):
    left_t = [k * P for k in range(20)]
    right_t = [k * P + (0.6 * P if 10 <= k <= 12 else 0.001) for k in range(20)]
    cams = {0: FakeCamera(left_t, range(20)), 1: FakeCamera(right_t, range(100, 120))}
    src = OpenCVStereoSource(0, 1, width=24, height=16, fps=30, timestamps="driver",
                             capture_factory=_factory(cams))
    root, s = record(src, tmp_path / "rec")
    rec, pairs = _pairs(root)
    expected = [(k, k) for k in range(10)] + [(11, 10), (12, 11)] + [(k, k) for k in range(13, 20)]
    assert pairs == expected
    assert s["source"]["unpaired_left"] == 1 and s["source"]["unpaired_right"] == 1
    # Finite fake cameras end like unplugged ones: the recording says so and keeps every pair.
    assert s["status"] == "source_lost" and "stopped delivering" in s["detail"]
    assert [f.left_timestamp_s for f in rec.frames][:3] == pytest.approx([0, P, 2 * P])
    assert cams[0].props[cv2.CAP_PROP_FPS] == 30 and cams[0].released.is_set()


def test_uvc_camera_lost_mid_run_keeps_all_received_pairs(tmp_path):
    t = [k * P for k in range(30)]
    cams = {0: FakeCamera(t, range(30)), 1: FakeCamera(t[:12], range(100, 112))}
    src = OpenCVStereoSource(0, 1, fps=30, timestamps="driver", capture_factory=_factory(cams))
    root, s = record(src, tmp_path / "rec")
    _, pairs = _pairs(root)
    assert pairs == [(k, k) for k in range(12)]
    assert s["status"] == "source_lost" and s["frames_written"] == 12


def test_uvc_stalled_camera_times_out(tmp_path):
    t = [k * P for k in range(8)]
    cams = {0: FakeCamera(t, range(8), stall=True), 1: FakeCamera(t, range(100, 108), stall=True)}
    src = OpenCVStereoSource(0, 1, fps=30, timestamps="driver", frame_timeout_s=0.3,
                             capture_factory=_factory(cams))
    t0 = time.monotonic()
    root, s = record(src, tmp_path / "rec")
    assert time.monotonic() - t0 < 5.0
    assert s["status"] == "source_lost" and "no frame for 0.3 s" in s["detail"]
    assert s["frames_written"] == 8


def test_uvc_open_errors():
    closed = {0: FakeCamera([], []), 1: FakeCamera([], [], opened=False)}
    with pytest.raises(SourceError, match="camera 1 does not open"):
        OpenCVStereoSource(0, 1, capture_factory=_factory(closed)).open()
    assert closed[0].released.is_set()          # the camera that did open is released again
    small = {0: FakeCamera([], [], size=(640, 480))}
    with pytest.raises(SourceError, match="delivers 640x480, not the requested 1280x800"):
        SideBySideSource(0, width=1280, height=800, capture_factory=_factory(small)).open()
    with pytest.raises(SourceError, match="timestamps must be"):
        OpenCVStereoSource(0, 1, timestamps="gps")


def test_side_by_side_camera_is_split_in_halves(tmp_path):
    cams = {0: FakeCamera([k * P for k in range(6)], range(6), size=(32, 8), sbs=True)}
    src = SideBySideSource(0, fps=30, timestamps="driver", capture_factory=_factory(cams))
    root, s = record(src, tmp_path / "rec")
    rec, pairs = _pairs(root)
    assert pairs == [(k, k) for k in range(6)] and s["status"] == "source_lost"
    assert cv2.imread(str(rec.frames[0].left_path), cv2.IMREAD_UNCHANGED).shape == (8, 16)


def test_replay_real_stereo_image_folder(shared_data, tmp_path):
    d = shared_data / "opencv" / "stereo_calib"
    src = open_replay(str(d / "left*.jpg"), str(d / "right*.jpg"), fps=2.0)
    assert isinstance(src, FolderSource)
    root, s = record(src, tmp_path / "rec")
    assert s["status"] == "complete" and s["frames_written"] == 13
    rec = layout.read_recording(root)
    names = sorted(d.glob("left*.jpg"))
    for f, name in zip(rec.frames, names):
        assert np.array_equal(cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED),
                              cv2.imread(str(name), cv2.IMREAD_UNCHANGED))
    assert rec.frames[-1].timestamp_s == pytest.approx(6.0)


def test_replay_real_video_as_side_by_side(shared_data, tmp_path):
    video = shared_data / "video" / "vtest.avi"
    with pytest.raises(SourceError, match="import-video"):  # a lone video is not split unasked
        open_replay(video)
    src = open_replay(video, side_by_side=True)
    assert isinstance(src, VideoSource)
    root, s = record(src, tmp_path / "rec", max_frames=4)
    assert s["frames_written"] == 4 and src.nominal_fps == pytest.approx(10.0)
    cap = cv2.VideoCapture(str(video))
    frames = layout.read_recording(root).frames
    for f in frames:
        ok, img = cap.read()
        assert ok
        assert np.array_equal(cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED), img[:, :384])
        assert np.array_equal(cv2.imread(str(f.right_path), cv2.IMREAD_UNCHANGED), img[:, 384:])
    assert frames[1].timestamp_s == pytest.approx(0.1)


def test_replay_folder_with_left_and_right(tmp_path):
    src = SyntheticSource(40, 20)
    for side in ("left", "right"):
        (tmp_path / "pairs" / side).mkdir(parents=True)
    for k in range(3):
        left, right = src.make_pair(k)
        cv2.imwrite(str(tmp_path / "pairs" / "left" / f"{k:03d}.png"), left)
        cv2.imwrite(str(tmp_path / "pairs" / "right" / f"{k:03d}.png"), right)
    with open_replay(tmp_path / "pairs") as rs:
        got = list(rs.frames())
    assert [np.array_equal(g.right, src.make_pair(k)[1]) for k, g in enumerate(got)] == [True] * 3
    assert got[2].timestamp_s == pytest.approx(2 / 30)


def test_replay_errors(tmp_path):
    (tmp_path / "l").mkdir()
    (tmp_path / "r").mkdir()
    with pytest.raises(SourceError, match="no images found"):
        FolderSource(tmp_path / "l", tmp_path / "r").open()
    cv2.imwrite(str(tmp_path / "l" / "a.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(SourceError, match="1 left images but 0 right images"):
        FolderSource(tmp_path / "l", tmp_path / "r").open()
    cv2.imwrite(str(tmp_path / "r" / "a.png"), np.zeros((5, 4), np.uint8))
    with pytest.raises(SourceError, match="differ in size"), \
            FolderSource(tmp_path / "l", tmp_path / "r") as fs:
        list(fs.frames())
    (tmp_path / "r" / "a.png").write_bytes(b"not a png")
    with pytest.raises(SourceError, match="corrupt or unreadable image"), \
            FolderSource(tmp_path / "l", tmp_path / "r") as fs:
        list(fs.frames())
    with pytest.raises(SourceError, match="neither a recording"):
        open_replay(tmp_path)
    with pytest.raises(SourceError, match="not found"):
        open_replay(tmp_path / "missing.avi")
    (tmp_path / "bad.avi").write_bytes(b"junk")
    with pytest.raises(SourceError, match="cannot open as a video"):
        VideoSource(tmp_path / "bad.avi").open()
    with pytest.raises(SourceError, match="video file not found"):
        VideoSource(tmp_path / "a.avi", tmp_path / "b.avi").open()


def test_synthetic_source_validates_and_can_be_lost():
    with pytest.raises(SourceError.__mro__[1], match="width >= 16"):
        SyntheticSource(8, 8)
    with SyntheticSource(32, 16, lost_after=2) as s, pytest.raises(SourceLost):
        list(s.frames())


def test_replay_folder_pairs_unpadded_numbers_in_numeric_order(tmp_path):
    """left/1.png, 2.png, 10.png replay as frames 1, 2, 10 (plain sorting gave 1, 10, 2)."""
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for i in (10, 1, 2):
            cv2.imwrite(str(tmp_path / side / f"{i}.png"), np.full((4, 6), i, np.uint8))
    with open_replay(tmp_path) as rs:
        got = [int(f.left[0, 0].max()) for f in rs.frames()]
    assert got == [1, 2, 10]
