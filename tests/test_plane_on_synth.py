"""The ground plane from the synthetic scene's own rendered agents, against the scene's true plane.

The scene generator (``staticdepth.dataset.synth``) ray-casts people as a body cylinder with a
narrower head on top, riders sitting on bicycles, bags and umbrellas as separate instances and
vehicles as boxes, so its masks differ from the fit's ideal cylinders the way real ones do. The
truth here is the scene's mounting and the true foot points of its agent rows, projected in the
test by sampling the foot disk's rim densely.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth import tracking
from staticdepth.dataset.synth import SyntheticScene, preset
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.plane import angle_between_deg

FRAMES = 300      # 30 s: 7-11 tracked people on c1 at 400x200 (40 frames hold 0-2)


@pytest.fixture(scope="module")
def c1():
    """c1 geometry (5.4 m up, pitched 25 degrees, 90 degree fov) at 400x200, 300 frames."""
    scene = SyntheticScene(preset("c1", seed=0, width=400, height=200))
    frames = list(scene.frames(FRAMES))
    return scene, [f["instances"] for f in frames], [f["agents"] for f in frames]


def _lowest_rim_rows(K: np.ndarray, n: np.ndarray, foot_c: np.ndarray,
                     radius: np.ndarray) -> np.ndarray:
    """Row of the lowest image point of each foot disk (centre foot_c (N, 3), radius (N,),
    horizontal = orthogonal to n), by sampling 720 rim points."""
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    phi = np.linspace(0.0, 2 * math.pi, 721)[:-1]
    rim = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2            # (720, 3)
    P = foot_c[:, None, :] + radius[:, None, None] * rim[None]              # (N, 720, 3)
    return np.max(K[1, 1] * P[..., 1] / P[..., 2] + K[1, 2], axis=1)


def test_fitted_plane_matches_the_scene(c1):
    """Bound 1 degree: on 5 seeds of this setup the error was 0.10-0.28 degrees (the settings
    before the fix: 5.3-5.9); with 40 frames there are too few people for any bound."""
    scene, maps, rows = c1
    obs = tracking.observations_from_instances(zip(maps, rows),
                                               tracking.TrackingConfig.for_model("exact"))
    plane = fit_agent_plane(scene.camera.K, obs, AgentPlaneConfig(model="exact", bootstrap=0))
    err = angle_between_deg(plane.normal, scene.mounting.normal)
    print(f"c1 400x200, {FRAMES} frames: normal off by {err:.2f} deg, "
          f"{int(plane.inliers.sum())}/{len(plane.inliers)} tracks")
    assert len(plane.inliers) >= 5
    assert err <= 1.0
    # the cause of the reported 4-6 degree tilt: head-column residuals with a head disk as wide as
    # the body (the former defaults) on the very same observations
    before = fit_agent_plane(scene.camera.K, obs,
                             AgentPlaneConfig(model="exact", bootstrap=0, column_weight=1.0,
                                              head_radius_m=0.2))
    assert angle_between_deg(before.normal, scene.mounting.normal) > 3.0


def test_occlusion_test_catches_raised_foot_points(c1):
    """Person masks whose lowest row is several pixels above the true foot (riders on bicycles,
    feet behind cars or bags) are the ones the mask-contact test marks occluded; the others sit
    on the true foot's lowest rim point (the half pixel of the mask row aside)."""
    scene, maps, rows = c1
    K, n = scene.camera.K, scene.mounting.normal
    raised, flagged, clean_err = 0, 0, []
    for m, r in zip(maps, rows):
        person = r[r["class_id"] == 0]
        if len(person) == 0:
            continue
        det = tracking.detections_from_instances(m, person)
        det = det[np.argsort(det["instance_id"])]
        person = person[np.argsort(person["instance_id"])]
        assert np.array_equal(det["instance_id"], person["instance_id"])
        foot_c = np.stack([person["foot_x"], person["foot_y"], person["foot_z"]], 1)
        true_v = _lowest_rim_rows(K, n, foot_c.astype(np.float64),
                                  person["radius_m"].astype(np.float64))
        off = true_v - (det["foot_v"] + 0.5)
        inside = ~det["border"] & (det["foot_v"] - det["top_v"] >= 10)
        bad = inside & (off > 3.0)
        raised += int(bad.sum())
        flagged += int((bad & det["occluded"]).sum())
        clean_err += list(off[inside & ~det["occluded"] & (off <= 3.0)])
    print(f"{raised} person rows with the foot > 3 px above the truth, {flagged} flagged")
    assert raised >= 50                      # riders alone give many
    assert flagged >= 0.9 * raised
    assert abs(np.median(clean_err)) < 0.25  # unoccluded rows: foot row + 0.5 is unbiased
