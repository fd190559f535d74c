"""The metric gate: the plane depth's relative error from the normal's uncertainty (closed form
and a finite rotation), and adapt refusing the metric maps of a plane it cannot trust."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from staticdepth.adapt import adapt
from staticdepth.adaptation.config import build_config
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.scale import metric_check, plane_depth_rel_std
from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin

K = np.array([[100.0, 0, 80], [0, 100.0, 40], [0, 0, 1]])


def test_plane_depth_rel_std_closed_form_and_finite_rotation():
    n = normal_from_pitch_roll(30.0)
    # the principal ray meets the ground at 30 deg: relative error sigma cos 30 / sin 30
    sigma = 0.5
    assert plane_depth_rel_std(K, n, sigma, [80.0], [40.0]) == pytest.approx(
        math.radians(sigma) * math.sqrt(3), rel=1e-9)
    # a pitch rotation is the worst direction for a ray in the vertical plane: the depth really
    # changes by that much (first order)
    r = np.array([0.0, 0.0, 1.0])
    d0, d1 = 1 / (n @ r), 1 / (normal_from_pitch_roll(30.0 + 0.01) @ r)
    assert abs(d1 / d0 - 1) == pytest.approx(math.radians(0.01) * math.sqrt(3), rel=1e-3)
    # rays nearer the horizon (row 40 - 100 tan 30 = -18) meet the ground at grazing angles
    assert plane_depth_rel_std(K, n, sigma, [80.0], [5.0]) > 5 * plane_depth_rel_std(
        K, n, sigma, [80.0], [150.0])
    assert math.isnan(plane_depth_rel_std(K, n, float("nan"), [80.0], [40.0]))


def test_metric_check_refuses_accepts_and_flags():
    n = normal_from_pitch_roll(30.0)
    feet = np.array([[80.0, 40.0], [60.0, 60.0], [100.0, 70.0]])
    assert metric_check(K, n, 0.5, feet, 5.0, None, 0.15) == (False, None)
    refuse, why = metric_check(K, n, 10.0, feet, 5.0, None, 0.15)
    assert refuse and why.startswith("metric depth refused") and "10.00 deg" in why
    # the camera height's own uncertainty counts: 1 m of 5 m is 20%
    refuse, why = metric_check(K, n, 0.1, feet, 5.0, 1.0, 0.15)
    assert refuse and "camera height 20%" in why
    refuse, why = metric_check(K, n, float("nan"), feet, 5.0, None, 0.15)
    assert not refuse and why.startswith("metric depth unverified")


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::torch.jit.TracerWarning")
def test_adapt_refuses_the_metric_maps_with_a_reason(tmp_path):
    torch.manual_seed(0)
    model = tmp_path / "tiny.pt"
    save_builtin(model, builtin_model(TinyDepthNet(enc_channels=(4, 8, 8, 16, 16),
                                                   dec_channels=(16, 8, 8, 4)),
                                      input_height=64, input_width=128))
    seq = tmp_path / "c1.h5"
    render_to_file(seq, preset_name="c1", n_frames=24, adapt_frames=20, seed=1,
                   overrides={"width": 256, "height": 128})
    settings = {"model": f"builtin:{model}", "detector.name": "gt", "finetune.epochs": 0,
                "tracking.min_height_px": 8}
    logs: list[str] = []
    s = adapt(str(seq), build_config({**settings, "scale.max_rel_error": 1e-6}), log=logs.append)
    assert s["plane"]["uncertainty"]["normal_std_deg"] is not None
    assert s["metric_refused"].startswith("metric depth refused")
    assert any(m == "warning: " + s["metric_refused"] for m in logs)
    assert "ft-align-metric" not in s["predictions"] and s["scale"] == {}
    with SequenceReader(seq) as r:
        assert not {"align-metric", "ft-align-metric"} & set(r.predictions())
    # the same plane under the default limit: accepted, the metric maps written
    s = adapt(str(seq), build_config(settings), log=lambda m: None)
    assert s["metric_refused"] is None and "ft-align-metric" in s["predictions"]
