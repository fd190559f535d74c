"""The adapt stage and command: outputs, summary, reproducibility, recipes, errors (tiny model)."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

from staticdepth.adapt import adapt, recipe_settings
from staticdepth.adaptation.config import ScaleConfig, build_config
from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.errors import InputError
from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::torch.jit.TracerWarning")

SMALL = dict(enc_channels=(4, 8, 8, 16, 16), dec_channels=(16, 8, 8, 4))
OUTPUTS = {"base", "ft", "align", "ft-align", "align-metric", "ft-align-metric"}


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.pt"
    save_builtin(path, builtin_model(TinyDepthNet(**SMALL), input_height=128, input_width=256))
    return str(path)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    path = tmp_path_factory.mktemp("seq") / "c1.h5"
    render_to_file(path, preset_name="c1", n_frames=24, adapt_frames=16, seed=1,
                   overrides={"width": 256, "height": 128})
    return str(path)


def _copy(src, dst):
    dst.write_bytes(open(src, "rb").read())
    return str(dst)


def test_adapt_writes_every_stage_and_is_reproducible(tmp_path, sequence, tiny_model):
    conf = build_config({"model": f"builtin:{tiny_model}", "detector.name": "gt",
                         "finetune.epochs": 1, "finetune.lr": 1e-3, "tracking.min_height_px": 8})
    a, b = _copy(sequence, tmp_path / "a.h5"), _copy(sequence, tmp_path / "b.h5")
    s = adapt(a, conf, log=lambda m: None)
    adapt(b, conf, log=lambda m: None, summary_path=str(tmp_path / "b.json"))
    with SequenceReader(a) as ra, SequenceReader(b) as rb:
        assert set(ra.predictions()) == OUTPUTS
        for name in OUTPUTS:
            for i in (0, 20):
                np.testing.assert_array_equal(ra.prediction(name, i), rb.prediction(name, i))
        base = ra.prediction("base", 3)
        assert base.dtype == np.float32 and base.shape == (128, 256) and np.all(base > 0)
        # metric = relative aligned x one temporal anchor scale
        ratio = ra.prediction("ft-align-metric", 5) / ra.prediction("ft-align", 5)
        np.testing.assert_allclose(ratio[np.isfinite(ratio)], 5.4, rtol=1e-5)   # x H_c
        assert s["scale"]["ft-align"] == pytest.approx(5.4) and s["anchor_scale"]["ft-align"] > 0
        assert ra.prediction_attrs("ft")["config_hash"] == s["stage_hashes"]["ft"]
        assert not np.array_equal(ra.prediction("ft", 3), base)       # fine-tuning changed it
    saved = json.load(open(s["summary_path"]))
    with SequenceReader(a) as ra:      # what locate/export-model check a summary against
        assert saved["sequence_id"] == ra.sequence_id()
    assert saved["camera_height_m"] == pytest.approx(5.4)              # the sequence's height
    assert saved["camera_height_source"] == "sequence"
    assert len(saved["finetune"]) == 1 and saved["finetune"][0]["seconds"] > 0
    assert set(saved["timings_s"]) >= {"base", "agents", "finetune", "align", "scale"}
    # the plane's accuracy is tested with staticdepth.geometry.agent_plane; here: it is stored
    assert np.linalg.norm(saved["plane"]["normal"]) == pytest.approx(1.0)
    assert 0 < saved["plane"]["pitch_deg"] < 89
    # Table 2's anchor depths: H_c / (n . K^-1 [W/2, H-1, 1]) and f H_c / (H-1 - c_y)
    with SequenceReader(s["sequence"]) as ra:
        K = ra.camera.K
    n = np.asarray(saved["plane"]["normal"])
    ray = np.linalg.inv(K) @ np.array([128.0, 127.0, 1.0])
    assert saved["anchor_pixel"] == [128.0, 127.0]
    assert saved["anchor_depth_m"] == pytest.approx(5.4 / (n @ ray), rel=1e-9)
    assert saved["anchor_depth_parallel_m"] == pytest.approx(K[1, 1] * 5.4 / (127 - K[1, 2]))
    assert saved["planes"]["agents"]["d"] == pytest.approx(5.4)
    assert not list(tmp_path.glob("*.ckpt"))


def test_adapt_command_with_recipe_and_overrides(tmp_path, sequence, tiny_model, capsys):
    seq = _copy(sequence, tmp_path / "r.h5")
    recipe = tmp_path / "r.yaml"
    recipe.write_text(f"name: R\ncamera_height_m: 6.0\nstages:\n  adapt:\n"
                      f"    sequence: {seq}\n    model: builtin:{tiny_model}\n"
                      f"    detector: gt\n    epochs: 3\n    tracking.min_height_px: 8\n")
    summary = tmp_path / "r.json"
    rc = main(["adapt", "--recipe", str(recipe), "--epochs", "0", "--set", "align.erode_px=4",
               "--summary", str(summary), "--device", "cpu"])
    assert rc == 0
    s = json.load(open(summary))
    assert s["config"]["finetune"]["epochs"] == 0                              # flag wins
    assert s["config"]["align"]["erode_px"] == 4.0
    assert s["config"]["tracking"]["min_height_px"] == 8
    assert s["camera_height_m"] == 6.0 and s["camera_height_source"] == "given"
    assert s["finetune"] == []
    p, u = s["plane"], s["plane"]["uncertainty"]       # the plane's line names each axis' std
    assert (f"plane: pitch {p['pitch_deg']:.2f} +- {u['pitch_std_deg']:.2f} deg, roll "
            f"{p['roll_deg']:.2f} +- {u['roll_std_deg']:.2f} deg; camera height 6.00 m (given)"
            ) in capsys.readouterr().out
    with SequenceReader(seq) as r:
        np.testing.assert_array_equal(r.prediction("ft", 2), r.prediction("base", 2))


def test_recipe_settings_formats(tmp_path):
    p = tmp_path / "a.yaml"
    p.write_text("camera_height_m: 9.7\nstages:\n  adapt:\n    command: adapt\n"
                 "    args: {_: [x.h5], camera-height: 5.0, epochs: 2}\n")
    assert recipe_settings(p) == {"sequence": "x.h5", "scale.camera_height_m": 5.0,
                                  "finetune.epochs": 2}
    p.write_text("camera_height_m: 9.7\nstages:\n  adapt: {detector: yolox}\n")
    assert recipe_settings(p) == {"detector.name": "yolox", "scale.camera_height_m": 9.7}
    p.write_text("stages:\n  import: {kind: carla}\n")
    with pytest.raises(InputError, match="no 'stages: {adapt"):
        recipe_settings(p)


def test_adapt_errors(tmp_path, sequence, tiny_model, capsys):
    with pytest.raises(InputError, match="metric_scale must be"):
        ScaleConfig(metric_scale="median")
    assert main(["adapt", "--device", "cpu"]) == 2
    assert "no sequence given" in capsys.readouterr().err
    assert main(["adapt", sequence, "--set", "learning_rate=1"]) == 2
    assert "unknown setting" in capsys.readouterr().err
    assert main(["adapt", str(tmp_path / "none.h5"), "--model", f"builtin:{tiny_model}"]) == 2
    onnx = tmp_path / "m.onnx"
    net = builtin_model(TinyDepthNet(**SMALL), input_height=128, input_width=256).net.eval()
    torch.onnx.export(net, (torch.zeros(1, 3, 128, 256),), str(onnx), dynamo=False,
                      opset_version=17)
    seq = _copy(sequence, tmp_path / "e.h5")
    with pytest.raises(InputError, match="inference only"):
        adapt(seq, build_config({"model": f"onnx:{onnx}", "detector.name": "gt",
                                 "finetune.epochs": 1}), log=lambda m: None)
    with pytest.raises(InputError, match="not below the image height"):    # before predicting
        adapt(seq, build_config({"model": f"onnx:{onnx}", "detector.name": "gt",
                                 "finetune.epochs": 0, "tracking.min_height_px": 500}),
              log=lambda m: None)
    assert not os.path.exists(seq + ".pred")
    with pytest.raises(InputError, match="tracked agents"):         # possible, but none is
        adapt(seq, build_config({"model": f"onnx:{onnx}", "detector.name": "gt",
                                 "finetune.epochs": 0, "tracking.min_height_px": 127}),
              log=lambda m: None)
    render_to_file(tmp_path / "noadapt.h5", preset_name="c1", n_frames=2, adapt_frames=0,
                   overrides={"width": 64, "height": 32})
    with pytest.raises(InputError, match="no adaptation split"):
        adapt(str(tmp_path / "noadapt.h5"), build_config({"model": f"builtin:{tiny_model}"}),
              log=lambda m: None)


def test_adapt_with_the_motion_detector(tmp_path, tiny_model):
    seq = tmp_path / "m.h5"
    render_to_file(seq, preset_name="c1", n_frames=40, adapt_frames=30, seed=1,
                   overrides={"width": 256, "height": 128})
    s = adapt(str(seq), build_config({"model": f"builtin:{tiny_model}", "detector.name": "motion",
                                      "finetune.epochs": 1, "finetune.lr": 1e-3,
                                      "tracking.min_height_px": 8}), log=lambda m: None)
    assert s["pseudo_label_agent_pixels"] > 0
    with SequenceReader(seq) as r:
        assert set(r.predictions()) == OUTPUTS
        assert np.isfinite(r.prediction("ft-align-metric", 35)).mean() > 0.9


class _TwoChannels(torch.nn.Module):
    def forward(self, x):
        return torch.cat([x[:, :1], x[:, 1:2]], 1)


def test_adapt_refuses_before_the_network_pass(tmp_path, tiny_model):
    """What the agents and their plane cannot serve, and a network whose output is not one map,
    are refused before the network's pass over every frame (with a real network the hours of a
    long sequence): nothing of the base prediction is written."""
    from staticdepth.dataset.predictions import prediction_path

    empty = tmp_path / "empty.h5"
    render_to_file(empty, preset_name="c1", n_frames=24, adapt_frames=16, seed=1,
                   overrides={"width": 128, "height": 64, "n_agents": 0})
    model = tmp_path / "two.pt"
    torch.jit.script(_TwoChannels()).save(str(model))
    conf = build_config({"model": f"torch:{model}", "detector.name": "motion",
                         "finetune.epochs": 0})
    with pytest.raises(InputError, match="expected one channel"):
        adapt(str(empty), conf, log=lambda m: None)
    assert not os.path.exists(f"{empty}.adapt/agents.h5")     # before the detector's pass
    conf = build_config({"model": f"builtin:{tiny_model}", "detector.name": "motion",
                         "finetune.epochs": 0})
    with pytest.raises(InputError, match="0 usable agent observations"):
        adapt(str(empty), conf, log=lambda m: None)
    assert not os.path.exists(prediction_path(empty, "base"))
    assert not os.path.exists(f"{empty}.adapt/inverse-base.h5")


def test_the_summary_counts_the_agents_labelled_pixels(tmp_path, tiny_model):
    """pseudo_label_agent_pixels summed every labelled pixel of the "aligned" labels (85% of the
    frames on a walk's scene), not the agents'. Against the scene's own instance maps: the
    agents' pixels of the adaptation split bound it, and most of them are labelled."""
    seq = str(tmp_path / "n.h5")
    render_to_file(seq, preset_name="c1", n_frames=40, adapt_frames=30, seed=1,
                   overrides={"width": 256, "height": 128})
    s = adapt(seq, build_config({"model": f"builtin:{tiny_model}", "detector.name": "gt",
                                 "finetune.epochs": 1, "tracking.min_height_px": 8}),
              log=lambda m: None)
    with SequenceReader(seq) as r:
        agents = sum(int((r.instances(i) > 0).sum()) for i in r.split("adapt"))
        frame_pixels = len(r.split("adapt")) * r.width * r.height
    assert 0.5 * agents <= s["pseudo_label_agent_pixels"] <= agents < 0.3 * frame_pixels


def test_another_summary_does_not_replace_an_earlier_runs_predictions(tmp_path, sequence,
                                                                       tiny_model, capsys):
    """A second run with other settings and another --summary replaced the first run's maps
    without a word, leaving its summary describing predictions that were gone. It is refused
    (one line naming a map) unless --overwrite; with it, a run whose metric maps are refused
    removes the earlier run's instead of leaving them beside its own."""
    from staticdepth.dataset.predictions import prediction_path

    seq = _copy(sequence, tmp_path / "o.h5")
    common = ["adapt", seq, "--model", f"builtin:{tiny_model}", "--detector", "gt",
              "--epochs", "0", "--set", "tracking.min_height_px=8", "--device", "cpu"]
    assert main([*common, "--summary", str(tmp_path / "a.json")]) == 0
    a = json.load(open(tmp_path / "a.json"))
    capsys.readouterr()

    def hashes():
        with SequenceReader(seq) as r:
            return {n: r.prediction_attrs(n)["config_hash"] for n in r.predictions()}

    first = hashes()
    assert first == {n: a["stage_hashes"][s] for n, s in
                     {"base": "base", "ft": "ft", "align": "align", "ft-align": "align",
                      "align-metric": "scale", "ft-align-metric": "scale"}.items()}
    other = [*common, "--set", "align.erode_px=4", "--summary", str(tmp_path / "b.json")]
    assert main(other) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and prediction_path(seq, "align") in err[0]
    assert "earlier adapt run" in err[0] and "--overwrite" in err[0]
    assert hashes() == first and not (tmp_path / "b.json").exists()
    # the same settings under another summary: every stage is up to date, nothing replaced
    assert main([*common, "--summary", str(tmp_path / "c.json")]) == 0
    assert hashes() == first
    # --overwrite replaces them; metric maps refused: the earlier run's are removed
    refused = [*other, "--set", "scale.max_rel_error=1e-9", "--overwrite"]
    assert main(refused) == 0
    b = json.load(open(tmp_path / "b.json"))
    assert b["metric_refused"] and "align-metric" not in b["predictions"]
    now = hashes()
    assert set(now) == {"base", "ft", "align", "ft-align"}
    assert now["base"] == first["base"] and now["align"] != first["align"]
    assert now["align"] == b["stage_hashes"]["align"]
    # report: a.json describes maps that b's run has replaced
    out = tmp_path / "rep"
    assert main(["report", f"o={seq}", "--summary", f"o={tmp_path / 'a.json'}", "--out",
                 str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and prediction_path(seq, "align") in err[0] and "'o'" in err[0]
    assert not out.exists()
    assert main(["report", f"o={seq}", "--summary", f"o={tmp_path / 'b.json'}", "--out",
                 str(out)]) == 0
