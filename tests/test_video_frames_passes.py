"""Decoding passes of a video: ``VideoFrames`` counts its frames by demuxing (no decoding), so
that ``stereo`` decodes a video once and ``observations`` (median background, then every frame)
twice, not two and three times; ``import-video`` decodes once. The count is still exact where the
container's header is wrong, and a backend without raw packets still counts by decoding."""
import struct

import cv2
import numpy as np
import pytest

from staticdepth.dataset.video import VideoFrames, import_video

N = 24


_VideoCapture = cv2.VideoCapture


class Counted:
    """cv2.VideoCapture that counts the frames it decodes (grab or read outside raw mode)."""

    decoded = 0
    raw_mode = True          # whether set(CAP_PROP_FORMAT, -1) is allowed

    def __init__(self, *args):
        self.cap, self.raw = _VideoCapture(*args), False

    def __getattr__(self, name):
        return getattr(self.cap, name)

    def set(self, prop, value):
        if prop == cv2.CAP_PROP_FORMAT and value == -1:
            self.raw = Counted.raw_mode and self.cap.set(prop, value)
            return self.raw
        return self.cap.set(prop, value)

    def grab(self):
        ok = self.cap.grab()
        Counted.decoded += bool(ok and not self.raw)
        return ok

    def read(self, *args):
        ok, img = self.cap.read(*args)
        Counted.decoded += bool(ok and not self.raw)
        return ok, img


@pytest.fixture
def counted(monkeypatch):
    monkeypatch.setattr(cv2, "VideoCapture", Counted)
    monkeypatch.setattr(Counted, "decoded", 0)
    monkeypatch.setattr(Counted, "raw_mode", True)
    return Counted


def _video(path, n: int = N, size=(64, 48)):
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size)
    for k in range(n):
        out.write(np.random.default_rng(k).integers(0, 256, (size[1], size[0], 3), np.uint8))
    out.release()
    return str(path)


def test_reading_in_order_decodes_each_frame_once(tmp_path, counted):
    """The ``stereo`` path: the length, then every frame in order (the old count decoded too)."""
    frames = VideoFrames(_video(tmp_path / "v.avi"))
    assert len(frames) == N and counted.decoded == 0
    assert [int(f[0, 0, 0]) for f in frames] == [int(f[0, 0, 0]) for f in frames[:]]
    assert counted.decoded == 2 * N                         # the two reads above, nothing more
    view = VideoFrames(str(tmp_path / "v.avi"), start=5, step=3, max_frames=4)
    assert len(view) == 4 and [view.source_index(i) for i in range(4)] == [5, 8, 11, 14]


def test_observations_decode_a_video_twice(tmp_path, counted):
    """Median background (samples over the whole run) and then every frame: two passes (three,
    and frame 0 once more, with the decoding count)."""
    from staticdepth.observations import from_video

    path = _video(tmp_path / "v.avi")
    _, info = from_video(path, detector="motion", max_frames=N)
    assert (info["width"], info["height"]) == (64, 48)
    assert counted.decoded == 2 * N


def test_import_video_decodes_once(tmp_path, counted):
    rep = import_video(_video(tmp_path / "v.avi"), str(tmp_path / "v.h5"))
    assert rep["frames"] == N and counted.decoded == N


def test_the_count_is_exact_where_the_header_is_wrong(tmp_path, counted):
    """An AVI whose headers say 40 frames (avih dwTotalFrames, strh dwLength) but holds 9."""
    data = bytearray(open(_video(tmp_path / "v.avi", 9), "rb").read())
    for tag, off in ((b"avih", 16), (b"strh", 32)):
        at = data.find(tag) + 8 + off
        assert struct.unpack_from("<I", data, at) == (9,)
        struct.pack_into("<I", data, at, 40)
    liar = tmp_path / "liar.avi"
    liar.write_bytes(bytes(data))
    assert cv2.VideoCapture(str(liar)).get(cv2.CAP_PROP_FRAME_COUNT) == 40
    frames = VideoFrames(str(liar))
    assert len(frames) == 9 and frames[8].shape == (48, 64, 3)


def test_a_backend_without_raw_packets_counts_by_decoding(tmp_path, counted):
    counted.raw_mode = False
    frames = VideoFrames(_video(tmp_path / "v.avi"), start=2, step=5)
    assert len(frames) == 5 and counted.decoded == N - 2
