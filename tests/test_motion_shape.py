"""The motion detector's shape test on long sequences: the running median of the upright
regions' aspect ratios is exact (the same decisions as keeping every ratio), holds one count per
distinct ratio, and carries nothing from one sequence to the next."""
from __future__ import annotations

import numpy as np
import pytest

from motion_scenes import ExactMotion, LongScene, box_sizes
from staticdepth.detectors.motion import MotionDetector, RunningMedian, median_background


def same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """Identical agent rows, bit for bit (the unset fields are NaN in both)."""
    return a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_running_median_is_np_median_of_everything_added():
    rng = np.random.default_rng(3)
    med, seen = RunningMedian(), []
    assert np.isnan(med.median())
    for size in [1, 0, 2, 5, 1, 30, 7, 0, 64, 3] * 4:
        h = rng.integers(2, 40, size)
        v = rng.integers(1, h) / h                      # w / h with w < h, many repeats
        med.add(v)
        seen.append(v)
        every = np.concatenate(seen)
        if len(every):
            assert med.median() == np.median(every)     # exact: odd and even counts
    assert med.n == len(every)
    np.testing.assert_array_equal(med.values, np.unique(every))
    med.add(np.array([np.nan, np.inf]))                 # not counted
    assert med.n == len(every)


class Keeping(MotionDetector):
    """The detector as it is, keeping its last sequence's running median to look at."""

    def aspect_statistic(self) -> RunningMedian:
        self.stats = super().aspect_statistic()
        return self.stats


def test_long_run_decides_as_the_exact_median_with_bounded_state():
    n = 800
    frames = LongScene(n)
    exact, det = ExactMotion(), Keeping()
    got = list(det.detect_sequence(frames))
    ref = list(exact.detect_sequence(frames))
    assert len(got) == len(ref) == n
    n_upright, odd, kept = 0, 0, 0
    for (inst, rows), (inst_ref, rows_ref) in zip(got, ref):
        np.testing.assert_array_equal(inst, inst_ref)
        assert same_rows(rows, rows_ref)                    # tolerance 0: scores included
        for r in rows:
            vs, us = np.nonzero(inst == r["instance_id"])
            w, h = us.max() - us.min() + 1, vs.max() - vs.min() + 1
            assert (w, h) in box_sizes()                    # the rendered boxes, exactly
            n_upright += w < h
            odd += r["score"] < 1
            kept += r["score"] == 1
    # the shape test decides both ways: the pair (aspect >= 0.62) and the thinnest walkers
    # (<= 0.5 x the median) are doubtful, the other walkers are kept
    assert odd > n and kept > n
    # one count per distinct ratio, not per region: at most the ratios of the scene's boxes
    possible = {w / h for w, h in box_sizes() if w < h}
    assert det.stats.n == n_upright == 3 * n
    assert set(det.stats.values) <= possible and len(possible) < 40
    assert det.stats.median() == np.median(np.concatenate(exact.stats.values))


def test_no_state_leaks_between_sequences():
    a, b = LongScene(150, seed=0), LongScene(120, seed=5)
    alone_a = list(MotionDetector().detect_sequence(a))
    alone_b = list(MotionDetector().detect_sequence(b))
    det = MotionDetector()
    for k, (x, y) in enumerate(zip(det.detect_sequence(a), det.detect_sequence(b))):
        for got, want in ((x, alone_a[k]), (y, alone_b[k])):
            np.testing.assert_array_equal(got[0], want[0])
            assert same_rows(got[1], want[1])
    again = list(det.detect_sequence(b))                  # after another sequence: the same
    assert all(same_rows(r1, r2) for (_, r1), (_, r2) in zip(again, alone_b))
    with pytest.raises(IndexError):
        a[150]


def test_median_background_in_strips_is_the_whole_median():
    rng = np.random.default_rng(7)
    frames = [rng.integers(0, 256, (200, 400, 3), dtype=np.uint8) for _ in range(50)]
    # 50 x 400 x 3 samples a row: strips of 69 rows, the last one shorter
    want = np.median(np.stack(frames), axis=0).astype(np.uint8)
    np.testing.assert_array_equal(median_background(frames), want)
