"""Stereo calibration on OpenCV's 13 chessboard pairs, against plain OpenCV in the same test."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import StereoRig
from staticdepth.stereo.calibrate import Board, calibrate_stereo, detect_corners
from staticdepth.stereo.io import read_rgb
from staticdepth.stereo.rectify import Rectifier


def _files(root):
    d = root / "opencv" / "stereo_calib"
    return sorted(map(str, d.glob("left*.jpg"))), sorted(map(str, d.glob("right*.jpg")))


def plain_opencv_rms(left, right):
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    O, A, B = [], [], []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    for lf, rf in zip(left, right):
        pts = []
        for f in (lf, rf):
            g = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
            ok, c = cv2.findChessboardCorners(g, (9, 6), flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                              | cv2.CALIB_CB_NORMALIZE_IMAGE)
            pts.append(cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit) if ok else None)
        if pts[0] is not None and pts[1] is not None:
            O.append(obj), A.append(pts[0]), B.append(pts[1])
    size = (640, 480)
    _, K1, d1, _, _ = cv2.calibrateCamera(O, A, size, None, None)
    _, K2, d2, _, _ = cv2.calibrateCamera(O, B, size, None, None)
    return cv2.stereoCalibrate(O, A, B, K1, d1, K2, d2, size, flags=cv2.CALIB_FIX_INTRINSIC)[0]


@pytest.fixture(scope="module")
def calibration(shared_data):
    left, right = _files(shared_data)
    return left, right, calibrate_stereo(left, right, Board("chessboard", 9, 6, 1.0))


def test_rms_at_most_plain_opencv(calibration):
    left, right, cal = calibration
    plain = plain_opencv_rms(left, right)
    assert 0.3 < plain < 0.6          # the README's "about 0.45 px"
    assert cal.rig.rms_reprojection_px <= plain
    assert len(cal.used) + len(cal.dropped) == 13 and not cal.not_found


def test_rectified_corners_share_rows(calibration):
    left, right, cal = calibration
    rect = Rectifier(cal.rig)
    board = Board("chessboard", 9, 6, 1.0)
    dv = []
    for lf, rf in zip(left, right):
        dl, dr = detect_corners(board, read_rgb(lf)), detect_corners(board, read_rgb(rf))
        if dl is None or dr is None:
            continue
        a = rect.rectify_points(dl[1], "left")
        b = rect.rectify_points(dr[1], "right")
        dv.append(b[:, 1] - a[:, 1])
    assert np.median(np.abs(np.concatenate(dv))) < 0.5
    # square units: the rig's baseline is a few squares, the right camera to the right
    assert cal.rig.T[0] < 0 and 2 < cal.rig.baseline_m < 5


def test_cli_calibrate_writes_rig(shared_data, tmp_path, capsys):
    d = shared_data / "opencv" / "stereo_calib"
    out = tmp_path / "rig.json"
    rc = main(["calibrate", "--board", "9x6", "--square", "0.025", "--left", str(d / "left*.jpg"),
               "--right", str(d / "right*.jpg"), "--out", str(out)])
    assert rc == 0
    rig = StereoRig.load(out)
    assert "stereo RMS" in capsys.readouterr().out
    assert rig.rms_reprojection_px < 0.45 and rig.rectification is not None
    assert rig.baseline_m == pytest.approx(0.025 * 3.33, rel=0.02)


def test_too_few_pairs_names_the_files(shared_data, tmp_path):
    left, right = _files(shared_data)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    with pytest.raises(InputError, match="found in only 2 of 5 pairs.*blank.png"):
        calibrate_stereo(left[:2] + [str(blank)] * 3, right[:2] + [str(blank)] * 3,
                         Board("chessboard", 9, 6, 1.0))


def test_bad_input(shared_data, tmp_path):
    left, right = _files(shared_data)
    with pytest.raises(InputError, match="13 left images but 12 right"):
        calibrate_stereo(left, right[:12], Board())
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 100), np.uint8))
    with pytest.raises(InputError, match="100x100"):
        calibrate_stereo([left[0], str(small)], [right[0], str(small)], Board())
    with pytest.raises(InputError, match="look like 9x6"):
        Board.parse("chessboard", "9by6", 0.02)
    with pytest.raises(InputError, match="pattern"):
        Board("circles")
    with pytest.raises(InputError, match="square size"):
        Board(square_m=0)
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not an image")
    with pytest.raises(InputError, match="unreadable"):
        calibrate_stereo([str(bad)], [str(bad)], Board())


def test_charuco_corners_land_on_the_board_geometry():
    """ChArUco through OpenCV 5's object API: every inner corner found, at its drawn position."""
    board = Board("charuco", 7, 5, 0.04, dictionary="DICT_4X4_50")
    px, margin = 60, 30                      # pixels per square, white margin
    img = board.charuco().generateImage((7 * px + 2 * margin, 5 * px + 2 * margin),
                                        marginSize=margin, borderBits=1)
    img = cv2.GaussianBlur(img, (3, 3), 0.8)
    ids, uv = detect_corners(board, np.repeat(img[..., None], 3, axis=2))
    assert sorted(ids.tolist()) == list(range(6 * 4)) and uv.shape == (24, 2)
    # a corner between pixels k-1 and k sits at k - 0.5 (pixel centres at integers)
    expected = margin + board.object_points()[ids][:, :2] / 0.04 * px - 0.5
    assert np.abs(uv - expected).max() < 0.5
