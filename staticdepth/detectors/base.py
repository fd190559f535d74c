"""The detector interface and the measurement of agent rows from instance masks.

A detector turns a sequence of RGB frames (H, W, 3) uint8 into, per frame, an instance map
(H, W) uint16 (0 = background) and AGENT_DTYPE rows (frame, instance_id, class_id, score, foot_u =
median column of the lowest mask row, foot_v = lowest row, top_v = highest row; track_id -1 and
the 3-D ground-truth fields NaN).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Iterable, Iterator, Sequence

import numpy as np

from staticdepth.dataset.schema import empty_agents
from staticdepth.errors import InputError

DETECTORS = ("motion", "yolox", "mask2former")


def rows_from_masks(frame: int, masks: Sequence[np.ndarray], class_ids: Sequence[int],
                    scores: Sequence[float], shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Paint masks (in the given order; later ones win overlaps) into an instance map, measure rows.

    Returns (instances (H, W) uint16, rows AGENT_DTYPE); masks left empty after painting are
    dropped and the ids renumbered 1..n.
    """
    if len(masks) >= 65535:
        raise InputError(f"frame {frame}: {len(masks)} instances do not fit a uint16 map")
    inst = np.zeros(shape, np.uint16)
    for k, m in enumerate(masks, start=1):
        inst[np.asarray(m, bool)] = k
    rows = []
    new = np.zeros(len(masks) + 1, np.uint16)
    for k in range(1, len(masks) + 1):
        vs, us = np.nonzero(inst == k)
        if len(vs) == 0:
            continue
        new[k] = len(rows) + 1
        r = empty_agents(1)[0]
        r["frame"], r["instance_id"] = frame, new[k]
        r["class_id"], r["score"] = int(class_ids[k - 1]), float(scores[k - 1])
        v1 = vs.max()
        r["foot_v"], r["top_v"] = v1, vs.min()
        r["foot_u"] = float(np.median(us[vs == v1]))
        rows.append(r)
    out = empty_agents(len(rows))
    if rows:
        out[:] = np.array(rows, dtype=out.dtype)
    return new[inst], out


class Detector(ABC):
    name = "detector"

    @abstractmethod
    def detect_sequence(self, images: Iterable[np.ndarray]
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Yield (instances, rows) for each frame in order (frame numbers from 0)."""


def make_detector(name: str, **options) -> Detector:
    """``motion`` | ``yolox`` (option ``model=PATH.onnx``) | ``mask2former`` (``model=DIR``)."""
    if name == "motion":
        from staticdepth.detectors.motion import MotionDetector
        return MotionDetector(**options)
    if name == "yolox":
        from staticdepth.detectors.yolox import YoloxDetector
        return YoloxDetector(**options)
    if name == "mask2former":
        from staticdepth.detectors.mask2former import Mask2FormerDetector
        return Mask2FormerDetector(**options)
    raise InputError(f"unknown detector {name!r} (one of {', '.join(DETECTORS)}, or gt)")
