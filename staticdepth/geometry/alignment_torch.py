"""Scene alignment (METHOD.md section 4) in torch operations that export to ONNX.

The function contract is that of :func:`staticdepth.geometry.alignment.align_depth` with no agent
mask and ``near_plane_rel=None``, for a fixed camera whose ground region is known in advance, in
both modes (:func:`alignment_module` picks the class):

    aligned = align_depth(Z, K, n_g, d_g, G, mode=mode, snap_rel=snap_rel).depth

Both assume every input depth is valid (finite, > 0), as ``1 / max(D, eps)`` of a finite network
output is: the ground pixels used by the fits are then constants of the camera.

``mode="eq2"`` (:class:`PlaneAlignment`, the paper's Eq. 2):

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

``mode="ground"`` (:class:`GroundAlignment`, :func:`~staticdepth.geometry.alignment.align_ground`):
the per-frame robust fit ``1/Z ~ s q + t`` on the ground pixels is the numpy one's three least
squares passes in closed form (centred sums, the 3-MAD trimming between passes as a mask, masked
medians by sorting), with its scale-only fallback (median of ``(1/Z) / q``, ``t = 0``) selected
in the graph when a pass has < 3 points or no range of ``q`` or the slope is not positive, or when
the shift puts more than ``alignment.BEYOND_SHARE`` of the pixels below the horizon beyond
infinity (``1/Z <= t``); then
``(1/Z - t) / s``, the snap to the plane within ``snap_rel`` and the far clamp at 50x the median
ground depth (a constant: ``q`` and the ground pixels are).
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from staticdepth.geometry.alignment import BEYOND_SHARE, FAR_REL


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


def masked_median(x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """``np.median(x[keep])`` of a 1-D tensor (the mean of the two middle values for an even
    count); +inf when nothing is kept."""
    srt, _ = torch.sort(torch.where(keep, x, torch.full_like(x, float("inf"))))
    k = keep.to(torch.int64).sum()
    lo = torch.clamp((k - 1) // 2, min=0)
    hi = (k // 2).reshape(1)
    return 0.5 * (torch.gather(srt, 0, lo.reshape(1)) + torch.gather(srt, 0, hi))[0]


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
        return torch.where(ok, out, Z * masked_median(ratio, ok_g))


def fit_inverse_affine(inv: torch.Tensor, target: torch.Tensor, iters: int = 3,
                       k_mad: float = 3.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`staticdepth.geometry.alignment.fit_inverse_affine` on 1-D tensors without raising:
    (s, t, ok) with ``ok`` false where the numpy version raises (then ``s, t`` are meaningless)."""
    x, y = target, inv
    keep = torch.isfinite(x) & torch.isfinite(y)
    x0, y0 = torch.where(keep, x, torch.zeros_like(x)), torch.where(keep, y, torch.zeros_like(y))
    ok = torch.ones((), dtype=torch.bool)
    s = t = torch.zeros(())
    inf = torch.full_like(x, float("inf"))
    for _ in range(iters):
        w = keep.to(x.dtype)
        n = w.sum()
        ptp = torch.where(keep, x0, -inf).max() - torch.where(keep, x0, inf).min()
        ok = ok & (n >= 3) & (ptp > 0)
        n1 = torch.clamp(n, min=1.0)
        mx, my = (w * x0).sum() / n1, (w * y0).sum() / n1
        dx = x0 - mx
        s = (w * dx * (y0 - my)).sum() / (w * dx * dx).sum()
        t = my - s * mx
        res = torch.abs(y - (s * x + t))
        mad = masked_median(res, keep) + 1e-12
        keep = keep & (res <= k_mad * 1.4826 * mad)
    return s, t, ok & (s > 0)


class GroundAlignment(nn.Module):
    """(H, W) relative depth -> depth in units of ``d_g`` by the ground mode (module doc)."""

    def __init__(self, K: np.ndarray, width: int, height: int, n_g, d_g: float,
                 ground_mask: np.ndarray, snap_rel: float = 0.1, max_points: int = 20000):
        super().__init__()
        from staticdepth.geometry.projection import ray_grid

        n_g = np.asarray(n_g, dtype=np.float64)
        q = (ray_grid(np.asarray(K, dtype=np.float64), width, height)
             @ (n_g / (np.linalg.norm(n_g) * d_g))).astype(np.float32)
        idx = ground_indices(np.asarray(ground_mask, bool) & (q > 0), max_points)
        if len(idx) < 3:
            raise ValueError("the ground region needs at least 3 pixels below the horizon")
        qg = q.ravel()[idx]
        self.register_buffer("q", torch.from_numpy(q))
        self.register_buffer("idx", torch.tensor(idx, dtype=torch.int64))
        self.register_buffer("qg", torch.from_numpy(qg))
        self.floor = float(np.float32(np.median(qg) / FAR_REL))
        self.snap_rel = float(np.float32(snap_rel))

    def forward(self, Z: torch.Tensor) -> torch.Tensor:
        return self.parts(Z)[0]

    def parts(self, Z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(aligned depth, (H, W) bool snapped pixels, depth before snapping)."""
        inv = 1.0 / Z
        ig = torch.index_select(inv.reshape(-1), 0, self.idx)
        s, t, ok = fit_inverse_affine(ig, self.qg)
        s_fb = masked_median(ig / self.qg, torch.ones_like(ig, dtype=torch.bool))
        q = self.q
        # the shift refuted by the map itself (alignment.BEYOND_SHARE): scale only
        below = (q > 0) & torch.isfinite(inv) & (Z > 0)
        beyond = (below & (inv - t <= 0)).sum()
        ok = ok & (beyond.to(torch.float32) <= BEYOND_SHARE
                   * torch.clamp(below.sum(), min=1).to(torch.float32))
        s = torch.where(ok, s, s_fb)
        t = torch.where(ok, t, torch.zeros_like(t))
        new_inv = (inv - t) / s
        snap = (q > 0) & (torch.abs(new_inv - q) <= self.snap_rel * q)
        far = torch.clamp(new_inv, min=self.floor)
        return 1.0 / torch.where(snap, q, far), snap, 1.0 / far


def alignment_module(mode: str, K: np.ndarray, width: int, height: int, n_g, d_g: float,
                     ground_mask: np.ndarray, *, eps: float = 1e-3, snap_rel: float = 0.1,
                     image: np.ndarray | None = None, **upright) -> nn.Module:
    """The exportable twin of ``align_depth(..., mode=mode, snap_rel=snap_rel, image=image,
    **upright)`` (``upright``: the upright mode's keywords, ``image`` its colour foot's static
    scene; geometry/alignment_upright_torch.py)."""
    if image is not None and mode != "upright":
        raise ValueError(f"the colour foot (image) is the upright mode's, not {mode!r}'s")
    if mode == "eq2":
        return PlaneAlignment(K, width, height, n_g, d_g, ground_mask, eps=eps)
    if mode == "ground":
        return GroundAlignment(K, width, height, n_g, d_g, ground_mask, snap_rel=snap_rel)
    if mode == "upright":
        from staticdepth.geometry.alignment_upright_torch import UprightAlignment

        return UprightAlignment(K, width, height, n_g, d_g, ground_mask, snap_rel=snap_rel,
                                image=image, **upright)
    raise ValueError(f"no exportable alignment for mode {mode!r} (eq2, ground, upright)")
