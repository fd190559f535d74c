"""Agents' observations from instance maps and agent rows."""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.dataset.schema import empty_agents
from staticdepth.errors import InputError
from staticdepth.tracking import (TrackingConfig, detections_from_agents, detections_from_instances,
                                  link_tracks,
                                  observations, observations_from_agents,
                                  observations_from_instances)

W, H = 120, 90


def ellipse(m, cu, top, bottom, half_w, value):
    """Fill an axis-aligned ellipse spanning rows top..bottom, centred on column cu."""
    v, u = np.mgrid[:H, :W]
    cv, a = (top + bottom) / 2, (bottom - top) / 2
    inside = ((u - cu) / half_w) ** 2 + ((v - cv) / (a + 0.5)) ** 2 <= 1
    inside &= (v >= top) & (v <= bottom)
    m[inside] = value


def frames():
    """Six frames: agents A and B walk on curved paths (ids change every frame), C touches the
    left border, D is 10 px tall, E has a low score."""
    out = []
    for f in range(6):
        m = np.zeros((H, W), np.uint16)
        ellipse(m, 20 + 6 * f, 10 + f, 44 + f + int((f - 2.5) ** 2), 5, 1 + (f % 3))  # A
        ellipse(m, 90 - 5 * f, 30 + 2 * f * (f % 2), 80 + 2 * f * (f % 2) - f, 6, 7)  # B
        ellipse(m, 2, 40, 70, 4, 9)                                                  # C
        ellipse(m, 60, 75, 85, 3, 11)                                                # D
        ellipse(m, 100, 5, 30 + f, 4, 12)                                            # E
        rows = [(1 + (f % 3), 0, 0.9), (7, 0, 0.8), (9, 0, 0.9), (11, 0, 0.9), (12, 0, 0.1)]
        out.append((m, np.array(rows)))
    return out


def test_detection_foot_point_is_the_bottom_centre():
    m = np.zeros((H, W), np.uint16)
    m[20:41, 30:37] = 5           # rows 20..40, columns 30..36
    m[40, 30:33] = 0              # the lowest row only covers columns 33..36
    m[20, 30:35] = 0              # the top row only covers columns 35..36
    d = detections_from_instances(m, np.array([[5, 0, 0.7]]), frame=3)
    assert len(d) == 1
    assert (d["foot_v"][0], d["top_v"][0], d["foot_u"][0], d["top_u"][0]) == (40, 20, 34.5, 35.5)
    assert (d["left"][0], d["right"][0], d["frame"][0], d["score"][0]) == (30, 36, 3,
                                                                           np.float32(0.7))
    assert not d["border"][0]
    assert len(detections_from_instances(m, np.array([[6, 0, 0.7]]))) == 0  # not listed


def test_observations_from_instance_maps_track_and_filter():
    obs = observations_from_instances(frames())
    tracks = np.unique(obs["track"])
    assert len(tracks) == 2                       # A and B; C, D, E are filtered out
    for t in tracks:
        sel = obs[obs["track"] == t]
        assert list(sel["frame"]) == list(range(6))
    a = obs[obs["foot_u"] < obs["foot_u"].mean()]   # A starts left
    first = a[a["frame"] == 0][0]
    # mask rows 10..50: the silhouette's extremes lie half a pixel beyond the extreme rows
    assert (first["foot_v"], first["top_v"], first["foot_u"], first["top_u"]) == (50.5, 9.5, 20,
                                                                                  20)
    assert first["height_px"] == 41
    raw = observations_from_instances(frames(), TrackingConfig(edge_px=0.0))
    raw_a = raw[(raw["foot_u"] < raw["foot_u"].mean()) & (raw["frame"] == 0)][0]
    assert (raw_a["foot_v"], raw_a["top_v"], raw_a["height_px"]) == (50, 10, 40)


def test_low_score_and_small_agents_kept_when_allowed():
    conf = TrackingConfig(min_score=0.0, min_height_px=5, drop_collinear=False, min_travel_px=0)
    obs = observations_from_instances(frames(), conf)
    # E (low score, moving foot straight down) is kept now; D is static (same point) but kept
    assert len(np.unique(obs["track"])) == 4


def test_collinear_and_short_tracks_dropped():
    a = empty_agents(8)
    a["frame"] = [0, 1, 2, 3, 0, 1, 2, 3]
    a["instance_id"] = [1, 1, 1, 1, 2, 2, 2, 2]
    a["class_id"] = 0
    a["foot_u"] = [10, 20, 30, 40, 80, 82, 86, 82]     # track 2 curves; track 1 is a line
    a["foot_v"] = [60, 61, 62, 63, 60, 64, 66, 70]
    a["top_v"] = a["foot_v"] - 30
    obs = observations_from_agents(a, W, H)             # no track ids: linked by foot distance
    assert len(np.unique(obs["track"])) == 1
    assert set(obs["foot_u"]) == {80, 82, 86}
    keep = observations_from_agents(a, W, H, TrackingConfig(drop_collinear=False))
    assert len(np.unique(keep["track"])) == 2
    short = observations_from_agents(a[a["frame"] < 2], W, H, TrackingConfig(drop_collinear=False))
    assert len(short) == 0


def test_hungarian_keeps_identities_of_close_agents():
    a = empty_agents(10)
    a["frame"] = np.repeat(np.arange(5), 2)
    a["instance_id"] = np.tile([1, 2], 5)[::-1].copy()       # instance ids swap meaning
    a["class_id"] = 0
    x = np.arange(5) * 4.0
    # they meet at frame 1; a greedy nearest match would swap them at frame 2, the optimal one not
    a["foot_u"] = np.ravel(np.column_stack([50 + x, 58 - x]))
    a["foot_v"] = np.ravel(np.column_stack([60 + 0.1 * x ** 2, 62 + 0.1 * x ** 2]))
    a["top_v"] = a["foot_v"] - 40
    d = link_tracks(detections_from_agents(a, W, H), TrackingConfig())
    for t in np.unique(d["track"]):
        us = d["foot_u"][d["track"] == t]
        assert np.all(np.diff(us) > 0) or np.all(np.diff(us) < 0)    # each track one agent
    assert len(np.unique(d["track"])) == 2


def test_agent_rows_with_track_ids_are_kept_and_errors():
    a = empty_agents(4)
    a["frame"], a["track_id"], a["class_id"] = [0, 1, 2, 3], 7, 0
    a["foot_u"], a["foot_v"], a["top_v"] = [10, 20, 25, 40], [50, 55, 52, 60], [20, 25, 22, 30]
    obs = observations(detections_from_agents(a, W, H))
    assert set(obs["track"]) == {7} and len(obs) == 4
    assert np.all(np.isnan(obs["top_u"]))            # agent rows carry no top column
    with pytest.raises(InputError, match="2-D"):
        detections_from_instances(np.zeros((2, 3, 4), np.uint16))
    with pytest.raises(InputError, match="no frames"):
        observations_from_instances([])


def straight_and_static_agents():
    """Track 1 walks a straight line (feet exactly collinear), track 2 curves, track 3 stands
    still (feet jitter by half a pixel), each seen in 5 frames with known track ids."""
    a = empty_agents(15)
    a["frame"] = np.tile(np.arange(5), 3)
    a["track_id"] = np.repeat([1, 2, 3], 5)
    a["instance_id"] = a["track_id"]
    a["class_id"] = 0
    a["foot_u"] = np.r_[10 + 8 * np.arange(5), [80, 82, 86, 82, 78], [50, 50.5, 50, 49.5, 50]]
    a["foot_v"] = np.r_[60 + 2 * np.arange(5), [60, 64, 66, 70, 72], [70, 70, 70.5, 70, 69.5]]
    a["top_v"] = a["foot_v"] - 30
    return a


def test_collinear_rule_drops_straight_walkers_only_for_eq1_models():
    a = straight_and_static_agents()
    for model, kept in (("paper", {2}), ("affine", {2}), ("exact", {1, 2})):
        conf = TrackingConfig.for_model(model)
        assert conf.drop_collinear == (model != "exact")
        obs = observations(detections_from_agents(a, W, H), conf)
        assert set(obs["track"]) == kept, model          # the static track 3 never passes
    # the static rule alone: feet within min_travel_px RMS in every direction
    loose = TrackingConfig.for_model("exact", min_travel_px=0.3)
    assert set(observations(detections_from_agents(a, W, H), loose)["track"]) == {1, 2, 3}
    assert TrackingConfig.for_model("paper", min_frames=6).min_frames == 6


def test_occluded_masks_are_flagged_and_dropped():
    """A rider's lowest row sits on the bicycle, a walker's feet are hidden behind a car (the car's
    mask right below them), an umbrella covers a head: all three are occluded; a walker on the
    ground with a bag beside the body (not below the feet) is not."""
    m = np.zeros((H, W), np.uint16)
    m[10:41, 10:15] = 1           # rider: rows 10..40
    m[41:55, 5:25] = 2            # bicycle right under the rider
    m[20:61, 40:45] = 3           # walker whose feet are behind the car
    m[61:75, 35:55] = 4           # car
    m[22:60, 70:75] = 5           # walker under an umbrella
    m[19:22, 66:80] = 6           # umbrella, just above the head
    m[30:71, 95:100] = 7          # free walker
    m[40:50, 101:105] = 8         # bag beside the walker's body, one column apart
    rows = np.array([[i, 0, 0.9] for i in range(1, 9)])
    d = detections_from_instances(m, rows)
    occ = dict(zip(d["instance_id"].tolist(), d["occluded"].tolist()))
    assert occ[1] and occ[3] and occ[5]
    assert not occ[7] and not occ[8]
    # the other side of each contact: the bicycle's and the car's top rows touch the person above,
    # the umbrella's lowest row the head (a person in front of a car is dropped too: without depth
    # the order is unknown)
    assert occ[2] and occ[4] and occ[6]
    assert not detections_from_instances(m, rows, contact_px=0)["occluded"].any()
    # a gap of 3 rows between the walker's feet and the car: not in contact within 2 rows
    m2 = m.copy()
    m2[58:61, 40:45] = 0
    d2 = detections_from_instances(m2, rows)
    assert not d2["occluded"][d2["instance_id"] == 3][0]


def _sequence_with_occlusion(n_frames=5):
    """A free walker (id 1) and a walker whose feet touch a car below (id 2) in every frame;
    AGENT rows with known track ids (10, 20, 30)."""
    out = []
    for f in range(n_frames):
        m = np.zeros((H, W), np.uint16)
        m[10 + f:50 + f, 20 + 3 * f:25 + 3 * f] = 1
        m[20:60 - f, 60 + 2 * f:65 + 2 * f] = 2
        m[60 - f:85, 50:100] = 3
        rows = empty_agents(3)
        rows["frame"], rows["instance_id"], rows["class_id"] = f, [1, 2, 3], [0, 0, 2]
        rows["track_id"] = [10, 20, 30]
        out.append((m, rows))
    return out


def test_instance_maps_keep_ground_truth_track_ids_and_drop_occluded():
    conf = TrackingConfig(drop_collinear=False, min_travel_px=0.0)
    obs = observations_from_instances(_sequence_with_occlusion(), conf)
    assert set(obs["track"]) == {10}    # the walker on the car and the car's top are in contact
    kept = observations_from_instances(_sequence_with_occlusion(),
                                       TrackingConfig(drop_collinear=False, min_travel_px=0.0,
                                                      drop_occluded=False))
    assert set(kept["track"]) == {10, 20, 30}
    # rows without track ids: linked by IoU, three tracks again
    seq = [(m, r[["instance_id", "class_id", "score"]]) for m, r in _sequence_with_occlusion()]
    relinked = observations_from_instances(seq, TrackingConfig(drop_collinear=False,
                                                               min_travel_px=0.0,
                                                               drop_occluded=False))
    assert len(np.unique(relinked["track"])) == 3


def test_agent_rows_visibility_and_side_border():
    a = straight_and_static_agents()
    vis = np.ones(len(a))
    vis[a["track_id"] == 2] = 0.5                  # track 2 half hidden in every frame
    conf = TrackingConfig.for_model("exact")
    obs = observations_from_agents(a, W, H, conf, visibility=vis)
    assert set(obs["track"]) == {1}
    assert set(observations_from_agents(a, W, H, conf)["track"]) == {1, 2}   # unknown: kept
    with pytest.raises(InputError, match="one value per agent row"):
        observations_from_agents(a, W, H, conf, visibility=vis[:3])
    # the top column at the image edge (a body cut by the side border) marks the row as border
    a["top_u"] = 40.0
    a["top_u"][a["track_id"] == 1] = W - 1
    assert set(observations_from_agents(a, W, H, conf)["track"]) == {2}


def test_rider_and_bicycle_become_one_two_wheeler():
    """A person whose lowest row lies on a bicycle joins it: one detection of class bicycle, its
    foot the wheels' lowest row, its top the rider's head; a pedestrian beside it stays apart."""
    m = np.zeros((H, W), np.uint16)
    ellipse(m, 40, 50, 80, 14, 2)          # bicycle, class 1
    ellipse(m, 40, 20, 58, 5, 3)           # rider (its lowest row 58 lies within the bicycle)
    ellipse(m, 90, 30, 80, 5, 4)           # pedestrian
    m[(m == 3) & (np.mgrid[:H, :W][0] >= 56)] = 2          # the bicycle's pixels in front
    rows = np.array([(2, 1, 0.9), (3, 0, 0.9), (4, 0, 0.9)])
    d = detections_from_instances(m, rows)
    assert sorted(d["instance_id"].tolist()) == [2, 4]
    bike = d[d["instance_id"] == 2][0]
    assert bike["class_id"] == 1 and bike["top_v"] == 20 and bike["foot_v"] == 80
    assert not bike["occluded"]
    walker = d[d["instance_id"] == 4][0]
    assert walker["class_id"] == 0 and walker["top_v"] == 30
