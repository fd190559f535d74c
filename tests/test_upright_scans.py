"""The upright alignment's scans, vectorised (pointer doubling up the columns' verticals,
cumulative sums along the rows), equal the row-by-row loops they replaced, exactly: on random
maps under cameras from level to steep (rows beyond the nadir's image, NaN depths, cuts), and
end to end on a frame of the independent renderer (tests/indep_scenes.py) with every option that
reaches them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.geometry import alignment_upright as au
from staticdepth.geometry.alignment import align_depth
from staticdepth.geometry.alignment_vertical import down_step
from staticdepth.geometry.projection import ray_grid
from tests.upright_reference import (contact_ratios_loop, fill_along_rows_loop,
                                     occluded_runs_loop)


def _camera(rng, w, h, pitch_deg):
    K = np.array([[0.8 * w, 0, (w - 1) / 2], [0, 0.8 * w, (h - 1) / 2], [0, 0, 1.0]])
    t, r = math.radians(pitch_deg), math.radians(rng.uniform(-5, 5))
    n = np.array([math.sin(r), math.cos(r) * math.cos(t), math.cos(r) * math.sin(t)])
    return K, n


def _maps(seed, w=97, h=61, pitch_deg=30.0):
    """A depth map of smooth stretches and steps (long continuous runs, some NaN), a ground mask
    of blobs, the plane's inverse depth, the verticals' steps and random cut / occluder masks."""
    rng = np.random.default_rng(seed)
    K, n = _camera(rng, w, h, pitch_deg)
    du = down_step(K, n, w, h)
    q = (ray_grid(K, w, h) @ n).reshape(h, w)
    A = 5.0 + np.cumsum(rng.normal(0, 0.02, (h, w)), 0) + np.cumsum(rng.normal(0, 0.02, (h, w)), 1)
    A *= np.where(rng.random((h, w)) < 0.03, rng.uniform(1.2, 2.0, (h, w)), 1.0)  # depth steps
    A[rng.random((h, w)) < 0.01] = np.nan
    blobs = np.cumsum(np.cumsum(rng.random((h, w)) < 0.02, 0), 1) % 3 == 0
    ground = blobs & (np.arange(h)[:, None] > h // 3)
    cut = rng.random((h, w)) < 0.05
    occluder = (rng.random((h, w)) < 0.04) & ~ground
    return A, ground, q, du, cut, occluder


@pytest.mark.parametrize("seed,pitch", [(0, 30.0), (1, 10.0), (2, 55.0), (3, 80.0), (4, 0.0),
                                        (5, 45.0)])
def test_the_scans_equal_the_row_by_row_loops_on_random_maps(seed, pitch):
    A, ground, q, du, cut, occluder = _maps(seed, pitch_deg=pitch)
    if pitch >= 75:
        assert np.isnan(du).any()          # the steep cameras reach rows beyond the nadir
    for jump in (0.02, 0.08, 0.3):
        for c in (None, cut):
            got, ref = au.contact_ratios(A, ground, q, du, jump, c), \
                contact_ratios_loop(A, ground, q, du, jump, c)
            np.testing.assert_array_equal(got[1], ref[1])
            np.testing.assert_array_equal(got[0], ref[0])      # NaN where both have none
            assert (ref[1] >= 0).sum() > 50 and (ref[1] >= 0).sum() < A.size
            for steps in (False, True):
                np.testing.assert_array_equal(
                    au.occluded_runs(A, occluder, ground, du, jump, steps, c),
                    occluded_runs_loop(A, occluder, ground, du, jump, steps, c))
        rng = np.random.default_rng(seed + 100)
        ratio = np.where(rng.random(A.shape) < 0.1, rng.uniform(0.5, 2.0, A.shape), np.nan)
        todo = rng.random(A.shape) < 0.8
        got, ref = ratio.copy(), ratio.copy()
        au.fill_along_rows(got, A, todo, jump)
        fill_along_rows_loop(ref, A, todo, jump)
        np.testing.assert_array_equal(got, ref)
        assert np.isfinite(got).sum() > 1.5 * np.isfinite(ratio).sum()   # chains were filled


def test_the_scans_on_one_row_and_one_column():
    A, ground, q, du, cut, occluder = _maps(7, w=1, h=1)
    for got, ref in zip(au.contact_ratios(A, ground, q, du, 0.08),
                        contact_ratios_loop(A, ground, q, du, 0.08)):
        np.testing.assert_array_equal(got, ref)
    A, ground, q, du, cut, occluder = _maps(8, w=1, h=40)
    for got, ref in zip(au.contact_ratios(A, ground, q, du, 0.08, cut),
                        contact_ratios_loop(A, ground, q, du, 0.08, cut)):
        np.testing.assert_array_equal(got, ref)
    ratio = np.array([[np.nan, 1.0, np.nan, np.nan]])
    au.fill_along_rows(ratio, np.ones((1, 4)), np.ones((1, 4), bool), 0.08)
    np.testing.assert_array_equal(ratio, [[1.0, 1.0, 1.0, 1.0]])


def test_an_independent_scenes_alignment_is_unchanged(tmp_path, monkeypatch):
    from staticdepth.dataset.h5 import SequenceReader
    from tests.indep_scenes import SCENES, write_scene

    path = write_scene(str(tmp_path / "i4.h5"), SCENES[3], frames=2, width=160, height=80)
    with SequenceReader(path) as r:
        Z, inst, left = r.depth(1), r.instances(1), r.left(1)
        K, mount = r.camera.K, r.meta.mounting
    yy = np.linspace(0.0, 1.0, Z.shape[0])[:, None]
    pred = 1.0 / (0.5 / Z + 0.01 + 0.02 * yy)        # a network's inverse-affine, ramped error
    agents = inst > 0
    ground = (np.abs(Z - mount.height_m / (ray_grid(K, 160, 80) @ mount.normal).reshape(80, 160))
              < 0.01 * Z) & ~agents
    ground[: 40] = False                             # the walked region: the near ground only
    image = left / 255.0
    runs = []
    for opts in ({}, {"occlude": True}, {"step_occlude": True, "fill": False},
                 {"occlude": True, "fill": False, "image": image}):
        kw = dict(mode="upright", agent_mask=agents, **opts)
        runs.append(align_depth(pred, K, mount.normal, mount.height_m, ground, **kw).depth)
        with monkeypatch.context() as m:
            m.setattr(au, "contact_ratios", contact_ratios_loop)
            m.setattr(au, "occluded_runs", occluded_runs_loop)
            m.setattr(au, "fill_along_rows", fill_along_rows_loop)
            ref = align_depth(pred, K, mount.normal, mount.height_m, ground, **kw).depth
        np.testing.assert_array_equal(runs[-1], ref)
    # the options reach the scans: they change the result
    assert not np.array_equal(runs[0], runs[1]) and not np.array_equal(runs[1], runs[2])
