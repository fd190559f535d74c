"""The joint ground plane on the real fixed-camera video vtest.avi with YOLOX: the two halves agree.

vtest.avi has no calibration: the intrinsics are assumed (f = 700 px, principal point at the
centre), so the test checks consistency, not the true plane: each half of the video (every 4th
frame; people only: the scene is a pedestrian area, YOLOX's rare 'car' there is a false
detection) gives a plane and a camera height with their bootstrap uncertainty. The halves' pitch,
normal and camera height must agree within twice their combined uncertainty (measured, issue 13's
ninth round: pitch 24.6 and 27.0 degrees, roll 0.2 and -5.5, normal +-0.81 and +-2.88 degrees
(bootstrap 1.02 / 3.99, Laplace 0.53 / 0.77; the former quadrature sum, 1.15 / 4.07, was sqrt(2)
too large, agent_plane_boot), so the normals are 5.6 degrees apart against a 2-sigma bound of
6.0 (9.2 with the sum, last round); camera height 6.20 +- 0.09 and 6.85 +- 0.50 m). Per axis
(issue 13's twenty-third round): pitch 24.62 +- 0.23 and 26.90 +- 1.42, roll 0.16 +- 0.84 and
-5.00 +- 2.64 degrees, 1.58 and 1.86 combined std apart.

Why the second half's roll is off and uncertain (docs/ground_plane.md): one track (24, 15
frames crossing the image sideways) moves it by 7.5 degrees: without it the roll is 0.3. The
masks' head-foot columns disagree with the rows here: their lean is about a quarter of what the
rows' pitch implies under the assumed f (the axes alone put the vertical vanishing point at a
pitch of 6-8 degrees) and carries a constant -4 px (walking legs, shadows in the motion masks, or
the assumed intrinsics), so the column cue, weighted 0.2-0.3 by the residual scales, lets a single
sideways track pull the roll (-5.5 this round). Rows only (column_weight 0) the halves give 23.3 +- 0.9 and
25.7 +- 3.2 degrees of pitch, -0.2 and -1.1 of roll.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import vtest_frames

from staticdepth import tracking
from staticdepth.detectors import make_detector
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import camera_height_from_agents, plane_gate
from staticdepth.geometry.plane import angle_between_deg

STEP = 4
F_PX = 700.0


@pytest.fixture(scope="module")
def halves(shared_data):
    frames, model = vtest_frames(shared_data, STEP)
    assert len(frames) >= 90, f"read {len(frames)} frames of vtest.avi"
    H, W = frames[0].shape[:2]
    K = np.array([[F_PX, 0, (W - 1) / 2], [0, F_PX, (H - 1) / 2], [0, 0, 1.0]])
    det = make_detector("yolox", model=str(model))
    out = []
    for part in (frames[:len(frames) // 2], frames[len(frames) // 2:]):
        obs = tracking.observations_from_instances(list(det.detect_sequence(part)),
                                                   tracking.TrackingConfig.for_model("joint"))
        plane = fit_agent_plane(K, obs, AgentPlaneConfig(bootstrap=8, classes=(0,)))
        d, sd, n = camera_height_from_agents(plane, bootstrap=100)
        out.append((plane, d, sd, n))
    return out


def test_halves_agree_within_their_uncertainty(halves):
    (p1, d1, sd1, n1), (p2, d2, sd2, n2) = halves
    for p, d, sd, n in halves:
        print(f"pitch {p.pitch_deg:.2f} roll {p.roll_deg:.2f} +- {p.normal_std_deg:.2f} deg, "
              f"camera height {d:.2f} +- {sd:.2f} m ({n} person tracks), inlier tracks "
              f"{int(p.inliers.sum())}/{len(p.inliers)}; {plane_gate(p).message}")
        assert n >= 8 and int(p.inliers.sum()) >= 8
        assert math.isfinite(p.normal_std_deg) and 0 < p.normal_std_deg < 6
        assert 0 < sd < 0.2 * d
        assert 10 < p.pitch_deg < 45 and abs(p.roll_deg) < 15     # a camera looking down
    gap = angle_between_deg(p1.normal, p2.normal)
    print(f"angle between the halves' normals {gap:.2f} deg")
    assert gap <= 2 * math.hypot(p1.normal_std_deg, p2.normal_std_deg), gap
    assert abs(p1.pitch_deg - p2.pitch_deg) <= 2 * math.hypot(p1.normal_std_deg,
                                                              p2.normal_std_deg)
    assert abs(d1 - d2) <= 2 * math.hypot(sd1, sd2), (d1, d2)
    # per axis (agent_plane_boot.axis_std): each of pitch and roll within 2 combined std
    q1, q2 = p1.normal_std_parts, p2.normal_std_parts
    for axis, a, b in (("pitch", p1.pitch_deg, p2.pitch_deg), ("roll", p1.roll_deg, p2.roll_deg)):
        sd = math.hypot(q1[f"{axis}_std_deg"], q2[f"{axis}_std_deg"])
        print(f"{axis}: {a:.2f} +- {q1[f'{axis}_std_deg']:.2f} and {b:.2f} +- "
              f"{q2[f'{axis}_std_deg']:.2f} deg, {abs(a - b) / sd:.2f} combined std apart")
        assert abs(a - b) <= 2 * sd, (axis, a, b, sd)
