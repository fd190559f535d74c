"""import-video: frames streamed from a video, a folder or the real vtest.avi into a sequence
file with stated intrinsics."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.video import camera_for, import_video
from staticdepth.errors import InputError


def _video(path, n=12, w=64, h=48, fps=5.0):
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert vw.isOpened()
    for i in range(n):
        vw.write(np.full((h, w, 3), 10 + 20 * i, np.uint8))      # frame i has grey 10 + 20 i
    vw.release()


def test_video_every_max_frames_fov_guess(tmp_path, capsys):
    src = tmp_path / "v.avi"
    _video(src)
    out = tmp_path / "v.h5"
    assert main(["import-video", str(src), "--out", str(out), "--every", "2", "--max-frames", "4",
                 "--fov-deg", "90"]) == 0
    printed = capsys.readouterr().out
    assert "GUESS" in printed and "90" in printed
    with SequenceReader(out) as r:
        assert len(r) == 4 and r.meta.gt_kind == "none" and r.streams() == ["left"]
        grey = [float(r.left(i).mean()) for i in range(4)]
        assert np.allclose(grey, [10 + 20 * k for k in (0, 2, 4, 6)], atol=4)   # MJPG loss
        assert np.allclose(r.timestamps(), [0.0, 0.4, 0.8, 1.2])
        assert abs(r.camera.fx - 64 / (2 * math.tan(math.radians(45)))) < 1e-9
        assert "GUESS" in r.meta.provenance["intrinsics"]
        assert len(r.split("adapt")) == 4                          # default: every frame


def test_folder_with_camera_json_scaled(tmp_path):
    d = tmp_path / "imgs"
    d.mkdir()
    for i in range(5):
        cv2.imwrite(str(d / f"{i:03d}.png"), np.full((48, 64, 3), 30 * i, np.uint8))
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 200.0, "fy": 200.0, "cx": 63.5, "cy": 47.5,
                               "width": 128, "height": 96}))
    rep = import_video(str(d), str(tmp_path / "f.h5"), camera_json=str(cam), adapt_frames=3,
                       fps=2.0)
    assert rep["frames"] == 5 and rep["adapt_frames"] == 3
    with SequenceReader(tmp_path / "f.h5") as r:
        assert abs(r.camera.fx - 100.0) < 1e-9                     # calibrated at twice the size
        assert np.allclose(r.timestamps(), np.arange(5) / 2.0)
        assert "camera JSON" in r.meta.provenance["intrinsics"]
        # said, not silent: a crop of the sensor (another field of view) would be wrong
        assert ("calibrated at 128x96, the source is 64x48: scaled (right for a resize of that "
                "image, not for a crop" in r.meta.provenance["intrinsics"])
    # a camera of the source's own size, the frames resized by --width: nothing to say
    assert camera_for(32, 24, str(cam), None, native=(128, 96))[1] == f"camera JSON {cam}"
    cam.write_text(json.dumps({"fx": 200.0, "fy": 200.0, "cx": 63.5, "cy": 47.5,
                               "width": 128, "height": 128}))
    with pytest.raises(InputError, match="not a uniform resize"):
        camera_for(64, 48, str(cam), None)
    # no width/height: the size 2 c + 1 (65 x 49 for c = 32, 24) is the frames' 64 x 48, not a
    # resize of it (scaling by 64 / 65 put a 1.5% error into the focal length)
    cam.write_text(json.dumps({"fx": 200.0, "fy": 200.0, "cx": 32.0, "cy": 24.0}))
    got = camera_for(64, 48, str(cam), None)[0]
    assert (got.width, got.height) == (64, 48) and got.fx == 200.0 and got.cx == 32.0


def test_bad_inputs(tmp_path):
    assert main(["import-video", str(tmp_path / "none.avi"), "--out", str(tmp_path / "x.h5")]) == 2
    src = tmp_path / "v.avi"
    _video(src, n=3)
    assert main(["import-video", str(src), "--out", str(tmp_path / "x.h5"), "--camera",
                 "c.json", "--fov-deg", "60"]) == 2
    assert main(["import-video", str(src), "--out", str(tmp_path / "x.h5"), "--every", "0"]) == 2
    (tmp_path / "empty").mkdir()
    assert main(["import-video", str(tmp_path / "empty"), "--out", str(tmp_path / "x.h5")]) == 2
    assert not (tmp_path / "x.h5").exists()


def test_adapt_frames_zero_is_refused_before_anything_is_written(tmp_path, capsys):
    """0 would leave adapt nothing to learn from (a video has no ground truth for an eval-only
    file); the help says N >= 1 and leaving the option out means every frame."""
    src, out = tmp_path / "v.avi", tmp_path / "x.h5"
    _video(src, n=3)
    assert main(["import-video", str(src), "--out", str(out), "--adapt-frames", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--adapt-frames must be >= 1" in err[0] and "got 0" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.avi"]
    assert main(["import-video", str(src), "--out", str(out), "--adapt-frames", "1"]) == 0
    with SequenceReader(out) as r:
        assert list(r.split("adapt")) == [0] and list(r.split("eval")) == [1, 2]


def test_vtest_streamed(shared_data, tmp_path):
    video = shared_data / "video" / "vtest.avi"
    if not video.exists():
        pytest.skip(f"{video} not found")
    rep = import_video(str(video), str(tmp_path / "vt.h5"), max_frames=5, width=384)
    assert rep["frames"] == 5 and rep["size"] == (384, 288)
    with SequenceReader(tmp_path / "vt.h5") as r:
        assert np.allclose(np.diff(r.timestamps()), 0.1)           # 10 frames per second
        assert r.left(0).std() > 10                                  # a real picture


def test_folder_import_resumes_after_a_broken_image(tmp_path, capsys):
    """A corrupt image stops the import and keeps the partial; once repaired, --resume reads on
    after the written frames (the same file as an import in one go); a written image that changed
    since is refused."""
    d = tmp_path / "imgs"
    d.mkdir()
    for i in range(8):
        cv2.imwrite(str(d / f"{i:03d}.png"), np.full((48, 64, 3), 25 * i, np.uint8))
    good = (d / "005.png").read_bytes()
    (d / "005.png").write_bytes(b"not a png")
    out = tmp_path / "f.h5"
    assert main(["import-video", str(d), "--out", str(out), "--fps", "2"]) == 2
    assert "005.png: corrupt or unreadable image" in capsys.readouterr().err
    assert not out.exists() and (tmp_path / "f.h5.partial").exists()
    assert main(["import-video", str(d), "--out", str(out), "--fps", "2"]) == 2   # neither flag
    assert capsys.readouterr().err.strip().endswith(
        "an earlier run stopped before finishing (interrupted, or by a bad input) and left this "
        "file: --resume continues it, --restart starts over")          # not "interrupted run"
    (d / "005.png").write_bytes(good)
    assert main(["import-video", str(d), "--out", str(out), "--fps", "3", "--resume"]) == 2
    assert "fps" in capsys.readouterr().err                  # another setting: refused
    assert main(["import-video", str(d), "--out", str(out), "--fps", "2", "--resume"]) == 0
    assert "resumed after the 5 frames" in capsys.readouterr().out
    ref = import_video(str(d), str(tmp_path / "ref.h5"), fps=2.0)
    with SequenceReader(out) as r, SequenceReader(tmp_path / "ref.h5") as q:
        assert len(r) == len(q) == ref["frames"] == 8
        assert all(np.array_equal(r.left(i), q.left(i)) for i in range(8))
        assert np.allclose(r.timestamps(), q.timestamps())
    # an image already written changed before the resume: refused, the partial kept
    (d / "007.png").write_bytes(b"broken")
    assert main(["import-video", str(d), "--out", str(tmp_path / "g.h5")]) == 2
    cv2.imwrite(str(d / "001.png"), np.full((48, 64, 3), 99, np.uint8))
    cv2.imwrite(str(d / "007.png"), np.full((48, 64, 3), 7, np.uint8))
    assert main(["import-video", str(d), "--out", str(tmp_path / "g.h5"), "--resume"]) == 2
    assert "001.png changed" in capsys.readouterr().err
    assert (tmp_path / "g.h5.partial").exists()


def _interrupt_at(monkeypatch, n: int):
    """Ctrl-C while the video's ``n``-th frame is decoded; returns (the real decoder, the calls
    so far): set ``video._to_rgb`` back to the first to go on."""
    import staticdepth.dataset.video as video

    real, calls = video._to_rgb, []

    def interrupted(img, where):
        calls.append(where)
        if len(calls) == n:
            raise KeyboardInterrupt
        return real(img, where)

    monkeypatch.setattr(video, "_to_rgb", interrupted)
    return real, calls


def test_video_import_resumes_after_an_interruption(tmp_path, monkeypatch, capsys):
    import staticdepth.dataset.video as video

    src = tmp_path / "v.avi"
    _video(src, n=12)
    real, calls = _interrupt_at(monkeypatch, 5)
    interrupted = video._to_rgb
    out = tmp_path / "v.h5"
    with pytest.raises(KeyboardInterrupt):
        import_video(str(src), str(out), every=2)
    monkeypatch.setattr(video, "_to_rgb", real)
    rep = import_video(str(src), str(out), every=2, resume=True)
    assert rep["resumed_from"] == 4 and rep["frames"] == 6
    import_video(str(src), str(tmp_path / "ref.h5"), every=2)
    with SequenceReader(out) as r, SequenceReader(tmp_path / "ref.h5") as q:
        assert all(np.array_equal(r.left(i), q.left(i)) for i in range(6))
        assert np.allclose(r.timestamps(), q.timestamps())
    # the video file changed (size/time): refused
    monkeypatch.setattr(video, "_to_rgb", interrupted)
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        import_video(str(src), str(tmp_path / "w.h5"))
    monkeypatch.setattr(video, "_to_rgb", real)
    # another --width: refused naming both sizes (it named two identical stream lists)
    with pytest.raises(InputError, match="frames are 64x48, these are 32x24"):
        import_video(str(src), str(tmp_path / "w.h5"), resume=True, width=32)
    _video(src, n=13)
    with pytest.raises(InputError, match="source_file"):
        import_video(str(src), str(tmp_path / "w.h5"), resume=True)
    assert main(["import-video", "rtsp://127.0.0.1:9/x", "--out", str(tmp_path / "u.h5"),
                 "--resume"]) == 2
    assert "URL cannot be resumed" in capsys.readouterr().err


def test_a_truncated_video_is_reported(tmp_path, capsys):
    # a file cut short imported its first frames as if they were the whole video
    src, cut = tmp_path / "v.avi", tmp_path / "cut.avi"
    # FFV1 through FFmpeg (OpenCV's own MJPG reader cannot open a cut file at all)
    vw = cv2.VideoWriter(str(src), cv2.VideoWriter_fourcc(*"FFV1"), 5.0, (160, 120))
    assert vw.isOpened()
    rng = np.random.default_rng(0)
    for _ in range(10):
        vw.write(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    vw.release()
    for name, data in (("whole", src.read_bytes()), ("cut", src.read_bytes()[:src.stat().st_size
                                                                            // 2])):
        cut.write_bytes(data)
        out = tmp_path / f"{name}.h5"
        capsys.readouterr()
        assert main(["import-video", str(cut), "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        with SequenceReader(out) as r:
            n, note = len(r), r.attrs.get("input_ended_early")
        if name == "whole":
            assert n == 10 and note is None and "warning" not in printed
        else:
            assert 1 <= n < 10
            want = f"the video's frames end at {n} of the 10 its header lists"
            assert f"warning: {cut}: {want}" in printed and want in note
    assert main(["verify", str(tmp_path / "cut.h5")]) == 0      # what was read is intact


def test_every_writer_refuses_a_name_of_more_than_one_line(tmp_path, capsys):
    # the importers checked --name; import-video and stereo wrote it into the file and the card
    src = tmp_path / "v.avi"
    _video(src, n=3)
    assert main(["import-video", str(src), "--out", str(tmp_path / "v.h5"), "--name",
                 "a\n# b"]) == 2
    assert "--name must be one line of printable text, got 'a\\n# b'" in capsys.readouterr().err
    assert not any(p.name.startswith("v.h5") for p in tmp_path.iterdir())


def test_a_width_beyond_the_frames_is_said_to_enlarge_them(tmp_path, capsys):
    src = tmp_path / "v.avi"
    _video(src, n=2)                                          # 64x48
    assert main(["import-video", str(src), "--out", str(tmp_path / "a.h5"), "--width", "160"]) == 0
    assert f"warning: --width 160 enlarges the {src} frames 2.5x" in capsys.readouterr().out
    assert main(["import-video", str(src), "--out", str(tmp_path / "b.h5"), "--width", "32"]) == 0
    assert "enlarges" not in capsys.readouterr().out


def test_ctrl_c_names_the_partial_and_how_to_resume(tmp_path, monkeypatch, capsys):
    """Ctrl-C used to print only "interrupted": the kept partial and --resume were not named."""
    import staticdepth.dataset.video as video

    src = tmp_path / "v.avi"
    _video(src, n=12)
    real, _ = _interrupt_at(monkeypatch, 5)
    out = tmp_path / "v.h5"
    assert main(["import-video", str(src), "--out", str(out)]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"note: {out}.partial keeps the 4 frame(s) written; the same command with "
                   "--resume continues it, --restart starts over",
                   "staticdepth import-video: interrupted"]
    monkeypatch.setattr(video, "_to_rgb", real)
    assert main(["import-video", str(src), "--out", str(out), "--resume"]) == 0
    with SequenceReader(out) as r:
        assert len(r) == 12


def test_a_folder_of_unpadded_numbers_is_read_in_numeric_order(tmp_path):
    """1.png, 2.png, 10.png are frames 1, 2, 10 (plain sorting read 1, 10, 2)."""
    d = tmp_path / "imgs"
    d.mkdir()
    for i in (1, 2, 10, 11, 3):
        cv2.imwrite(str(d / f"{i}.png"), np.full((48, 64, 3), 20 * i, np.uint8))
    import_video(str(d), str(tmp_path / "f.h5"), fov_deg=60.0, fps=1.0)
    with SequenceReader(tmp_path / "f.h5") as r:
        assert [int(r.left(k).mean()) for k in range(len(r))] == [20, 40, 60, 200, 220]
