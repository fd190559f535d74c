"""align.min_ground_r2: a prediction whose ground the agents' plane does not explain is not
aligned; its output is the plane's depth with the agents at their contact (issue 19)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry.alignment import depth_from_inverse, ground_fit_r2, plane_depth
from staticdepth.geometry.alignment_upright import AlignCamera
from tests.test_adapt_stages import clip, tiny  # noqa: F401  (fixtures)
from tests.test_alignment import dpt_failure, scene

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _camera(K, n, depth, d=5.0):
    return AlignCamera(K, depth.shape[1], depth.shape[0], n, d)


def test_ground_r2_is_one_for_a_scaled_and_shifted_ground_and_near_zero_for_noise():
    K, n, depth, ground, _ = scene()
    cam = _camera(K, n, depth)
    # the paper's failure (inverse depth with a scale and a shift) is the plane exactly
    assert ground_fit_r2(depth_from_inverse(dpt_failure(depth)), ground, cam) \
        == pytest.approx(1.0, abs=1e-5)
    # a noisy one keeps what its noise leaves: R^2 = var(signal) / (var(signal) + var(noise))
    rng = np.random.default_rng(0)
    inv = 1.0 / depth
    sd = float(np.std(inv[ground]))
    noisy = 1.0 / (inv + rng.normal(0, sd, inv.shape)).clip(1e-3)
    assert ground_fit_r2(noisy, ground, cam) == pytest.approx(0.5, abs=0.05)
    # a network whose ground is noise, or comes nearer up the image, does not see it
    assert ground_fit_r2(rng.uniform(1, 50, depth.shape), ground, cam) < 0.01
    assert ground_fit_r2(1.0 / (0.5 - inv), ground, cam) == 0.0
    assert ground_fit_r2(np.full(depth.shape, 7.0), ground, cam) == 0.0    # saturated
    # nothing to fit on
    few = np.zeros_like(ground)
    few[np.nonzero(ground)[0][:2], np.nonzero(ground)[1][:2]] = True
    assert np.isnan(ground_fit_r2(depth, few, cam))


def test_plane_depth_is_the_ground_along_each_ray_and_the_far_limit_above_it():
    K, n, depth, ground, wall = scene()
    P = plane_depth(_camera(K, n, depth), ground)
    np.testing.assert_allclose(P[ground], depth[ground], rtol=1e-5)
    # the wall's pixels see the ground behind it; the sky the far limit, 50x the median
    far = 50 * np.median(depth[ground])
    assert np.all(P[wall] > depth[wall])
    sky = depth == 200.0
    np.testing.assert_allclose(P[sky], far, rtol=1e-4)
    with pytest.raises(InputError, match="horizon"):
        plane_depth(_camera(K, n, depth), sky)


def _adapt(seq, tiny_model, **sets):  # noqa: F811
    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config

    conf = {"model": f"builtin:{tiny_model}", "detector.name": "gt", "finetune.epochs": 0,
            "tracking.min_height_px": 3, "plane.bootstrap": 0, **sets}
    return adapt(seq, build_config(conf), log=lambda m: None)


def test_adapt_takes_the_plane_for_a_network_under_the_bar_and_says_so(tmp_path, clip, tiny):  # noqa: F811,E501
    from staticdepth.dataset.h5 import SequenceReader

    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    s0 = _adapt(seq, tiny, **{"align.min_ground_r2": 0.0})
    r2 = s0["align_ground_r2"]["align"]
    assert 0 <= r2 <= 1 and s0["align_plane_only"] == []
    with SequenceReader(seq) as r:
        aligned = [r.prediction("align", i) for i in range(len(r))]
    # a bar above the network's R^2: the plane alone, as plane_frame gives it
    s1 = _adapt(seq, tiny, **{"align.min_ground_r2": min(r2 + 0.01, 0.999)})
    assert s1["align_ground_r2"]["align"] == r2
    assert s1["align_plane_only"] == ["align", "ft-align"]       # ft is base's copy here
    with SequenceReader(seq) as r:
        K, n = r.camera.K, np.asarray(s1["plane"]["normal"])
        cam = AlignCamera(K, r.width, r.height, n, 1.0)
        changed = 0
        for i in range(len(r)):
            A, inst = r.prediction("align", i), r.instances(i)
            # static pixels: the plane's depth along the ray (the far limit above the horizon)
            P = plane_depth(cam, cam.q > np.median(cam.q[cam.q > 0]))
            below = cam.q > 3.0 / P.max()     # well below either run's far limit
            np.testing.assert_allclose(A[(inst == 0) & below], P[(inst == 0) & below],
                                       rtol=1e-6)
            # each agent one depth: the plane's at its contact, nearer than the far limit
            for k in np.unique(inst[inst > 0]):
                vals = A[inst == k]
                assert np.ptp(vals) == 0 and vals[0] < P.max()
            changed += not np.allclose(A, aligned[i], rtol=1e-3)
    assert changed == len(aligned)          # every frame differs from the network's alignment
    # the labels follow the same map: one scale per frame over the plane's depth (the plane's
    # static pixels repeat in every frame, so all of them are trusted)
    from staticdepth.adaptation.common import FrameFile

    with SequenceReader(seq) as r, FrameFile(seq + ".adapt/labels.h5", None) as f:
        for k, i in enumerate(r.split("adapt")):
            label, A = f[k], r.prediction("align", i)
            m = np.isfinite(label)
            assert m.mean() > 0.9
            prod = label[m] * A[m]
            np.testing.assert_allclose(prod, np.median(prod), rtol=1e-4)
