"""`observations` writes the obs.csv that `ground-plane` reads: from a synthetic sequence (its
true camera pitch comes back) and from the real video vtest.avi (heights fit one ground plane)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.geometry.camera import pitch_roll_from_normal
from staticdepth.ground_plane import read_observations_csv


def test_sequence_to_ground_plane_recovers_the_pitch(tmp_path, capsys):
    seq, obs, cam, plane = (tmp_path / n for n in ("s.h5", "obs.csv", "cam.json", "plane.json"))
    assert main(["synth", "--preset", "demo", "--frames", "16", "--adapt-frames", "16",
                 "--set", "fps=1", "--set", "n_agents=48", "--out", str(seq)]) == 0
    assert main(["observations", str(seq), "--out", str(obs), "--camera-out", str(cam)]) == 0
    rows, size = read_observations_csv(obs)
    assert len(np.unique(rows["track"])) >= 4 and np.all(rows["height_px"] > 0)
    camera = json.loads(cam.read_text())
    assert size == (camera["width"], camera["height"])      # the size the pixels belong to
    assert main(["ground-plane", "--observations", str(obs), "--intrinsics", str(cam),
                 "--camera-height", "5.0", "--out", str(plane),
                 "--accept-uncertain"]) == 0  # 16 frames: few tracks, the gate would refuse
    fit = json.loads(plane.read_text())
    pitch, _ = pitch_roll_from_normal(fit["normal"])
    assert pitch == pytest.approx(25.0, abs=1.5)      # the demo preset: 5 m up, pitched 25 deg
    capsys.readouterr()
    assert main(["observations", str(seq), "--out", str(obs)]) == 2
    assert "pass --overwrite" in capsys.readouterr().err


def test_video_with_the_motion_detector(shared_data, tmp_path):
    obs = tmp_path / "obs.csv"
    assert main(["observations", str(shared_data / "video" / "vtest.avi"), "--max-frames", "30",
                 "--out", str(obs)]) == 0
    rows, size = read_observations_csv(obs)
    assert size == (768, 576)                               # vtest.avi's frames
    assert len(np.unique(rows["track"])) >= 3 and rows["frame"].max() <= 29
    # Upright people on one ground plane: pixel height is affine in the foot pixel (Eq. 1).
    A = np.column_stack([rows["foot_u"], rows["foot_v"], np.ones(len(rows))])
    coef = np.linalg.lstsq(A, rows["height_px"], rcond=None)[0]
    rel = np.abs(A @ coef - rows["height_px"]) / rows["height_px"]
    assert np.median(rel) < 0.1
    assert coef[1] > 0              # lower in the image = nearer = taller
