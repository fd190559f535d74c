"""The "ground" alignment mode: align what the plane explains, scale and shift the rest."""
from __future__ import annotations

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry.alignment import align_depth, depth_from_inverse, fit_inverse_affine
from tests.test_alignment import dpt_failure, scene


def _absrel(pred, gt, m):
    return float(np.mean(np.abs(pred[m] - gt[m]) / gt[m]))


def test_scale_and_shift_failure_is_undone_everywhere_walls_included():
    K, n, Z, ground, wall = scene(pitch_deg=30.0, cam_height=5.0)
    pred = depth_from_inverse(dpt_failure(Z, s=3.0, t=0.08))
    g = align_depth(pred, K, n, 5.0, ground, mode="ground", snap_rel=0.0)
    e = align_depth(pred, K, n, 5.0, ground, mode="eq2")
    assert _absrel(g.depth, Z, ground) < 1e-4
    assert _absrel(g.depth, Z, wall) < 1e-3          # the wall keeps its shape: exact
    assert _absrel(e.depth, Z, wall) < 1e-3          # so does Eq. 2 on this pure failure
    s, t, _ = g.plane_normal
    assert s == pytest.approx(3.0, rel=1e-3) and t == pytest.approx(0.08, rel=1e-3)
    # snapping to the plane changes a pixel by at most snap_rel (here the wall's foot)
    g5 = align_depth(pred, K, n, 5.0, ground, mode="ground", snap_rel=0.05)
    change = np.abs(1.0 / g5.depth - 1.0 / g.depth) * g.depth
    assert change.max() <= 0.05 + 1e-4 and change[wall].max() > 0.01


def test_a_correct_prediction_is_only_rescaled():
    K, n, Z, ground, wall = scene(pitch_deg=25.0, cam_height=6.0)
    g = align_depth(Z * 0.37, K, n, 1.0, ground, mode="ground", snap_rel=0.0)
    np.testing.assert_allclose(g.depth * 6.0, Z, rtol=2e-4)
    # Eq. 2 is the same map when the prediction is an exact inverse-affine failure (section 3)
    e = align_depth(Z * 0.37, K, n, 1.0, ground, mode="eq2")
    np.testing.assert_allclose(e.depth * 6.0, Z, rtol=2e-4)


def test_outliers_on_the_ground_do_not_move_the_fit():
    rng = np.random.default_rng(0)
    q = rng.uniform(0.02, 0.3, 2000)
    y = 4.0 * q + 0.1
    y[:300] += rng.uniform(0.2, 1.0, 300)             # 15% of the ground is something else
    s, t = fit_inverse_affine(y, q)
    assert s == pytest.approx(4.0, rel=1e-3) and t == pytest.approx(0.1, rel=1e-2)


def test_ground_mode_errors():
    K, n, Z, ground, _ = scene()
    flipped = (Z.max() - Z + 1).astype(np.float32)       # nearer where the ground is far
    with pytest.raises(InputError, match="recede"):
        fit_inverse_affine(1.0 / flipped[ground], 1.0 / Z[ground])
    a = align_depth(flipped, K, n, 1.0, ground, mode="ground", snap_rel=0.0)
    assert a.plane_normal[2] == 1.0 and np.all(np.isfinite(a.depth)) and np.all(a.depth > 0)
    with pytest.raises(InputError, match="mode"):
        align_depth(Z, K, n, 1.0, ground, mode="nope")
