"""Timestamp pairing and stream statistics (staticdepth.capture.sync)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from staticdepth.capture.sync import (LEFT, RIGHT, NearestPairer, pair_nearest, stream_summary,
                                      timestamp_gaps)

P = 1 / 30  # frame period
TOL = P / 2


def test_identical_clocks_pair_one_to_one():
    t = [k * P for k in range(20)]
    pairs, ul, ur = pair_nearest(t, t, TOL)
    assert pairs == [(k, k) for k in range(20)] and (ul, ur) == (0, 0)


def test_constant_offset_below_half_period_pairs_all():
    left = [k * P for k in range(20)]
    right = [k * P + 0.4 * P for k in range(20)]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    assert pairs == [(k, k) for k in range(20)] and (ul, ur) == (0, 0)


def test_offset_above_half_period_pairs_with_the_next_frame():
    # Right lags by 0.7 periods: its frame k is nearest to left frame k + 1 (0.3 P away).
    left = [k * P for k in range(20)]
    right = [k * P + 0.7 * P for k in range(20)]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    assert pairs == [(k + 1, k) for k in range(19)]
    assert (ul, ur) == (1, 1)  # left 0 has no partner, right 19 has none either


def test_missing_frames_are_counted_not_mispaired():
    left = [k * P for k in range(30)]
    missing = {5, 6, 17}
    right_idx = [k for k in range(30) if k not in missing]
    right = [k * P + 0.001 for k in right_idx]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    assert pairs == [(k, j) for j, k in enumerate(right_idx)]
    assert (ul, ur) == (3, 0)


def test_late_burst_pairs_with_nearest_and_counts_the_rest():
    # Right frames 10-12 arrive 0.6 P late (a USB hiccup). Left 10 then has no right frame within
    # P/2; right 10 and 11 are 0.4 P from left 11 and 12; right 12 (12.6 P) loses left 13 to
    # right 13, which is exactly on time.
    left = [k * P for k in range(20)]
    right = [k * P + (0.6 * P if 10 <= k <= 12 else 0.0) for k in range(20)]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    expected = [(k, k) for k in range(10)] + [(11, 10), (12, 11)] + [(k, k) for k in range(13, 20)]
    assert pairs == expected and (ul, ur) == (1, 1)
    assert all(abs(left[i] - right[j]) <= TOL for i, j in pairs)


def test_backwards_timestamps_raise():
    p = NearestPairer(TOL)
    p.push(LEFT, 1.0)
    with pytest.raises(ValueError, match="backwards"):
        p.push(LEFT, 0.5)


def test_max_pending_drops_oldest_of_a_stalled_pair():
    p = NearestPairer(TOL, max_pending=4)
    for k in range(10):
        assert p.push(LEFT, k * P, k) == []
    assert p.unpaired == [6, 0]
    out = p.push(RIGHT, 9 * P, "r")
    # Left 6, 7, 8 can no longer pair (right frames only come later); 9 pairs.
    assert [(a, b) for a, b, _, _ in out] == [(9, "r")]
    assert p.unpaired == [9, 0]


def _brute_force(left, right, tol):
    """Independent reference: repeatedly take, in time order of the earlier frame, mutual nearest
    free frames within tol (the pairer's rule, written as a global search)."""
    free_l, free_r = set(range(len(left))), set(range(len(right)))
    pairs = []
    while True:
        best = None
        for i in sorted(free_l):
            cands = [j for j in free_r if abs(left[i] - right[j]) <= tol]
            if not cands:
                continue
            j = min(cands, key=lambda j: (abs(left[i] - right[j]), j))
            back = min((k for k in free_l if abs(left[k] - right[j]) <= tol),
                       key=lambda k: (abs(left[k] - right[j]), k))
            if back == i:
                key = min(left[i], right[j])
                if best is None or key < best[0]:
                    best = (key, i, j)
        if best is None:
            break
        _, i, j = best
        pairs.append((i, j))
        free_l.discard(i)
        free_r.discard(j)
    return sorted(pairs), len(free_l), len(free_r)


def _jittered(periods):
    return list(np.cumsum(periods))


@settings(max_examples=200, deadline=None)
@given(dl=st.lists(st.floats(0.8 * P, 1.2 * P), max_size=25),
       dr=st.lists(st.floats(0.8 * P, 1.2 * P), max_size=25), off=st.floats(-0.05, 0.05))
def test_pairing_matches_reference_with_realistic_jitter(dl, dr, off):
    # Frame intervals within +-20 % of the period (USB cameras, host timestamps).
    left, right = _jittered(dl), [t + off for t in _jittered(dr)]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    ref_pairs, ref_ul, ref_ur = _brute_force(left, right, TOL)
    assert sorted(pairs) == ref_pairs and (ul, ur) == (ref_ul, ref_ur)


@settings(max_examples=200, deadline=None)
@given(dl=st.lists(st.floats(0.0, 2 * P), max_size=25),
       dr=st.lists(st.floats(0.0, 2 * P), max_size=25), off=st.floats(-0.05, 0.05))
def test_pairing_invariants_with_wild_jitter(dl, dr, off):
    left, right = _jittered(dl), [t + off for t in _jittered(dr)]
    pairs, ul, ur = pair_nearest(left, right, TOL)
    assert 2 * len(pairs) + ul + ur == len(left) + len(right)
    assert all(abs(left[i] - right[j]) <= TOL for i, j in pairs)
    assert len({i for i, _ in pairs}) == len(pairs) == len({j for _, j in pairs})
    assert [j for _, j in sorted(pairs)] == sorted(j for _, j in pairs)  # order kept


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_online_result_does_not_depend_on_arrival_interleaving(seed):
    rng = np.random.default_rng(seed)
    left = list(np.cumsum(rng.uniform(0.015, 0.05, 30)))
    right = list(np.cumsum(rng.uniform(0.015, 0.05, 30)))
    expected = pair_nearest(left, right, TOL)
    # Arrival order: random interleaving that keeps each camera's own order.
    order = rng.permutation([LEFT] * 30 + [RIGHT] * 30)
    p = NearestPairer(TOL, max_pending=100)
    idx = [0, 0]
    got = []
    for side in order:
        t = (left, right)[side][idx[side]]
        got += [(a, b) for a, b, _, _ in p.push(side, t, idx[side])]
        idx[side] += 1
    got += [(a, b) for a, b, _, _ in p.flush()]
    assert sorted(got) == sorted(expected[0])
    assert tuple(p.unpaired) == expected[1:]


def test_timestamp_gaps_and_summary():
    t = [k * P for k in range(10)] + [12 * P + k * P for k in range(10)]  # frames 10, 11 missing
    assert timestamp_gaps(t) == [(10, pytest.approx(3 * P))]
    s = stream_summary(t, 30.0)
    assert s["frames"] == 20 and s["gaps"] == 1 and s["missing_frames_estimate"] == 2
    assert s["duration_s"] == pytest.approx(21 * P)
    assert s["achieved_fps"] == pytest.approx(19 / (21 * P))
    assert stream_summary([1.0])["achieved_fps"] is None
