"""The "upright" alignment mode: structures re-anchored at their contact with the ground."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry.alignment import align_depth, depth_from_inverse
from staticdepth.geometry.alignment_vertical import down_step
from tests.test_alignment import dpt_failure, scene


def _absrel(pred, gt, m):
    return float(np.mean(np.abs(pred[m] - gt[m]) / gt[m]))


def test_down_step_follows_the_image_of_a_vertical_line():
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 39.5], [0, 0, 1]])
    t, roll = math.radians(30), math.radians(5)
    n = np.array([math.sin(roll), math.cos(roll) * math.cos(t), math.cos(roll) * math.sin(t)])
    du = down_step(K, n, 160, 80)
    rng = np.random.default_rng(1)
    for _ in range(20):
        u, v, Z = rng.uniform(0, 159), rng.uniform(0, 79), rng.uniform(3, 30)
        P = Z * np.linalg.solve(K, [u, v, 1.0])
        p1 = K @ (P + 1e-4 * n)                 # a point a little lower on the vertical
        slope = (p1[0] / p1[2] - u) / (p1[1] / p1[2] - v)
        iu, iv = int(round(u)), int(round(v))
        assert du[iv, iu] == pytest.approx(slope, abs=0.02 + 0.02 * abs(slope))
    level = down_step(K, np.array([0.0, 1.0, 0.0]), 160, 80)
    np.testing.assert_allclose(level, 0.0, atol=1e-12)     # level camera: verticals are columns


def test_an_exact_prediction_stays_exact_and_a_wrong_wall_is_fixed():
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = depth_from_inverse(dpt_failure(Z, s=3.0, t=0.08))
    up = align_depth(pred, K, n, 5.0, ground, mode="upright")
    assert _absrel(up.depth, Z, ground) < 1e-4
    # the foot is found within a pixel; the shift t bends the network's own shape a little
    assert _absrel(up.depth, Z, wall) < 0.03
    bad = pred.copy()
    bad[wall] *= 1.5                                  # the network puts the wall 50% too far
    g = align_depth(bad, K, n, 5.0, ground, mode="ground")
    for shape in ("network", "vertical"):
        u = align_depth(bad, K, n, 5.0, ground, mode="upright", shape=shape)
        assert _absrel(g.depth, Z, wall) > 0.5
        assert _absrel(u.depth, Z, wall) < 0.07, shape
        assert _absrel(u.depth, Z, ground) < 1e-4


def test_a_compressed_far_ground_recedes_like_the_plane_and_takes_its_depth():
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = Z.copy()
    far = Z > 15
    pred[far] = 15 * (Z[far] / 15) ** 0.5             # the network squashes the far ground
    near_ground = ground & ~far
    g = align_depth(pred, K, n, 5.0, near_ground, mode="ground")
    u = align_depth(pred, K, n, 5.0, near_ground, mode="upright")
    off = align_depth(pred, K, n, 5.0, near_ground, mode="upright", recede=None)
    m = ground & far
    assert _absrel(g.depth, Z, m) > 0.1
    assert _absrel(off.depth, Z, m) > 0.1             # without the recession test: still wrong
    assert _absrel(u.depth, Z, m) < 1e-3
    assert _absrel(u.depth, Z, wall) < 0.02


def test_upright_errors():
    K, n, Z, ground, _ = scene()
    with pytest.raises(InputError, match="shape"):
        align_depth(Z, K, n, 1.0, ground, mode="upright", shape="slanted")
    with pytest.raises(InputError, match="jump_rel"):
        align_depth(Z, K, n, 1.0, ground, mode="upright", jump_rel=0.0)


def test_upright_settings_are_checked():
    from staticdepth.adaptation.config import build_config

    conf = build_config({"align.mode": "upright", "align.shape": "vertical"})
    assert conf.align.mode == "upright" and conf.align.shape == "vertical"
    with pytest.raises(InputError, match="align.shape"):
        build_config({"align.mode": "upright", "align.shape": "slanted"})
    with pytest.raises(InputError, match="recede"):
        build_config({"align.recede_min": 2.0, "align.recede_max": 1.0})
    with pytest.raises(InputError, match="jump_rel"):
        build_config({"align.jump_rel": 0.0})


def test_structures_of_an_independent_scene_take_their_ground_contact_depth():
    """One frame of tests/indep_scenes.py (facades, walls, poles, crates on the ground): a
    prediction with the scene's own shape but every structure 40% too far and the ground beyond
    15 m squashed; ``ground`` keeps both errors, ``upright`` removes most of them (measured:
    structures 0.40 -> 0.15, far ground 0.15 -> 0.007)."""
    from staticdepth.evaluate import region_masks
    from tests.indep_scenes import SCENES, Scene

    sc = Scene(SCENES[0], 240, 120)     # at 160x80 the far facades' feet are not resolved
    f = sc.render(0)
    gt, K = f["depth"], sc.camera.K
    t = math.radians(SCENES[0].pitch_deg)
    n, d = np.array([0.0, math.cos(t), math.sin(t)]), SCENES[0].height_m
    reg = region_masks(gt, f["instances"], f["agents"], K, (n, d), 80.0)
    valid = np.isfinite(gt)
    pred = np.where(valid, gt, np.nan).astype(np.float32)
    st = reg["structures"] & valid
    pred[st] *= 1.4
    far = reg["ground"] & (gt > 15)
    pred[far] = 15 * (gt[far] / 15) ** 0.6
    feet = reg["ground"] & (gt < 12)
    g = align_depth(pred, K, n, d, feet, mode="ground")
    u = align_depth(pred, K, n, d, feet, mode="upright", agent_mask=f["instances"] > 0)
    for m, before_min, after_max in ((st, 0.3, 0.2), (far, 0.1, 0.02)):
        assert _absrel(g.depth, gt, m) > before_min
        assert _absrel(u.depth, gt, m) < after_max
    assert _absrel(u.depth, gt, reg["ground"]) <= _absrel(g.depth, gt, reg["ground"]) + 1e-3


def test_upright_does_not_depend_on_the_predictions_scale():
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = depth_from_inverse(dpt_failure(Z, s=3.0, t=0.08))
    pred[wall] *= 1.5
    a = align_depth(pred, K, n, 5.0, ground, mode="upright").depth
    b = align_depth(pred * 1000.0, K, n, 5.0, ground, mode="upright").depth
    np.testing.assert_allclose(b, a, rtol=1e-3)
    assert _absrel(b, Z, wall) < 0.07


def test_untrusted_contacts_keep_the_ground_mode():
    """align.max_pull: a run the re-anchoring would pull nearer than its ground-mode depth /
    max_pull keeps the ground mode; align.contact_range: so does one whose contact lies beyond
    contact_range x the farthest plane depth of the ground mask. The wall (12 m away, the
    network 50% too far) is pulled to about 1/1.5 of its ground-mode depth: fixed with
    max_pull 2, refused at 1.25; its contact (about 12 m) is within 1.2x of a ground mask
    that reaches 15 m, beyond 0.5x."""
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = depth_from_inverse(dpt_failure(Z, s=3.0, t=0.08))
    pred[wall] *= 1.5
    mask = ground & (Z < 15)
    g = align_depth(pred, K, n, 5.0, mask, mode="ground").depth
    ok = align_depth(pred, K, n, 5.0, mask, mode="upright", max_pull=2.0, contact_range=1.2,
                     fill=False).depth
    assert _absrel(g, Z, wall) > 0.3 and _absrel(ok, Z, wall) < 0.07
    for kw in ({"max_pull": 1.25}, {"contact_range": 0.5}):
        refused = align_depth(pred, K, n, 5.0, mask, mode="upright", **kw).depth
        np.testing.assert_allclose(refused[wall], g[wall], rtol=1e-6)
        assert _absrel(refused, Z, mask) < 1e-4                 # the ground stays on the plane
    with pytest.raises(InputError, match="max_pull"):
        from staticdepth.adaptation.config import build_config

        build_config({"align.max_pull": 0.5})


def test_the_default_refuses_pulls_beyond_the_ground_modes_noise():
    """A traced contact is never behind the structure's foot (it is the foot, or ground in front
    of an occluder that hides it), so a run pulled nearer than its ground-mode depth is as likely
    a contact in front as a network that put the structure too far; on the independent scenes
    pulls beyond 1.1x lost against the ground mode in all runs (docs/gains.md). With adapt's default
    (align.max_pull 1.1) no pixel of the wall the network puts 50% too far ends more than 1.1x
    nearer than its ground-mode depth: the wall is only partly fixed (max_pull 2 fixes it, the
    price of the rule), still far better than the ground mode, and the ground stays exact."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    opts = upright_options(build_config({}).align)
    assert opts["max_pull"] == pytest.approx(1.1)
    mask = ground & (Z < 15)
    pred = depth_from_inverse(dpt_failure(Z, s=3.0, t=0.08))
    pred[wall] *= 1.5
    g = align_depth(pred, K, n, 5.0, mask, mode="ground").depth
    u = align_depth(pred, K, n, 5.0, mask, mode="upright", **opts).depth
    loose = align_depth(pred, K, n, 5.0, mask, mode="upright", **{**opts, "max_pull": 2.0}).depth
    assert _absrel(u, Z, mask) < 1e-4
    from staticdepth.geometry.projection import ray_grid

    plane = 5.0 / (ray_grid(K, Z.shape[1], Z.shape[0]) @ n)      # the plane's bound (wall: > 0)
    assert np.all(u[wall] * 1.1 >= np.minimum(g, plane)[wall] * (1 - 1e-5))
    assert _absrel(loose, Z, wall) < 0.07 < 0.2 < _absrel(u, Z, wall) < 0.4 < _absrel(g, Z, wall)


def test_ground_the_network_did_not_recede_inside_the_walked_region_takes_the_plane():
    """align.walked_ratio: a network that fails on the view keeps its ground flat from 7 m to
    11 m (it does not recede: traced like a wall down to its contact at 7 m, up to 36% too near).
    Inside the walked region (the ground mask) a traced pixel whose plane depth is more than
    walked_ratio x its contact's is ground: beyond 1.2 x 7 m = 8.4 m it takes the plane. The wall
    at 12 m (outside the walked region) then finds its contact on that ground."""
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = Z.copy()
    flat = ground & (Z > 7) & (Z < 11)
    pred[flat] = 7.0
    walked = ground & (Z < 11)
    off = align_depth(pred, K, n, 5.0, walked, mode="upright").depth
    on = align_depth(pred, K, n, 5.0, walked, mode="upright", walked_ratio=1.2).depth
    far = flat & (Z > 9)      # the contact is placed between rows: 7-7.5 m
    assert _absrel(off, Z, far) > 0.15
    assert _absrel(on, Z, far) < 1e-3
    assert _absrel(on, Z, flat) < 0.5 * _absrel(off, Z, flat)
    # the wall at 12 m stands on the ground beyond the band: it recedes in the network's own
    # shape and takes the plane, so the wall is re-anchored with or without the rule (0.069; 0.02
    # before the recession was measured on the network's shape too: the wall's lowest row, whose
    # recession reaches into the ground below it, now takes the plane, and the contact is one row
    # higher). The ground mode's scale and shift, which the flat band broke, put 44% of the
    # pixels below the horizon beyond infinity (the wall 30x too far at the far clamp): refuted
    # (alignment.BEYOND_SHARE), a scale alone leaves the wall 0.095 off
    g = align_depth(pred, K, n, 5.0, walked, mode="ground")
    assert _absrel(on, Z, wall) < 0.08 and _absrel(off, Z, wall) < 0.08
    assert g.plane_normal[2] == 1.0 and g.plane_normal[1] == 0.0      # scale only
    assert 0.05 < _absrel(g.depth, Z, wall) < 0.15
    assert _absrel(on, Z, ground & (Z < 7)) < 1e-3
    with pytest.raises(InputError, match="walked_ratio"):
        from staticdepth.adaptation.config import build_config

        build_config({"align.walked_ratio": 0.5})


def test_ground_known_by_another_cue_takes_the_plane_and_carries_the_wall():
    """``extra_ground``: beyond the walked region (ground closer than 7 m) the network keeps the
    ground flat from 7 to 11 m, which nothing in the depth tells from a wall; pixels another cue
    says are ground (here the scene's true ground) take the plane, and the wall at 12 m finds its
    contact on them. ``info`` reports each pixel's category."""
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = Z.copy()
    flat = ground & (Z > 7) & (Z < 11)
    pred[flat] = 7.0
    pred[wall] *= 0.8                   # and the network has the wall 20% too near
    walked = ground & (Z < 7)
    info_off, info_on = {}, {}
    off = align_depth(pred, K, n, 5.0, walked, mode="upright", walked_ratio=1.2, info=info_off)
    on = align_depth(pred, K, n, 5.0, walked, mode="upright", walked_ratio=1.2,
                     extra_ground=ground, info=info_on)
    assert _absrel(off.depth, Z, flat) > 0.1 and _absrel(on.depth, Z, flat) < 1e-3
    assert _absrel(on.depth, Z, wall) < 0.03
    assert _absrel(on.depth, Z, ground & (Z < 7)) < 1e-3
    # categories: the flat band was traced like a wall, now it is plane; the wall is re-anchored
    # at a contact beyond 11 m (its error is the same without the cue: 1.2%)
    assert info_off["traced"][flat].mean() > 0.9 and not info_on["traced"][flat].any()
    took = info_on["planar"] | info_on["snapped"]          # snapped: the band's first metre
    assert took[flat].all() and info_on["planar"][flat].mean() > 0.8
    assert info_on["moved"][wall].mean() > 0.9
    c = info_on["contact"][wall & info_on["moved"]]
    assert np.median(Z.ravel()[c]) > 11.0
    for key in ("snapped", "ground_mode", "ground"):
        assert info_on[key].shape == Z.shape


def test_plane_bound_keeps_every_pixel_below_the_horizon_nearer_than_the_ground():
    """align.plane_bound: whatever a pixel below the agents' horizon sees stands in front of the
    ground along its ray (or is it), so no aligned depth exceeds the plane's there. A network
    that does not see the wall (a thin structure, as the poles) gives it the far background's
    depth, 3.2x too far: the contact would pull it nearer than max_pull (2) allows, so the
    ground mode keeps it there; the bound brings each of its pixels within the plane's depth
    (measured: AbsRel 2.24 -> 0.30 on the wall)."""
    from staticdepth.geometry.projection import ray_grid

    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = Z.copy()
    pred[wall] = 40.0
    off = align_depth(pred, K, n, 5.0, ground, mode="upright", max_pull=2.0).depth
    on = align_depth(pred, K, n, 5.0, ground, mode="upright", max_pull=2.0,
                     plane_bound=True).depth
    h, w = Z.shape
    nr = ray_grid(K, w, h) @ n
    with np.errstate(divide="ignore"):
        plane = np.where(nr > 0, 5.0 / nr, np.inf)
    below = nr > 0
    assert np.all(on[below] <= plane[below] * (1 + 1e-5))
    assert np.any(off[below] > plane[below] * 1.5)
    assert _absrel(off, Z, wall) > 2.0 and _absrel(on, Z, wall) < 0.35
    np.testing.assert_allclose(on[ground], off[ground], rtol=1e-6)   # the ground: unchanged
    # above the horizon (the sky at 200) nothing bounds it
    np.testing.assert_allclose(on[~below], off[~below], rtol=1e-6)
    from staticdepth.adaptation.config import build_config

    assert build_config({}).align.plane_bound is True


def test_the_align_stage_applies_the_plane_bound_and_the_labels_do_not():
    """adapt's aligned_frame: the align stage passes plane_bound (its outputs, like the align
    command and export-model, are bounded by the plane); the pseudo labels call it without."""
    from staticdepth.adaptation.align import aligned_frame, upright_options
    from staticdepth.adaptation.config import build_config
    from staticdepth.dataset.schema import AGENT_DTYPE

    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = Z.copy()
    pred[wall] = 40.0                   # unseen by the network, beyond max_pull's reach
    conf = build_config({})
    none, rows = np.zeros(Z.shape, np.int32), np.zeros(0, AGENT_DTYPE)
    stage = aligned_frame(conf, K, n, ground, none, rows, pred, plane_bound=True)
    label = aligned_frame(conf, K, n, ground, none, rows, pred)
    opts = upright_options(conf.align)
    assert opts["plane_bound"] is True
    ref = align_depth(pred, K, n, 1.0, ground, mode="upright", snap_rel=conf.align.snap_rel,
                      **opts).depth
    np.testing.assert_allclose(stage, ref, rtol=1e-6)
    assert _absrel(stage * 5.0, Z, wall) < 0.35 < 2.0 < _absrel(label * 5.0, Z, wall)
