"""The paper's Eq. 1: pixel height as an affine function of the foot position (METHOD.md section 2).

An upright agent of height H with its foot at depth Z is taken to have pixel height h = f H / Z;
with the ground plane ``n . P = d`` this gives ``a x + b y + c f = d h / H``. Two solvers:

- :func:`plane_paper`: the paper's least squares with c = 1, ``[x, y, -h] . [a, b, k] = -f``;
- :func:`plane_affine`: the equivalent, better-conditioned regression ``h = alpha x + beta y +
  gamma``, n ∝ (alpha fx/fy, beta, gamma/fy).

Both are biased for a tilted camera (the agent is not parallel to the image plane); the exact
cylinder model of :mod:`staticdepth.geometry.agent_plane` starts from them.
"""
from __future__ import annotations

import math

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.projection import rays_from_pixels

LINEAR_MODELS = ("affine", "paper")


def _centered(K: np.ndarray, u, v) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets from the principal point in row pixels: x = (u - cx) fy/fx, y = v - cy."""
    r = rays_from_pixels(K, u, v)
    return r[:, 0] * K[1, 1], r[:, 1] * K[1, 1]


def plane_paper(K: np.ndarray, u, v, h) -> tuple[np.ndarray, float]:
    """The paper's Eq. 1 with c = 1: solve ``[x, y, -h] . [a, b, k] = -f``; returns (n, d/H).

    u, v, h: (N,) foot pixels and pixel heights. n = (a, b, 1)/|.|, d/H = k / |(a, b, 1)|.
    """
    x, y = _centered(K, u, v)
    A = np.stack([x, y, -np.asarray(h, dtype=np.float64)], axis=1)
    sol, *_ = np.linalg.lstsq(A, -np.full(len(x), K[1, 1]), rcond=None)
    a, b, k = sol
    s = math.sqrt(a * a + b * b + 1.0)
    return np.array([a, b, 1.0]) / s, float(k / s)


def plane_affine(K: np.ndarray, u, v, h) -> tuple[np.ndarray, float]:
    """Regression ``h = alpha x + beta y + gamma``; n ∝ (alpha fx/fy, beta, gamma/fy) (in row
    pixels x is already scaled by fy/fx, so n ∝ (alpha, beta, gamma/fy)); returns (n, d/H)."""
    x, y = _centered(K, u, v)
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    (al, be, ga), *_ = np.linalg.lstsq(A, np.asarray(h, dtype=np.float64), rcond=None)
    m = np.array([al, be, ga / K[1, 1]])
    s = float(np.linalg.norm(m))
    if s < 1e-12:
        raise InputError("pixel heights do not vary with position: no ground plane")
    return m / s, 1.0 / s


def fit_linear(K: np.ndarray, u, v, h, model: str = "affine") -> tuple[np.ndarray, float]:
    """(n, d/H) by ``model`` ("affine" or "paper"), n oriented so that d/H > 0.

    Raises InputError when the heights carry no plane (d/H zero or not finite).
    """
    if model not in LINEAR_MODELS:
        raise InputError(f"unknown linear ground-plane model {model!r} (use "
                         f"{', '.join(LINEAR_MODELS)})")
    fit = plane_paper if model == "paper" else plane_affine
    n, d_over_h = fit(np.asarray(K, dtype=np.float64), u, v, h)
    if d_over_h < 0:
        n, d_over_h = -n, -d_over_h
    if d_over_h == 0 or not np.isfinite(d_over_h) or not np.all(np.isfinite(n)):
        raise InputError("pixel heights do not vary with position: no ground plane")
    return n, d_over_h


def vertical_from_axes(K: np.ndarray, foot_uv: np.ndarray, top_uv: np.ndarray,
                       iters: int = 5) -> np.ndarray | None:
    """The ground normal (3,) (camera frame, towards the ground) from upright agents' head-foot
    axes alone: every axis lies in a plane through the camera centre that contains the vertical,
    so with ``m_i = foot ray x top ray`` the vertical is the direction most nearly orthogonal to
    all ``m_i`` (their vanishing point). Unnormalised ``m_i`` weigh long axes more (pixel noise
    turns their direction less); a few Huber-reweighted passes resist off-axis detections.
    foot_uv, top_uv: (N, 2) pixels. None with fewer than 5 finite axes."""
    ok = np.all(np.isfinite(foot_uv), 1) & np.all(np.isfinite(top_uv), 1)
    if ok.sum() < 5:
        return None
    f = rays_from_pixels(K, foot_uv[ok, 0], foot_uv[ok, 1])
    M = np.cross(f, rays_from_pixels(K, top_uv[ok, 0], top_uv[ok, 1]))
    w = np.ones(len(M))
    for _ in range(iters):
        n = np.linalg.svd(M * w[:, None], full_matrices=False)[2][-1]
        r = np.abs(M @ n)
        scale = 1.4826 * float(np.median(r)) + 1e-12
        w = np.sqrt(np.minimum(1.0, 1.5 * scale / np.maximum(r, 1e-300)))
    return n if np.median(f @ n) > 0 else -n
