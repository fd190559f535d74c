"""How many agents a foreground blob holds, from how blobs merge and split over time.

Background subtraction cannot split two agents whose silhouettes touch: the blob's lowest row is
the nearer agent's foot and its top row the farther agent's head, a height that fits no plane.
Counting recovers most of them: a blob that two earlier blobs (each one agent) flow into holds
two (a forward pass), and so does a blob that later splits into two (a backward pass). Pure numpy.

An edge from a blob ``p`` to a blob ``b`` of the next (or previous) frame counts when at least
``min_share`` of ``p``'s pixels fall in ``b`` and ``p`` is at least ``min_height_rel`` as tall as
``b`` (a fragment of one body, e.g. legs cut from the torso where the clothes match the
background, is much shorter than the whole and adds no agent). ``p``'s count is shared among the
blobs it flows into; a blob's count is the sum it receives, at least 1.
"""
from __future__ import annotations

import numpy as np


def overlap_matrix(prev: np.ndarray, cur: np.ndarray, n_prev: int, n_cur: int) -> np.ndarray:
    """(n_prev, n_cur) shared pixels of the components of two label maps (0 = background)."""
    both = (prev > 0) & (cur > 0)
    idx = (prev[both].astype(np.int64) - 1) * n_cur + (cur[both].astype(np.int64) - 1)
    return np.bincount(idx, minlength=n_prev * n_cur).reshape(n_prev, n_cur)


def propagate(counts: np.ndarray, overlap: np.ndarray, area: np.ndarray, height: np.ndarray,
              next_height: np.ndarray, min_share: float = 0.25,
              min_height_rel: float = 0.5) -> np.ndarray:
    """Counts of the next frame's blobs from this frame's ``counts`` (len = overlap rows),
    ``overlap`` (n, m), this frame's blob areas and heights and the next frame's heights (m,)."""
    n, m = overlap.shape
    if m == 0:
        return np.zeros(0)
    if n == 0:
        return np.ones(m)
    valid = ((overlap >= min_share * area[:, None])
             & (height[:, None] >= min_height_rel * next_height[None, :]))
    succ = np.maximum(valid.sum(1), 1)
    got = (np.where(valid, (counts / succ)[:, None], 0.0)).sum(0)
    return np.maximum(got, 1.0)


def backward_counts(overlaps: list[np.ndarray], areas: list[np.ndarray],
                    heights: list[np.ndarray], **kw) -> np.ndarray:
    """Counts of the first frame's blobs from the frames after it: ``overlaps[k]`` between
    frames k and k+1 (len(areas) - 1 of them), propagated from the last frame back."""
    counts = np.ones(len(areas[-1]))
    for k in range(len(overlaps) - 1, -1, -1):
        counts = propagate(counts, overlaps[k].T, areas[k + 1], heights[k + 1], heights[k], **kw)
    return counts
