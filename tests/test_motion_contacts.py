"""The motion detector's contact (foot) and top points against an independent scene's truth, and
the merge test that keeps regions holding several agents out of the ground plane."""
from __future__ import annotations

import numpy as np
import pytest

from indep_scenes import Scene, SceneSpec
from staticdepth import tracking
from staticdepth.detectors.merges import backward_counts, overlap_matrix, propagate
from staticdepth.detectors.motion import MotionDetector, clean_foreground


@pytest.fixture(scope="module")
def scene_frames():
    """3 s (12 frames, 320x160) of a street seen from 5.4 m at 25 deg pitch, 6 people, 1 car."""
    scene = Scene(SceneSpec("contacts", 5.4, 25.0, 7, people=6, vehicles=1), 320, 160)
    return [scene.render(i) for i in range(12)]


def _matched(frames):
    """Per motion detection (>= 10 px tall): number of true agents it holds (>= 30% of each one's
    pixels), its score, whether the one true agent is clean (off the border, not occluded), and
    the errors motion - truth of foot row, top row and foot column (NaN unless one agent)."""
    det = list(MotionDetector().detect_sequence([f["left"] for f in frames]))
    out = []
    for i, (f, (dm, drows)) in enumerate(zip(frames, det)):
        truth = {int(g["instance_id"]): g
                 for g in tracking.detections_from_instances(f["instances"], f["agents"], i)}
        for d in tracking.detections_from_instances(dm, drows, i):
            if d["foot_v"] - d["top_v"] < 10:
                continue
            blob = dm == d["instance_id"]
            held = [int(g) for g in np.unique(f["instances"][blob]) if g > 0
                    and (blob & (f["instances"] == g)).sum() >= 0.3 * (f["instances"] == g).sum()]
            g = truth.get(held[0]) if len(held) == 1 else None
            err = ((np.nan,) * 3 if g is None else
                   (d["foot_v"] - g["foot_v"], d["top_v"] - g["top_v"], d["foot_u"] - g["foot_u"]))
            out.append((len(held), d["score"], g is not None and not (g["border"] or g["occluded"]))
                       + err)
    return np.array(out, float)


def test_motion_contacts_match_the_truth_within_a_pixel(scene_frames):
    r = _matched(scene_frames)
    single = (r[:, 0] == 1) & (r[:, 2] == 1)
    assert single.sum() >= 40
    for k, what in ((3, "foot row"), (4, "top row"), (5, "foot column")):
        within = np.mean(np.abs(r[single, k]) <= 1.0)
        # before the hysteresis foreground most tops were 3-4 px low and feet 1-3 px high
        assert within >= 0.9, f"{what}: only {within:.0%} within 1 px of the truth"
    merged = r[:, 0] >= 2
    assert merged.any()
    assert np.mean(r[merged, 1] < 0.3) >= 0.8      # dropped by the tracker's min_score


def test_clean_foreground_restores_thin_extremes():
    strong = np.zeros((20, 12), bool)
    strong[5:15, 3:8] = True                      # a 5 px wide body
    strong[2:5, 5] = True                         # a 1 px wide head the opening erases
    weak = strong.copy()
    weak[15:17, 4:6] = True                       # feet only above the low threshold
    weak[0, 0] = True                             # a weak speckle touching no seed
    fg = clean_foreground(strong, weak, open_px=3, close_px=1)
    vs, us = np.nonzero(fg)
    assert vs.min() == 2 and vs.max() == 16 and not fg[0, 0]
    fg_open = clean_foreground(strong, None, open_px=3, close_px=1)
    assert np.nonzero(fg_open)[0].min() == 2       # reconstruction keeps the head with no weak map


def test_merge_counts_closed_form():
    a = np.zeros((10, 20), np.int32)
    a[2:8, 2:5], a[2:8, 10:13] = 1, 2              # two people
    b = np.zeros_like(a)
    b[2:8, 3:12] = 1                               # one region holding both
    c = a.copy()                                   # they part again
    areas = [np.array([18.0, 18.0]), np.array([54.0]), np.array([18.0, 18.0])]
    heights = [np.array([6.0, 6.0]), np.array([6.0]), np.array([6.0, 6.0])]
    o_ab, o_bc = overlap_matrix(a, b, 2, 1), overlap_matrix(b, c, 1, 2)
    np.testing.assert_array_equal(o_ab, [[12], [12]])
    fwd = propagate(np.ones(2), o_ab, areas[0], heights[0], heights[1])
    np.testing.assert_allclose(fwd, [2.0])
    np.testing.assert_allclose(propagate(fwd, o_bc, areas[1], heights[1], heights[2]), [1, 1])
    # backward: the merged region splits later, the first frame's two stay one each
    np.testing.assert_allclose(backward_counts([o_bc], areas[1:], heights[1:]), [2.0])
    np.testing.assert_allclose(backward_counts([o_ab, o_bc], areas, heights), [1.0, 1.0])
    # a short fragment (legs cut from the body) joining its body adds no agent
    frag_h = np.array([6.0, 2.0])
    np.testing.assert_allclose(propagate(np.ones(2), o_ab, areas[0], frag_h, heights[1]), [1.0])
