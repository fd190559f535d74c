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
    # a noisy one keeps what its noise leaves: R^2 = var(signal) / (var(signal) + var(noise)),
    # the noise's variance over the 80% of pixels kept (R2_KEEP) that of a normal truncated at
    # its 10th and 90th percentiles: with the signal's variance, 1 / (1 + 0.438) = 0.696
    from scipy.stats import norm, truncnorm

    from staticdepth.geometry.alignment import R2_KEEP

    rng = np.random.default_rng(0)
    inv = 1.0 / depth
    sd = float(np.std(inv[ground]))
    noisy = 1.0 / (inv + rng.normal(0, sd, inv.shape)).clip(1e-3)
    z = norm.ppf(0.5 + R2_KEEP / 2)
    assert ground_fit_r2(noisy, ground, cam) == pytest.approx(1 / (1 + truncnorm.var(-z, z)),
                                                              abs=0.04)
    # a near patch on 15% of the ground (an undetected object) is left out
    patch = depth_from_inverse(dpt_failure(depth)).copy()
    vs, us = np.nonzero(ground)
    near = vs >= np.quantile(vs, 0.85)
    patch[vs[near], us[near]] = 0.2
    assert ground_fit_r2(patch, ground, cam) > 0.95
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


def _cli_inputs(tmp_path):
    import cv2

    from tests.test_cli_ground_align import _align_inputs

    K, n, depth, ground = _align_inputs(tmp_path)     # cam.json, plane.json, mask.png, pred.npy
    wall = scene()[4]
    cv2.imwrite(str(tmp_path / "wall.png"), wall.astype(np.uint8) * 255)
    noise = np.random.default_rng(1).uniform(0.01, 1.0, depth.shape).astype(np.float32)
    np.save(tmp_path / "noise.npy", noise)
    args = ["align", "--inverse", "--intrinsics", str(tmp_path / "cam.json"), "--plane",
            str(tmp_path / "plane.json"), "--ground-mask", str(tmp_path / "mask.png"),
            "--camera-height", "5", "--json", str(tmp_path / "info.json"),
            "--out", str(tmp_path / "out.npy"), "--overwrite"]
    return K, depth, ground, wall, noise, args


def test_align_command_takes_the_plane_for_a_prediction_under_the_bar(tmp_path, capsys):
    """`staticdepth align` applies align.min_ground_r2 as adapt does: a map whose ground is
    noise becomes the plane's depth, the agent mask's component at its contact, with a warning;
    a map that sees the ground (the paper's failure: 1/Z scaled and shifted) is aligned."""
    import json

    from staticdepth.cli import main

    K, depth, ground, wall, _, args = _cli_inputs(tmp_path)
    info = lambda: json.loads((tmp_path / "info.json").read_text())  # noqa: E731
    assert main(args + ["--pred", str(tmp_path / "noise.npy"), "--agent-mask",
                        str(tmp_path / "wall.png")]) == 0
    err = capsys.readouterr().err.strip()
    assert "does not see the agents' ground" in err and len(err.splitlines()) == 1
    i = info()
    assert i["plane_only"] is True and i["ground_r2"] < 0.05 and i["frames"][0]["mode"] == "plane"
    out = np.load(tmp_path / "out.npy")
    np.testing.assert_allclose(out[ground & ~wall], depth[ground & ~wall], rtol=1e-4)  # metres
    vs, us = np.nonzero(wall)                       # the wall as one agent: its contact's depth
    foot = depth[vs.max(), int(np.median(us[vs == vs.max()]))]
    assert np.ptp(out[wall]) < 1e-4 * foot and out[wall][0] == pytest.approx(foot, rel=0.03)
    # the bar at 0: the noise is aligned (and no warning)
    assert main(args + ["--pred", str(tmp_path / "noise.npy"), "--set",
                        "align.min_ground_r2=0"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert info()["plane_only"] is False and info()["frames"][0]["mode"] == "upright"
    assert not np.allclose(np.load(tmp_path / "out.npy")[ground], depth[ground], rtol=0.05)
    # a prediction that sees the ground: R^2 1, aligned
    assert main(args + ["--pred", str(tmp_path / "pred.npy")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert info()["plane_only"] is False and info()["ground_r2"] == pytest.approx(1.0, abs=1e-3)


def test_align_sequence_decides_on_its_adaptation_frames(tmp_path, capsys):
    import json

    from staticdepth.cli import main
    from staticdepth.dataset.h5 import SequenceReader, add_prediction
    from tests.test_cli_ground_align import _sequence

    K, depth, ground, wall, noise, _ = _cli_inputs(tmp_path)
    seq = _sequence(tmp_path, depth, K, n_frames=3)
    add_prediction(seq, "noise", [1.0 / np.roll(noise, k, axis=1) for k in range(3)])
    common = ["align", "--sequence", str(seq), "--plane", str(tmp_path / "plane.json"),
              "--ground-aux", "ground", "--camera-height", "5", "--json",
              str(tmp_path / "i.json"), "--overwrite"]
    assert main(common + ["--pred-name", "noise"]) == 0
    assert "does not see the agents' ground" in capsys.readouterr().err
    i = json.loads((tmp_path / "i.json").read_text())
    assert i["plane_only"] is True and i["ground_r2"] < 0.05
    with SequenceReader(seq) as r:
        for k in range(3):
            out = r.prediction("noise-align", k)
            np.testing.assert_allclose(out[ground], depth[ground], rtol=1e-4)
    assert main(common + ["--pred-name", "base"]) == 0
    i = json.loads((tmp_path / "i.json").read_text())
    assert i["plane_only"] is False and i["ground_r2"] == pytest.approx(1.0, abs=1e-3)


def test_deployment_refuses_a_network_adapt_replaced_by_the_plane(tmp_path):
    """export-model and predict --summary deploy ft + alignment: a summary whose ft-align was
    the plane alone is refused in one line before the sequence is read."""
    import json

    from staticdepth.deploy import deployment_constants

    summary = tmp_path / "s.adapt.json"
    summary.write_text(json.dumps({"align_plane_only": ["align", "ft-align"],
                                   "align_ground_r2": {"align": 0.01, "ft-align": 0.05},
                                   "config": {"align": {"min_ground_r2": 0.2}}}))
    with pytest.raises(InputError, match=r"R\^2 0.05 under align.min_ground_r2 0.2") as e:
        deployment_constants(str(summary), str(tmp_path / "missing.h5"))
    assert e.value.path == str(summary) and "\n" not in str(e.value)
