"""transformers DPT / Depth Anything through the real local loading path, with tiny random configs."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from staticdepth.errors import InputError
from staticdepth.models import load_model

transformers = pytest.importorskip("transformers", reason="transformers (extra 'hf') not installed")
pytestmark = pytest.mark.filterwarnings("ignore")


def _save(model, path, pp: dict) -> str:
    model.save_pretrained(path)
    (path / "preprocessor_config.json").write_text(json.dumps(pp))
    return str(path)


def _tiny_dpt(tmp_path):
    from transformers import DPTConfig, DPTForDepthEstimation
    torch.manual_seed(0)
    cfg = DPTConfig(hidden_size=16, num_hidden_layers=4, num_attention_heads=2,
                    intermediate_size=20, image_size=32, patch_size=8,
                    neck_hidden_sizes=[8, 8, 16, 16], fusion_hidden_size=8,
                    backbone_out_indices=[0, 1, 2, 3], reassemble_factors=[4, 2, 1, 0.5])
    pp = {"size": {"height": 32, "width": 32}, "keep_aspect_ratio": False,
          "ensure_multiple_of": 1, "image_mean": [0.5] * 3, "image_std": [0.5] * 3}
    return _save(DPTForDepthEstimation(cfg).eval(), tmp_path / "dpt", pp), pp


def _tiny_depth_anything(tmp_path):
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation, Dinov2Config
    torch.manual_seed(0)
    bb = Dinov2Config(hidden_size=16, num_hidden_layers=4, num_attention_heads=2,
                      intermediate_size=20, image_size=28, patch_size=14,
                      out_features=["stage1", "stage2", "stage3", "stage4"],
                      reshape_hidden_states=False)
    cfg = DepthAnythingConfig(backbone_config=bb, reassemble_hidden_size=16,
                              neck_hidden_sizes=[8, 8, 16, 16], fusion_hidden_size=8,
                              head_hidden_size=4, patch_size=14, depth_estimation_type="relative")
    pp = {"size": {"height": 42, "width": 42}, "keep_aspect_ratio": True,
          "ensure_multiple_of": 14, "image_mean": [0.485, 0.456, 0.406],
          "image_std": [0.229, 0.224, 0.225]}
    return _save(DepthAnythingForDepthEstimation(cfg).eval(), tmp_path / "da", pp), pp


def _reference(path, pp, img):
    """Independent preprocessing (cv2) + the transformers model called directly."""
    from transformers import AutoModelForDepthEstimation
    net = AutoModelForDepthEstimation.from_pretrained(path, local_files_only=True).eval()
    H, W = img.shape[:2]
    h, w = pp["size"]["height"], pp["size"]["width"]
    if pp["keep_aspect_ratio"]:
        s = h / H if abs(1 - h / H) < abs(1 - w / W) else w / W
        m = pp["ensure_multiple_of"]
        h, w = round(s * H / m) * m, round(s * W / m) * m
    x = cv2.resize(img.astype(np.float32) / 255, (w, h), interpolation=cv2.INTER_CUBIC)
    x = (x - np.float32(pp["image_mean"])) / np.float32(pp["image_std"])
    with torch.no_grad():
        out = net(pixel_values=torch.from_numpy(x.transpose(2, 0, 1)[None].copy())).predicted_depth
    out = out[0].numpy()
    return cv2.resize(out, (W, H), interpolation=cv2.INTER_LINEAR), (h, w)


@pytest.mark.parametrize("build", [_tiny_dpt, _tiny_depth_anything])
def test_hf_local_directory_round_trip(tmp_path, build):
    path, pp = build(tmp_path)
    model = load_model(f"hf:{path}")
    img = np.random.default_rng(0).integers(0, 256, (45, 80, 3), dtype=np.uint8)
    got = model.predict(img)
    ref, size = _reference(path, pp, img)
    assert model.input_size(45, 80) == size
    assert got.shape == (45, 80) and got.dtype == np.float32
    # cv2 and torch bicubic differ slightly at the borders; the network output must agree closely
    assert np.corrcoef(got.ravel(), ref.ravel())[0, 1] > 0.99
    np.testing.assert_allclose(got, ref, atol=0.05 * np.abs(ref).max() + 1e-6)
    dec = {id(p) for p in model.parameters_for("decoder")}
    head = {id(p) for p in model.parameters_for("head")}
    assert head < dec < {id(p) for p in model.net.parameters()}


def test_depth_anything_keeps_aspect(tmp_path):
    path, _ = _tiny_depth_anything(tmp_path)
    model = load_model(f"hf:{path}")
    h, w = model.input_size(400, 800)
    assert (h, w) == (42, 84) and h % 14 == 0 and w % 14 == 0


def test_hf_defaults_without_preprocessor_config(tmp_path):
    path, _ = _tiny_depth_anything(tmp_path)
    (tmp_path / "da" / "preprocessor_config.json").unlink()
    model = load_model(f"hf:{path}")
    assert model.input_size(576, 768) == (518, 686)   # Depth Anything: 518, aspect kept, x14


def test_hf_missing_weights_say_where_and_how(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(InputError) as e:
        load_model("hf:nonexistent-org/nonexistent-depth-model")
    msg = str(e.value)
    assert "Hugging Face cache" in msg and "pre-populate" in msg and "nothing is downloaded" in msg
    with pytest.raises(InputError, match="model directory not found"):
        load_model(f"hf:{tmp_path / 'no' / 'such' / 'dir'}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no local depth model found in directory"):
        load_model(f"hf:{tmp_path / 'empty'}")


def test_hf_bad_preprocessor_config(tmp_path):
    path, _ = _tiny_dpt(tmp_path)
    (tmp_path / "dpt" / "preprocessor_config.json").write_text("{not json")
    with pytest.raises(InputError, match="unreadable preprocessor config"):
        load_model(f"hf:{path}")
    (tmp_path / "dpt" / "preprocessor_config.json").write_text(json.dumps({"size": "big"}))
    with pytest.raises(InputError, match="unsupported preprocessor size"):
        load_model(f"hf:{path}")
