"""The upright alignment's scans as row-by-row loops: the reference the vectorised ones
(``geometry/alignment_upright.py``: ``contact_ratios``, ``occluded_runs``, ``fill_along_rows``,
pointer doubling and cumulative sums) must equal exactly (tests/test_upright_scans.py) and are
timed against (benchmarks/bench_upright_scans.py). They are the library's own former code, kept
here only as that reference."""
from __future__ import annotations

import numpy as np


def contact_ratios_loop(A: np.ndarray, ground: np.ndarray, q: np.ndarray, du: np.ndarray,
                   jump_rel: float, cut: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """March every row from the bottom up: each non-ground pixel inherits the contact of the
    pixel below it on its vertical line when their depths are continuous (and ``cut``, (H, W)
    bool an edge between a pixel and the one below, is not set), or becomes a contact when that
    pixel is ground. Returns (H, W) the contact's plane inverse depth ``qc`` and the
    contact's flat pixel index (NaN / -1 where a pixel has no contact)."""
    h, w = A.shape
    qc = np.full((h, w), np.nan, np.float64)
    idx = np.full((h, w), -1, np.int64)
    cols = np.arange(w)
    for v in range(h - 2, -1, -1):
        step = du[v]
        ok = np.isfinite(step) & ~ground[v] & np.isfinite(A[v])
        ub = np.where(ok, np.rint(cols + np.nan_to_num(step)), -1).astype(np.int64)
        ok &= (ub >= 0) & (ub < w)
        ub = np.clip(ub, 0, w - 1)
        below, a_b = ground[v + 1, ub], A[v + 1, ub]
        qv = 0.5 * (q[v] + q[v + 1, ub])
        contact = ok & below & (qv > 0)
        qc[v, contact] = qv[contact]
        idx[v, contact] = v * w + cols[contact]
        with np.errstate(invalid="ignore"):
            cont = ok & ~below & (np.abs(A[v] - a_b) <= jump_rel * np.minimum(A[v], a_b))
        if cut is not None:
            cont &= ~cut[v]
        qc[v, cont] = qc[v + 1, ub[cont]]
        idx[v, cont] = idx[v + 1, ub[cont]]
    return qc, idx


def occluded_runs_loop(A: np.ndarray, occluder: np.ndarray, ground: np.ndarray, du: np.ndarray,
                  jump_rel: float, steps: bool = False,
                  cut: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels whose run (continuous depth down the vertical, not ground) ends on an
    ``occluder`` pixel: whatever stands behind an agent has its foot hidden by it. With
    ``steps``, also those whose run ends at a depth step down to a nearer pixel that is not
    ground: what stands in front hides the foot. With ``cut`` ((H, W) bool, an image edge
    between a pixel and the one below), also those whose run ends at such an edge above a pixel
    that is not ground (the edge of a nearer occluder the network blurred through)."""
    h, w = A.shape
    out = np.zeros((h, w), bool)
    cols = np.arange(w)
    for v in range(h - 2, -1, -1):
        step = du[v]
        ok = np.isfinite(step) & ~ground[v] & ~occluder[v] & np.isfinite(A[v])
        ub = np.where(ok, np.rint(cols + np.nan_to_num(step)), -1).astype(np.int64)
        ok &= (ub >= 0) & (ub < w)
        ub = np.clip(ub, 0, w - 1)
        a_b = A[v + 1, ub]
        hidden = occluder[v + 1, ub]
        with np.errstate(invalid="ignore"):
            cont = ~ground[v + 1, ub] & ~hidden \
                & (np.abs(A[v] - a_b) <= jump_rel * np.minimum(A[v], a_b))
            if steps:
                hidden = hidden | (~ground[v + 1, ub] & (A[v] > (1.0 + jump_rel) * a_b))
            if cut is not None:
                hidden = hidden | (~ground[v + 1, ub] & cut[v])
                cont &= ~cut[v]
        out[v] = ok & (hidden | (cont & out[v + 1, ub]))
    return out


def fill_along_rows_loop(ratio: np.ndarray, A: np.ndarray, todo: np.ndarray,
                         jump_rel: float) -> None:
    """In place: pixels of ``todo`` without a ratio take their left, then right, neighbour's when
    their depths are continuous (one sweep each way)."""
    h, w = A.shape
    for order in (range(1, w), range(w - 2, -1, -1)):
        for u in order:
            prev = u - 1 if order.step == 1 else u + 1
            with np.errstate(invalid="ignore"):
                m = (todo[:, u] & ~np.isfinite(ratio[:, u]) & np.isfinite(ratio[:, prev])
                     & (np.abs(A[:, u] - A[:, prev]) <= jump_rel * np.minimum(A[:, u], A[:, prev])))
            ratio[m, u] = ratio[m, prev]
