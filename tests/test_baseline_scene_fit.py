"""The stereo baseline's settings fitted to the rig and the scene, and the collapse check."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.baseline.config import PRESETS
from staticdepth.baseline.scene_fit import check_not_collapsed, network_size, scene_depth_range
from staticdepth.errors import InputError


def test_depth_range_starts_near_the_scene_and_keeps_disparities_inside_the_image():
    # 320x160 at 90 deg (f = 160), 27 cm rig, camera 9.7 m up pitched 35 deg (C2-like)
    K = np.array([[160.0, 0, 160], [0, 160.0, 80], [0, 0, 1]])
    t = math.radians(35)
    n = np.array([0, math.cos(t), math.sin(t)])
    lo, hi = scene_depth_range(160.0, 320, 160, 0.27, 320, K, n, 9.7)
    r = np.linalg.solve(K, [160, 159, 1])
    near = 9.7 / (n @ r)                               # the bottom row's ground depth
    assert lo == pytest.approx(0.5 * near)
    assert 160 * 0.27 / lo < 0.25 * 320                # widest disparity: a quarter of the width
    start = 1.0 / (1 / hi + 0.5 * (1 / lo - 1 / hi))   # sigmoid 0.5 at the start
    assert 0.5 * near < start < 2.5 * near
    # MonoDepth2's 0.1 m would start at 0.2 m: 216 px of disparity in a 320 px image
    assert 160 * 0.27 / 0.2 > 0.5 * 320
    # no mounting: the disparity bound alone
    lo2, _ = scene_depth_range(160.0, 320, 160, 0.27, 320)
    assert 160 * 0.27 / lo2 == pytest.approx(0.25 * 320)


def test_network_size_follows_the_aspect_within_the_preset_width():
    assert network_size(320, 160, 640) == (320, 160)
    assert network_size(800, 400, 640) == (640, 320)
    assert network_size(192, 96, 128) == (128, 64)


def test_collapsed_predictions_are_refused_with_one_line():
    conf = PRESETS["default"]
    rng = np.random.default_rng(0)
    good = rng.uniform(3, 40, (2, 16, 32))
    assert check_not_collapsed(good, conf)["relative_spread"] > 0.1
    with pytest.raises(InputError, match="collapsed .*min_depth"):
        check_not_collapsed(np.full((2, 16, 32), conf.min_depth * 1.01), conf)
    with pytest.raises(InputError, match="collapsed .*max_depth"):
        check_not_collapsed(np.full((2, 16, 32), conf.max_depth), conf)
    with pytest.raises(InputError, match="collapsed"):
        check_not_collapsed(np.full((2, 16, 32), 7.0), conf)


def test_site_preset_trains_at_the_sequence_resolution_tiny_stays_small(tmp_path):
    """``site``: the tiny network at the sequence's own size (disparities 2.5x those at 128 px);
    ``tiny`` keeps its 128 px cap; both take the rig's depth range."""
    from test_baseline_scene import BASELINE_M, camera, write_sequence

    from staticdepth.baseline.config import preset
    from staticdepth.baseline.scene_fit import fit_to_scene
    from staticdepth.dataset.h5 import SequenceReader

    seq = write_sequence(tmp_path / "s.h5", n_frames=2, adapt_frames=2,
                         cam=camera(width=320, height=160))
    with SequenceReader(seq) as r:
        site, tiny = fit_to_scene(r, preset("site")), fit_to_scene(r, preset("tiny"))
        fx = r.camera.fx
    assert (site.width, site.height) == (320, 160) and (tiny.width, tiny.height) == (128, 64)
    assert site.encoder_width == tiny.encoder_width == 16
    # the widest disparity stays within a quarter of the network's width at min_depth
    assert fx * BASELINE_M / site.min_depth <= 0.25 * 320 + 1e-6
    assert fx * 128 / 320 * BASELINE_M / tiny.min_depth <= 0.25 * 128 + 1e-6
