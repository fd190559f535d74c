"""SGBM on real pairs with ground truth (Aloe, Middlebury Art and Midd1) against textbook SGBM.

The reference is plain ``cv2.StereoSGBM_create`` with textbook parameters, run in the same test on
the same pair with the same disparity range. One default, no per-scene tuning.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.geometry.camera import Camera, StereoRig
from staticdepth.stereo.io import read_rgb
from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline
from staticdepth.stereo.scores import disparity_scores

PAIRS = {  # name: (left, right, ground truth, ground-truth scale)
    "aloe": ("opencv/aloe/aloeL.jpg", "opencv/aloe/aloeR.jpg", "opencv/aloe/aloeGT.png", 1.0),
    "art": ("middlebury/Art/view1.png", "middlebury/Art/view5.png", "middlebury/Art/disp1.png",
            3.0),
    "midd1": ("middlebury/Midd1/view1.png", "middlebury/Midd1/view5.png",
              "middlebury/Midd1/disp1.png", 3.0),
}


def load_pair(root, name):
    l, r, g, scale = PAIRS[name]
    left, right = read_rgb(root / l), read_rgb(root / r)
    gt = cv2.imread(str(root / g), cv2.IMREAD_UNCHANGED).astype(np.float32) / scale
    gt[gt == 0] = np.nan
    n = int(16 * np.ceil((np.nanmax(gt) + 1) / 16))
    return left, right, gt, n


def textbook(left, right, n):
    s = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n, blockSize=5, P1=8 * 3 * 25,
                              P2=32 * 3 * 25, uniquenessRatio=10, speckleWindowSize=100,
                              speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = s.compute(left[..., ::-1].copy(), right[..., ::-1].copy())
    d = raw.astype(np.float32) / 16
    d[raw < 0] = np.nan
    return d


def ours(left, right, n, fill):
    h, w = left.shape[:2]
    rig = StereoRig.rectified(Camera.from_intrinsics(1000, 1000, w / 2, h / 2, w, h), 0.1)
    pipe = StereoPipeline(rig, StereoConfig(num_disparities=n, fill=fill, max_depth_m=1e9))
    return pipe.process(left, right)


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_ground_truth_mode_beats_textbook(shared_data, name):
    left, right, gt, n = load_pair(shared_data, name)
    ref = disparity_scores(textbook(left, right, n), gt)
    res = ours(left, right, n, fill=False)
    got = disparity_scores(res.disparity, gt)
    assert np.array_equal(res.valid, np.isfinite(res.disparity))
    assert got["bad-2"] <= 0.75 * ref["bad-2"], (got, ref)
    assert got["density"] >= 0.9 * ref["density"], (got, ref)


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_dense_mode_beats_textbook(shared_data, name):
    left, right, gt, n = load_pair(shared_data, name)
    ref = disparity_scores(textbook(left, right, n), gt)
    res = ours(left, right, n, fill=True)
    got = disparity_scores(res.disparity, gt)
    assert np.isfinite(res.disparity).all()
    assert got["density"] == pytest.approx(100.0)
    assert got["bad-2-all"] <= 0.6 * ref["bad-2-all"], (got, ref)
