"""The second built-in architecture: shapes, layer groups, and a save/load round trip."""
from __future__ import annotations

import numpy as np
import torch

from staticdepth.models.tiny import builtin_model, load_builtin, save_builtin
from staticdepth.models.unet import TinyUNet


def test_unet_predicts_positive_inverse_depth_and_round_trips(tmp_path):
    torch.manual_seed(0)
    net = TinyUNet((4, 8, 8, 16))
    model = builtin_model(net, input_height=64, input_width=128)
    img = np.random.default_rng(0).integers(0, 255, (64, 128, 3), dtype=np.uint8)
    d = model.predict(img)
    assert d.shape == (64, 128) and np.all(d > 0)
    heads = model.set_trainable("head")
    assert sum(p.numel() for p in heads) == sum(p.numel() for p in net.head.parameters())
    path = save_builtin(tmp_path / "u.pt", model)
    back = load_builtin(path)
    assert isinstance(back.net, TinyUNet)
    np.testing.assert_allclose(back.predict(img), d, rtol=1e-5)
