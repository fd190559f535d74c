"""Fine-tuning loop: learns, trains only the chosen layers, resumes exactly, is reproducible."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from staticdepth.errors import InputError
from staticdepth.finetune import FinetuneConfig, epoch_order, finetune
from staticdepth.losses import ssi_loss
from staticdepth.models.tiny import TinyDepthNet, builtin_model

SMALL = dict(enc_channels=(4, 8, 8, 16, 16), dec_channels=(16, 8, 8, 4))
H, W, N = 32, 64, 6


def _model(seed=0):
    torch.manual_seed(seed)
    return builtin_model(TinyDepthNet(**SMALL), input_height=H, input_width=W)


def _data(seed=0):
    """Images whose target inverse depth is a ground ramp (nearer at the bottom) plus a block."""
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (N, H, W, 3), dtype=np.uint8)
    v = np.arange(H, dtype=np.float32)[:, None] / H
    targets = np.repeat((0.2 + v * np.ones((1, W), np.float32))[None], N, 0)
    for i in range(N):
        u0 = 5 + 8 * i
        images[i, 8:20, u0:u0 + 6] = 255
        targets[i, 8:20, u0:u0 + 6] = 0.9
    return images, targets


def _ssi_of(model, images, targets):
    with torch.no_grad():
        x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
        return float(ssi_loss(model.forward(x), torch.from_numpy(targets), grad_weight=0.0))


def _flat(model):
    return torch.cat([p.detach().flatten() for p in model.net.parameters()])


# the gradient-matching term needs more than a 32 x 64 image to be fitted by a 1/32 encoder
CONF = FinetuneConfig(epochs=8, lr=1e-2, batch_size=2, seed=0, layers="decoder", grad_weight=0.0)


def test_finetune_learns_and_freezes_the_encoder():
    model = _model()
    images, targets = _data()
    enc_before = [p.detach().clone() for p in model.net.stages.parameters()]
    before = _ssi_of(model, images, targets)
    hist = finetune(model, images, targets, conf=CONF)
    after = _ssi_of(model, images, targets)
    assert after < 0.5 * before
    assert len(hist) == 8 and hist[-1]["loss"] < hist[0]["loss"]
    assert all(r["seconds"] > 0 and r["peak_memory_mb"] > 10 for r in hist)
    for a, b in zip(enc_before, model.net.stages.parameters()):
        assert torch.equal(a, b)
    assert not any(p.requires_grad for p in model.net.parameters())


def test_l1_option_pulls_prediction_to_labels():
    model = _model()
    images, _ = _data()
    with torch.no_grad():
        x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
        pred = model.forward(x).numpy()
    labels = pred + 0.05                       # labels in the model's own space
    conf = dataclasses.replace(CONF, loss="l1", epochs=6)
    finetune(model, images, labels, conf=conf)
    with torch.no_grad():
        new = model.forward(x).numpy()
    assert np.abs(new - labels).mean() < 0.5 * np.abs(pred - labels).mean()


def test_resume_after_interruption(tmp_path):
    images, targets = _data()
    conf3 = dataclasses.replace(CONF, epochs=3)
    straight = _model()
    finetune(straight, images, targets, conf=conf3)
    ck = tmp_path / "ft.ckpt"

    def stop_at_2(rec):
        if rec["epoch"] == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        finetune(_model(), images, targets, conf=conf3, checkpoint=ck, on_epoch=stop_at_2)
    resumed = _model()                          # a fresh process would start from the same init
    hist = finetune(resumed, images, targets, conf=conf3, checkpoint=ck)
    assert [r["epoch"] for r in hist] == [1, 2, 3]
    assert torch.equal(_flat(resumed), _flat(straight))
    assert not list(tmp_path.glob("*.tmp*"))
    with pytest.raises(InputError, match="another configuration"):
        finetune(_model(), images, targets, conf=dataclasses.replace(conf3, lr=1e-3), checkpoint=ck)
    ck.write_bytes(b"junk")
    with pytest.raises(InputError, match="unreadable fine-tuning checkpoint"):
        finetune(_model(), images, targets, conf=conf3, checkpoint=ck)


def test_seed_reproducibility_and_flips():
    images, targets = _data()
    a, b, c = _model(), _model(), _model()
    conf = dataclasses.replace(CONF, epochs=2)
    finetune(a, images, targets, conf=conf)
    finetune(b, images, targets, conf=conf)
    finetune(c, images, targets, conf=dataclasses.replace(conf, seed=1))
    assert torch.equal(_flat(a), _flat(b))
    assert not torch.equal(_flat(a), _flat(c))
    order, flips = epoch_order(1000, conf, 0)
    assert sorted(order) == list(range(1000)) and 400 < flips.sum() < 600
    assert not epoch_order(10, dataclasses.replace(conf, flip=False), 0)[1].any()


def test_errors():
    images, targets = _data()
    with pytest.raises(InputError, match="do not match"):
        finetune(_model(), images, targets[:, :-1], conf=CONF)
    with pytest.raises(InputError, match="no frame"):
        finetune(_model(), images[:0], targets[:0], conf=CONF)
    with pytest.raises(InputError, match="loss must be one of"):
        FinetuneConfig(loss="mse")
    with pytest.raises(InputError, match="finetune.lr must be a finite number > 0, got 0"):
        FinetuneConfig(lr=0)
    with pytest.raises(InputError, match="diverged"):
        bad = targets.copy()
        bad[:] = 3e38                           # finite, but the float32 sum overflows to inf
        finetune(_model(), images, bad,
                 conf=dataclasses.replace(CONF, loss="l1", epochs=1))


def test_step_budget_cuts_the_schedule():
    from staticdepth.finetune import epoch_steps

    conf = dataclasses.replace(CONF, epochs=3, batch_size=4, max_steps=0)
    assert epoch_steps(10, conf) == [3, 3, 3]                       # no budget: 3 x ceil(10/4)
    assert epoch_steps(10, dataclasses.replace(conf, max_steps=7)) == [3, 3, 1]
    assert epoch_steps(10, dataclasses.replace(conf, max_steps=2)) == [2]
    assert epoch_steps(10, dataclasses.replace(conf, max_steps=100)) == [3, 3, 3]
    assert epoch_steps(800, dataclasses.replace(conf, epochs=30, max_steps=200)) == [200]
    assert epoch_steps(10, dataclasses.replace(conf, epochs=0, max_steps=5)) == []
    with pytest.raises(InputError, match="max_steps"):
        FinetuneConfig(max_steps=-1)


def test_budgeted_run_is_the_unbudgeted_run_cut_short():
    """N=6, batch 2: 3 steps an epoch. A budget of 4 steps runs epoch 1 (the same loss as a run of
    epochs=1) and one step of epoch 2, so it ends between the runs of epochs=1 and epochs=2."""
    images, targets = _data()
    cut = _model()
    hist = finetune(cut, images, targets, conf=dataclasses.replace(CONF, epochs=8, max_steps=4))
    assert [r["steps"] for r in hist] == [3, 1]
    one = _model()
    h1 = finetune(one, images, targets, conf=dataclasses.replace(CONF, epochs=1, max_steps=0))
    assert h1[0]["steps"] == 3 and h1[0]["loss"] == pytest.approx(hist[0]["loss"], rel=1e-6)
    two = _model()
    finetune(two, images, targets, conf=dataclasses.replace(CONF, epochs=2, max_steps=0))
    a, b, c = _flat(one), _flat(cut), _flat(two)
    assert not torch.equal(a, b) and not torch.equal(b, c)


def test_divergence_is_one_error_without_a_torch_warning(monkeypatch):
    """A NaN loss (it requires grad) is refused naming finetune.lr; reading its value must not
    make torch warn 'Converting a tensor with requires_grad=True to a scalar'."""
    import warnings

    import staticdepth.finetune as ft

    monkeypatch.setattr(ft, "compute_loss", lambda pred, batch, conf: pred.mean() * float("nan"))
    # torch warns once per process ('Converting a tensor with requires_grad=True to a scalar'):
    # the conversions themselves are recorded, so that an earlier test cannot hide one
    converted, to_float = [], torch.Tensor.__float__
    monkeypatch.setattr(torch.Tensor, "__float__",
                        lambda t: converted.append(t.requires_grad) or to_float(t))
    images, targets = _data()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError) as e:
            finetune(_model(), images, targets, conf=dataclasses.replace(CONF, epochs=1))
    assert not [w for w in caught if "requires_grad" in str(w.message)]
    assert converted and not any(converted)
    assert str(e.value) == "fine-tuning diverged (loss nan); lower the learning rate (finetune.lr)"
    assert isinstance(e.value, ft.DivergedError) and np.isnan(e.value.loss)
