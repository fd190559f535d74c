"""The exportable torch alignment against the numpy one (geometry/alignment.py) as it is, in both
modes (eq2, ground)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from staticdepth.geometry.alignment import align_depth, ground_mask_from_polygon
from staticdepth.geometry.alignment_torch import PlaneAlignment, tls_plane
from staticdepth.geometry.camera import normal_from_pitch_roll
from staticdepth.geometry.plane import fit_plane, plane_depth_map

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")   # the ONNX exporter's


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
    # Every pixel compared in inverse depth, where the alignment is linear: near the horizon Eq. 2's
    # depth 1 / (a D + b) amplifies float32 rounding (seed 2: a 3714 m pixel 0.3% apart in depth,
    # 4e-6 of the median in inverse depth; it passed or failed with the numpy build).
    inv_err = np.abs(1 / out - 1 / ref) / np.median(1 / ref)
    assert np.median(rel) < 1e-4 and inv_err.max() < 1e-4, (np.median(rel), inv_err.max())


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


def _ground_ref(Z, K, n_g, G, snap_rel):
    a = align_depth(Z, K, n_g, 1.0, G, mode="ground", snap_rel=snap_rel)
    return a.depth, a.plane_normal


@pytest.mark.parametrize("seed,snap_rel", [(0, 0.1), (1, 0.0), (2, 0.05)])
def test_torch_ground_mode_matches_numpy(seed, snap_rel):
    """Each frame has its own scale and shift (the fit runs in the graph), with outliers on the
    ground that the trimmed passes must drop the same way."""
    from staticdepth.geometry.alignment_torch import GroundAlignment

    Z, K, n_g, G = _scene(seed)
    mod = GroundAlignment(K, Z.shape[1], Z.shape[0], n_g, 1.0, G, snap_rel=snap_rel)
    rng = np.random.default_rng(seed + 10)
    fits = []
    for s_f, t_f in [(1.0, 0.0), (2.5, 0.03), (0.4, -0.01)]:
        inv = s_f / Z + t_f
        inv[G & (rng.random(Z.shape) < 0.1)] *= 1.6                 # 10% outliers on the ground
        Zf = (1.0 / inv).astype(np.float32)
        ref, (s, t, scale_only) = _ground_ref(Zf, K, n_g, G, snap_rel)
        assert scale_only == 0.0
        fits.append((s, t))
        out = mod(torch.from_numpy(Zf)).numpy()
        rel = np.abs(out - ref) / ref
        assert np.median(rel) < 1e-5 and np.mean(rel > 1e-3) < 1e-3, (np.median(rel), rel.max())
    assert len({round(s, 3) for s, _ in fits}) == 3           # the fit did change per frame


def test_torch_ground_mode_scale_only_fallback():
    """A prediction whose ground does not recede: the numpy version falls back to a median
    scale; the graph selects the same branch."""
    from staticdepth.geometry.alignment_torch import GroundAlignment

    Z, K, n_g, G = _scene(4)
    flipped = (Z.max() - Z + 1).astype(np.float32)
    ref, (_, _, scale_only) = _ground_ref(flipped, K, n_g, G, 0.1)
    assert scale_only == 1.0
    out = GroundAlignment(K, Z.shape[1], Z.shape[0], n_g, 1.0, G)(torch.from_numpy(flipped))
    rel = np.abs(out.numpy() - ref) / ref
    assert np.median(rel) < 1e-5 and rel.max() < 1e-3


@pytest.mark.parametrize("share,scale_only", [(0.04, 0.0), (0.06, 1.0)])
def test_ground_mode_refuses_a_shift_that_puts_the_map_beyond_infinity(share, scale_only):
    """The fit ``1/Z ~ s q + t`` puts inverse depth t at infinity; pixels below the horizon at
    ``1/Z <= t`` (a band of far structures the network put behind its compressed ground) are
    beyond it. Up to BEYOND_SHARE (5%) of them the shift stays; past it, scale only (the median of
    ``(1/Z) / q`` on the ground, closed form), in numpy and in the graph alike."""
    from staticdepth.geometry.alignment import fit_inverse_affine
    from staticdepth.geometry.alignment_torch import GroundAlignment
    from staticdepth.geometry.projection import ray_grid

    Z, K, n_g, G = _scene(1)
    h, w = Z.shape
    q = (ray_grid(K, w, h) @ n_g).astype(np.float32)
    inv = (1.0 / Z).astype(np.float32)
    on = G & (q > 0)
    s, t = fit_inverse_affine(inv[on], q[on])
    below = q > 0
    # the highest rows below the horizon outside the ground mask, up to the share wanted
    cand = np.flatnonzero((below & ~G & (inv > t)).ravel())     # not beyond infinity already
    n_beyond = int(np.count_nonzero(below & (inv <= t)))
    k = int(share * np.count_nonzero(below)) - n_beyond
    band = np.zeros(h * w, bool)
    band[cand[:k]] = True
    inv2 = inv.copy()
    inv2[band.reshape(h, w)] = np.float32(0.5 * t)
    Z2 = (1.0 / inv2).astype(np.float32)
    ref, (s_ref, t_ref, only) = _ground_ref(Z2, K, n_g, G, 0.1)
    assert only == scale_only
    if scale_only:
        s_med = float(np.median(inv2[on] / q[on]))
        assert s_ref == pytest.approx(s_med, rel=1e-6) and t_ref == 0.0
        far = band.reshape(h, w) & (np.abs(inv2 / s_med - q) > 0.1 * q)
        assert far.any()
        np.testing.assert_allclose(ref[far], s_med * Z2[far], rtol=1e-5)
    else:
        assert s_ref == pytest.approx(s, rel=1e-6) and t_ref == pytest.approx(t, rel=1e-6)
    out = GroundAlignment(K, w, h, n_g, 1.0, G)(torch.from_numpy(Z2)).numpy()
    rel = np.abs(out - ref) / ref
    assert np.median(rel) < 1e-5 and np.mean(rel > 1e-3) < 1e-3, (np.median(rel), rel.max())


def test_ground_mode_exports_to_onnx(tmp_path):
    import onnxruntime as ort

    from staticdepth.geometry.alignment_torch import alignment_module

    Z, K, n_g, G = _scene(5)
    mod = alignment_module("ground", K, Z.shape[1], Z.shape[0], n_g, 1.0, G, snap_rel=0.1)
    path = str(tmp_path / "g.onnx")
    torch.onnx.export(mod, (torch.from_numpy(Z),), path, input_names=["z"], opset_version=17,
                      dynamo=False)
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    for s_f, t_f in [(1.0, 0.0), (3.0, 0.05)]:
        Zf = (1.0 / (s_f / Z + t_f)).astype(np.float32)
        ref = _ground_ref(Zf, K, n_g, G, 0.1)[0]
        got = sess.run(None, {"z": Zf})[0]
        rel = np.abs(got - ref) / ref
        assert np.median(rel) < 1e-5 and np.mean(rel > 1e-3) < 1e-3
    with pytest.raises(ValueError, match="mode"):
        alignment_module("nope", K, Z.shape[1], Z.shape[0], n_g, 1.0, G)
