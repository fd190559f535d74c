"""Depth models: input sizing, the built-in network, torch / ONNX loading, the spec registry."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from staticdepth.errors import InputError
from staticdepth.models import Resize, TorchDepthModel, load_model
from staticdepth.models.registry import default_builtin_path, parse_spec
from staticdepth.models.trust import trusted_models
from staticdepth.models.tiny import TinyDepthNet, builtin_model, load_builtin, save_builtin

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

SMALL = dict(enc_channels=(4, 8, 8, 16, 16), dec_channels=(16, 8, 8, 4))


def _image(h=64, w=128, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _small_model(seed=0):
    torch.manual_seed(seed)
    return builtin_model(TinyDepthNet(**SMALL).eval(), input_height=64, input_width=128)


# -- Resize: MiDaS / HF DPT semantics --------------------------------------------------------------
def test_resize_exact_cases():
    assert Resize(384, 384).output_size(400, 800) == (384, 384)
    # keep aspect: the side needing less scaling wins (800 -> 384 is 0.48, 400 -> 384 is 0.96)
    assert Resize(384, 384, keep_aspect_ratio=True, multiple=32).output_size(400, 800) == (384, 768)
    assert Resize(192, 384, keep_aspect_ratio=True, multiple=32).output_size(400, 800) == (192, 384)
    # Depth Anything: 518 lower side, multiples of 14
    assert Resize(518, 518, keep_aspect_ratio=True, multiple=14).output_size(576, 768) == (518, 686)
    with pytest.raises(InputError):
        Resize(0, 10)


def test_resize_matches_transformers():
    mod = pytest.importorskip("transformers.models.dpt.image_processing_pil_dpt",
                              reason="transformers (optional extra 'hf') is not installed")
    rng = np.random.default_rng(1)
    for _ in range(50):
        H, W = (int(x) for x in rng.integers(20, 1500, 2))
        size = tuple(int(x) for x in rng.integers(14, 600, 2))
        keep = bool(rng.integers(2))
        mult = int(rng.choice([1, 14, 32]))
        ref = mod.get_resize_output_image_size(np.zeros((3, H, W)), size, keep, mult)
        got = Resize(size[0], size[1], keep, mult).output_size(H, W)
        if min(ref.height, ref.width) >= mult:  # ours never returns a side below one multiple
            assert got == (ref.height, ref.width)


# -- the built-in network ---------------------------------------------------------------------------
def test_builtin_default_size_and_output():
    net = TinyDepthNet()
    n_params = sum(p.numel() for p in net.parameters())
    assert 1_000_000 < n_params < 3_000_000
    model = _small_model()
    d = model.predict(_image(70, 150))
    assert d.shape == (70, 150) and d.dtype == np.float32
    assert np.all(d >= 0) and np.all(np.isfinite(d))   # softplus: inverse depth is non-negative


def test_builtin_layer_groups_cover_decoder_not_encoder():
    model = _small_model()
    dec = {id(p) for p in model.parameters_for("decoder")}
    head = {id(p) for p in model.parameters_for("head")}
    enc = {id(p) for p in model.net.stages.parameters()}
    assert head < dec and not dec & enc
    assert dec | enc == {id(p) for p in model.net.parameters()}
    trainable = model.set_trainable("head")
    assert {id(p) for p in trainable} == head
    assert all(not p.requires_grad for p in model.net.stages.parameters())
    with pytest.raises(InputError, match="no layer group 'neck'"):
        model.parameters_for("neck")


def test_builtin_save_load_round_trip(tmp_path):
    model = _small_model()
    path = save_builtin(tmp_path / "m.pt", model, info={"frames": 3})
    loaded = load_model(f"builtin:{path}")
    img = _image()
    np.testing.assert_array_equal(loaded.predict(img), model.predict(img))
    assert loaded.info == {"frames": 3}
    assert not list(tmp_path.glob("*.tmp*"))


def test_builtin_missing_and_wrong_files(tmp_path):
    with pytest.raises(InputError, match="train-builtin --out"):
        load_builtin(tmp_path / "none.pt")
    torch.save({"a": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(InputError, match="not a built-in model checkpoint"):
        load_builtin(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable torch checkpoint"):
        load_builtin(tmp_path / "junk.pt")
    ckpt = torch.load(save_builtin(tmp_path / "m.pt", _small_model()), weights_only=True)
    ckpt["config"]["enc_channels"] = (8, 8, 8, 16, 16)
    torch.save(ckpt, tmp_path / "bad.pt")
    with pytest.raises(InputError, match="do not match"):
        load_builtin(tmp_path / "bad.pt")
    with pytest.raises(InputError, match="5 encoder"):
        TinyDepthNet((4, 8), (4,))


def test_forward_rejects_multichannel_output():
    model = TorchDepthModel(torch.nn.Conv2d(3, 2, 1), name="two")
    with pytest.raises(InputError, match="one channel"):
        model.predict(_image(32, 32))
    model = TorchDepthModel(torch.nn.Flatten(), name="flat")
    with pytest.raises(InputError, match="expected"):
        model.predict(_image(32, 32))
    with pytest.raises(InputError, match="RGB uint8"):
        _small_model().predict(np.zeros((8, 8), np.float32))


# -- torch: and onnx: files --------------------------------------------------------------------------
def test_torch_files(tmp_path):
    model = _small_model()
    img = _image()
    ref = model.predict(img)
    scripted = torch.jit.trace(model.net, torch.zeros(1, 3, 64, 128))
    scripted.save(str(tmp_path / "s.pt"))
    m = load_model(f"torch:{tmp_path / 's.pt'}")
    m.resize = model.resize
    np.testing.assert_allclose(m.predict(img), ref, rtol=1e-5, atol=1e-6)
    torch.save(model.net, tmp_path / "whole.pt")
    with pytest.raises(InputError, match="would run code .*--trust-model"):
        load_model(f"torch:{tmp_path / 'whole.pt'}")
    with trusted_models():
        m2 = load_model(f"torch:{tmp_path / 'whole.pt'}")
    m2.resize = model.resize
    np.testing.assert_allclose(m2.predict(img), ref, rtol=1e-5, atol=1e-6)
    assert "head" in m2.layer_groups
    torch.save(model.net.state_dict(), tmp_path / "sd.pt")
    with pytest.raises(InputError, match="state dict alone"):
        load_model(f"torch:{tmp_path / 'sd.pt'}")
    with pytest.raises(InputError, match="not found"):
        load_model(f"torch:{tmp_path / 'none.pt'}")
    (tmp_path / "junk.pt").write_bytes(b"junk")
    with pytest.raises(InputError, match="not a readable torch file"):
        load_model(f"torch:{tmp_path / 'junk.pt'}")


def test_onnx_matches_torch(tmp_path):
    pytest.importorskip("onnx", reason="onnx (test extra) is needed to export")
    model = _small_model()
    path = tmp_path / "tiny.onnx"
    x = torch.zeros(1, 3, 64, 128)
    torch.onnx.export(model.net, (x,), str(path), input_names=["x"], output_names=["y"],
                      dynamic_axes={"x": {2: "h", 3: "w"}, "y": {1: "h", 2: "w"}},
                      dynamo=False, opset_version=17)
    m = load_model(f"onnx:{path}")
    m.resize = model.resize
    img = _image(64, 128)       # already the network size: no resampling on either side
    np.testing.assert_allclose(m.predict(img), model.predict(img), rtol=1e-4, atol=1e-5)
    img = _image(90, 170, seed=3)   # resized by cv2 vs torch: same bicubic / bilinear kernels
    a, b = m.predict(img), model.predict(img)
    assert a.shape == b.shape == (90, 170)
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.99
    # a static input shape in the file fixes the network size
    torch.onnx.export(model.net, (x,), str(tmp_path / "static.onnx"), dynamo=False,
                      opset_version=17)
    ms = load_model(f"onnx:{tmp_path / 'static.onnx'}")
    assert ms.input_size(400, 800) == (64, 128)
    assert ms.predict(_image(50, 60)).shape == (50, 60)


def test_onnx_errors(tmp_path):
    with pytest.raises(InputError, match="ONNX model file not found"):
        load_model(f"onnx:{tmp_path / 'none.onnx'}")
    (tmp_path / "junk.onnx").write_bytes(b"junk")
    with pytest.raises(InputError, match="onnxruntime cannot load"):
        load_model(f"onnx:{tmp_path / 'junk.onnx'}")


def test_onnx_wrong_input_rank(tmp_path):
    pytest.importorskip("onnx", reason="onnx (test extra) is needed to export")
    torch.onnx.export(torch.nn.Linear(3, 1), (torch.zeros(2, 3),), str(tmp_path / "lin.onnx"),
                      dynamo=False, opset_version=17)
    with pytest.raises(InputError, match=r"expected one \(1, 3, h, w\) input"):
        load_model(f"onnx:{tmp_path / 'lin.onnx'}")


# -- specs -----------------------------------------------------------------------------------------
def test_parse_spec(monkeypatch, tmp_path):
    assert parse_spec("onnx:/a/b.onnx") == ("onnx", "/a/b.onnx")
    assert parse_spec("hf:Intel/dpt-large") == ("hf", "Intel/dpt-large")
    monkeypatch.setenv("STATICDEPTH_CACHE", str(tmp_path))
    assert parse_spec("builtin") == ("builtin", str(tmp_path / "builtin.pt"))
    assert default_builtin_path() == str(tmp_path / "builtin.pt")
    for bad in ("dpt", "foo:bar", "onnx:", ""):
        with pytest.raises(InputError, match="bad model spec"):
            parse_spec(bad)
    with pytest.raises(InputError, match="train-builtin"):
        load_model("builtin")
