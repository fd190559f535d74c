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
from staticdepth.geometry.agent_plane_laplace import (CramerRao, chance_over, cramer_rao_of_fit,
                                                      laplace_uncertainty, tracks_for)
from staticdepth.geometry.agent_plane_problem import _normal, _Problem
from staticdepth.geometry.agent_shape import GROUPS
from staticdepth.geometry.camera import normal_from_pitch_roll, pitch_roll_from_normal
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
    bound = cramer_rao_of_fit(s.K, s.obs, p, conf, s.normal, s.agent_heights, s.height_m)
    crb, crb_priors = bound.normal_deg, bound.normal_priors_deg
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


def test_bound_on_the_camera_height_is_the_height_priors_where_the_pixels_pin_the_heights():
    # thin axes, camera 0: 21 degrees from 3.1 m, near people 24 tracks; the pixels fix each
    # track's H_j / d far better than its class prior does, so what the bound leaves for d is the
    # priors' information alone: sum_j (zr'(z_j) / sd)^2 with z_j each true height's offset from
    # the class mean in log sds and zr the pseudo-Huber row (agent_plane_problem.residuals)
    s = scene("thin", 0)
    conf = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    p = fit_agent_plane(s.K, s.obs, conf)
    bound = cramer_rao_of_fit(s.K, s.obs, p, conf, s.normal, s.agent_heights, s.height_m)
    mean, sd = GROUPS[0].typical_height
    z = (np.log(np.array(list(s.agent_heights.values()))) - np.log(mean)) / sd
    zr = np.sign(z) * np.sqrt(2 * (np.sqrt(1 + z * z) - 1))
    slope = z / (np.sqrt(1 + z * z) * zr)            # d zr / d z (z is never exactly 0 here)
    priors_only = 1 / np.sqrt(np.sum((slope / sd) ** 2))
    # the pixels and the normal only add variance to d: above the priors' bound, and close to it
    assert priors_only <= bound.camera_height_std() <= 1.05 * priors_only
    assert 0.010 < priors_only < 0.016     # 24 people, 5.3% each, children weighed down


def test_bound_on_the_anchor_is_the_normal_covariance_through_the_anchor_ray():
    # a (pitch, roll) covariance given; the anchor depth d / (n . r) of normals drawn from it
    # (staticdepth.geometry.scale.anchor_depth, the bench's and adapt's) spreads by anchor_std
    from staticdepth.geometry.scale import anchor_depth

    K = np.array([[700.0, 0, 479.5], [0, 700.0, 269.5], [0, 0, 1]])
    pitch, roll = 18.0, 3.0
    n = normal_from_pitch_roll(pitch, roll)
    cov = np.zeros((3, 3))
    cov[:2, :2] = np.array([[0.6 ** 2, 0.5 * 0.6 * 0.4], [0.5 * 0.6 * 0.4, 0.4 ** 2]]) * (
        np.pi / 180) ** 2
    bound = CramerRao(0.0, 0.0, cov, n)
    rng = np.random.default_rng(0)
    dp = rng.multivariate_normal([0, 0], cov[:2, :2], 20000)
    d0 = anchor_depth(K, n, 5.0, 480.0, 539.0)
    rel = np.array([anchor_depth(K, normal_from_pitch_roll(pitch + np.degrees(a),
                                                           roll + np.degrees(b)), 5.0, 480.0,
                                 539.0) / d0 - 1 for a, b in dp])
    assert bound.anchor_std(K, 480.0, 539.0) == pytest.approx(rel.std(), rel=0.03)
    # the bottom row looks down 18 + 21 degrees: mostly the pitch moves it, ~tan(51) x 0.6 deg
    assert 0.010 < rel.std() < 0.015


def test_chance_over_is_the_gaussian_tail():
    from scipy.stats import chi2, norm

    for std, lim in ((1.0, 1.0), (0.4, 1.0), (2.3, 5.0)):
        assert chance_over(std, lim) == pytest.approx(2 * norm.sf(lim / std), rel=1e-9)
        # an isotropic 2-D error of RMS length std: each axis std / sqrt(2)
        assert chance_over(std, lim, 2) == pytest.approx(chi2.sf(2 * (lim / std) ** 2, 2),
                                                         rel=1e-9)
    assert chance_over(0.0, 1.0) == 0.0


def test_a_known_camera_height_adds_its_information_to_log_1_over_d():
    # the known height is one prior row on lam = log 1 / d (agent_plane_problem.residuals): in
    # the bound's information it adds (w / sd)^2 to lam's entry only, so the marginal covariance
    # of (pitch, roll, lam) takes the rank-one update of a Gaussian prior on lam (closed form)
    from dataclasses import replace

    s = scene("thin", 1)        # far people, 0.8 deg RMS: the height pulls on the normal
    conf = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    p = fit_agent_plane(s.K, s.obs, conf)
    free = cramer_rao_of_fit(s.K, s.obs, p, conf, s.normal, s.agent_heights, s.height_m)
    sd, w = 0.04, conf.height_prior_weight
    known = cramer_rao_of_fit(s.K, s.obs, p, replace(conf, known_height_m=s.height_m,
                                                     known_height_sd=sd),
                              s.normal, s.agent_heights, s.height_m)
    C = free.cov
    expect = C - np.outer(C[:, 2], C[2, :]) / (C[2, 2] + (sd / w) ** 2)
    np.testing.assert_allclose(known.cov, expect, rtol=1e-3, atol=1e-12)
    assert known.camera_height_std() == pytest.approx(
        1 / np.sqrt(1 / free.camera_height_std() ** 2 + (w / sd) ** 2), rel=1e-3)
    # not a vacuous update: the normal's variance falls (4.9% of its trace on this camera)
    assert np.trace(known.cov[:2, :2]) < 0.97 * np.trace(C[:2, :2])


def test_a_given_camera_height_enters_the_fit():
    # estimate_ground_plane (the ground-plane command) passes a given camera height to the joint
    # fit as its prior: the same plane as the fit told the height, another than the free fit
    from dataclasses import replace

    from staticdepth.ground_plane import estimate_ground_plane

    s = scene("tapered", 9)
    conf = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
    given = estimate_ground_plane(s.obs, s.K, conf, camera_height_m=s.height_m)
    told = fit_agent_plane(s.K, s.obs, replace(conf, known_height_m=s.height_m))
    free = fit_agent_plane(s.K, s.obs, conf)
    np.testing.assert_allclose(given.normal, told.normal, atol=1e-12)
    assert given.camera_height_m == s.height_m and given.camera_height_source == "given"
    assert angle_between_deg(told.normal, free.normal) > 0.01
    with pytest.raises(Exception, match=r"plane.known_height_m must be a height in metres"):
        AgentPlaneConfig(known_height_m=0.0)
    with pytest.raises(Exception, match="known_height_sd must be > 0"):
        AgentPlaneConfig(known_height_sd=0.0)
