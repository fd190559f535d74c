"""``staticdepth train-builtin``: its training set against closed-form geometry, the command, errors."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.models import load_model
from staticdepth.train_builtin import TrainBuiltinConfig, parse_size, render_training_set

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_training_targets_are_inverse_depth_of_the_level_ground():
    """A level camera at height H sees ground row v at Z = f H / (v - c_y): target (v - c_y)/(f H)."""
    from staticdepth.dataset.synth import SyntheticScene, preset

    conf = TrainBuiltinConfig(frames=2, width=128, height=64, pitch_range_deg=(0.0, 0.0),
                              height_range_m=(1.6, 1.6))
    images, targets = render_training_set(conf)
    assert images.shape == (2, 64, 128, 3) and images.dtype == np.uint8
    scene = SyntheticScene(preset("street", seed=0, width=128, height=64))
    frame = scene.render(0)
    ground = frame["ground_mask"]
    f, cy = scene.camera.fy, scene.camera.cy
    v = np.nonzero(ground)[0].astype(np.float64)
    np.testing.assert_allclose(targets[0][ground], (v - cy) / (f * 1.6), rtol=2e-3, atol=1e-5)
    sky = ~np.isfinite(frame["depth"])
    assert sky.any() and np.all(targets[0][sky] == 0.0)     # the sky is at infinity


def test_train_builtin_command_writes_loadable_weights(tmp_path, capsys):
    out = tmp_path / "b.pt"
    rc = main(["train-builtin", "--out", str(out), "--frames", "4", "--epochs", "1",
               "--size", "64x32", "--batch-size", "2", "--device", "cpu"])
    assert rc == 0 and "wrote" in capsys.readouterr().out
    model = load_model(f"builtin:{out}")
    assert model.info["train"]["frames"] == 4 and model.input_size(64, 128) == (32, 64)
    # what the weights depend on besides the seed: torch and its thread count
    import torch
    assert model.info["torch_threads"] == torch.get_num_threads() >= 1
    assert model.info["torch"] == str(torch.__version__)
    assert model.predict(np.zeros((40, 70, 3), np.uint8)).shape == (40, 70)
    assert not (tmp_path / "b.pt.ckpt").exists()


def test_train_builtin_errors(tmp_path, capsys):
    for bad in ("384", "384x100", "axb", "16x16"):
        with pytest.raises(InputError, match="size"):
            parse_size(bad)
    assert parse_size("384x192") == (384, 192)
    with pytest.raises(InputError, match="--frames must be a finite number >= 1, got 0"):
        TrainBuiltinConfig(frames=0)
    assert main(["train-builtin", "--out", str(tmp_path / "e.pt"), "--epochs", "0"]) == 2
    assert "--epochs must be a finite number >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "e.pt").exists()     # was: an untrained network, "wrote e.pt"
    assert main(["train-builtin", "--out", str(tmp_path / "no" / "b.pt"), "--frames", "1",
                 "--epochs", "1", "--size", "64x32"]) == 2
    assert "output's parent does not exist" in capsys.readouterr().err


def test_hf_without_transformers_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "transformers", None)
    with pytest.raises(InputError, match="optional dependency transformers"):
        load_model("hf:Intel/dpt-large")
    from staticdepth.detectors import make_detector
    with pytest.raises(InputError, match="needs transformers"):
        make_detector("mask2former", model="x")


def test_train_builtin_runs_every_epoch_asked_for(tmp_path):
    """It stopped at adapt's fine-tuning budget (finetune.max_steps, 60 steps) without a word:
    8 frames, batch 1, 8 epochs are 64 steps, of which 60 were taken; --max-steps cuts on
    purpose."""
    from staticdepth.train_builtin import train_builtin

    conf = TrainBuiltinConfig(frames=8, epochs=8, width=64, height=32, batch_size=1)
    _, hist = train_builtin(conf, out=tmp_path / "a.pt", device="cpu", log=lambda *_: None)
    assert [r["steps"] for r in hist] == [8] * 8
    conf = TrainBuiltinConfig(frames=8, epochs=8, width=64, height=32, batch_size=1,
                              max_steps=10)
    _, hist = train_builtin(conf, out=tmp_path / "b.pt", device="cpu", log=lambda *_: None)
    assert [r["steps"] for r in hist] == [8, 2]


def _tiny_run(out):
    return ["train-builtin", "--out", str(out), "--frames", "2", "--epochs", "1", "--size",
            "64x32", "--batch-size", "2", "--device", "cpu"]


def test_train_builtin_lr_range_is_checked_first(tmp_path, capsys):
    """--lr 1e12 is refused before rendering, in one line naming --lr (it ran and diverged)."""
    out = tmp_path / "tb0.pt"
    with pytest.raises(InputError, match=r"--lr must be in \(0, 1\], got 1e\+12"):
        TrainBuiltinConfig(lr=1e12)
    assert TrainBuiltinConfig(lr=1.0).lr == 1.0
    assert main([*_tiny_run(out), "--lr", "1e12"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--lr must be in (0, 1], got 1e+12" in err
    assert not out.exists()


def test_train_builtin_divergence_names_lr(tmp_path, capsys, monkeypatch):
    """A diverging run says 'training diverged' and names --lr, with no torch warning (it said
    'fine-tuning diverged; lower the learning rate' after a multi-line UserWarning)."""
    import warnings

    import torch

    import staticdepth.finetune as ft

    out = tmp_path / "tb0.pt"
    tiny = _tiny_run(out)
    monkeypatch.setattr(ft, "compute_loss", lambda pred, batch, conf: pred.mean() * float("nan"))
    # torch warns once per process ('Converting a tensor with requires_grad=True to a scalar'):
    # the conversions themselves are recorded, so that an earlier test cannot hide one
    converted, to_float = [], torch.Tensor.__float__
    monkeypatch.setattr(torch.Tensor, "__float__",
                        lambda t: converted.append(t.requires_grad) or to_float(t))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*tiny, "--lr", "0.5"]) == 2
    assert not [w for w in caught if "requires_grad" in str(w.message)]
    assert converted and not any(converted)
    err = capsys.readouterr().err
    assert err == ("staticdepth train-builtin: error: training diverged (loss nan); lower --lr "
                   "(it was 0.5)\n")
    assert not out.exists()


def test_train_builtin_help_example_runs_as_written():
    """The example in `train-builtin --help` parses (it lacked the required --out)."""
    import shlex

    from staticdepth import cli

    argv = shlex.split(cli.COMMANDS["train-builtin"][2])[1:]
    args = cli.build_parser(argv).parse_args(argv)
    assert args.out and (args.frames, args.epochs) == (400, 15)
