"""Pseudo labels read from the agents' plane in the network's own inverse-depth space."""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.dataset.schema import COCO, empty_agents
from staticdepth.errors import InputError
from staticdepth.geometry.projection import ray_grid
from staticdepth.pseudo_labels import plane_pseudo_label, pseudo_label
from tests.test_alignment import dpt_failure, scene


def _agent_frame():
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    inst = np.zeros(Z.shape, np.uint16)
    inst[50:70, 40:46] = 1                      # a person whose feet are at row 69
    rows = empty_agents(1)
    rows["instance_id"], rows["class_id"] = 1, COCO["person"]
    return K, n, Z, ground, inst, rows


def test_agents_take_the_plane_depth_at_their_contact_in_the_networks_space():
    K, n, Z, ground, inst, rows = _agent_frame()
    # the network sees the person as ground-like blur: its own contact value is off by 30%
    D = dpt_failure(Z, s=3.0, t=0.08)
    D_bad = D.copy()
    D_bad[inst == 1] = D[inst == 1] * 0.7
    q = (ray_grid(K, Z.shape[1], Z.shape[0]) @ n).astype(np.float32)   # plane with d = 1
    label, mask = plane_pseudo_label(D_bad, inst, rows, q * 0.2, ground)
    contact = 3.0 / Z[69, 42] + 0.08            # truth at the contact pixel
    np.testing.assert_allclose(label[inst == 1], contact, rtol=1e-4)
    assert mask.sum() == (inst == 1).sum()
    np.testing.assert_array_equal(label[inst == 0], D_bad[inst == 0])
    own, _ = pseudo_label(D_bad, inst, rows)
    assert abs(own[69, 42] - contact) > 0.2 * contact   # the paper's label inherits the error


def test_ground_labels_and_errors():
    K, n, Z, ground, inst, rows = _agent_frame()
    D = dpt_failure(Z, s=2.0, t=0.05)
    noisy = D * (1 + 0.05 * np.random.default_rng(0).standard_normal(D.shape)).astype(np.float32)
    q = (ray_grid(K, Z.shape[1], Z.shape[0]) @ n).astype(np.float32)
    label, mask = plane_pseudo_label(noisy, inst, rows, q, ground, label_ground=True)
    g = ground & (inst == 0)
    assert mask[g].all()
    np.testing.assert_allclose(label[g], D[g], rtol=0.02)   # the noise is gone on the ground
    with pytest.raises(InputError, match="ground mask"):
        plane_pseudo_label(D, inst, rows, q, np.zeros_like(ground))


def test_aligned_labels_are_the_alignment_in_the_networks_space():
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse
    from staticdepth.pseudo_labels import aligned_pseudo_label

    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    D = dpt_failure(Z, s=3.0, t=0.08)
    D_bad = D.copy()
    D_bad[wall] = 3.0 / (1.5 * Z[wall]) + 0.08         # the network puts the wall 50% too far
    q = (ray_grid(K, Z.shape[1], Z.shape[0]) @ n).astype(np.float32)   # plane with d = 1
    A = align_depth(depth_from_inverse(D_bad), K, n, 1.0, ground, mode="upright").depth
    label, mask = aligned_pseudo_label(D_bad, A, q, ground)
    np.testing.assert_allclose(label[ground], D[ground], rtol=1e-4)
    assert np.mean(np.abs(label[wall] - D[wall]) / D[wall]) < 0.07     # the wall's truth
    assert np.mean(np.abs(D_bad[wall] - D[wall]) / D[wall]) > 0.2
    assert mask[wall].mean() > 0.9 and not mask[ground].any()
    with pytest.raises(InputError, match="ground mask"):
        aligned_pseudo_label(D, A, q, np.zeros_like(ground))
