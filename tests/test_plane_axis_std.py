"""The plane normal's uncertainty split into pitch and roll (agent_plane_boot.axis_std): closed-form
replicate sets give their own second moments, scaled to the combined std, and a roll change dr
tilts the normal by cos(pitch) dr; a joint fit reports the split and the plane file keeps it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.geometry.agent_plane_boot import axis_std
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import angle_between_deg

P0, R0 = 30.0, 2.0


def _normals(offsets):
    return [normal_from_pitch_roll(P0 + dp, R0 + dr) for dp, dr in offsets]


def test_independent_axes():
    a, b = 0.6, 1.5                    # pitch replicates +-a, roll replicates +-b
    reps = _normals([(a, 0), (-a, 0), (0, b), (0, -b)])
    c2 = math.cos(math.radians(P0)) ** 2
    total = math.sqrt(a * a / 2 + c2 * b * b / 2)      # the replicates' own RMS tilt
    out = axis_std(normal_from_pitch_roll(P0, R0), reps, total)
    assert out["pitch_std_deg"] == pytest.approx(a / math.sqrt(2), rel=1e-9)
    assert out["roll_std_deg"] == pytest.approx(b / math.sqrt(2), rel=1e-9)
    assert out["pitch_roll_corr"] == pytest.approx(0.0, abs=1e-9)
    # the tilt that roll alone gives is cos(pitch) dr: the replicates' own angles agree
    angles = [angle_between_deg(m, normal_from_pitch_roll(P0, R0)) for m in reps]
    assert angles[2] == pytest.approx(math.cos(math.radians(P0)) * b, rel=1e-3)
    assert math.sqrt(np.mean(np.square(angles))) == pytest.approx(total, rel=1e-3)
    # the size is the combined std's: twice the total, twice each axis
    twice = axis_std(normal_from_pitch_roll(P0, R0), reps, 2 * total)
    assert twice["pitch_std_deg"] == pytest.approx(2 * out["pitch_std_deg"], rel=1e-9)
    assert twice["roll_std_deg"] == pytest.approx(2 * out["roll_std_deg"], rel=1e-9)


def test_the_laplace_covariance_is_averaged_in():
    a, b = 0.8, 0.6                    # the replicates move in pitch only, the Laplace in roll
    reps = _normals([(a, 0), (-a, 0)])
    c2 = math.cos(math.radians(P0)) ** 2
    C = np.diag([a * a, 0.0]) / 2 + np.diag([0.0, b * b]) / 2
    total = math.sqrt(C[0, 0] + c2 * C[1, 1])
    out = axis_std(normal_from_pitch_roll(P0, R0), reps, total, np.diag([0.0, b * b]))
    assert out["pitch_std_deg"] == pytest.approx(a / math.sqrt(2), rel=1e-9)
    assert out["roll_std_deg"] == pytest.approx(b / math.sqrt(2), rel=1e-9)
    nan = axis_std(normal_from_pitch_roll(P0, R0), reps, 1.0, np.full((2, 2), np.nan))
    assert nan["roll_std_deg"] == 0.0 and nan["pitch_std_deg"] == pytest.approx(1.0)


def test_correlated_axes_and_degenerate_sets():
    reps = _normals([(0.5, 1.0), (-0.5, -1.0), (1.0, 2.0), (-1.0, -2.0)])
    out = axis_std(normal_from_pitch_roll(P0, R0), reps, 1.0)
    assert out["pitch_roll_corr"] == pytest.approx(1.0, abs=1e-9)
    assert out["roll_std_deg"] == pytest.approx(2 * out["pitch_std_deg"], rel=1e-9)
    c2 = math.cos(math.radians(P0)) ** 2
    assert out["pitch_std_deg"] ** 2 + c2 * out["roll_std_deg"] ** 2 == pytest.approx(1.0)
    anti = axis_std(normal_from_pitch_roll(P0, R0), _normals([(0.5, -1), (-0.5, 1)]), 1.0)
    assert anti["pitch_roll_corr"] == pytest.approx(-1.0, abs=1e-9)
    n = normal_from_pitch_roll(P0, R0)
    assert axis_std(n, [n, n], 1.0) == {}                 # replicates that do not move
    assert axis_std(n, _normals([(1, 0)]), float("nan")) == {}
    assert axis_std(n, [], 1.0) == {}
    # roll across +-180 (a camera upside down) is a small step, not 360 degrees
    flip = [normal_from_pitch_roll(P0, 179.5), normal_from_pitch_roll(P0, -179.5)]
    out = axis_std(normal_from_pitch_roll(P0, 180.0), flip, 0.5 * math.cos(math.radians(P0)))
    assert out["roll_std_deg"] == pytest.approx(0.5, rel=1e-6)


def test_a_joint_fit_reports_pitch_and_roll():
    from plane_generators import scene

    from staticdepth.geometry.agent_plane import AgentPlane, AgentPlaneConfig, fit_agent_plane
    from staticdepth.ground_plane import summary

    s = scene("tapered", 5, n_tracks=8)
    p = fit_agent_plane(s.K, s.obs, AgentPlaneConfig(bootstrap=5, column_weight=1.0))
    q = p.normal_std_parts
    c2 = math.cos(math.radians(p.pitch_deg)) ** 2
    assert q["pitch_std_deg"] > 0 and q["roll_std_deg"] > 0 and -1 <= q["pitch_roll_corr"] <= 1
    assert q["pitch_std_deg"] ** 2 + c2 * q["roll_std_deg"] ** 2 == pytest.approx(
        p.normal_std_deg ** 2, rel=1e-9)
    assert AgentPlane.from_dict(p.to_dict()).normal_std_parts == q
    assert f"(pitch {q['pitch_std_deg']:.2f}, roll {q['roll_std_deg']:.2f})" in summary(p)
