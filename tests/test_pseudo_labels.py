"""Pseudo labels: contact values, riders, accessories, untouched pixels (METHOD.md section 1)."""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.dataset.schema import COCO
from staticdepth.detectors.base import rows_from_masks
from staticdepth.detectors.grouping import label_sources
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, normal_from_pitch_roll
from staticdepth.pseudo_labels import PRESETS, PseudoLabelConfig, contact_value, pseudo_label

H, W = 120, 160


def _rect(v0, v1, u0, u1):
    m = np.zeros((H, W), bool)
    m[v0:v1 + 1, u0:u1 + 1] = True
    return m


def _frame(masks, classes):
    return rows_from_masks(0, masks, classes, [1.0] * len(masks), (H, W))


def _ground_inverse_depth(scale=2.0, shift=0.05):
    """D = s (n . r) / d + t: a tilted camera's ground in a network's relative inverse depth."""
    cam = Camera.from_intrinsics(150, 150, W / 2, H / 2, W, H)
    n = normal_from_pitch_roll(np.radians(25), 0.0)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    r = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    return (scale * (r @ n) / 5.0 + shift).astype(np.float32)


def test_rows_from_masks_measures_feet_and_head():
    m = _rect(30, 70, 40, 49)
    m[70, 40:44] = False                    # lowest row covers columns 44..49: median 46.5
    inst, rows = _frame([m], [COCO["person"]])
    assert rows["foot_v"][0] == 70 and rows["top_v"][0] == 30 and rows["foot_u"][0] == 46.5
    assert np.all(inst[m] == 1) and inst.max() == 1
    # an instance fully covered by a later one disappears and ids are renumbered
    inst, rows = _frame([_rect(10, 12, 10, 12), _rect(0, 50, 0, 50), _rect(60, 70, 60, 70)],
                        [0, 2, 0])
    assert list(rows["instance_id"]) == [1, 2] and list(rows["class_id"]) == [2, 0]
    assert set(np.unique(inst)) == {0, 1, 2}


def test_label_is_ground_value_at_the_lowest_pixel():
    D = _ground_inverse_depth()
    D_obj = D.copy()
    person = _rect(40, 90, 70, 79)
    D_obj[person] = 0.0                     # the network's own (wrong) value on the person
    inst, rows = _frame([person], [COCO["person"]])
    label, agent = pseudo_label(D_obj, inst, rows)
    lowest = D_obj[90, 74]                  # lowest row 90, columns 70..79: lower median 74
    assert np.all(label[person] == lowest)
    np.testing.assert_array_equal(label[~person], D_obj[~person])
    np.testing.assert_array_equal(agent, person)
    # the robust option: median over the bottom rows
    conf = PseudoLabelConfig(contact="bottom_rows", bottom_rows=3)
    D2 = D.copy()
    D2[90, 70:80] = 9.0                     # a blurred boundary row
    assert contact_value(D2, person, conf) == pytest.approx(np.median(D2[88:91, 70:80]))
    assert contact_value(D2, person) == 9.0
    assert np.isnan(contact_value(D2, np.zeros((H, W), bool)))


def test_rider_takes_vehicle_contact_and_pedestrian_keeps_its_own():
    D = _ground_inverse_depth()
    bike = _rect(70, 95, 50, 80)
    rider = _rect(35, 80, 60, 70) & ~bike   # upper body above the bike, feet inside its box
    walker = _rect(50, 100, 100, 108)       # stands beside, lower than the bike
    walker2 = _rect(60, 96, 81, 86)         # touches the bike but stands on the ground (lower)
    inst, rows = _frame([bike, rider, walker, walker2],
                        [COCO["bicycle"], COCO["person"], COCO["person"], COCO["person"]])
    src = label_sources(inst, rows)
    assert src[2] == 1 and src[3] == 3 and src[4] == 4
    label, _ = pseudo_label(D, inst, rows)
    assert np.all(label[rider] == D[95, 65])
    assert np.all(label[walker] == D[100, 104])
    assert np.all(label[walker2] == D[96, 83])


def test_accessory_takes_nearest_person_or_stands_alone():
    D = _ground_inverse_depth()
    p1, p2 = _rect(20, 80, 30, 40), _rect(30, 100, 90, 100)
    bag = _rect(50, 60, 42, 46)             # 2 px right of person 1's box
    far_bag = _rect(105, 115, 140, 150)     # far from everyone
    inst, rows = _frame([p1, p2, bag, far_bag], [COCO["person"], COCO["person"],
                                                COCO["handbag"], COCO["suitcase"]])
    label, agent = pseudo_label(D, inst, rows)
    assert np.all(label[bag] == D[80, 35])
    assert np.all(label[far_bag] == D[115, 145])
    assert agent[bag].all() and agent[far_bag].all()
    # a bag carried by a rider follows the rider to the vehicle
    bike = _rect(60, 90, 20, 50)
    inst, rows = _frame([bike, p1 & ~bike, bag & ~bike],
                        [COCO["bicycle"], COCO["person"], COCO["backpack"]])
    label, _ = pseudo_label(D, inst, rows)
    assert np.all(label[bag & ~bike] == D[90, 35])


def test_other_classes_keep_the_prediction():
    D = _ground_inverse_depth()
    bench = _rect(80, 100, 10, 40)
    inst, rows = _frame([bench], [13])      # COCO bench: not an agent
    label, agent = pseudo_label(D, inst, rows)
    np.testing.assert_array_equal(label, D)
    assert not agent.any()


def test_config_and_shape_errors():
    with pytest.raises(InputError, match="contact must be one of"):
        PseudoLabelConfig(contact="top")
    with pytest.raises(InputError, match="bottom_rows"):
        PseudoLabelConfig(bottom_rows=0)
    with pytest.raises(InputError, match="differ in size"):
        pseudo_label(np.zeros((4, 4)), np.zeros((5, 5), np.uint16), _frame([], [])[1], PRESETS["paper"])


def test_stable_depth_keeps_what_the_alignment_repeats():
    """Pixel (0, 0): 10 m +- 1% in every frame -> stable, median 10; (0, 1): alternates 5 / 20 m
    (two contacts) -> not stable; (0, 2): 8 m, but an agent covers it in 3 of 4 frames -> seen
    static too rarely; (0, 3): an agent in 1 of 4 frames hides an outlier there -> stable at 7."""
    from staticdepth.pseudo_labels import stable_depth

    F = 4
    d = np.zeros((F, 1, 4), np.float32)
    d[:, 0, 0] = [10.0, 10.1, 9.9, 10.0]
    d[:, 0, 1] = [5.0, 20.0, 5.0, 20.0]
    d[:, 0, 2] = 8.0
    d[:, 0, 3] = [7.0, 7.0, 30.0, 7.0]
    static = np.ones(d.shape, bool)
    static[:3, 0, 2] = False
    static[2, 0, 3] = False
    med, ok = stable_depth(d, static, 0.03)
    assert ok.tolist() == [[True, False, False, True]]
    assert med[0, 0] == pytest.approx(10.0) and med[0, 3] == pytest.approx(7.0)
    assert med[0, 1] == pytest.approx(12.5)        # the median of 5, 5, 20, 20
    _, loose = stable_depth(d, static, 2.0)
    assert loose[0, 1] and not loose[0, 2]


def test_stable_depth_is_the_same_on_every_row_whatever_the_row_chunks():
    """The four pixels above, each row of a 37-row stack scaled by its own factor: every row's
    median is its factor times (10, 12.5, NaN-or-8, 7) and its stability the same, whether
    computed 16 rows at a time (chunks ending inside the stack), 1 row or all at once."""
    from staticdepth.pseudo_labels import stable_depth

    base = np.array([[10.0, 10.1, 9.9, 10.0], [5.0, 20.0, 5.0, 20.0], [8.0] * 4,
                     [7.0, 7.0, 30.0, 7.0]], np.float32).T          # (F, 4)
    k = np.linspace(0.5, 3.0, 37).astype(np.float32)
    d = base[:, None, :] * k[None, :, None]                         # (F, 37, 4)
    static = np.ones(d.shape, bool)
    static[:3, :, 2] = False
    static[2, :, 3] = False
    for rows in (16, 1, 64):
        med, ok = stable_depth(d, static, 0.03, rows=rows)
        assert ok.tolist() == [[True, False, False, True]] * 37
        np.testing.assert_allclose(med[:, 0], 10.0 * k, rtol=1e-6)
        np.testing.assert_allclose(med[:, 1], 12.5 * k, rtol=1e-6)
        np.testing.assert_allclose(med[:, 3], 7.0 * k, rtol=1e-6)


def test_trusted_label_keeps_the_base_or_drops_untrusted_pixels():
    """Trusted pixels: the network is 2 / A + 0.5 there except one outlier -> the robust map
    recovers (2, 0.5) and labels every trusted pixel 2 / A (the outlier too: shift-free);
    untrusted pixels take the network's value less its shift 0.5 (NaN where that is <= 0) or
    NaN."""
    from staticdepth.pseudo_labels import trusted_label

    rng = np.random.default_rng(0)
    A = rng.uniform(2.0, 40.0, (6, 8)).astype(np.float32)
    inv = (2.0 / A + 0.5).astype(np.float32)
    inv[0, 0] += 3.0                                  # an outlier the fit drops
    trusted = np.ones(A.shape, bool)
    trusted[3:, 5:] = False
    inv[~trusted] = rng.uniform(0.1, 1.0, np.count_nonzero(~trusted))
    got = trusted_label(inv, A, trusted, "base")
    np.testing.assert_allclose(got[trusted], 2.0 / A[trusted], rtol=1e-5)
    above = ~trusted & (inv > 0.5)
    assert 0 < np.count_nonzero(above) < np.count_nonzero(~trusted)
    np.testing.assert_allclose(got[above], inv[above] - 0.5, atol=1e-5)
    assert np.isnan(got[~trusted & ~above]).all()
    dropped = trusted_label(inv, A, trusted, "ignore")
    assert np.isnan(dropped[~trusted]).all()
    np.testing.assert_array_equal(dropped[trusted], got[trusted])
    assert trusted_label(inv, A, np.zeros(A.shape, bool), "base") is None
    assert trusted_label(-inv, A, trusted, "base") is None        # no positive slope
    with pytest.raises(InputError, match="untrusted must be one of"):
        PseudoLabelConfig(untrusted="drop")


def test_untrusted_pixels_keep_the_base_depth():
    """``untrusted="depth"``: untrusted pixels keep the base's depth ``1 / inv`` up to one scale
    a frame, the scale of the trusted labels. A network whose inverse depth is ``2 / A + 0.5``
    on the trusted pixels: the labels there are ``2 / A``; an untrusted pixel the network puts at
    inverse depth 0.6 (depth 1 / 0.6) keeps that depth relative to the others (``inv - t`` would
    make it 1 / 0.1, six times farther), at the scale c = median(2 / A / inv) over the trusted."""
    from staticdepth.pseudo_labels import trusted_label

    rng = np.random.default_rng(1)
    A = rng.uniform(2.0, 40.0, (6, 8)).astype(np.float32)
    inv = (2.0 / A + 0.5).astype(np.float32)
    trusted = np.ones(A.shape, bool)
    trusted[3:, 5:] = False
    inv[~trusted] = rng.uniform(0.55, 1.0, np.count_nonzero(~trusted))
    got = trusted_label(inv, A, trusted, "depth")
    np.testing.assert_allclose(got[trusted], 2.0 / A[trusted], rtol=1e-5)
    c = np.median((2.0 / A[trusted]) / inv[trusted])
    np.testing.assert_allclose(got[~trusted], c * inv[~trusted], rtol=1e-5)
    ratio = got[~trusted] / inv[~trusted]           # the base's depth ratios are kept
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-5)
