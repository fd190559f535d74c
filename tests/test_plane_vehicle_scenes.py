"""Vehicles in the ground-plane fit on an independent rendered scene (tests/indep_scenes.py).

The scene's cars are three boxes (body, a shorter cabin, wheels), not the joint model's one box:
a car mask's highest row is its cabin's far edge, a run of pixels whose median column lies between
two corners, 2-13 px from the model's highest corner. Fitted as a corner, these columns pulled
the all-class plane 3.91 deg off on i2 (people only: 0.40). The joint model now leaves box
classes' top columns out and fits their side columns instead (the lowest corner slides along the
foot row to centre the box between them; benchmarks/bench_agent_plane.py --scenes i1,i2,i3,i4:
all classes 0.60 / 0.43 / 0.31 / 0.24 deg, people only 0.28 / 0.40 / 0.10 / 0.24).
"""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth import tracking
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import angle_between_deg
from tests.indep_scenes import SCENES, Scene


@pytest.fixture(scope="module")
def i2():
    """(K, observations from the ground-truth instance maps as adapt takes them, true normal)."""
    spec = next(s for s in SCENES if s.name == "i2")
    sc = Scene(spec, 320, 160)
    pairs = [(f["instances"], f["agents"]) for f in (sc.render(i) for i in range(27))]
    obs = tracking.observations_from_instances(pairs, tracking.TrackingConfig(
        drop_collinear=False, min_height_px=10))
    return sc.camera.K, obs, normal_from_pitch_roll(spec.pitch_deg, 0.0)


def test_cars_do_not_pull_the_plane(i2):
    K, obs, truth = i2
    cars = np.unique(obs["track"][obs["class_id"] == 2])
    assert len(cars) == 3
    err = {name: angle_between_deg(fit_agent_plane(K, obs, AgentPlaneConfig(
        classes=cls, bootstrap=0)).normal, truth) for name, cls in (("people", (0,)),
                                                                   ("all", None))}
    # measured: people 0.40, all classes 0.43 (3.91 with the cars' top columns fitted as corners)
    assert err["people"] < 0.6
    assert err["all"] < 0.6
    assert err["all"] < err["people"] + 0.2
