"""locate on the real pedestrian video vtest.avi: YOLOX people, tracked, at walking speeds.

The video has no ground truth. The plane given here is the one ``staticdepth adapt`` found on its
first 300 frames (YOLOX agents, exact model, a 60 deg field-of-view guess, the 1.7 m height prior:
pitch 24.6 deg, camera height 5.78 m), so the check is one of plausibility: walking people move at
0.5-2.5 m/s, and a person's track is smooth (no jump of more than a few metres between frames).
"""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.dataset.video import import_video
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.locate import PERSON, LocateConfig, locate, speed_summary


def test_vtest_people_walk(shared_data, tmp_path):
    video = shared_data / "video" / "vtest.avi"
    model = shared_data / "models" / "yolox_nano" / "yolox_nano.onnx"
    for p in (video, model):
        if not p.exists():
            pytest.skip(f"{p} not found")
    seq = str(tmp_path / "vt.h5")
    import_video(str(video), seq, max_frames=40, width=384, fov_deg=60.0)
    pos = locate(seq, normal_from_pitch_roll(24.6, -0.18), 5.78, LocateConfig(),
                 detector="yolox", detector_model=str(model))
    people = pos[pos["class_id"] == PERSON]
    assert len(np.unique(people["frame"])) == 40 and len(people) >= 40 * 4
    assert np.all((people["distance_m"] > 5) & (people["distance_m"] < 80))
    sp = speed_summary(pos, min_track_s=2.0)
    assert sp["tracks"] >= 5
    assert 0.7 <= sp["median"] <= 2.0 and sp["p90"] <= 2.5, sp
    for t in np.unique(people["track"]):
        tr = people[(people["track"] == t) & ~people["occluded"]]
        if len(tr) >= 10:
            step = np.hypot(np.diff(tr["ground_x"]), np.diff(tr["ground_y"]))
            assert np.median(step) < 0.5                      # 0.1 s apart
