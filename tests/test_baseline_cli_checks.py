"""``baseline predict`` refuses to replace a prediction without ``--overwrite``; ``baseline train``
prints its epoch lines above the progress bar on a terminal and refuses impossible settings, each
in one line naming the file or the setting. Micro runs at 64x64: seconds."""
from __future__ import annotations

import fcntl
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest
from test_baseline_scene import write_sequence

import staticdepth.dataset.h5 as h5
from staticdepth.baseline.config import preset
from staticdepth.baseline.predict import predict_sequence
from staticdepth.baseline.train import train
from staticdepth.cli import main
from staticdepth.errors import InputError

pytestmark = pytest.mark.usefixtures("one_thread")

MICRO = ["--preset", "tiny", "--scene-fit", "none", "--set", "width=64", "--set", "height=64",
         "--set", "epochs=2", "--set", "batch_size=4", "--device", "cpu"]
README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 6-frame stereo sequence and a 2-epoch checkpoint of it (about 2 s)."""
    d = tmp_path_factory.mktemp("checks")
    seq = write_sequence(d / "s.h5", n_frames=6, adapt_frames=4)
    conf = preset("tiny", {"width": 64, "height": 64, "epochs": 2, "batch_size": 4})
    train(seq, d / "s.baseline.pt", conf, "cpu")
    return seq, str(d / "s.baseline.pt")


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


# -- 1. predict refuses an existing prediction unless --overwrite --------------------------------
def test_predict_refuses_to_replace_a_prediction(trained, capsys, monkeypatch):
    seq, _ = trained
    out = Path(f"{seq}.pred/stereo-baseline.h5")
    calls = []
    real = h5.add_prediction
    monkeypatch.setattr(h5, "add_prediction",
                        lambda *a, **kw: calls.append(kw["overwrite"]) or real(*a, **kw))
    assert main(["baseline", "predict", seq, "--device", "cpu"]) == 0
    assert calls == [False]                   # passed explicitly, not the function's default
    assert str(out) in capsys.readouterr().out
    before = out.read_bytes()
    # refused before any work: a missing checkpoint is not even looked at
    assert main(["baseline", "predict", seq, "--checkpoint", str(out.parent / "none.pt"),
                 "--device", "cpu"]) == 2
    captured = capsys.readouterr()
    line = _one_line(captured.err)
    assert f"{out}: exists already; pass --overwrite to replace it" in line, line
    assert captured.out == "" and out.read_bytes() == before and calls == [False]
    with pytest.raises(InputError, match="exists already") as e:
        predict_sequence(seq, out.parent / "none.pt")
    assert e.value.path == str(out)
    assert main(["baseline", "predict", seq, "--device", "cpu", "--overwrite"]) == 0
    assert calls == [False, True] and out.exists()


def test_predict_other_name_is_not_refused(trained, capsys):
    seq, _ = trained
    assert main(["baseline", "predict", seq, "--name", "sb-2", "--device", "cpu"]) == 0
    assert f"{seq}.pred/sb-2.h5" in capsys.readouterr().out
    assert Path(f"{seq}.pred/sb-2.h5").is_file()


# -- 3. help and README name the file that is written --------------------------------------------
def test_help_and_readme_name_the_prediction_file(capsys):
    assert main(["baseline", "predict", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "SEQ.h5.pred/NAME.h5" in text and "pred/NAME/depth" not in text
    assert "--overwrite" in text
    readme = README.read_text(encoding="utf-8")
    section = readme.split("### Stereo self-supervised baseline", 1)[1].split("\n### ", 1)[0]
    assert "`SEQ.h5.pred/stereo-baseline.h5`" in section
    assert "pred/stereo-baseline/depth" not in readme


# -- 4. settings refused in one line naming them -------------------------------------------------
NAN = "setting '{}': NaN is no value (give a number, or none where the setting allows it)"


@pytest.mark.parametrize("args, message", [
    (["--checkpoint-every", "0"], "--checkpoint-every must be >= 1 (optimisation steps), got 0"),
    (["--checkpoint-every", "-5"], "--checkpoint-every must be >= 1 (optimisation steps), got -5"),
    (["--set", "epochs=0"], "epochs must be >= 1, got 0"),
    (["--set", "batch_size=-1"], "batch_size must be >= 1, got -1"),
    (["--set", "encoder_width=0"], "encoder_width must be >= 1, got 0"),
    (["--set", "lr_step_epochs=0"], "lr_step_epochs must be >= 1, got 0"),
    (["--set", "lr=-1"], "need a finite lr > 0, got lr -1.0"),
    (["--set", "lr=nan"], NAN.format("lr")),
    (["--set", "lr=inf"], "need a finite lr > 0, got lr inf"),          # segfaulted in training
    (["--set", "lr_gamma=nan"], NAN.format("lr_gamma")),
    (["--set", "ssim_weight=nan"], NAN.format("ssim_weight")),
    (["--set", "smoothness_weight=inf"],                                 # segfaulted in training
     "need a finite smoothness_weight >= 0, got smoothness_weight inf"),
    (["--set", "smoothness_weight=-1"],
     "need a finite smoothness_weight >= 0, got smoothness_weight -1.0"),
    (["--set", "max_depth=inf"], "need a finite max_depth > 0 (metres), got max_depth inf"),
    (["--set", "min_depth=nan"], NAN.format("min_depth")),
    (["--set", "min_depth=-1"], "need a finite min_depth > 0 (metres), got min_depth -1.0"),
    (["--set", "height=-64"], "width and height must be multiples of 32, at least 64 (the decoder "
                              "pads the stride-32 features), got height -64"),
    (["--set", "seed=-1"], "need 0 <= seed < 2**32, got seed -1"),
    (["--set", "seed=20000000000000"], "need 0 <= seed < 2**32, got seed 20000000000000"),
])
def test_train_refuses_impossible_settings(tmp_path, capsys, args, message):
    seq = str(tmp_path / "absent.h5")       # refused before the sequence is opened
    assert main(["baseline", "train", seq, *MICRO, *args]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == f"staticdepth baseline: error: {message}", line
    assert not os.path.exists(tmp_path / "absent.baseline.pt")


def test_train_library_refuses_checkpoint_every_zero(trained, tmp_path):
    seq, _ = trained
    with pytest.raises(InputError, match=r"--checkpoint-every must be >= 1 .*got 0"):
        train(seq, tmp_path / "c.pt", preset("tiny", {"width": 64, "height": 64}), "cpu",
              checkpoint_every=0)
    assert not (tmp_path / "c.pt").exists()


# -- 2. epoch lines above the progress bar on a terminal -----------------------------------------
def _screen(raw: str) -> list[str]:
    """The lines a terminal shows for ``raw`` (carriage returns overwrite; no other controls)."""
    assert "\x1b" not in raw, repr(raw)
    lines = []
    for row in raw.replace("\r\n", "\n").split("\n"):
        cells: list[str] = []
        col = 0
        for ch in row:
            if ch == "\r":
                col = 0
                continue
            cells[col:col + 1] = [ch]
            col += 1
        lines.append("".join(cells).rstrip())
    return lines


def test_epoch_lines_are_printed_above_the_bar_on_a_terminal(trained, tmp_path):
    seq, _ = trained
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    cmd = [sys.executable, "-c", "import sys; from staticdepth.cli import main; sys.exit(main())",
           "baseline", "train", seq, *MICRO, "--checkpoint", str(tmp_path / "tty.pt")]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=slave, stderr=slave,
                            env={**os.environ, "TERM": "xterm"}, close_fds=True)
    os.close(slave)
    raw = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:                      # EIO: the child closed the terminal
            break
        if not chunk:
            break
        raw += chunk
    os.close(master)
    assert proc.wait(timeout=120) == 0, raw.decode(errors="replace")
    text = raw.decode()
    assert "baseline train:" in text and "%|" in text           # a bar was drawn
    epoch_lines = [ln for ln in _screen(text) if "epoch 1/2" in ln or "epoch 2/2" in ln]
    assert len(epoch_lines) == 2, _screen(text)
    for ln in epoch_lines:
        assert re.fullmatch(r"epoch [12]/2: loss \d\.\d{4} \(lr 1\.00e-03\)", ln), ln
