"""Acceptance of ``staticdepth adapt`` on a synthetic high, tilted camera with the built-in model.

The built-in network is trained by ``staticdepth train-builtin`` on street-level scenes (about 40 s
on 2 free cores; cached in pytest's cache folder when that plugin is on, keyed by its settings) and
adapted on the ``c1`` scene (5.4 m up, pitched 25 deg) at 256x128: 60 frames, the first 40 for
adaptation, ground-truth agents (``--detector gt``), 5 epochs. Metrics: AbsRel over the evaluation
split, median-scaled per image (the paper's Table 1) or metric (Table 3, scale from the camera
height).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.metrics import average, evaluate
from conftest import trained_builtin

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")
# 60 optimiser steps (of 480): the network these checks have run on since finetune.max_steps
# (until train-builtin honoured --epochs, it stopped there without a word)
TRAIN = ["--frames", "320", "--epochs", "12", "--size", "256x128", "--seed", "0",
         "--max-steps", "60"]


@pytest.fixture(scope="module")
def builtin_weights(request, tmp_path_factory):
    return str(trained_builtin(request, tmp_path_factory, TRAIN))


@pytest.fixture(scope="module")
def adapted(tmp_path_factory, builtin_weights):
    seq = tmp_path_factory.mktemp("acc") / "c1.h5"
    render_to_file(seq, preset_name="c1", n_frames=60, adapt_frames=40, seed=1,
                   overrides={"width": 256, "height": 128})
    rc = main(["adapt", str(seq), "--model", f"builtin:{builtin_weights}", "--detector", "gt",
               "--epochs", "5", "--seed", "0", "--device", "cpu",
               "--set", "tracking.min_height_px=8"])
    assert rc == 0
    table = {}
    with SequenceReader(seq) as r:
        ev = list(r.split("eval"))
        for name in ("base", "ft", "align", "ft-align", "align-metric", "ft-align-metric"):
            proto = "metric" if name.endswith("-metric") else "median"
            table[name] = average(evaluate(r.prediction(name, i), r.depth(i), proto)
                                  for i in ev)["abs_rel"]
            table[name + "@agents"] = average(
                evaluate(r.prediction(name, i), r.depth(i), proto, mask=r.instances(i) > 0)
                for i in ev if (r.instances(i) > 0).sum() > 20)["abs_rel"]
    summary = json.load(open(str(seq).replace(".h5", ".adapt.json")))
    print("\nAbsRel (eval split):", json.dumps({k: round(v, 4) for k, v in table.items()}))
    return table, summary


def test_finetuning_does_not_hurt_agents(adapted):
    # The paper's claim is that fine-tuning on the pseudo labels improves the agents; here it does
    # not reliably: measured base 0.0896 -> ft 0.0901 on agents with weights trained on 2 threads
    # (0.0843 -> 0.0842 with other weights). Issue 19 stays open on this; what holds is that it
    # does no harm beyond noise.
    table, _ = adapted
    assert table["ft@agents"] <= 1.05 * table["base@agents"]


def test_alignment_improves_on_the_base_prediction(adapted):
    table, _ = adapted
    assert table["align"] < table["base"] and table["ft-align"] < table["base"]


def test_metric_scale_from_camera_height_is_close_to_median_scaling(adapted):
    table, summary = adapted
    assert summary["camera_height_m"] == pytest.approx(5.4)
    assert table["ft-align-metric"] <= 1.2 * table["ft-align"]


def test_ft_align_at_most_65_percent_of_base(adapted):
    # measured 0.0784 / 0.1285 = 0.61 with the defaults: the body-model-free 'joint' plane (0.8 deg
    # off here) and the 'ground' alignment (Eq. 2 instead: 0.70). The fixed-cylinder 'exact' model,
    # tuned to this very renderer, fitted it to 0.1 deg and gave 0.555; it is off by 2-5 deg on
    # bodies of other generators (tests/test_plane_joint.py), hence no longer the default.
    table, summary = adapted
    assert table["ft-align"] <= 0.65 * table["base"]
    n = np.asarray(summary["plane"]["normal"])
    truth = np.array([0.0, np.cos(np.radians(25.0)), np.sin(np.radians(25.0))])  # c1: 25 deg
    assert np.degrees(np.arccos(np.clip(n @ truth, -1, 1))) < 1.5


def test_agents_take_the_plane_depth_at_their_contact():
    """Closed form: camera 5 m over a plane pitched 20 deg; a person's mask gets d_g / (n_g . r)
    of its lowest pixel, a backpack touching it the same value, the rest is untouched."""
    from staticdepth.dataset.schema import COCO, empty_agents
    from staticdepth.geometry.alignment import agents_at_contact
    from staticdepth.geometry.camera import Camera
    from staticdepth.geometry.projection import ray_grid

    cam = Camera.from_fov(64, 48, 60.0)
    t = np.radians(20.0)
    n_g = np.array([0.0, np.cos(t), np.sin(t)])
    depth = np.full((48, 64), 7.0, np.float32)
    inst = np.zeros((48, 64), np.uint16)
    inst[20:40, 30:34] = 1                     # person, lowest row 39
    inst[25:30, 34:37] = 2                     # backpack touching it
    rows = empty_agents(2)
    rows["instance_id"] = [1, 2]
    rows["class_id"] = [COCO["person"], COCO["backpack"]]
    out, changed = agents_at_contact(depth, cam.K, n_g, 5.0, inst, rows)
    expect = 5.0 / (ray_grid(cam.K, 64, 48)[39, [31, 32]] @ n_g)
    assert np.all(changed == (inst > 0))
    assert out[inst == 1].min() == pytest.approx(out[inst == 1].max())
    assert expect.min() - 1e-4 <= out[35, 31] <= expect.max() + 1e-4
    assert out[27, 35] == pytest.approx(out[35, 31])
    assert np.all(out[inst == 0] == 7.0)


def test_stage_timings_and_finetune_record(adapted):
    _, summary = adapted
    assert len(summary["finetune"]) == 5
    assert all(r["peak_memory_mb"] > 0 and r["seconds"] > 0 for r in summary["finetune"])
    assert np.isfinite(summary["plane"]["pitch_deg"])
