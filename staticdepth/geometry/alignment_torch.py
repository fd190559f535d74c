"""Scene alignment (METHOD.md section 4) in torch operations that export to ONNX.

The function contract is that of :func:`staticdepth.geometry.alignment.align_depth` with no agent
mask and ``near_plane_rel=None``, for a fixed camera whose ground region is known in advance:

    aligned = align_depth(Z, K, n_g, d_g, G).depth

1. Total-least-squares plane of the back-projected points ``P = Z r`` at the ground pixels ``G``
   (the same pixels as the numpy fit: ``G`` in row-major order, an even stride to at most
   ``max_points``): the smallest eigenvector of their 3x3 covariance. No SVD (ONNX has none): the
   adjugate of the covariance has that eigenvector as its dominant one, with the eigenvalue ratio
   ``lambda_min / lambda_mid``; repeated squaring (``2^squarings`` power steps) isolates it.
2. Eq. 2 and the re-projection in closed form: ``Z_new = d_g Z / (C0 + Z L(u, v))`` with ``L``
   affine in the normalised pixel coordinates.
3. Pixels with ``C0 + Z L <= eps d_p`` (above the agents' horizon) keep ``Z`` times the median
   ratio ``Z_new / Z`` over the ground pixels.
The nadir case of the numpy version (a predicted plane facing the camera) is not handled: the
exported graph is for cameras that see the horizon's side of the ground.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn


def ground_indices(ground_mask: np.ndarray, max_points: int = 20000) -> np.ndarray:
    """Flat indices of the ground pixels used by the numpy fit (row-major, stride-subsampled)."""
    idx = np.flatnonzero(np.asarray(ground_mask, bool))
    if len(idx) > max_points:
        idx = idx[::-(-len(idx) // max_points)]
    return idx


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                        a[0] * b[1] - a[1] * b[0]])


def tls_plane(points: torch.Tensor, squarings: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """(n, d) of the total-least-squares plane of (N, 3) points, |n| = 1, d >= 0."""
    c = points.mean(0)
    A = points - c
    C = A.t() @ A
    C = C / (C[0, 0] + C[1, 1] + C[2, 2])
    r0, r1, r2 = C[0], C[1], C[2]
    M = torch.stack([_cross(r1, r2), _cross(r2, r0), _cross(r0, r1)])
    for _ in range(squarings):
        M = M @ M
        M = M / M.abs().max()
    k = torch.argmax(torch.stack([M[0, 0], M[1, 1], M[2, 2]]))
    v = torch.index_select(M, 1, k.reshape(1))[:, 0]
    n = v / torch.sqrt((v * v).sum())
    d = (n * c).sum()
    sign = torch.where(d < 0, -1.0, 1.0).to(n.dtype)
    return n * sign, d * sign


class PlaneAlignment(nn.Module):
    """(H, W) relative depth -> aligned depth in units of ``d_g`` (see the module doc)."""

    def __init__(self, K: np.ndarray, width: int, height: int, n_g, d_g: float,
                 ground_mask: np.ndarray, eps: float = 1e-3, max_points: int = 20000):
        super().__init__()
        K = np.asarray(K, dtype=np.float64)
        fx, fy, cx, cy, sk = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
        y = np.broadcast_to(((np.arange(height) - cy) / fy)[:, None], (height, width))
        x = (np.arange(width)[None, :] - cx - sk * y) / fx
        n_g = np.asarray(n_g, dtype=np.float64)
        n_g = n_g / np.linalg.norm(n_g)
        idx = ground_indices(ground_mask, max_points)
        if len(idx) < 3:
            raise ValueError("the ground region needs at least 3 pixels")
        f32 = torch.float32
        self.register_buffer("x", torch.tensor(x, dtype=f32))
        self.register_buffer("y", torch.tensor(y, dtype=f32))
        self.register_buffer("idx", torch.tensor(idx, dtype=torch.int64))
        rays = np.stack([x.ravel()[idx], y.ravel()[idx], np.ones(len(idx))], 1)
        self.register_buffer("rays", torch.tensor(rays, dtype=f32))
        self.register_buffer("n_g", torch.tensor(n_g, dtype=f32))
        self.d_g = float(d_g)
        self.eps = float(eps)

    def forward(self, Z: torch.Tensor) -> torch.Tensor:
        z_flat = Z.reshape(-1)
        zg = torch.index_select(z_flat, 0, self.idx)
        n_p, d_p = tls_plane(zg[:, None] * self.rays)
        a, b, c = n_p[0], n_p[1], n_p[2]
        s2 = a * a + b * b
        ng0, ng1, ng2 = self.n_g[0], self.n_g[1], self.n_g[2]
        C0 = (ng0 * a + ng1 * b) * d_p / s2
        L = (self.x * ((ng0 * b * b - ng1 * a * b) / s2)
             + self.y * ((ng1 * a * a - ng0 * a * b) / s2)
             + (ng2 - c * (ng0 * a + ng1 * b) / s2))
        denom = C0 + Z * L
        ok = denom > self.eps * d_p
        safe = torch.where(ok, denom, torch.ones_like(denom))
        out = self.d_g * Z / safe
        ratio = torch.index_select((out / Z).reshape(-1), 0, self.idx)
        ok_g = torch.index_select(ok.reshape(-1), 0, self.idx)
        inf = torch.full_like(ratio, float("inf"))
        srt, _ = torch.sort(torch.where(ok_g, ratio, inf))
        k = ok_g.to(torch.int64).sum()
        lo = torch.clamp((k - 1) // 2, min=0)
        med = 0.5 * (torch.gather(srt, 0, lo.reshape(1)) + torch.gather(srt, 0, (k // 2).reshape(1)))
        return torch.where(ok, out, Z * med[0])
