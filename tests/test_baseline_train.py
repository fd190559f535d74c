"""The stereo baseline end to end: train on a synthetic stereo sequence, predict, evaluate
metrically; resume, determinism, and every user-facing error."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from test_baseline_scene import BASELINE_M, camera, write_sequence

import staticdepth.baseline.train as train_mod
from staticdepth.baseline.config import preset
from staticdepth.baseline.predict import predict_sequence
from staticdepth.baseline.train import load_checkpoint, train
from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError
from staticdepth.metrics import depth_metrics

pytestmark = pytest.mark.usefixtures("one_thread")

# A few steps at 64x64: for resume, determinism and error paths.
MICRO = {"width": 64, "height": 64, "epochs": 2, "batch_size": 4}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The synthetic sequence trained with the ``tiny`` preset through the CLI (about 10-20 s)."""
    d = tmp_path_factory.mktemp("baseline")
    seq = write_sequence(d / "seq.h5", n_frames=12, adapt_frames=8)
    assert main(["baseline", "train", seq, "--preset", "tiny", "--device", "cpu"]) == 0
    return seq, str(d / "seq.baseline.pt")


def test_training_lowers_the_loss(trained):
    _, ckpt = trained
    state = load_checkpoint(ckpt)
    assert state["epoch"] == state["config"].epochs == 16
    assert state["baseline_m"] == pytest.approx(BASELINE_M)
    assert state["focal_px"] == pytest.approx(camera().fx * 128 / 192)
    first = np.mean([h["loss"] for h in state["history"] if h["epoch"] == 0])
    last = np.mean([h["loss"] for h in state["history"] if h["epoch"] == 15])
    print(f"loss: first epoch {first:.4f}, last epoch {last:.4f}")
    assert last < 0.4 * first, (first, last)


def test_predictions_are_metric_and_beat_a_constant(trained, capsys):
    seq, ckpt = trained
    assert main(["baseline", "predict", seq, "--device", "cpu"]) == 0
    assert f"{seq}.pred/stereo-baseline.h5" in capsys.readouterr().out     # the file written
    with SequenceReader(seq) as r:
        assert "stereo-baseline" in r.predictions()
        assert r.prediction_attrs("stereo-baseline")["metric"] == 1
        for i in r.split("adapt"):                      # every frame is predicted
            p = r.prediction("stereo-baseline", i)
            assert np.isfinite(p).all() and p.min() >= 1.0 and p.max() <= 100.0
        gts = [r.depth(i) for i in r.split("eval")]
        preds = [r.prediction("stereo-baseline", i) for i in r.split("eval")]
    const = float(np.median(np.concatenate([g.ravel() for g in gts])))   # oracle constant
    ours = np.mean([depth_metrics(p, g)["abs_rel"] for p, g in zip(preds, gts)])
    flat = np.mean([depth_metrics(np.full_like(g, const), g)["abs_rel"] for g in gts])
    print(f"eval AbsRel {ours:.4f}, oracle constant {flat:.4f}")
    assert ours < 0.15 and ours < 0.4 * flat, (ours, flat)     # no median rescaling


def test_finished_checkpoint_is_kept(trained, capsys):
    seq, ckpt = trained
    before = load_checkpoint(ckpt)["step"]
    from staticdepth.baseline.scene_fit import fit_to_scene
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(seq) as r:               # the CLI fits the preset to the scene
        conf = fit_to_scene(r, preset("tiny"))
    info = train(seq, ckpt, conf, "cpu", log=print)
    assert "already trained" in capsys.readouterr().out
    assert info["steps"] == before == load_checkpoint(ckpt)["step"]


def test_resume_after_interruption_is_bit_exact(tmp_path, monkeypatch):
    seq = write_sequence(tmp_path / "s.h5", n_frames=5, adapt_frames=4)
    conf = preset("tiny", MICRO)
    full = train(seq, tmp_path / "full.pt", conf, "cpu")
    assert full["steps"] == 4                       # 4 frames x 2 sides / batch 4, 2 epochs
    calls = {"n": 0}
    real_step = train_mod.train_step

    def flaky(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real_step(*a, **kw)
    monkeypatch.setattr(train_mod, "train_step", flaky)
    with pytest.raises(KeyboardInterrupt):
        train(seq, tmp_path / "cut.pt", conf, "cpu", checkpoint_every=1)
    assert load_checkpoint(tmp_path / "cut.pt")["step"] == 3    # mid-epoch checkpoint
    monkeypatch.setattr(train_mod, "train_step", real_step)
    resumed = train(seq, tmp_path / "cut.pt", conf, "cpu")
    assert resumed["steps"] == 4
    a, b = load_checkpoint(tmp_path / "full.pt"), load_checkpoint(tmp_path / "cut.pt")
    for k, v in a["model"].items():
        assert torch.equal(v, b["model"][k]), k
    assert [h["loss"] for h in a["history"]] == [h["loss"] for h in b["history"]]
    assert not list(tmp_path.glob("*.tmp*"))         # atomic writes leave no temporary file


def test_resume_refuses_other_settings_or_geometry(tmp_path):
    seq = write_sequence(tmp_path / "s.h5", n_frames=4, adapt_frames=4)
    conf = preset("tiny", {**MICRO, "epochs": 1})
    train(seq, tmp_path / "c.pt", conf, "cpu")
    with pytest.raises(InputError, match=r"other settings \(lr\)"):
        train(seq, tmp_path / "c.pt", preset("tiny", {**MICRO, "epochs": 1, "lr": 0.1}), "cpu")
    other = write_sequence(tmp_path / "o.h5", n_frames=4, adapt_frames=4,
                           cam=camera(focal=120.0))
    with pytest.raises(InputError, match="trained on another sequence"):
        train(other, tmp_path / "c.pt", conf, "cpu")
    # the geometry is checked too: a checkpoint that records no sequence (an older one), or
    # another sequence's used on purpose
    state = load_checkpoint(tmp_path / "c.pt")
    del state["sequence_id"]
    train_mod.save_checkpoint(str(tmp_path / "old.pt"), {**state, "config": conf.to_dict()})
    with pytest.raises(InputError, match="another stereo geometry"):
        train(other, tmp_path / "old.pt", conf, "cpu")
    with pytest.raises(InputError, match="trained with focal"):
        predict_sequence(other, tmp_path / "c.pt", any_sequence=True)
    with pytest.raises(InputError, match="batch size"):
        predict_sequence(seq, tmp_path / "c.pt", batch_size=0)
    assert train(other, tmp_path / "c.pt", conf, "cpu", overwrite=True)["steps"] == 2


def test_sequence_without_right_images_says_how_to_fix_it(tmp_path, capsys):
    seq = write_sequence(tmp_path / "mono.h5", n_frames=2, adapt_frames=2, stereo=False)
    with pytest.raises(InputError, match=r"--right option \(image_03\)"):
        train(seq, tmp_path / "c.pt", preset("tiny", MICRO), "cpu")
    assert main(["baseline", "train", seq, "--preset", "tiny", "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "no right images" in err and "image_03" in err and len(err.strip().splitlines()) == 1


def test_other_input_errors(tmp_path, capsys):
    norig = write_sequence(tmp_path / "norig.h5", n_frames=2, adapt_frames=2, rig=False)
    with pytest.raises(InputError, match="no stereo rig"):
        train(norig, tmp_path / "c.pt", preset("tiny", MICRO), "cpu")
    noadapt = write_sequence(tmp_path / "noadapt.h5", n_frames=2, adapt_frames=0)
    with pytest.raises(InputError, match="adaptation split is empty"):
        train(noadapt, tmp_path / "c.pt", preset("tiny", MICRO), "cpu")
    assert main(["baseline", "train", noadapt, "--set", "epoch=3"]) == 2
    assert "unknown setting(s) ['epoch']" in capsys.readouterr().err
    ok = write_sequence(tmp_path / "ok.h5", n_frames=2, adapt_frames=2)
    assert main(["baseline", "train", ok, "--preset", "tiny", "--set", "width=64", "--set",
                 "encoder_width=64", "--weights", str(tmp_path / "no.pth")]) == 2
    assert "ImageNet weights file not found" in capsys.readouterr().err
    assert main(["baseline", "predict", noadapt, "--device", "cpu"]) == 2
    assert "checkpoint not found" in capsys.readouterr().err
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(InputError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    torch.save({"format": "something else"}, bad)
    with pytest.raises(InputError, match="not a stereo-baseline checkpoint"):
        load_checkpoint(bad)
