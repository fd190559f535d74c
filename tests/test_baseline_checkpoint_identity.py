"""The stereo baseline's checkpoint against the files around it: it never replaces one of the
command's inputs (even with ``--overwrite``), it records the sequence it was trained on (a
sequence replaced since is refused by ``train`` and ``predict``), a second ``train`` says it kept
the earlier training, and a truncated checkpoint is refused in one clear line. Micro runs at
64x64: seconds."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch
from test_baseline_scene import write_sequence

from staticdepth.baseline.config import preset
from staticdepth.baseline.predict import predict_sequence
from staticdepth.baseline.train import load_checkpoint, save_checkpoint, train
from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError

pytestmark = pytest.mark.usefixtures("one_thread")

MICRO = ["--preset", "tiny", "--scene-fit", "none", "--set", "width=64", "--set", "height=64",
         "--set", "epochs=1", "--set", "batch_size=4", "--device", "cpu"]
CONF = preset("tiny", {"width": 64, "height": 64, "epochs": 1, "batch_size": 4})
ERR = "staticdepth baseline: error: "


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 5-frame sequence, a 1-epoch checkpoint of it, and a sequence of other content (one
    frame more) with the same camera and rig (about 1 s)."""
    d = tmp_path_factory.mktemp("identity")
    seq = write_sequence(d / "s.h5", n_frames=5, adapt_frames=4)
    other = write_sequence(d / "other.h5", n_frames=6, adapt_frames=4)
    train(seq, d / "s.baseline.pt", CONF, "cpu")
    return seq, str(d / "s.baseline.pt"), other


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _sequence_id(path) -> str:
    with SequenceReader(path) as r:
        return r.sequence_id()


# -- 1. the checkpoint never names one of train's inputs -----------------------------------------
def test_train_refuses_a_checkpoint_that_is_its_sequence(trained, tmp_path, capsys, monkeypatch):
    seq = str(shutil.copy(trained[0], tmp_path / "b1.h5"))
    before = Path(seq).read_bytes()
    (tmp_path / "link.pt").symlink_to(seq)
    monkeypatch.chdir(tmp_path)
    os.mkdir("sub")
    message = ("--checkpoint names this command's input (sequence): writing it would destroy the "
               "input; choose another --checkpoint")
    for ckpt in (seq, "b1.h5", "./sub/../b1.h5", str(tmp_path / "link.pt")):
        for extra in ([], ["--overwrite"]):
            assert main(["baseline", "train", seq, *MICRO, "--checkpoint", ckpt, *extra]) == 2
            captured = capsys.readouterr()
            assert _one_line(captured.err) == f"{ERR}{ckpt}: {message}"
            assert captured.out == ""                 # refused before any work (no scene fit)
    assert Path(seq).read_bytes() == before and (tmp_path / "link.pt").is_symlink()
    with pytest.raises(InputError, match=r"names this command's input \(sequence\)"):
        train(seq, tmp_path / "link.pt", CONF, "cpu", overwrite=True)
    assert Path(seq).read_bytes() == before


def test_train_refuses_a_checkpoint_that_is_its_weights(trained, tmp_path, capsys):
    weights = tmp_path / "resnet18.pth"
    torch.save({"conv1.weight": torch.zeros(1)}, weights)
    before = weights.read_bytes()
    assert main(["baseline", "train", trained[0], *MICRO, "--weights", str(weights),
                 "--checkpoint", str(weights), "--overwrite"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (f"{ERR}{weights}: --checkpoint names this command's input (weights): writing "
                    "it would destroy the input; choose another --checkpoint")
    assert weights.read_bytes() == before


# -- 2. the checkpoint records its sequence ------------------------------------------------------
def test_checkpoint_records_the_sequence_it_was_trained_on(trained):
    seq, ckpt, _ = trained
    assert load_checkpoint(ckpt)["sequence_id"] == _sequence_id(seq)


def test_train_refuses_a_checkpoint_of_a_replaced_sequence(trained, tmp_path, capsys):
    seq, ckpt, other = trained
    x, x_ckpt = str(tmp_path / "x.h5"), str(tmp_path / "x.baseline.pt")
    shutil.copy(seq, x)
    shutil.copy(ckpt, x_ckpt)
    os.replace(shutil.copy(other, tmp_path / "new.h5"), x)     # same path, other content
    before = Path(x_ckpt).read_bytes()
    assert main(["baseline", "train", x, *MICRO]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (f"{ERR}{x_ckpt}: checkpoint was trained on another sequence ('baseline-test', "
                    f"id {_sequence_id(seq)}) than {x} holds now (id {_sequence_id(other)}); use "
                    "--overwrite to retrain or another --checkpoint")
    assert Path(x_ckpt).read_bytes() == before
    assert main(["baseline", "train", x, *MICRO, "--overwrite"]) == 0      # retrains
    out = capsys.readouterr().out
    assert "trained 1 epochs (2 steps, 4 frames" in out and "kept" not in out
    assert load_checkpoint(x_ckpt)["sequence_id"] == _sequence_id(x)


def test_predict_refuses_a_checkpoint_of_another_sequence(trained, tmp_path, capsys):
    seq, ckpt, other = trained
    x = shutil.copy(other, tmp_path / "x.h5")
    assert main(["baseline", "predict", str(x), "--checkpoint", ckpt, "--device", "cpu"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (f"{ERR}{ckpt}: the network was trained on another sequence ('baseline-test', "
                    f"id {_sequence_id(seq)}) than {x} (id {_sequence_id(other)}); train on this "
                    "sequence, or pass --any-sequence to predict with it anyway")
    assert not os.path.exists(f"{x}.pred")                          # nothing stored
    with pytest.raises(InputError, match="trained on another sequence"):
        predict_sequence(x, ckpt)
    assert main(["baseline", "predict", str(x), "--checkpoint", ckpt, "--any-sequence",
                 "--device", "cpu"]) == 0                           # the user's choice
    with SequenceReader(x) as r:
        assert r.prediction_attrs("stereo-baseline")["trained_on_id"] == _sequence_id(seq)


def test_checkpoint_without_identity_is_used_with_a_warning(trained, tmp_path, capsys):
    """A checkpoint written before identities were stored: predict and resume warn once."""
    seq, ckpt, _ = trained
    state = torch.load(ckpt, map_location="cpu", weights_only=True)
    del state["sequence_id"]
    old = str(tmp_path / "old.pt")
    save_checkpoint(old, state)
    assert main(["baseline", "predict", seq, "--checkpoint", old, "--name", "old",
                 "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert out.count(f"warning: {old} does not record which sequence it was trained on") == 1
    with SequenceReader(seq) as r:
        assert r.prediction_attrs("old")["trained_on_id"] == "unknown"
    info = train(seq, old, CONF, "cpu", log=print)
    assert info["already_trained"] and info["steps"] == 2
    assert capsys.readouterr().out.count("does not record which sequence") == 1


# -- 3. a second train says it kept the earlier training -----------------------------------------
def test_second_train_reports_the_earlier_training(trained, tmp_path, capsys):
    seq = shutil.copy(trained[0], tmp_path / "s.h5")
    assert main(["baseline", "train", str(seq), *MICRO]) == 0
    first = capsys.readouterr().out.splitlines()
    assert first[-1].startswith("trained 1 epochs (2 steps, 4 frames")
    ckpt = tmp_path / "s.baseline.pt"
    before = ckpt.read_bytes()
    assert main(["baseline", "train", str(seq), *MICRO]) == 0
    second = capsys.readouterr().out.splitlines()
    assert second[0] == f"{ckpt} is already trained (1 epochs); --overwrite to retrain"
    assert second[1].startswith(f"{ckpt} kept, from an earlier run: 1 epochs (2 steps, 4 frames")
    assert len(second) == 2 and not any(ln.startswith("trained") for ln in second)
    assert ckpt.read_bytes() == before


# -- 4. a truncated checkpoint: one clear line ---------------------------------------------------
def test_truncated_checkpoint_is_refused_in_one_clear_line(trained, tmp_path, capsys):
    seq, ckpt, _ = trained
    bad = {"trunc.pt": Path(ckpt).read_bytes()[:1000], "empty.pt": b"", "text.pt": b"garbage\n"}
    for name, data in bad.items():
        (tmp_path / name).write_bytes(data)
        path = str(tmp_path / name)
        assert main(["baseline", "predict", seq, "--checkpoint", path, "--name", "t",
                     "--device", "cpu"]) == 2
        line = _one_line(capsys.readouterr().err)
        assert line == f"{ERR}{path}: not a readable checkpoint (truncated or not a torch file)"
    x = shutil.copy(seq, tmp_path / "x.h5")          # resuming it: the same line
    shutil.copy(tmp_path / "trunc.pt", tmp_path / "x.baseline.pt")
    assert main(["baseline", "train", str(x), *MICRO]) == 2
    assert _one_line(capsys.readouterr().err).endswith(
        "x.baseline.pt: not a readable checkpoint (truncated or not a torch file)")


def test_damaged_zip_checkpoint_is_refused_in_one_line(trained, tmp_path, capsys):
    import zipfile

    seq = trained[0]
    path = str(tmp_path / "other.zip")
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("notes.txt", "not a torch file")
    assert main(["baseline", "predict", seq, "--checkpoint", path, "--name", "t",
                 "--device", "cpu"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (f"{ERR}{path}: not a readable checkpoint (a damaged torch file or another "
                    "zip archive)")
