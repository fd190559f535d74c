"""The joint ground plane's data-only (Laplace) uncertainty and the gate that uses it (issue 13).

Truth: the independent generators of tests/plane_generators.py. The Laplace std is read off the
fit's curvature at its solution (:mod:`staticdepth.geometry.agent_plane_laplace`); a Monte Carlo
over noise draws of one noise-free scene gives the spread it has to match. The bootstrap over
tracks accepted far cameras 1.3-2.2 degrees off (seeds 40-59); with the Laplace uncertainty beside
it the gate refuses them.
"""
from __future__ import annotations

import numpy as np
import pytest

from plane_generators import scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, _prepare, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import plane_gate
from staticdepth.geometry.agent_plane_laplace import (cramer_rao_of_fit, laplace_uncertainty,
                                                      tracks_for)
from staticdepth.geometry.agent_plane_problem import _normal, _Problem
from staticdepth.geometry.camera import pitch_roll_from_normal
from staticdepth.geometry.plane import angle_between_deg

NO_PRIORS = AgentPlaneConfig(bootstrap=0, column_weight=1.0, height_prior_weight=0.0,
                             shape_prior_weight=0.01, relative_noise=0.0, one_foot=False)


def _local_fit(K, table, start):
    """The joint model's least-squares fit from ``start`` (pitch, roll deg) on every
    observation: (normal, Laplace data-only std deg)."""
    prob = _Problem(K, _prepare(K, table, "joint", None))
    p, r, theta, s, _ = prob.fit(NO_PRIORS, [start], loss=NO_PRIORS.loss, max_nfev=60)
    n = _normal(p, r)
    lap = laplace_uncertainty(K, prob, NO_PRIORS, n, theta, s, np.ones(prob.J, bool), 1e3)
    return n, lap["laplace_data_std_deg"]


def test_laplace_std_matches_the_spread_over_noise_draws():
    # tapered bodies: their extents are inside the bounds (a thin body's true extents are 0, on
    # the bound, where the truncated fits spread less than the curvature says)
    s = scene("tapered", 6, noise_px=0.0, n_tracks=10, frames=(6, 8))
    start = pitch_roll_from_normal(s.normal)
    rng = np.random.default_rng(123)
    normals, stds = [], []
    for _ in range(24):
        t = s.obs.copy()
        for c in ("foot_u", "foot_v", "top_v", "top_u"):
            t[c] = t[c] + rng.normal(0.0, 1.0, len(t))
        t["height_px"] = t["foot_v"] - t["top_v"]
        n, sd = _local_fit(s.K, t, start)
        normals.append(n)
        stds.append(sd)
    mean = np.mean(normals, 0)
    spread = np.sqrt(np.mean([angle_between_deg(n, mean) ** 2 for n in normals]))
    assert 0.2 < spread < 3.0          # a camera where the noise matters
    print(f"Laplace {np.median(stds):.3f} deg, spread {spread:.3f} deg")
    assert abs(np.median(stds) / spread - 1) < 0.3, (np.median(stds), spread)


def test_gate_refuses_a_far_camera_the_bootstrap_alone_accepted():
    # thin axes, camera 50: 43 degrees from 11.8 m, far small people; 1.32 degrees off at 1 px
    s = scene("thin", 50)
    conf = AgentPlaneConfig(bootstrap=20, column_weight=1.0)
    p = fit_agent_plane(s.K, s.obs, conf)
    err = angle_between_deg(p.normal, s.normal)
    q = p.normal_std_parts
    assert err > 1.0
    assert q["bootstrap_std_deg"] <= 1.0                   # the bootstrap alone: accepted
    assert q["laplace_std_deg"] > q["bootstrap_std_deg"]
    gate = plane_gate(p)
    assert not gate.ok and err <= 2.45 * p.normal_std_deg
    assert gate.tracks_needed > gate.tracks and "Laplace" in gate.message
    # what 1 px allows here: the bound at the truth; an unbiased fit is over 1 degree with
    # probability exp(-(1 / bound)^2) (a 2-D Gaussian), and more tracks bring it down
    crb, crb_priors = cramer_rao_of_fit(s.K, s.obs, p, conf, s.normal, s.agent_heights,
                                        s.height_m)
    assert crb_priors <= crb + 1e-9 and 0.5 < crb < q["laplace_data_std_deg"] * 1.5
    assert tracks_for(crb, 24) > 24


def test_the_plane_file_carries_both_uncertainties():
    from staticdepth.geometry.agent_plane import AgentPlane

    s = scene("tapered", 5, n_tracks=8)
    p = fit_agent_plane(s.K, s.obs, AgentPlaneConfig(bootstrap=3, column_weight=1.0))
    q = p.normal_std_parts
    assert {"bootstrap_std_deg", "laplace_std_deg", "laplace_data_std_deg"} <= set(q)
    # the bootstrap's and the Laplace's variances averaged (two estimates of one spread), the
    # class misfit's square halved too (agent_plane_boot)
    assert p.normal_std_deg == pytest.approx(np.sqrt(
        (q["bootstrap_std_deg"] ** 2 + q["laplace_std_deg"] ** 2 + q["class_misfit_deg"] ** 2)
        / 2), rel=1e-12)
    back = AgentPlane.from_dict(p.to_dict())
    assert back.normal_std_parts == q and back.normal_std_deg == p.normal_std_deg
