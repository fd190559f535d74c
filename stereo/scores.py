"""Disparity accuracy against ground truth: bad-N rates and density (Middlebury's measures)."""
from __future__ import annotations

import numpy as np


def disparity_scores(pred: np.ndarray, gt: np.ndarray, thresholds_px=(1.0, 2.0)
                     ) -> dict[str, float]:
    """Scores of ``pred`` against ``gt`` (both (H, W) px, NaN = invalid/unknown), in percent.

    - ``density``: predicted share of the ground-truth pixels;
    - ``bad-N``: share of the pixels with both values whose error exceeds N px (ground-truth
      mode: errors over the prediction's own valid pixels);
    - ``bad-N-all``: share of all ground-truth pixels that are missing or off by more than N px
      (dense mode: a missing value counts as bad).
    """
    pred = np.asarray(pred, dtype=np.float32)
    gt = np.asarray(gt, dtype=np.float32)
    known = np.isfinite(gt)
    both = known & np.isfinite(pred)
    err = np.abs(pred - gt)
    n_known, n_both = max(int(known.sum()), 1), max(int(both.sum()), 1)
    out = {"density": 100.0 * both.sum() / n_known}
    for t in thresholds_px:
        name = f"bad-{t:g}"
        out[name] = 100.0 * float(np.count_nonzero(err[both] > t)) / n_both
        out[f"{name}-all"] = 100.0 * float(np.count_nonzero(~(err[known] <= t))) / n_known
    return out
