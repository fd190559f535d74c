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
