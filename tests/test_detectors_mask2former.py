"""Mask2Former through the real local loading path with a tiny random configuration."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from staticdepth.dataset.schema import COCO
from staticdepth.detectors import make_detector
from staticdepth.detectors.mask2former import coco_id_map
from staticdepth.errors import InputError

transformers = pytest.importorskip("transformers", reason="transformers (extra 'hf') not installed")
pytestmark = pytest.mark.filterwarnings("ignore")
LABELS = {0: "person", 1: "car", 2: "tree"}


@pytest.fixture(scope="module")
def tiny_m2f(tmp_path_factory):
    from transformers import Mask2FormerConfig, Mask2FormerForUniversalSegmentation, SwinConfig
    torch.manual_seed(0)
    bb = SwinConfig(image_size=64, patch_size=4, embed_dim=8, depths=[1, 1, 1, 1],
                    num_heads=[1, 1, 1, 1], window_size=2,
                    out_features=["stage1", "stage2", "stage3", "stage4"])
    cfg = Mask2FormerConfig(backbone_config=bb, feature_size=32, mask_feature_size=32,
                            hidden_dim=32, encoder_feedforward_dim=32, dim_feedforward=32,
                            encoder_layers=1, decoder_layers=2, num_attention_heads=2,
                            num_queries=12, num_labels=3, id2label=LABELS,
                            label2id={v: k for k, v in LABELS.items()})
    path = tmp_path_factory.mktemp("m2f") / "tiny"
    Mask2FormerForUniversalSegmentation(cfg).eval().save_pretrained(path)
    return str(path)


def test_coco_id_map_by_name():
    assert coco_id_map(LABELS) == {0: COCO["person"], 1: COCO["car"]}
    assert coco_id_map({5: "Motorcycle", 7: "traffic light"}) == {5: COCO["motorcycle"]}


def test_mask2former_detections_follow_the_queries(tiny_m2f):
    det = make_detector("mask2former", model=tiny_m2f, score_thr=0.0, min_area=1, short_side=64)
    img = np.random.default_rng(0).integers(0, 256, (48, 80, 3), dtype=np.uint8)
    with torch.no_grad():
        out = det.net(pixel_values=det.preprocess(img))
    probs = out.class_queries_logits[0].softmax(-1)[:, :-1]
    labels = probs.argmax(-1).numpy()
    masks = torch.nn.functional.interpolate(out.masks_queries_logits, size=(48, 80),
                                            mode="bilinear", align_corners=False)[0].sigmoid() > 0.5
    expected = sorted(COCO["person"] if labels[q] == 0 else COCO["car"]
                      for q in range(12) if labels[q] in (0, 1) and masks[q].sum() >= 1)
    m, c, s = det.segment(img)
    assert sorted(c) == expected and len(m) == len(c) == len(s)
    assert all(mask.shape == (48, 80) and mask.dtype == bool for mask in m)
    assert s == sorted(s)                                   # best painted last
    (inst, rows), = list(det.detect_sequence([img]))
    assert inst.shape == (48, 80) and set(rows["class_id"]) <= {COCO["person"], COCO["car"]}


def test_mask2former_missing_weights(tmp_path):
    with pytest.raises(InputError, match="needs a model"):
        make_detector("mask2former")
    with pytest.raises(InputError, match="no local Mask2Former model") as e:
        make_detector("mask2former", model=str(tmp_path))
    assert "nothing is downloaded" in str(e.value)
