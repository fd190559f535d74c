"""Rectification check, clipped disparity range and swapped views on the real sample pairs."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.stereo.diagnose import stereo_warnings, suggested_range
from staticdepth.stereo.rectify import check_rectified, measure_rectification


def _pair(shared_data, scene):
    d = shared_data / "middlebury" / scene
    return (np.ascontiguousarray(cv2.imread(str(d / "view1.png"))[..., ::-1]),
            np.ascontiguousarray(cv2.imread(str(d / "view5.png"))[..., ::-1]),
            cv2.imread(str(d / "disp1.png"), cv2.IMREAD_UNCHANGED) / 3.0)


def test_rectification_check_measures_the_row_offset(shared_data):
    left, right, _ = _pair(shared_data, "Art")
    assert measure_rectification(left, right).offset_px < 0.5
    shifted = np.ascontiguousarray(np.roll(right, 7, axis=0))
    assert measure_rectification(left, shifted).offset_px == pytest.approx(7, abs=0.6)
    with pytest.raises(InputError, match="px apart vertically"):
        check_rectified(left, shifted)


def test_textureless_pair_is_inconclusive_not_an_error():
    flat = np.full((80, 160, 3), 120, np.uint8)
    warnings = []
    res = check_rectified(flat, flat, warn=warnings.append)
    assert not res.conclusive and "cannot check" in warnings[0]


def test_clipped_range_and_swapped_views(shared_data):
    left, right, gt = _pair(shared_data, "Art")
    check = measure_rectification(left, right)
    # Feature disparities lie in the ground truth's range (Art's reaches about 75 px).
    p99, gt_p99 = np.percentile(check.disparities, 99), np.percentile(gt[gt > 0], 99)
    assert 0.8 * gt_p99 < p99 and check.disparities.max() <= gt.max() + 1
    assert stereo_warnings(check, 128) == []
    clipped = stereo_warnings(check, 32)
    assert len(clipped) == 1 and "clips the scene" in clipped[0]
    assert f"--max-disparity {suggested_range(np.percentile(check.disparities, 99.5))}" \
        in clipped[0]
    swapped = stereo_warnings(measure_rectification(right, left), 128)
    assert len(swapped) == 1 and "swapped" in swapped[0]
    # The matcher's own output: many measured pixels pinned at the range's last disparities.
    disp = np.full((10, 10), 40.0)
    disp[:2] = 31.0
    assert "sit at its limit" in stereo_warnings(None, 32, disp)[0]
    assert stereo_warnings(None, 64, disp) == []


def test_cli_warns_and_ply_needs_a_rig(shared_data, tmp_path, capsys):
    d = shared_data / "middlebury" / "Art"
    args = ["stereo", "--rectified", "--left", str(d / "view1.png"), "--right",
            str(d / "view5.png"), "--disparity-out", str(tmp_path / "d.npy")]
    assert main(args + ["--max-disparity", "32"]) == 0
    assert "clips the scene" in capsys.readouterr().err
    assert main(args + ["--max-disparity", "96", "--ply", str(tmp_path / "p.ply")]) == 2
    assert "--ply with --rectified needs --rig" in capsys.readouterr().err
    shifted = tmp_path / "shifted.png"
    cv2.imwrite(str(shifted), np.roll(cv2.imread(str(d / "view5.png")), 9, axis=0))
    args[5] = str(shifted)
    args.append("--overwrite")
    assert main(args + ["--max-disparity", "96"]) == 2
    assert "not rectified" in capsys.readouterr().err
    assert main(args + ["--max-disparity", "96", "--skip-rectification-check"]) == 0
