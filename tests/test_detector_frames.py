"""Frames read one at a time (dataset.video.VideoFrames, detectors.frames.SequenceFrames): a
video's frames by ``start`` / ``step`` / ``max_frames`` (checked against a plain sequential decode
of the same file), a sequence's split, and ``observations`` on a video keeps neither the frames
nor the instance maps of the whole run in memory."""
from __future__ import annotations

import tracemalloc

import cv2
import numpy as np
import pytest

from staticdepth.dataset.video import VideoFrames
from staticdepth.detectors.frames import SequenceFrames
from staticdepth.errors import InputError

W, H = 160, 96


def _write_video(path, n: int, size=(W, H), person: bool = False) -> None:
    """An MJPG video whose frame k is a distinct noise image (seed k); with ``person`` a dark
    upright 14x40 block walks right over a fixed textured background."""
    w, h = size
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (w, h))
    assert out.isOpened()
    bg = np.random.default_rng(99).integers(100, 200, (h, w, 3), dtype=np.uint8)
    for k in range(n):
        if person:
            img = bg.copy()
            u = 10 + (3 * k) % (w - 30)
            v = h // 2 + (k % 40) // 2
            img[v - 40:v, u:u + 14] = 20
        else:
            img = np.random.default_rng(k).integers(0, 256, (h, w, 3), dtype=np.uint8)
        out.write(img)
    out.release()


def _decoded(path) -> list[np.ndarray]:
    """Every frame of the file as RGB, read in one sequential pass (the reference)."""
    cap, out = cv2.VideoCapture(str(path)), []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        out.append(bgr[..., ::-1])
    cap.release()
    return out


@pytest.mark.parametrize("start,step,max_frames", [(0, 1, None), (0, 1, 7), (5, 3, None),
                                                   (4, 2, 6), (22, 5, 100), (0, 4, 6)])
def test_video_frames_match_a_sequential_decode(tmp_path, start, step, max_frames):
    path = tmp_path / "v.avi"
    _write_video(path, 25)
    ref = _decoded(path)
    assert len(ref) == 25
    want = list(range(start, 25, step))[:max_frames]
    frames = VideoFrames(str(path), start, step, max_frames)
    assert len(frames) == len(want)
    assert [frames.source_index(i) for i in range(len(frames))] == want
    for i, k in enumerate(want):                       # forward
        assert np.array_equal(frames[i], ref[k])
    for i in reversed(range(len(want))):               # backward: reopens from start
        assert np.array_equal(frames[i], ref[want[i]])
    if want:
        assert np.array_equal(frames[-1], ref[want[-1]])
        assert len(frames[::2]) == len(want[::2])
    assert sum(1 for _ in frames) == len(want)         # iteration stops at the end
    with pytest.raises(IndexError):
        frames[len(want)]
    frames.close()


def test_video_frames_refuse_a_file_that_is_not_a_video(tmp_path):
    bad = tmp_path / "not.avi"
    bad.write_bytes(b"\0" * 100)
    with pytest.raises(InputError) as e:
        VideoFrames(str(bad))
    assert "not.avi" in str(e.value)


def test_sequence_frames_read_the_split(tmp_path):
    from staticdepth.cli import main
    from staticdepth.dataset.h5 import SequenceReader

    seq = tmp_path / "s.h5"
    assert main(["synth", "--preset", "demo", "--frames", "6", "--adapt-frames", "3",
                 "--set", "width=64", "--set", "height=48", "--out", str(seq)]) == 0
    with SequenceReader(str(seq)) as r:
        every, split = SequenceFrames(r), SequenceFrames(r, [4, 1, 5])
        assert len(every) == 6 and len(split) == 3
        assert np.array_equal(split[0], r.left(4)) and np.array_equal(split[-1], r.left(5))
        assert [f.shape for f in split[1:]] == [r.left(1).shape, r.left(5).shape]
        assert np.array_equal(every[2], r.left(2))
        with pytest.raises(IndexError):
            split[3]


def _traced_peak(fn):
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_observations_from_a_video_hold_one_frame_at_a_time(tmp_path):
    """Peak memory (tracemalloc) of ``observations`` on 400 frames against 200 of the same
    walk: reading every frame first, as the command did, grew with the length (320x240 RGB is
    0.23 MB a frame, its instance map 0.15 MB: 83 and 160 MB); streamed, the peak is the motion
    detector's 50 background samples and its 31-frame window (23 MB at both lengths)."""
    from staticdepth.observations import from_video

    path = tmp_path / "walk.avi"
    size = (320, 240)
    _write_video(path, 400, size, person=True)
    from_video(str(path), detector="motion", max_frames=20)       # imports and caches first
    peaks = {}
    for n in (200, 400):
        (obs, info), peaks[n] = _traced_peak(lambda: from_video(
            str(path), detector="motion", max_frames=n, min_height_px=20))
        assert (info["width"], info["height"]) == size
        assert len(obs) > n // 2 and obs["frame"].max() >= n - 10    # the walker, throughout
        assert np.median(obs["height_px"]) == pytest.approx(40, abs=3)
    assert peaks[400] < 1.2 * peaks[200], {n: f"{p / 1e6:.0f} MB" for n, p in peaks.items()}
