"""Detectors: motion on a synthetic moving scene, YOLOX decoding, grouping inputs, errors."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.dataset.schema import COCO
from staticdepth.detectors import make_detector
from staticdepth.detectors.motion import MotionDetector, median_background
from staticdepth.detectors.yolox import boxes_from_output, decode, grabcut_mask, letterbox
from staticdepth.errors import InputError

H, W = 120, 200


def _scene(n=12, seed=0):
    """A textured static background with a 'person' (10x30 px) walking right and a 'car'."""
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.integers(60, 120, (H, W, 3)).astype(np.uint8), (5, 5), 0)
    frames, truth = [], []
    for i in range(n):
        im = bg.copy()
        u0 = 20 + 10 * i
        im[50:80, u0:u0 + 10] = (230, 40, 40)          # person: rows 50..79
        im[95:110, 170 - 5 * i:200 - 5 * i] = (30, 30, 220)  # car: 30 wide, 15 tall
        frames.append(im)
        truth.append((u0, 170 - 5 * i))
    return frames, truth


def test_motion_detector_finds_moving_agents_exactly():
    frames, truth = _scene()
    out = list(MotionDetector(min_area=50).detect_sequence(frames))
    assert len(out) == len(frames)
    for i, ((inst, rows), (u_person, u_car)) in enumerate(zip(out, truth)):
        persons = rows[rows["class_id"] == COCO["person"]]
        cars = rows[rows["class_id"] == COCO["car"]]
        assert len(persons) == 1 and len(cars) == 1, i
        assert persons["top_v"][0] == 50 and persons["foot_v"][0] == 79
        assert persons["foot_u"][0] == pytest.approx(u_person + 4.5, abs=0.5)
        assert cars["top_v"][0] == 95 and cars["foot_v"][0] == 109
        m = inst == persons["instance_id"][0]
        assert m.sum() == 300 and np.all(rows["frame"] == i)


def test_motion_mog2_finds_the_walker_after_warm_up():
    frames, truth = _scene(40)
    frames = [frames[0]] * 30 + frames[:10]       # background first, then motion
    out = list(MotionDetector(method="mog2", min_area=50).detect_sequence(iter(frames)))
    inst, rows = out[-1]
    persons = rows[rows["class_id"] == COCO["person"]]
    assert len(persons) == 1
    assert abs(persons["foot_v"][0] - 79) <= 1 and abs(persons["top_v"][0] - 50) <= 1


def test_median_background_ignores_movers():
    frames, _ = _scene()
    bg = median_background(frames)
    clean, _ = _scene(1)
    np.testing.assert_array_equal(bg[10:40], clean[0][10:40])
    with pytest.raises(InputError, match="no frame"):
        median_background([])


def test_letterbox_and_decode_closed_form():
    img = np.zeros((200, 400, 3), np.uint8)
    img[..., 0] = 255                               # red in RGB -> last channel in BGR
    x, r = letterbox(img, 416)
    assert r == pytest.approx(416 / 400) and x.shape == (1, 3, 416, 416)
    assert x[0, 2, 0, 0] == 255 and x[0, 0, 0, 0] == 0       # BGR order
    assert x[0, 0, 300, 10] == 114                              # padding below the image
    raw = np.zeros((3549, 85), np.float32)
    # anchor (gx, gy) = (3, 2) on the stride-8 grid (52 x 52): index 2 * 52 + 3
    raw[2 * 52 + 3, :4] = (0.5, 0.25, np.log(2.0), 0.0)
    d = decode(raw, 416)
    np.testing.assert_allclose(d[2 * 52 + 3, :4], [(3.5) * 8, (2.25) * 8, 16.0, 8.0])
    # stride-32 anchors (13 x 13) follow the 52^2 + 26^2 others; index 14 is cell (1, 1)
    raw[52 * 52 + 26 * 26 + 14, :2] = (1.0, 0.5)
    np.testing.assert_allclose(decode(raw, 416)[52 * 52 + 26 * 26 + 14, :2], [64.0, 48.0])
    with pytest.raises(InputError, match="anchors"):
        decode(raw[:100], 416)


def test_classwise_nms():
    def det(cx, cy, w, h, obj, cls, p):
        row = np.zeros(85, np.float32)
        row[:5] = (cx, cy, w, h, obj)
        row[5 + cls] = p
        return row
    d = np.stack([det(100, 100, 20, 40, 0.9, 0, 0.9),     # person
                  det(102, 101, 20, 40, 0.9, 0, 0.8),     # duplicate person: suppressed
                  det(101, 100, 20, 40, 0.9, 2, 0.7),     # a car on top: other class, kept
                  det(300, 100, 20, 40, 0.2, 0, 0.9),     # low score
                  det(200, 100, 20, 40, 0.9, 13, 0.9)])   # a bench: not an agent class
    boxes, scores, cls = boxes_from_output(d, 2.0, 0.3, 0.45, {0, 2})
    assert list(cls) == [0, 2]
    np.testing.assert_allclose(boxes[0], [45, 40, 55, 60])          # (cx -+ w/2, cy -+ h/2) / r
    assert scores[0] == pytest.approx(0.81)
    # the vehicle classes are one: a van scored as a truck and as a car is one truck; a bus
    # beside it and a bicycle over a person are objects of their own
    v = np.stack([det(400, 100, 60, 40, 0.9, 7, 0.8), det(399, 101, 58, 40, 0.9, 2, 0.7),
                  det(500, 100, 60, 40, 0.9, 5, 0.6),
                  det(100, 100, 20, 40, 0.9, 0, 0.9), det(100, 110, 20, 30, 0.9, 1, 0.8)])
    boxes, scores, cls = boxes_from_output(v, 1.0, 0.3, 0.45, {0, 1, 2, 5, 7})
    assert sorted(cls) == [0, 1, 5, 7] and scores[list(cls).index(7)] == pytest.approx(0.72)


def test_grabcut_mask_stays_in_box():
    frames, _ = _scene(1)
    m = grabcut_mask(frames[0], (15, 45, 35, 85))
    assert m.any() and not m[:44].any() and not m[:, 37:].any()
    assert m[55:75, 22:28].all()                    # the red figure itself
    tiny = grabcut_mask(frames[0], (5, 5, 6, 6))
    assert tiny.sum() == 4


def test_detector_errors(tmp_path):
    with pytest.raises(InputError, match="unknown detector"):
        make_detector("sam")
    with pytest.raises(InputError, match="median or mog2"):
        MotionDetector(method="knn")
    with pytest.raises(InputError, match="YOLOX ONNX model not found"):
        make_detector("yolox", model=str(tmp_path / "none.onnx"))
    (tmp_path / "junk.onnx").write_bytes(b"junk")
    with pytest.raises(InputError, match="onnxruntime cannot load"):
        make_detector("yolox", model=str(tmp_path / "junk.onnx"))
    with pytest.raises(InputError, match="mask mode"):
        make_detector("yolox", model=str(tmp_path / "junk.onnx"), mask="sam")


def test_motion_default_min_area_scales_with_the_image():
    frames, _ = _scene()
    frames[-1] = frames[-1].copy()
    frames[-1][5:8, 5:8] = 255                 # 9 px survive the 3x3 opening; 3e-4 x 120 x 200 = 7
    frames[-2] = frames[-2].copy()             # -> floor 12 px: the speck is dropped
    frames[-2][5:9, 5:9] = 255                 # 16 px: kept
    out = list(MotionDetector().detect_sequence(frames))
    assert len(out[0][1]) == 2 and len(out[-1][1]) == 2 and len(out[-2][1]) == 3


def test_masks_reach_the_image_edges_their_boxes_reach():
    """A mask that stops short of the image edge its box reaches gets that edge's pixel in its
    own rows (columns): its top and lowest rows stay, and tracking's border test sees the cut."""
    from staticdepth.detectors.yolox import reach_cut_edges
    from staticdepth.tracking import detections_from_instances

    m = np.zeros((40, 60), bool)
    m[10:30, 3:12] = True                       # stops 3 px short of the left edge
    box = (0, 8, 13, 39)                        # the box reaches the left and bottom edges
    out = reach_cut_edges(m, box)
    assert out[10:30, 0].all() and not out[:10, 0].any() and not out[30:39, 0].any()
    assert out[39, 3:12].all() and out[39].sum() == 9 and out[:39, 12:].sum() == 0
    assert m.sum() == 180                       # the input is left as it was
    d = detections_from_instances(out.astype(np.uint16))
    assert d["border"][0] and d["top_v"][0] == 10 and d["foot_v"][0] == 39
    assert not detections_from_instances(m.astype(np.uint16))["border"][0]
    inner = reach_cut_edges(m, (2, 8, 13, 30))  # a box inside the frame: the mask as it is
    assert inner is m
    near = reach_cut_edges(m, (2, 8, 13, 37), tol_px=2.0)     # 2 px from the left and bottom
    assert near[10:30, 0].all() and near[39, 3:12].all() and near[:39, 12:].sum() == 0
    assert reach_cut_edges(m, (3, 8, 13, 36), tol_px=2.0) is m     # 3 px from both: inside
