"""``staticdepth predict``'s outputs: files named by the source frame index under ``--every``, the
MP4 at the source's rate / ``every`` with a colour bar, and 16-bit PNGs that use the full range
for relative depth and carry their scale.

The model is replaced by a known function of the image (``depth = 0.3 + mean(RGB) / 60``)
so that every written value can be checked exactly; the command and its files are the real ones.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

import staticdepth.deploy_predict as dp
from staticdepth.cli import main
from staticdepth.dataset.inspect import colorize_depth
from staticdepth.report_figures import depth_colour_bar, depth_range


def known_depth(img: np.ndarray) -> np.ndarray:
    return (0.3 + img.astype(np.float32).mean(axis=2) / 60.0).astype(np.float32)


@pytest.fixture
def known_model(monkeypatch):
    """Replace the network by :func:`known_depth`; ``kind`` ('relative' | 'metric') settable."""
    state = {"kind": "relative", "fn": known_depth}
    monkeypatch.setattr(dp, "make_predictor",
                        lambda *a, **k: (state["fn"], state["kind"], "known depth"))
    return state


def write_video(path: Path, fps: float, n: int, w: int = 320, h: int = 96) -> list[np.ndarray]:
    """``n`` frames (RGB, a moving gradient) as an MJPG AVI at ``fps``; returns them decoded."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    x = np.linspace(0, 255, w)[None, :]
    for i in range(n):
        g = ((x + 8 * i + np.linspace(0, 60, h)[:, None]) % 256).astype(np.uint8)
        writer.write(np.dstack([g, 255 - g, g // 2]))
    writer.release()
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(np.ascontiguousarray(f[..., ::-1]))
    assert len(frames) == n
    return frames


def decoded(path: Path) -> tuple[float, list[np.ndarray]]:
    cap = cv2.VideoCapture(str(path))
    fps, frames = cap.get(cv2.CAP_PROP_FPS), []
    while True:
        ok, f = cap.read()
        if not ok:
            return fps, frames
        frames.append(f[..., ::-1])


def run(source, out: Path, *extra: str) -> int:
    return main(["predict", "--model", "builtin", "--input", str(source), "--out", str(out),
                 "--device", "cpu", *extra])


@pytest.mark.parametrize("fmt", ["npy", "png16"])
def test_every_names_files_by_source_frame(shared_data, tmp_path, known_model, capsys, fmt):
    """Was: 000000, 000001, 000002 for source frames 0, 5, 10 of vtest.avi."""
    video = shared_data / "video" / "vtest.avi"
    assert run(video, tmp_path / "o", "--format", fmt, "--every", "5", "--max-frames", "3") == 0
    ext = "npy" if fmt == "npy" else "png"
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [
        f"{i:06d}.{ext}" for i in (0, 5, 10)]
    assert "3 frames (source frames 0-10, every 5)" in capsys.readouterr().out
    cap = cv2.VideoCapture(str(video))
    for i in range(11):
        ok, bgr = cap.read()
        assert ok
        if i % 5:
            continue
        want = known_depth(bgr[..., ::-1])
        path = tmp_path / "o" / f"{i:06d}.{ext}"
        got = np.load(path) if fmt == "npy" else dp.depth_from_png16(str(path))[0]
        assert np.allclose(got, want, rtol=1e-4, atol=0), i


def test_mp4_plays_at_source_rate_over_every(tmp_path, known_model, capsys):
    """Was: 10 frames/s whatever the source (here 25/s, every 3rd frame: 8.33/s)."""
    write_video(tmp_path / "v.avi", 25.0, 12)
    assert run(tmp_path / "v.avi", tmp_path / "o", "--format", "mp4", "--every", "3") == 0
    fps, frames = decoded(tmp_path / "o" / "depth.mp4")
    assert len(frames) == 4 and fps == pytest.approx(25.0 / 3, abs=0.01)
    assert "at 8.33 frames/s" in capsys.readouterr().out


def test_mp4_real_video_and_folder_rates(shared_data, tmp_path, known_model, capsys):
    """vtest.avi is 10 frames/s: every 2nd frame plays at 5/s; an image folder has no rate, so
    DEFAULT_FPS (10) / every, said in a note."""
    assert run(shared_data / "video" / "vtest.avi", tmp_path / "a", "--format", "mp4",
               "--every", "2", "--max-frames", "3") == 0
    fps, frames = decoded(tmp_path / "a" / "depth.mp4")
    assert len(frames) == 3 and fps == pytest.approx(5.0, abs=1e-3)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(write_video(tmp_path / "v.avi", 30.0, 6)):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f[..., ::-1])
    capsys.readouterr()
    assert run(folder, tmp_path / "b", "--format", "mp4", "--every", "4") == 0
    fps, frames = decoded(tmp_path / "b" / "depth.mp4")
    assert len(frames) == 2 and fps == pytest.approx(10 / 4, abs=1e-3)
    assert "gives no frame rate; the video plays at 10 / 4 = 2.5 frames/s" in \
        capsys.readouterr().out


@pytest.mark.parametrize("kind,caption", [("relative", "relative"), ("metric", "depth m")])
def test_mp4_frames_carry_a_colour_bar(tmp_path, known_model, kind, caption):
    """Was: the colour map alone (96 rows), no scale. Now the depth over the first frame's range
    with the report's colour bar under it, labelled in metres or 'relative'."""
    known_model["kind"] = kind
    src = write_video(tmp_path / "v.avi", 25.0, 2)
    assert run(tmp_path / "v.avi", tmp_path / "o", "--format", "mp4") == 0
    _, frames = decoded(tmp_path / "o" / "depth.mp4")
    depth = known_depth(src[0])
    rng = depth_range(depth)
    bar = depth_colour_bar(320, *rng, caption=caption)
    other = depth_colour_bar(320, *rng, caption="depth m" if kind == "relative" else "relative")
    assert frames[0].shape == (96 + bar.shape[0], 320, 3)
    err = lambda a, b: float(np.abs(a.astype(float) - b.astype(float)).mean())  # noqa: E731
    assert err(frames[0][:96], colorize_depth(depth, *rng)) < 6          # mp4v's loss only
    assert err(frames[0][96:], bar) < 6
    assert err(frames[0][96:], bar) < err(frames[0][96:], other)        # the right caption
    assert err(frames[1][:96], colorize_depth(known_depth(src[1]), *rng)) < 6   # same range


def test_png16_relative_uses_the_full_range(tmp_path, known_model):
    """Was: relative depth x256 (here 1.01-3.27 -> levels 259-838, max relative error 1.4e-3).
    Now scale = 65535 / the frame's largest depth, in the PNG's text chunk (max relative error
    2.3e-5); read with OpenCV and Pillow (not the module's reader) every value is within half a
    level."""
    src = write_video(tmp_path / "v.avi", 25.0, 1)
    assert run(tmp_path / "v.avi", tmp_path / "o", "--format", "png16") == 0
    path = tmp_path / "o" / "000000.png"
    q = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    d = known_depth(src[0]).astype(np.float64)
    assert q.dtype == np.uint16 and q.max() == 65535
    with Image.open(path) as im:
        scale = float(im.text["staticdepth.depth_scale"])
        assert im.text["staticdepth.depth_unit"] == "relative"
    assert scale == pytest.approx(65535 / d.max(), rel=1e-12)
    half_level = 0.5 / scale                                  # the 16-bit resolution
    assert np.abs(q / scale - d).max() <= half_level * (1 + 1e-6)
    rel = np.abs(q / scale - d) / d
    assert rel.max() <= half_level / d.min() * (1 + 1e-6) < 5e-5      # was 1.4e-3
    got, unit = dp.depth_from_png16(str(path))
    assert unit == "relative" and np.abs(got - d).max() <= half_level * 1.01


def test_png16_metric_stays_x256_unknown_zero_known_never_zero(tmp_path, known_model):
    known_model["kind"] = "metric"
    depth = np.array([[np.nan, np.inf, -1.0, 0.0], [1e-4, 2.5, 300.0, 1.0]], np.float32)
    known_model["fn"] = lambda im: depth
    write_video(tmp_path / "v.avi", 25.0, 1, w=64, h=48)
    assert run(tmp_path / "v.avi", tmp_path / "o", "--format", "png16") == 0
    q = cv2.imread(str(tmp_path / "o" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert q.tolist() == [[0, 0, 0, 0], [1, 640, 65535, 256]]
    got, unit = dp.depth_from_png16(str(tmp_path / "o" / "000000.png"))
    assert unit == "m" and np.isnan(got[0]).all() and got[1, 1] == 2.5
    q, scale = dp.png16_from_depth(np.full((2, 2), np.nan, np.float32), metric=False)
    assert (q == 0).all() and scale == 1.0                    # no known pixel: all unknown


@pytest.mark.parametrize("args,message", [
    (["--every", "0"], "--every must be >= 1, got 0"),
    (["--max-frames", "0"], "--max-frames must be >= 1, got 0"),
    (["--format", "mp4", "--every", "-2"], "--every must be >= 1, got -2")])
def test_bad_counts_one_line_nothing_written(tmp_path, known_model, capsys, args, message):
    write_video(tmp_path / "v.avi", 25.0, 2, w=64, h=48)
    assert run(tmp_path / "v.avi", tmp_path / "o", *args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "o").exists()


def test_mp4_depth_size_change_refused(tmp_path, known_model, capsys):
    sizes = iter([(48, 64), (40, 64)])
    known_model["fn"] = lambda im: np.ones(next(sizes), np.float32)
    write_video(tmp_path / "v.avi", 25.0, 2, w=64, h=48)
    assert run(tmp_path / "v.avi", tmp_path / "o", "--format", "mp4") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame 1: depth 64x40, the video's is 64x48" in err[0], err
    assert not (tmp_path / "o").exists()       # nor the folder this run made, left empty


def test_depth_from_png16_refuses_other_pngs(tmp_path):
    from PIL import PngImagePlugin

    from staticdepth.errors import InputError

    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match="not a predict png16 depth file"):
        dp.depth_from_png16(str(tmp_path / "rgb.png"))
    info = PngImagePlugin.PngInfo()
    info.add_text("staticdepth.depth_scale", "many")
    Image.fromarray(np.ones((4, 4), np.uint16)).save(tmp_path / "bad.png", pnginfo=info)
    with pytest.raises(InputError, match="unreadable staticdepth.depth_scale 'many'"):
        dp.depth_from_png16(str(tmp_path / "bad.png"))


def test_overwrite_leaves_no_frame_of_an_earlier_run(tmp_path, known_model, capsys):
    """Was: a second run with --overwrite into the same folder (another --every, another format)
    kept the first run's frames beside its own, so the folder mixed two runs. Now only this run's
    frames stay; files not named as predict names its outputs are never touched, and a run that
    fails removes nothing."""
    write_video(tmp_path / "v.avi", 25.0, 12)
    out = tmp_path / "o"
    assert run(tmp_path / "v.avi", out, "--format", "npy") == 0
    (out / "notes.txt").write_text("mine")
    (out / "12345.npy").write_bytes(b"not ours: 5 digits")
    first = {p.name for p in out.iterdir()}
    assert {f"{i:06d}.npy" for i in range(12)} <= first
    # a failing run (a missing input) removes nothing
    assert run(tmp_path / "missing.avi", out, "--overwrite", "--format", "npy") == 2
    assert {p.name for p in out.iterdir()} == first
    capsys.readouterr()
    assert run(tmp_path / "v.avi", out, "--overwrite", "--format", "npy", "--every", "4") == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "000000.npy", "000004.npy", "000008.npy", "12345.npy", "notes.txt"]
    assert "removed 9 file(s) of an earlier run" in capsys.readouterr().out
    assert (out / "notes.txt").read_text() == "mine"
    for i in (0, 4, 8):
        assert np.load(out / f"{i:06d}.npy").shape == (96, 320)
    assert run(tmp_path / "v.avi", out, "--overwrite", "--format", "mp4") == 0
    assert sorted(p.name for p in out.iterdir()) == ["12345.npy", "depth.mp4", "notes.txt"]
