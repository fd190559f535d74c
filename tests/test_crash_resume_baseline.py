"""`baseline train` killed (SIGKILL, SIGTERM) at a random step resumes from its last checkpoint to
the very weights of an uninterrupted run, running only the missing steps."""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import pytest
import torch
from test_baseline_scene import write_sequence

import staticdepth.baseline.train as train_mod
from staticdepth.baseline.config import preset
from staticdepth.baseline.train import load_checkpoint, train

pytestmark = pytest.mark.usefixtures("one_thread")

# Each step of the killed run is slowed by 0.3 s (the weights are unchanged): the signal must land
# while steps are left, and a loaded machine's poll can take longer than three bare tiny steps.
CLI = ("import sys, time; import staticdepth.baseline.train as t; step = t.train_step; "
       "t.train_step = lambda *a, **k: (time.sleep(0.3), step(*a, **k))[1]; "
       "from staticdepth.cli import main; sys.exit(main(sys.argv[1:]))")
SETTINGS = {"width": 64, "height": 64, "epochs": 5, "batch_size": 4}  # 2 steps per epoch


def checkpoint_step(path) -> int:
    try:
        return int(torch.load(path, map_location="cpu", weights_only=True)["step"])
    except Exception:
        return -1


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killed_baseline_training_resumes_to_the_uninterrupted_weights(sig, tmp_path,
                                                                       monkeypatch):
    seq = write_sequence(tmp_path / "s.h5", n_frames=4, adapt_frames=4)
    ckpt = tmp_path / "cut.pt"
    total = 2 * SETTINGS["epochs"]
    at = random.Random(f"baseline{sig}").randint(2, total - 3)
    args = ["baseline", "train", seq, "--preset", "tiny", "--device", "cpu", "--checkpoint",
            str(ckpt), "--checkpoint-every", "1", "--scene-fit", "none"]  # the bare preset, as train() below
    args += [a for k, v in SETTINGS.items() for a in ("--set", f"{k}={v}")]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-c", CLI, *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    try:
        while checkpoint_step(ckpt) < at:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < 300, "no checkpoint written"
            time.sleep(0.02)
        proc.send_signal(sig)
        proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    k = load_checkpoint(ckpt)["step"]
    assert at <= k < total, (at, k)
    steps = []
    real_step = train_mod.train_step

    def counting(*a, **kw):
        steps.append(1)
        return real_step(*a, **kw)

    monkeypatch.setattr(train_mod, "train_step", counting)
    resumed = train(seq, ckpt, preset("tiny", SETTINGS), "cpu", checkpoint_every=1)
    assert resumed["steps"] == total and len(steps) == total - k  # only the missing steps
    monkeypatch.setattr(train_mod, "train_step", real_step)
    train(seq, tmp_path / "full.pt", preset("tiny", SETTINGS), "cpu")
    a, b = load_checkpoint(tmp_path / "full.pt"), load_checkpoint(ckpt)
    for name, v in a["model"].items():
        assert torch.equal(v, b["model"][name]), name
