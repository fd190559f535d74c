"""The joint ground-plane model on independent generators (tests/plane_generators.py, issue 13).

Each generator has its own body model (thin axis, tapered, wide cylinder, ellipsoid with swinging
legs, vehicle boxes); the truth is the generator's camera. Few cameras per generator keep the
runtime small; benchmarks/bench_agent_plane.py runs more.
"""
from __future__ import annotations

import numpy as np
import pytest

from plane_generators import GENERATORS, scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import (camera_height_from_agents, camera_height_ml,
                                                   plane_gate)
from staticdepth.geometry.plane import angle_between_deg
from staticdepth.geometry.scale import anchor_depth, anchor_pixel

FAST = AgentPlaneConfig(bootstrap=0, column_weight=1.0)
SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def fits():
    """(generator, seed) -> (scene, plane) on masks, 1 px noise."""
    return {}


def _fit(fits, kind, seed, **kw):
    key = (kind, seed, tuple(sorted(kw.items())))
    if key not in fits:
        s = scene(kind, seed, **kw)
        fits[key] = (s, fit_agent_plane(s.K, s.obs, FAST))
    return fits[key]


# (median, max) normal error in degrees: the goal (0.5, 1.0) on every body model. People
# on swinging legs meet it here (seeds 0-2: 0.06, 0.04, 0.06) since their one-foot frames take
# the foot interpolated between two-foot frames (else an extent of their own) and their residual
# scale grows with their size (agent_walker.py; seed 1, 48 degrees from 11.5 m, 66 px people, was
# 2.92 off, 0.90 with the extent alone); over 20 cameras the max is 0.71 (seeds 20-39: 1.41)
CLEAN = {"thin": (0.5, 1.0), "tapered": (0.5, 1.0), "cylinder": (0.5, 1.0),
         "ellipsoid": (0.5, 1.0), "vehicles": (0.5, 1.0)}
# max error with 20% outliers: the goal, 2 degrees, or the gate refuses the plane (below)
OUTLIERS = {"tapered": 2.0, "vehicles": 2.0, "ellipsoid": 2.0}


def test_only_striding_walkers_show_two_feet():
    """The generators' masks show two feet apart only for the walkers on swinging legs (about
    three quarters of their observations); rigid bodies never, boxes carry no foot count."""
    share = {k: np.mean(scene(k, 0).obs["feet"] == 2) for k in ("thin", "cylinder", "ellipsoid")}
    assert share["thin"] == 0 and share["cylinder"] == 0 and 0.5 < share["ellipsoid"] < 0.95
    assert np.all(scene("ellipsoid", 0, detection="box", n_tracks=4).obs["feet"] == 0)


@pytest.mark.parametrize("kind", GENERATORS)
def test_normal_on_every_body_model(fits, kind):
    errs = [angle_between_deg(_fit(fits, kind, k)[1].normal, _fit(fits, kind, k)[0].normal)
            for k in SEEDS]
    med, top = CLEAN[kind]
    assert np.median(errs) <= med and max(errs) <= top, errs


@pytest.mark.parametrize("kind", sorted(OUTLIERS))
def test_normal_with_twenty_percent_outliers(fits, kind):
    """Within the goal, or refused by the gate with a bootstrap uncertainty that covers the error
    (2.45 std: the 95% radius of a 2-D Gaussian). The ellipsoid walkers' seed 1 (48 degrees from
    11.5 m, 66 px people) with 20% outliers is 1.1 degrees off with the interpolated one-foot
    frames (4.9 with their extent, uncertainty 3.6: refused)."""
    for k in SEEDS[:2]:
        s, p = _fit(fits, kind, k, outliers=0.2)
        err = angle_between_deg(p.normal, s.normal)
        if err > OUTLIERS[kind]:
            q = fit_agent_plane(s.K, s.obs, AgentPlaneConfig(bootstrap=10, column_weight=1.0))
            assert angle_between_deg(q.normal, p.normal) < 1e-9    # the same fit, with bootstrap
            assert not plane_gate(q).ok and err <= 2.45 * q.normal_std_deg, (
                k, err, q.normal_std_deg)


@pytest.mark.parametrize("kind", [k for k in GENERATORS if k != "vehicles"])
def test_camera_height_from_people(fits, kind):
    rel = []
    for k in SEEDS:
        s, p = _fit(fits, kind, k)
        d, sd, n = camera_height_from_agents(p, bootstrap=50)
        assert n >= 10 and 0 < sd < 0.1 * d
        rel.append(abs(d / s.height_m - 1))
    assert np.median(rel) <= 0.03 and max(rel) <= 0.05, rel


def test_anchor_depth_with_known_camera_height(fits):
    rel = []
    for kind in GENERATORS:
        for k in SEEDS[:2]:
            s, p = _fit(fits, kind, k)
            u, v = anchor_pixel(960, 540)
            true = anchor_depth(s.K, s.normal, s.height_m, u, v)
            rel.append(abs(anchor_depth(s.K, p.normal, s.height_m, u, v) / true - 1))
    assert np.median(rel) <= 0.01 and max(rel) <= 0.03, rel


def test_extent_is_estimated_not_assumed(fits):
    """Thin walkers drive the people's extent to ~0, wide cylinders (0.3 m) up to ~0.17."""
    thin = _fit(fits, "thin", 0)[1].extra["extents"]["people"]
    wide = _fit(fits, "cylinder", 0)[1].extra["extents"]["people"]
    assert max(thin) < 0.03 and min(wide) > 0.1, (thin, wide)


def test_camera_height_ml_weighs_children_by_their_share():
    """Closed-form check: adults at exactly 1.70 m and one child at 1.25 m out of ten tracks give
    d within 1% of the truth (a plain median of 1.7/s would too; a mean would be 2.7% off)."""
    d = 8.0
    s = np.r_[np.full(9, 1.70), 1.25] / d
    groups = np.zeros(10, int)
    assert abs(camera_height_ml(s, groups) / d - 1) < 0.01
    assert abs(1.7 / np.mean(s) / d - 1) > 0.02


def test_gate_refuses_few_tracks_and_scales_with_sqrt_n():
    s = scene("tapered", 5, n_tracks=32)
    conf = AgentPlaneConfig(bootstrap=6)
    few_tracks = np.unique(s.obs["track"])[:4]
    few = fit_agent_plane(s.K, s.obs[np.isin(s.obs["track"], few_tracks)], conf)
    many = fit_agent_plane(s.K, s.obs, conf)
    g_few, g_many = plane_gate(few, 0.3), plane_gate(many, 0.3)
    assert many.normal_std_deg < few.normal_std_deg
    ratio = few.normal_std_deg / many.normal_std_deg       # 1/sqrt(n): about sqrt(32/4) = 2.8
    assert 1.5 < ratio < 8, ratio
    assert not g_few.ok and g_few.tracks_needed > g_few.tracks
    assert g_few.frames_factor == pytest.approx((few.normal_std_deg / 0.3) ** 2)
    assert "need about" in g_few.message
    assert plane_gate(many, 5.0).ok


def test_bad_inputs_raise():
    from staticdepth.errors import InputError
    from staticdepth.geometry.agent_plane_gate import class_set
    s, p = scene("thin", 0, n_tracks=6), None
    p = fit_agent_plane(s.K, s.obs, FAST)
    with pytest.raises(InputError, match="unknown class set"):
        class_set("animals")
    with pytest.raises(InputError, match="no inlier track of the requested classes"):
        camera_height_from_agents(p, (2,))
    with pytest.raises(InputError, match="limit must be positive"):
        plane_gate(p, 0.0)
    with pytest.raises(InputError, match="classes must be a tuple"):
        AgentPlaneConfig(classes="people")
    with pytest.raises(InputError, match="relative_noise must be a finite number >= 0"):
        AgentPlaneConfig(relative_noise=-0.1)
    assert not plane_gate(p).ok and "uncertainty unknown" in plane_gate(p).message   # no bootstrap


def test_vertical_from_axes_recovers_the_normal_of_thin_walkers():
    """Closed-form check of the vanishing-point cue: thin axes (1 px noise) give the generator's
    normal within 0.5 degrees at any pitch, nadir included (measured 0.02-0.34 over 4 seeds)."""
    from staticdepth.geometry.agent_plane_linear import vertical_from_axes
    for pitch in (20.0, 45.0, 90.0):
        s = scene("thin", 3, pitch_deg=pitch)
        o = s.obs
        n = vertical_from_axes(s.K, np.stack([o["foot_u"], o["foot_v"]], 1),
                               np.stack([o["top_u"], o["top_v"]], 1))
        assert angle_between_deg(n, s.normal) < 0.5, pitch


@pytest.mark.parametrize("kind,pitch", [("thin", 90.0), ("tapered", 85.0), ("ellipsoid", 80.0),
                                        ("tapered", 70.0)])
def test_joint_refuses_a_near_nadir_camera(kind, pitch):
    """Seen from (nearly) above, the fit lands tens of degrees off (tapered at 86-90 degrees:
    38-70 degrees, measured before this check): it must refuse with a one-line reason, from the
    axes' vanishing point or from the fitted pitch (tapered at 70: the fit says 72-78)."""
    from staticdepth.errors import InputError
    s = scene(kind, 1, pitch_deg=pitch)
    with pytest.raises(InputError, match="near-nadir camera") as e:
        fit_agent_plane(s.K, s.obs, FAST)
    assert "\n" not in str(e.value)


def test_box_widths_fix_the_cylinder_that_rows_alone_missed():
    """Boxes carry no head column, so from rows alone the extent and the pitch are nearly
    degenerate: wide cylinders seen steeply from far (camera 1: 48 degrees from 11.5 m) came out
    6.1 degrees off, with a bootstrap uncertainty of 1.5 that made the gate refuse it. The box's
    sides give the body's width, which does not foreshorten with the viewing angle while its
    height does: measured 0.06 degrees with them (rows alone, the sides unknown: 6.1)."""
    s = scene("cylinder", 1, detection="box")
    with_sides = angle_between_deg(fit_agent_plane(s.K, s.obs, FAST).normal, s.normal)
    rows = s.obs.copy()
    rows["left"] = rows["right"] = np.nan
    rows_only = angle_between_deg(fit_agent_plane(s.K, rows, FAST).normal, s.normal)
    assert with_sides < 0.5 and rows_only > 3.0, (with_sides, rows_only)


def test_the_one_foot_extent_is_the_winning_fits(monkeypatch):
    """The main fit and the wide start's each rewrite ``sub.e1``; the one kept is the lower
    cost's, whichever ran last (the wide start's used to stay when it lost)."""
    from types import SimpleNamespace

    from staticdepth.geometry import agent_plane_joint as j

    class Sub:
        e1 = 0.0

        def fit(self, conf, starts, theta0=None, **kw):
            wide = theta0 is not None
            self.e1 = 0.3 if wide else 0.1
            return (0.5, 0.0, np.zeros(1), np.ones(1), costs["wide" if wide else "main"])

    monkeypatch.setattr(j, "wide_start", lambda sub: np.ones(1))
    monkeypatch.setattr(j, "RESTARTS_DEG", ())          # the fits alone
    conf = SimpleNamespace(loss="soft_l1")
    for costs, e1, cost in (({"main": 1.0, "wide": 2.0}, 0.1, 1.0),
                            ({"main": 2.0, "wide": 1.0}, 0.3, 1.0)):
        sub = Sub()
        best = j._main_fit(sub, conf, [(20.0, 0.0)])
        assert sub.e1 == e1 and best[4] == cost
