"""The image of the vertical, for the ``upright`` alignment (geometry/alignment_upright.py) and
its torch twin: the column step per row down it, a walk up it from every pixel, and how fast a
depth map recedes along it compared with the ground plane's (the recession test that tells ground,
which recedes, from a structure standing on it, which does not).

Pure numpy functions of (K, plane normal, depth maps); no I/O.
"""
from __future__ import annotations

import numpy as np


def down_step(K: np.ndarray, n: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) horizontal pixel shift ``du`` per one row down along the image of the vertical
    direction ``n`` (pointing into the ground) at each pixel; NaN where moving down the vertical
    does not move down the image (beyond the nadir's image row)."""
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy, sk = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = ((np.arange(height) - cy) / fy)[:, None]
    x = (np.arange(width)[None, :] - cx - sk * y) / fx
    dx = n[0] - x * n[2]          # d(normalised coordinates) of P + l n, times Z
    dy = n[1] - y * n[2]
    dv = fy * dy
    du = fx * dx + sk * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(dv > 1e-9, du / np.where(dv > 1e-9, dv, 1.0), np.nan)


def walk_up(du: np.ndarray, n: int, span: int):
    """Walk ``span`` rows up the image's vertical from every pixel of rows ``[0, n)``: per step
    ``j`` = 1..span, the (n, W) rows and columns reached and whether the walk is still inside the
    image (cumulative; the same array is updated in place). ``du`` is :func:`down_step`'s column
    step per row."""
    w = du.shape[1]
    vs = np.arange(n)[:, None]
    u = np.broadcast_to(np.arange(w, dtype=np.float64)[None, :], (n, w)).copy()
    inside = np.ones((n, w), bool)
    for j in range(1, span + 1):
        u = u + np.nan_to_num(du[vs + j - 1, np.clip(np.rint(u), 0, w - 1).astype(np.int64)])
        ui = np.rint(u).astype(np.int64)
        inside &= (ui >= 0) & (ui < w)
        yield vs + j, np.clip(ui, 0, w - 1), inside


def recession(maps, q: np.ndarray, du: np.ndarray, span: int,
              jump_rel: float) -> list[np.ndarray]:
    """Per map of ``maps`` (each (H, W)), how fast the depth grows up the image's vertical
    relative to the plane's: the ratio of the ``ln A`` to the ``ln (1 / q)`` difference over
    ``span`` rows; NaN where that is not measurable or a single row's step exceeds the plane's by
    more than a depth step (``jump_rel``). About 1 on the ground (also where the network has it at
    the wrong depth), 0 or below on a structure standing on it (it gets nearer or stays going up).
    The maps share one walk up the verticals."""
    h, w = q.shape
    outs = [np.full((h, w), np.nan) for _ in maps]
    if span >= h:
        return outs
    n = h - span
    oks = [np.ones((n, w), bool) for _ in maps]
    inside = oks[0]
    a_prev, q_prev = [A[:n] for A in maps], q[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        for rows, ui, inside in walk_up(du, n, span):
            q_j = q[rows, ui]
            plane = (q_j > 0, np.log1p(jump_rel) + np.log(q_j / q_prev))
            for i, A in enumerate(maps):
                a_j = A[rows, ui]
                oks[i] &= plane[0] & (np.log(a_prev[i] / a_j) <= plane[1])
                a_prev[i] = a_j
            q_prev = q_j
        g_pl = np.log(q_prev / q[:n])
        for A, ok, a_end, out in zip(maps, oks, a_prev, outs):
            ok &= inside
            g_net = np.log(A[:n] / a_end)
            out[:n] = np.where(ok & (q[:n] > 0) & (g_pl > 1e-6), g_net / g_pl, np.nan)
    return outs


def receding(maps, q: np.ndarray, du: np.ndarray, span: int, jump_rel: float,
              recede: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool: ``flat`` (on no map of ``maps`` does the pixel or the pixel ``span`` rows
    above it recede: a structure, if the plane's depth snapped it) and ``recedes`` (on some map
    the depth grows up the vertical ``recede`` times as fast as the plane's, measured from above
    at a step)."""
    h, w = q.shape
    vu = np.arange(h)[:, None] - span
    uu = np.clip(np.rint(np.arange(w)[None, :] - span * np.nan_to_num(du)), 0, w - 1)
    flat, recedes = np.ones((h, w), bool), np.zeros((h, w), bool)
    for k in recession(maps, q, du, span, jump_rel):
        k_up = np.where(vu >= 0, k[np.maximum(vu, 0), uu.astype(np.int64)], np.nan)
        k_any = np.where(np.isfinite(k), k, k_up)
        with np.errstate(invalid="ignore"):
            flat &= (k < recede[0]) & ~(k_up >= recede[0])
            recedes |= (k_any >= recede[0]) & (k_any <= recede[1])
    return flat, recedes
