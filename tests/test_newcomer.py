"""The README's documented workflows, run as a newcomer would, on the real sample data.

calibrate -> mount -> stereo on OpenCV's chessboard pairs; stereo on the Aloe pair; import-kitti
-> inspect -> export -> publish -> verify on the KITTI raw sample. Each step goes through the
command line (`main`) with the README's flags; results are checked against independent truth
(OpenCV's own solvePnP, Aloe's ground-truth disparity, the LiDAR scan's point count).
"""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.geometry.camera import StereoRig


def test_calibrate_mount_stereo_on_the_chessboard_pairs(shared_data, tmp_path, capsys):
    d = shared_data / "opencv" / "stereo_calib"
    rig = tmp_path / "rig.json"
    # square size unknown: work in square units (--square 1)
    assert main(["calibrate", "--pattern", "chessboard", "--board", "9x6", "--square", "1",
                 "--left", str(d / "left*.jpg"), "--right", str(d / "right*.jpg"),
                 "--out", str(rig)]) == 0
    calibrated = StereoRig.load(rig)
    assert calibrated.rms_reprojection_px < 0.5 and calibrated.left.dist[4] != 0   # has a k3
    # mount: the board's plane in the first view, pycolmap (FULL_OPENCV) with OpenCV's cross-check
    mounted = tmp_path / "rig_mounted.json"
    assert main(["mount", "--rig", str(rig), "--images", str(d / "left01.jpg"), "--board", "9x6",
                 "--square", "1", "--out", str(mounted)]) == 0
    out = capsys.readouterr().out
    check = float(out.split("cross-check ")[1].split(" deg")[0])
    assert check < 0.1
    grey = cv2.imread(str(d / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    ok, corners = cv2.findChessboardCorners(grey, (9, 6))
    corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3))
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    _, rvec, tvec = cv2.solvePnP(obj, corners, calibrated.left.K, calibrated.left.dist)
    n = cv2.Rodrigues(rvec)[0][:, 2]
    assert StereoRig.load(mounted).mounting.height_m == pytest.approx(abs(n @ tvec.ravel()),
                                                                       rel=0.01)
    # stereo: the calibrated rig rectifies the pairs (the rectification check passes)
    seq = tmp_path / "board.h5"
    assert main(["stereo", "--rig", str(mounted), "--left", str(d / "left0[1-3].jpg"),
                 "--right", str(d / "right0[1-3].jpg"), "--out", str(seq)]) == 0
    assert "not rectified" not in capsys.readouterr().err
    with SequenceReader(seq) as r:
        assert len(r) == 3 and np.isfinite(r.depth(0)).mean() > 0.05
    # the same pair swapped vertically by 12 px is refused, unless the check is skipped
    shifted = tmp_path / "right_shifted.png"
    cv2.imwrite(str(shifted), np.roll(cv2.imread(str(d / "right01.jpg")), 12, axis=0))
    args = ["stereo", "--rig", str(rig), "--left", str(d / "left01.jpg"), "--right",
            str(shifted), "--out", str(tmp_path / "bad.h5")]
    assert main(args) == 2 and "not rectified" in capsys.readouterr().err


def test_stereo_on_aloe(shared_data, tmp_path, capsys):
    d = shared_data / "opencv" / "aloe"
    disp = tmp_path / "disp.pfm"
    args = ["stereo", "--rectified", "--left", str(d / "aloeL.jpg"), "--right",
            str(d / "aloeR.jpg"), "--disparity-out", str(disp)]
    assert main(args + ["--max-disparity", "128"]) == 0          # the README's old example
    assert "clip the scene" in capsys.readouterr().err
    assert main(args + ["--max-disparity", "224", "--overwrite"]) == 0
    assert "warning" not in capsys.readouterr().err
    from staticdepth.stereo.io import read_disparity

    gt = cv2.imread(str(d / "aloeGT.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    ours = read_disparity(str(disp))
    ok = (gt > 0) & np.isfinite(ours)
    assert ok.mean() > 0.6 and np.median(np.abs(ours[ok] - gt[ok])) < 0.5


def test_kitti_import_inspect_export_publish_verify(shared_data, tmp_path, capsys):
    seq, sheet, js = tmp_path / "K.h5", tmp_path / "K.png", tmp_path / "K.json"
    assert main(["import-kitti", "--root", str(shared_data / "kitti_raw"), "--drives",
                 "2011_09_26_drive_sample", "--name", "K", "--adapt-frames", "1",
                 "--out", str(seq)]) == 0
    assert main(["inspect", str(seq), "--sheet", str(sheet), "--json", str(js)]) == 0
    info = json.loads(js.read_text())
    assert info["frames"] == 3 and info["size"] == "1242x375" and 0.01 < info["gt_density"] < 0.2
    assert cv2.imread(str(sheet)) is not None
    assert main(["export", str(seq), "--format", "kitti", "--out", str(tmp_path / "exp")]) == 0
    assert len(list((tmp_path / "exp").rglob("*.png"))) >= 6
    rel = tmp_path / "release"
    assert main(["publish", str(seq), "--out", str(rel), "--licence", "CC-BY-NC-SA-3.0",
                 "--citation", "Geiger et al., IJRR 2013"]) == 0
    capsys.readouterr()
    assert main(["verify", str(rel)]) == 0
    assert "OK" in capsys.readouterr().out
