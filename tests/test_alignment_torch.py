"""The exportable torch alignment against the numpy one (geometry/alignment.py) as it is."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from staticdepth.geometry.alignment import align_depth, ground_mask_from_polygon
from staticdepth.geometry.alignment_torch import PlaneAlignment, tls_plane
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import fit_plane, plane_depth_map


def _scene(seed: int, w: int = 160, h: int = 80):
    """A prediction whose ground is tilted the way METHOD.md section 3 says (inverse depth with
    a shift), with objects above the ground and noise."""
    rng = np.random.default_rng(seed)
    K = np.array([[100.0, 0, w / 2 - 0.5], [0, 100.0, h / 2 + 3], [0, 0, 1]])
    n_true = normal_from_pitch_roll(rng.uniform(15, 40), rng.uniform(-5, 5))
    Zt = plane_depth_map(K, n_true, 4.0, w, h)
    Zt = np.where(np.isfinite(Zt) & (Zt > 0), Zt, 60.0)
    Zt[10:30, 40:60] = 12.0                                  # a building
    D = 2.0 / Zt + 0.05                                       # relative inverse depth, shifted
    D *= np.exp(rng.normal(0, 0.01, D.shape))
    Z = (1 / D).astype(np.float32)
    G = ground_mask_from_polygon([(10, h - 1), (w - 10, h - 1), (w - 40, h // 2 + 8),
                                  (40, h // 2 + 8)], w, h)
    n_g = normal_from_pitch_roll(rng.uniform(15, 40), rng.uniform(-5, 5))
    return Z, K, n_g, G


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_torch_alignment_matches_numpy(seed):
    Z, K, n_g, G = _scene(seed)
    ref = align_depth(Z, K, n_g, 1.0, G).depth
    mod = PlaneAlignment(K, Z.shape[1], Z.shape[0], n_g, 1.0, G)
    out = mod(torch.from_numpy(Z)).numpy()
    rel = np.abs(out - ref) / ref
    assert np.median(rel) < 1e-4 and rel.max() < 2e-3, (np.median(rel), rel.max())


def test_tls_plane_matches_svd():
    rng = np.random.default_rng(3)
    n = np.array([0.1, 0.9, 0.4]) / np.linalg.norm([0.1, 0.9, 0.4])
    uv = rng.uniform(-5, 5, (500, 2))
    e1 = np.cross(n, [1, 0, 0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    P = 3.0 * n + uv[:, :1] * e1 + uv[:, 1:] * e2 + rng.normal(0, 0.02, (500, 1)) * n
    n_ref, d_ref = fit_plane(P)
    n_t, d_t = tls_plane(torch.tensor(P, dtype=torch.float32))
    assert np.allclose(n_t.numpy(), n_ref, atol=1e-5) and abs(float(d_t) - d_ref) < 1e-4
