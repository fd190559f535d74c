"""``calibrate``, ``mount`` and ``stereo`` refuse what cannot give a usable rig or depth (swapped or
identical views, too few pairs, an unwritable output, views that disagree on the ground, options
that contradict each other) in one line with exit code 2, naming the file or option."""
from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig
from staticdepth.stereo import calibrate as calibrate_module
from staticdepth.stereo import mount
from staticdepth.stereo.calibrate import Board, calibrate_stereo
from tests.test_mount import CAM, render_board_on_ground


def _pairs(shared_data, n=3):
    d = shared_data / "opencv" / "stereo_calib"
    return sorted(map(str, d.glob("left*.jpg")))[:n], sorted(map(str, d.glob("right*.jpg")))[:n]


def _copy(files, folder):
    folder.mkdir(exist_ok=True)
    for f in files:
        shutil.copy(f, folder)
    return str(folder / "*.jpg")


def _error(capsys, command, *words):
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"staticdepth {command}: error:") and "\n" not in err, err
    for w in words:
        assert w in err, err
    return err


def _calibrate(left, right, out, *extra):
    return main(["calibrate", "--board", "9x6", "--square", "0.025", "--left", left, "--right",
                 right, "--out", str(out), "--min-pairs", "2", *extra])


def test_swapped_views_are_refused(shared_data, tmp_path, capsys):
    left, right = _pairs(shared_data)
    L, R = _copy(left, tmp_path / "L"), _copy(right, tmp_path / "R")
    assert _calibrate(R, L, tmp_path / "c.json") == 2
    _error(capsys, "calibrate", "swapped", "--left")
    assert not (tmp_path / "c.json").exists()
    assert _calibrate(L, R, tmp_path / "c.json") == 0          # the right order calibrates
    rig = StereoRig.load(tmp_path / "c.json")
    assert rig.T[0] < 0 and rig.baseline_m == pytest.approx(0.0832, rel=0.03)


def test_same_images_for_both_views_are_refused(shared_data, tmp_path, capsys):
    left, _ = _pairs(shared_data)
    L = _copy(left, tmp_path / "L")
    assert _calibrate(L, L, tmp_path / "c.json") == 2
    _error(capsys, "calibrate", "both the left and the right")
    copy = _copy(left, tmp_path / "copy")        # the same images under other names
    assert _calibrate(L, copy, tmp_path / "c.json") == 2
    _error(capsys, "calibrate", "m apart", "one camera")
    assert not (tmp_path / "c.json").exists()


def test_min_pairs(shared_data, tmp_path, capsys):
    left, right = _pairs(shared_data)
    L, R = _copy(left, tmp_path / "L"), _copy(right, tmp_path / "R")
    for n in ("0", "1"):
        assert main(["calibrate", "--board", "9x6", "--square", "0.025", "--left", L, "--right",
                     R, "--out", str(tmp_path / "c.json"), "--min-pairs", n]) == 2
        _error(capsys, "calibrate", "--min-pairs must be at least 2")
    assert main(["calibrate", "--board", "9x6", "--square", "0.025", "--left", L, "--right", R,
                 "--out", str(tmp_path / "c.json"), "--min-pairs", "100"]) == 2
    _error(capsys, "calibrate", "--min-pairs 100", "only 3 left images")
    with pytest.raises(InputError, match="at least 2"):
        calibrate_stereo(left, right, Board("chessboard", 9, 6, 0.025), min_pairs=1)
    with pytest.raises(InputError) as e:
        calibrate_stereo(left, right, Board("chessboard", 9, 6, 0.025), min_pairs=4)
    assert "found in all 3 pairs, but 4 are needed" in str(e.value)
    assert "not found in" not in str(e.value)


def _no_detection(*a, **k):
    raise AssertionError("the board was searched for before the output was checked")


def test_unwritable_output_is_refused_before_any_work(shared_data, tmp_path, capsys,
                                                      monkeypatch):
    left, right = _pairs(shared_data)
    monkeypatch.setattr(calibrate_module, "detect_corners", _no_detection)
    monkeypatch.setattr(mount, "detect_corners", _no_detection)
    out = str(tmp_path / "missing" / "c.json")
    missing = f"{tmp_path / 'missing'}: output's parent does not exist"   # fileio's one line
    assert _calibrate(left[0], right[0], out) == 2
    _error(capsys, "calibrate", missing)
    rig = tmp_path / "rig.json"
    StereoRig.rectified(CAM, 0.27).save(rig)
    assert main(["mount", "--rig", str(rig), "--images", left[0], "--board", "9x6",
                 "--square", "0.1", "--out", out]) == 2
    _error(capsys, "mount", missing)


def _ground_views(tmp_path, heights, pitch=30.0):
    for k, h in enumerate(heights):
        img, _ = render_board_on_ground(CAM, h, pitch, 0.0, seed=k)
        cv2.imwrite(str(tmp_path / f"g{k}.png"), img[..., ::-1])
    return sorted(str(p) for p in tmp_path.glob("g*.png"))


def test_mount_refuses_views_that_disagree(tmp_path, capsys):
    files = _ground_views(tmp_path, [4.0, 5.0])
    rig = tmp_path / "rig.json"
    StereoRig.rectified(CAM, 0.27).save(rig)
    args = ["mount", "--rig", str(rig), "--images", str(tmp_path / "g*.png"), "--board", "9x6",
            "--square", "0.4", "--out", str(tmp_path / "m.json")]
    assert main(args) == 2
    _error(capsys, "mount", str(tmp_path / "g*.png"), "disagree", "g0.png", "g1.png",
           "at most 5%")
    assert not (tmp_path / "m.json").exists()
    assert main(args + ["--max-height-spread", "0.3"]) == 0     # tolerance raised on purpose
    for f, pitch in zip(files, (30.0, 40.0)):                    # normals 10 deg apart
        img, _ = render_board_on_ground(CAM, 4.0, pitch, 0.0)
        cv2.imwrite(f, img[..., ::-1])
    with pytest.raises(InputError, match="normals up to 10.0 deg apart"):
        mount.mount_from_board(StereoRig.rectified(CAM, 0.27), files,
                               Board("chessboard", 9, 6, 0.4))


def test_mount_combines_height_and_normal_of_one_plane(tmp_path):
    """Views at 4.0, 4.1 and 4.5 m (same normal): the plane through the mean of the board origins
    gives 4.2 m (the median, 4.1 m, belonged to no combined plane)."""
    files = _ground_views(tmp_path, [4.0, 4.1, 4.5])
    est = mount.mount_from_board(StereoRig.rectified(CAM, 0.27), files,
                                 Board("chessboard", 9, 6, 0.4), max_height_spread=0.2)
    assert est.mounting.height_m == pytest.approx(4.2, rel=0.005)
    assert [h for h, _ in est.per_view.values()] == pytest.approx([4.0, 4.1, 4.5], rel=0.01)


@pytest.mark.parametrize("thickness", ["-5", "0.5", "nan"])
def test_mount_thickness_is_checked_by_name(tmp_path, capsys, monkeypatch, thickness):
    monkeypatch.setattr(mount, "detect_corners", _no_detection)
    rig = tmp_path / "rig.json"
    StereoRig.rectified(CAM, 0.27).save(rig)
    assert main(["mount", "--rig", str(rig), "--images", str(rig), "--board", "9x6", "--square",
                 "0.1", "--thickness", thickness, "--out", str(tmp_path / "m.json")]) == 2
    _error(capsys, "mount", "--thickness")
    with pytest.raises(InputError, match="thickness"):
        mount.mount_from_board(StereoRig.rectified(CAM, 0.27), [], Board(), thickness_m=-5.0)


STEREO_CAM = Camera.from_intrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)


@pytest.fixture
def frames(tmp_path):
    rng = np.random.default_rng(0)
    for side in ("L", "R"):
        (tmp_path / side).mkdir()
        cv2.imwrite(str(tmp_path / side / "0.png"), rng.integers(0, 255, (48, 64), np.uint8))
    return tmp_path


def _stereo(frames, rig, *extra):
    return main(["stereo", "--rig", str(rig), "--left", str(frames / "L"), "--right",
                 str(frames / "R"), "--out", str(frames / "v.h5"), *extra])


@pytest.mark.parametrize("extra, words, not_words", [
    (["--max-disparity", "32", "--min-depth", "1"], ["give one of --max-disparity or --min-depth"],
     []),
    (["--set", "num_disparities=32", "--min-depth", "1"], ["--set num_disparities"], []),
    (["--min-depth", "-2"], ["--min-depth"], ["--set"]),
    (["--min-depth", "100"], ["--min-depth", "--max-depth"], ["--set"]),
    (["--max-depth", "-2"], ["--max-depth"], ["--set"]),
    (["--set", "min_depth_m=-2"], ["--set", "min_depth_m"], []),
])
def test_stereo_depth_options_blame_the_option_given(frames, capsys, extra, words, not_words):
    rig = frames / "rig.json"
    StereoRig.rectified(STEREO_CAM, 0.1).save(rig)
    assert _stereo(frames, rig, *extra) == 2
    err = _error(capsys, "stereo", *words)
    assert not any(w in err for w in not_words), err
    assert not (frames / "v.h5").exists()


@pytest.mark.parametrize("T, words", [([0.0, -0.1, 0.0], "rectified vertically"),
                                      ([1e-9, 0.0, 0.0], "no baseline")])
def test_stereo_names_the_rig_it_cannot_rectify(frames, capsys, T, words):
    rig = frames / "odd_rig.json"
    StereoRig(STEREO_CAM, STEREO_CAM, cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0], T).save(rig)
    assert _stereo(frames, rig) == 2
    _error(capsys, "stereo", str(rig), words)
    assert not (frames / "v.h5").exists()
