"""The upright alignment's scans as row-by-row loops: the reference the vectorised ones
(``geometry/alignment_upright.py``: ``contact_ratios``, ``occluded_runs``, ``fill_along_rows``,
pointer doubling and cumulative sums) must equal exactly (tests/test_upright_scans.py). They are
the library's own former code, kept here only as that reference (the speed of versions:
benchmarks/bench_align_versions.py against the tree before them)."""
from __future__ import annotations

import numpy as np


def contact_ratios_loop(A, ground, q, du, jump_rel, cut=None):
    """``contact_ratios`` as it was: every row marched from the bottom up, each pixel taking
    the contact of the pixel below it (continuous depth) or becoming one (ground below)."""
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


def occluded_runs_loop(A, occluder, ground, du, jump_rel, steps=False, cut=None):
    """``occluded_runs`` as it was: each row from the bottom up, a run hidden where it ends on
    an occluder (with ``steps``: a step down to a nearer pixel; with ``cut``: an image edge)."""
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


def fill_along_rows_loop(ratio, A, todo, jump_rel):
    """``fill_along_rows`` as it was: one column at a time, left then right, in place."""
    h, w = A.shape
    for order in (range(1, w), range(w - 2, -1, -1)):
        for u in order:
            prev = u - 1 if order.step == 1 else u + 1
            with np.errstate(invalid="ignore"):
                m = (todo[:, u] & ~np.isfinite(ratio[:, u]) & np.isfinite(ratio[:, prev])
                     & (np.abs(A[:, u] - A[:, prev]) <= jump_rel * np.minimum(A[:, u], A[:, prev])))
            ratio[m, u] = ratio[m, prev]
