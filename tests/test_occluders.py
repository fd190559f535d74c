"""benchmarks/bench_occluders.py: the agents' occlusion bound on a closed-form scene."""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
import bench_occluders  # noqa: E402


def _scene():
    """A static wall 10 m away on a 20x30 image; an agent 6 m away in front of it (rows 4-13,
    columns 5-12) in frame 0, another 8 m away (rows 4-13, columns 13-20) touching it."""
    inst = np.zeros((20, 30), np.int32)
    inst[4:14, 5:13] = 1
    inst[4:14, 13:21] = 2
    depth = np.full((20, 30), 10.0)
    depth[inst == 1], depth[inst == 2] = 6.0, 8.0
    return inst, depth


def test_each_agents_eroded_mask_bounds_the_wall_behind_it():
    inst, depth = _scene()
    bound = bench_occluders.add_to_bound(np.zeros(inst.shape), inst, depth, erode=1)
    # eroded apart: the rims of each agent, even where the two touch, give no bound
    exp = np.zeros(inst.shape)
    exp[5:13, 6:12] = 6.0
    exp[5:13, 14:20] = 8.0
    np.testing.assert_array_equal(bound, exp)
    # a later frame with the first agent farther (7 m) raises its part of the bound; a nearer
    # one (3 m) does not lower it
    later = np.where(inst == 1, 7.0, np.where(inst == 2, 3.0, 10.0))
    bound = bench_occluders.add_to_bound(bound, inst, later, erode=1)
    exp[5:13, 6:12] = 7.0
    np.testing.assert_array_equal(bound, exp)


def test_push_back_moves_only_static_pixels_nearer_than_the_bound():
    inst, depth = _scene()
    bound = bench_occluders.add_to_bound(np.zeros(inst.shape), inst, depth, erode=0)
    wall = np.full(inst.shape, 5.0)          # a prediction that puts the wall at 5 m
    out = bench_occluders.push_back(wall, np.zeros_like(inst), bound)
    np.testing.assert_array_equal(out[inst == 1], 6.0)
    np.testing.assert_array_equal(out[inst == 2], 8.0)
    np.testing.assert_array_equal(out[inst == 0], 5.0)      # never covered: no bound
    # a wall already behind its bound stays; an agent of the evaluated frame is never moved
    far = np.full(inst.shape, 9.0)
    np.testing.assert_array_equal(bench_occluders.push_back(far, np.zeros_like(inst), bound), far)
    now = np.zeros_like(inst)
    now[8, 8] = 3
    out = bench_occluders.push_back(wall, now, bound)
    assert out[8, 8] == 5.0 and out[8, 9] == 6.0
