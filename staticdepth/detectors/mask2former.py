"""Mask2Former panoptic / instance segmentation through transformers (local weights only).

Loads ``Mask2FormerForUniversalSegmentation`` from a local directory or the local Hugging Face
cache (``local_files_only=True``); the image is resized so that its shorter side is
``short_side`` (aspect kept, multiple of 32) and normalised with ImageNet statistics by our own
code. Each query whose best class is an agent class (COCO ids of ``config.id2label``) with score
above ``score_thr`` and a mask (sigmoid > 0.5) of at least ``min_area`` pixels becomes an agent.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_CLASSES, COCO
from staticdepth.detectors.base import Detector, rows_from_masks
from staticdepth.errors import InputError
from staticdepth.models.base import IMAGENET_MEAN, IMAGENET_STD, Resize


def coco_id_map(id2label: dict) -> dict[int, int]:
    """Model label index -> COCO id of our agent classes, matched by name."""
    names = {v: k for k, v in COCO.items()}
    out = {}
    for idx, label in id2label.items():
        key = str(label).lower().replace(" ", "")
        for coco_id, name in names.items():
            if key == name:
                out[int(idx)] = coco_id
    return out


@dataclass
class Mask2FormerDetector(Detector):
    model: str = ""
    score_thr: float = 0.5
    min_area: int = 50
    short_side: int = 384
    classes: frozenset = field(default_factory=lambda: AGENT_CLASSES | ACCESSORY_CLASSES)
    name: str = "mask2former"

    def __post_init__(self):
        try:
            from transformers import Mask2FormerForUniversalSegmentation
        except ImportError:
            raise InputError("the mask2former detector needs transformers "
                             "(pip install 'staticdepth[hf]')") from None
        from staticdepth.models.hf import HOW_TO_PROVIDE
        if not self.model:
            raise InputError(f"mask2former needs a model (--set detector.model=DIR); {HOW_TO_PROVIDE}")
        try:
            self.net = Mask2FormerForUniversalSegmentation.from_pretrained(
                self.model, local_files_only=True).eval()
        except (OSError, ValueError) as e:
            where = self.model if os.path.isdir(self.model) else f"the Hugging Face cache ({self.model})"
            raise InputError(f"no local Mask2Former model in {where} ({str(e).splitlines()[0]}); "
                             f"{HOW_TO_PROVIDE}") from None
        self.label_map = coco_id_map(self.net.config.id2label)
        self.resize = Resize(self.short_side, self.short_side, keep_aspect_ratio=True, multiple=32)

    def preprocess(self, image_rgb: np.ndarray):
        """(H, W, 3) uint8 -> (1, 3, h, w) normalised tensor at the model's input size."""
        import torch
        import torch.nn.functional as F

        h, w = self.resize.output_size(*image_rgb.shape[:2])
        x = torch.from_numpy(np.ascontiguousarray(image_rgb)).permute(2, 0, 1)[None].float() / 255
        x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)
        return (x - torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)) / torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)

    def segment(self, image_rgb: np.ndarray) -> tuple[list[np.ndarray], list[int], list[float]]:
        """Masks (H, W) bool, COCO class ids and scores of the agent queries, best last."""
        import torch
        import torch.nn.functional as F

        H, W = image_rgb.shape[:2]
        with torch.no_grad():
            out = self.net(pixel_values=self.preprocess(image_rgb))
        probs = out.class_queries_logits[0].softmax(-1)[:, :-1]      # last class = "no object"
        scores, labels = probs.max(-1)
        masks = F.interpolate(out.masks_queries_logits, size=(H, W), mode="bilinear",
                              align_corners=False)[0].sigmoid() > 0.5
        keep_m, keep_c, keep_s = [], [], []
        for q in torch.argsort(scores).tolist():                       # best painted last
            coco = self.label_map.get(int(labels[q]))
            m = masks[q].numpy()
            if coco in self.classes and float(scores[q]) >= self.score_thr and m.sum() >= self.min_area:
                keep_m.append(m)
                keep_c.append(coco)
                keep_s.append(float(scores[q]))
        return keep_m, keep_c, keep_s

    def detect_sequence(self, images: Iterable[np.ndarray]
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for i, im in enumerate(images):
            m, c, s = self.segment(im)
            yield rows_from_masks(i, m, c, s, im.shape[:2])
