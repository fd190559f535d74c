"""adapt's fine-tuning frames: the loss weights put ``finetune.agent_weight`` on the agents'
pixels of the instance maps, 1 elsewhere, 0 where the label is not finite; flips keep the image,
label and weights together."""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.adaptation.common import Workspace
from staticdepth.adaptation.finetune import AdaptationFrames
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.pseudo_labels import PseudoLabelConfig

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_agent_pixels_take_the_agent_weight(tmp_path):
    seq = tmp_path / "c1.h5"
    render_to_file(seq, preset_name="c1", n_frames=4, adapt_frames=4, seed=1,
                   overrides={"width": 128, "height": 64})
    ws = Workspace(seq, log=lambda s: None)
    rng = np.random.default_rng(0)
    labels = rng.random((4, 64, 128)).astype(np.float32)
    labels[:, :3] = np.nan                        # e.g. above the horizon: no label
    with ws.frame_writer("labels.h5", n=4, shape=(64, 128), dtype=np.float32,
                         config_hash="test") as w:
        for k in range(4):
            w.write(k, labels[k])
    classes = PseudoLabelConfig().classes
    with SequenceReader(seq) as r:
        agents = [np.isin(r.instances(i), r.agents(i)["instance_id"][
            np.isin(r.agents(i)["class_id"], list(classes))]) & (r.instances(i) > 0)
            for i in range(4)]
        left = [r.left(i) for i in range(4)]
    assert sum(a.sum() for a in agents) > 50       # the scene has people in view
    plain, heavy = AdaptationFrames(ws, "gt"), AdaptationFrames(ws, "gt", 7.0, classes)
    try:
        for k in range(4):
            a = plain[(k, False)]
            assert np.array_equal(a["mask"], np.isfinite(labels[k]).astype(np.float32))
            b = heavy[(k, False)]
            expect = np.where(agents[k], 7.0, 1.0) * np.isfinite(labels[k])
            assert np.array_equal(b["mask"], expect)
            np.testing.assert_array_equal(b["target"], labels[k])
            f = heavy[(k, True)]
            assert np.array_equal(f["mask"], expect[:, ::-1])
            np.testing.assert_array_equal(f["target"], labels[k][:, ::-1])
            assert np.array_equal(f["image"], left[k][:, ::-1])
    finally:
        plain.close()
        heavy.close()


def test_agent_weight_must_be_positive():
    from staticdepth.errors import InputError
    from staticdepth.finetune import FinetuneConfig

    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="agent_weight"):
            FinetuneConfig(agent_weight=bad)


def test_adapt_finetune_stops_at_the_step_budget(tmp_path):
    """adapt's fine-tuning loop over 10 adaptation frames, batch 4, 5 epochs, max_steps 7: epochs
    of 3, 3 and 1 batches (24 frames drawn), the cut epoch's frames from its random order of the
    whole split; the summary records carry the steps actually run."""
    import dataclasses

    import torch

    from staticdepth.adaptation.config import build_config
    from staticdepth.adaptation.finetune import run
    from staticdepth.finetune import epoch_order
    from staticdepth.models.tiny import TinyDepthNet, builtin_model

    seq = tmp_path / "c1.h5"
    render_to_file(seq, preset_name="c1", n_frames=10, adapt_frames=10, seed=1,
                   overrides={"width": 64, "height": 32})
    ws = Workspace(seq, log=lambda s: None)
    labels = np.random.default_rng(0).random((10, 32, 64)).astype(np.float32) + 0.5
    with ws.frame_writer("labels.h5", n=10, shape=(32, 64), dtype=np.float32,
                         config_hash="test") as w:
        for k in range(10):
            w.write(k, labels[k])
    conf = build_config({"finetune.epochs": 5, "finetune.max_steps": 7, "finetune.batch_size": 4})
    torch.manual_seed(0)
    model = builtin_model(TinyDepthNet(enc_channels=(4, 8, 8, 16, 16), dec_channels=(16, 8, 8, 4)),
                          input_height=32, input_width=64)
    seen = []
    real = AdaptationFrames.__getitem__

    def spy(self, item):
        seen.append(item[0])
        return real(self, item)

    AdaptationFrames.__getitem__ = spy
    try:
        hist = run(conf, ws, model, "h", "decoder")
    finally:
        AdaptationFrames.__getitem__ = real
    assert [r["steps"] for r in hist] == [3, 3, 1]
    assert ws.frames["finetune"] == 24 and len(seen) == 24
    order, _ = epoch_order(10, dataclasses.replace(conf.finetune), 2)
    assert seen[20:] == [int(k) for k in order[:4]]    # epoch 3: the first batch of its order
    assert sorted(seen[:10]) == list(range(10))         # a full epoch: every frame once
