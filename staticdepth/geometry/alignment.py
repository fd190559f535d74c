"""Scene alignment (METHOD.md section 4): move a prediction's ground onto the agents' plane.

1. Back-project the prediction ``P = Z r`` and fit its ground plane ``a X + b Y + c Z = d_p`` by
   total least squares inside a ground mask (agents' pixels removed).
2. Eq. 2 moves every point within its depth slice onto that plane, and the re-projection onto the
   agents' plane ``n_g . P = d_g`` is, in closed form, ``Z_new = d_g Z / (n_g . P_g)``.
Because ``P_g`` is affine in Z with pixel-affine coefficients, ``n_g . P_g = C0 + Z L(u, v)`` with
``L`` affine in (u, v): the whole map costs a few float32 array operations.

The result does not depend on the prediction's global scale and is in the units of ``d_g`` (metres
when ``d_g`` is the camera height). Pixels where ``n_g . P_g <= eps d_p`` (above the agents'
horizon) keep their depth times the median ratio ``Z_new / Z`` over the ground mask.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from staticdepth.errors import InputError
from staticdepth.geometry.alignment_upright import KEEP_REL, AlignCamera, align_camera
from staticdepth.geometry.plane import fit_plane


def depth_from_inverse(inverse_depth: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Relative depth ``1 / max(D, eps)`` of a relative inverse depth map (the paper's DPT depth);
    NaN stays NaN."""
    D = np.asarray(inverse_depth, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        return (1.0 / np.maximum(D, np.float32(eps))).astype(np.float32)


def ground_mask_from_feet(foot_uv: np.ndarray, width: int, height: int,
                          erode_px: float = 10.0) -> np.ndarray:
    """The convex hull of the agents' foot points (N, 2), eroded by ``erode_px``, as (H, W) bool.

    Erosion of a convex polygon by a disk is the intersection of its edges' half-planes moved
    inward by the radius. Raises when the points span no area.
    """
    uv = np.asarray(foot_uv, dtype=np.float64).reshape(-1, 2)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    if len(uv) < 3:
        raise InputError(f"a ground mask from feet needs at least 3 foot points, got {len(uv)}")
    try:
        hull = ConvexHull(uv)
    except QhullError:
        raise InputError("the foot points are collinear: they cover no ground area") from None
    u = np.arange(width, dtype=np.float32)[None, :]
    v = np.arange(height, dtype=np.float32)[:, None]
    mask = np.ones((height, width), bool)
    for a, b, c in hull.equations:          # a u + b v + c <= 0 inside, (a, b) unit
        mask &= (np.float32(a) * u + np.float32(b) * v + np.float32(c + erode_px)) <= 0
    if not mask.any():
        raise InputError(f"the feet's hull eroded by {erode_px} px leaves no ground pixel")
    return mask


def ground_mask_from_polygon(vertices, width: int, height: int) -> np.ndarray:
    """Pixels (H, W) bool whose centre (integer u, v) lies inside the polygon (N, 2) of (u, v)
    vertices (even-odd rule; a pixel centre exactly on an edge may fall either side).

    Raises for fewer than 3 finite vertices, a polygon without area or one that covers no pixel.
    """
    try:
        P = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    except ValueError:
        raise InputError("ground polygon vertices must be (u, v) pairs") from None
    if len(P) < 3 or not np.all(np.isfinite(P)):
        raise InputError(f"a ground polygon needs at least 3 finite (u, v) vertices, got {len(P)}")
    x, y = P[:, 0], P[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    if area < 1e-9:
        raise InputError("the ground polygon has no area (its vertices are collinear)")
    u = np.arange(width, dtype=np.float64)[None, :]
    v = np.arange(height, dtype=np.float64)[:, None]
    inside = np.zeros((height, width), bool)
    for (x1, y1), (x2, y2) in zip(P, np.roll(P, -1, axis=0)):
        rows = (y1 > v[:, 0]) != (y2 > v[:, 0])           # the edge crosses these rows
        if not rows.any():
            continue
        vr = v[rows]
        x_cross = x1 + (vr - y1) * (x2 - x1) / (y2 - y1)
        inside[rows] ^= u < x_cross
    if not inside.any():
        raise InputError(f"the ground polygon covers no pixel of the {width}x{height} image")
    return inside


def ground_mask_from_semantics(labels: np.ndarray, ground_labels=(1,)) -> np.ndarray:
    """Ground mask (H, W) bool from a ground-truth semantic or boolean map: pixels whose label is
    one of ``ground_labels`` (a boolean map: its true pixels). Raises when none is ground."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise InputError(f"a semantic map must be 2-D (H, W), got shape {lab.shape}")
    mask = lab if lab.dtype == bool else np.isin(lab, list(ground_labels))
    if not mask.any():
        raise InputError(f"the semantic map has no ground pixel (labels {list(ground_labels)})")
    return mask


def fit_predicted_plane(depth: np.ndarray, K: np.ndarray, mask: np.ndarray,
                        max_points: int = 20000) -> tuple[np.ndarray, float]:
    """TLS plane (n_p, d_p) of the back-projected prediction inside ``mask`` (H, W bool).

    At most about ``max_points`` pixels (an even stride over the mask) are used. Raises when
    fewer than 3 valid depths lie in the mask or they are collinear.
    """
    depth = np.asarray(depth)
    vs, us = np.nonzero(np.asarray(mask, bool) & np.isfinite(depth) & (depth > 0))
    if len(vs) < 3:
        raise InputError(f"the ground mask holds {len(vs)} valid predicted depths (need >= 3)")
    vs, us = _strided(vs, us, max_points)
    K = np.asarray(K, dtype=np.float64)
    z = depth[vs, us].astype(np.float64)
    x = (us - K[0, 2] - K[0, 1] * (vs - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (vs - K[1, 2]) / K[1, 1]
    return fit_plane(np.stack([x * z, y * z, z], axis=1))


@dataclass(frozen=True, eq=False)
class Alignment:
    """One aligned frame: ``depth`` (H, W) float32 in units of d_g (NaN where the input was), the
    predicted plane, the fallback ratio and how many pixels used it, and ``skipped`` (nadir)."""

    depth: np.ndarray
    plane_normal: np.ndarray
    plane_d: float
    fallback_ratio: float
    n_fallback: int
    skipped: bool


ALIGN_MODES = ("ground", "eq2", "upright")


def align_depth(depth: np.ndarray, K: np.ndarray, n_g, d_g: float, ground_mask: np.ndarray, *,
                agent_mask: np.ndarray | None = None, near_plane_rel: float | None = None,
                eps: float = 1e-3, nadir_tol: float = 1e-6, mode: str = "eq2",
                snap_rel: float = 0.1, jump_rel: float = 0.08,
                shape: str = "network", recede: tuple[float, float] | None = (0.1, 8.0),
                fill: bool = True, max_pull: float = np.inf, contact_range: float | None = None,
                recede_push: float = np.inf, walked_ratio: float = np.inf,
                plane_bound: bool = False, extra_ground: np.ndarray | None = None,
                keep_rel: float | None = KEEP_REL, occlude: bool = False,
                step_occlude: bool = False, image: np.ndarray | None = None,
                info: dict | None = None, camera: AlignCamera | None = None) -> Alignment:
    """Align a relative depth map (H, W) to the agents' ground plane ``n_g . P = d_g``.

    ground_mask: (H, W) bool where the ground is expected; ``agent_mask`` pixels are removed from
    it and, with ``near_plane_rel``, aligned together with pixels whose back-projection lies
    within ``near_plane_rel * d_p`` of the predicted plane (every other pixel is only rescaled by
    the median ratio). ``eps`` is relative to d_p. A nadir prediction (a_p = b_p = 0) is rescaled
    by the median ratio of the agents' plane depth over the ground and flagged ``skipped``.
    Raises InputError for an empty ground mask (also after removing the agents), too few valid
    depths in it, a non-finite or zero ``n_g``, a ``d_g`` that is not positive, or when no ground
    pixel can be aligned; the output is never a map of NaN where the input had depths.
    ``extra_ground``, ``keep_rel``, ``occlude``, ``step_occlude``, ``image``, ``info``: the
    upright mode's
    (``align_upright``). ``camera``: the :class:`AlignCamera` of (``K``, the map's size, ``n_g``
    and ``d_g`` as given here; ``image`` when it holds one) that a sequence's frames share, else
    built here; its :meth:`~AlignCamera.normalised` camera goes on to the modes.
    """
    Z = np.asarray(depth, dtype=np.float32)
    if Z.ndim != 2:
        raise InputError(f"a depth map must be 2-D (H, W), got shape {Z.shape}")
    h, w = Z.shape
    K = np.asarray(K, dtype=np.float64)
    n_g = np.asarray(n_g, dtype=np.float64)
    if n_g.shape != (3,) or not np.all(np.isfinite(n_g)) or np.linalg.norm(n_g) < 1e-12:
        raise InputError(f"the agents' plane normal must be a finite non-zero 3-vector, got {n_g}")
    if not (np.isfinite(d_g) and d_g > 0):
        raise InputError(f"the agents' plane offset (camera height) must be positive, got {d_g}")
    cam = align_camera(camera, K, n_g, d_g, w, h)
    n_g = n_g / np.linalg.norm(n_g)
    G = np.asarray(ground_mask, bool)
    if G.shape != Z.shape:
        raise InputError(f"ground mask shape {G.shape} differs from the prediction's {Z.shape}")
    if not G.any():
        raise InputError("the ground mask is empty")
    if agent_mask is not None:
        A = np.asarray(agent_mask, bool)
        if A.shape != Z.shape:
            raise InputError(f"agent mask shape {A.shape} differs from the prediction's {Z.shape}")
        G = G & ~A
        if not G.any():
            raise InputError("the ground mask is empty once the agents' pixels are removed")
    if mode not in ALIGN_MODES:
        raise InputError(f"alignment mode must be one of {ALIGN_MODES}, got {mode!r}")
    if mode == "ground":
        return align_ground(Z, K, n_g, d_g, G, snap_rel=snap_rel, camera=cam.normalised())
    if mode == "upright":
        return align_upright(Z, K, n_g, d_g, G, snap_rel=snap_rel, jump_rel=jump_rel, shape=shape,
                             agent_mask=agent_mask, recede=recede, fill=fill, max_pull=max_pull,
                             contact_range=contact_range, recede_push=recede_push,
                             walked_ratio=walked_ratio, plane_bound=plane_bound,
                             extra_ground=extra_ground, keep_rel=keep_rel, occlude=occlude,
                             step_occlude=step_occlude, image=image, info=info,
                             camera=cam.normalised())
    n_p, d_p = fit_predicted_plane(Z, K, G)
    a, b, c = n_p
    s2 = a * a + b * b
    fx, fy, cx, cy, sk = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = ((np.arange(h) - cy) / fy)[:, None]
    x = (np.arange(w)[None, :] - cx - sk * y) / fx
    valid = np.isfinite(Z) & (Z > 0)
    if s2 < nadir_tol:
        rays_ng = (cam.rays @ n_g).astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(rays_ng > 0, d_g / (rays_ng * Z), np.nan)
        r = _median_ratio(ratio, G & valid)
        return Alignment(Z * np.float32(r), n_p, d_p, r, int(valid.sum()), True)
    # n_g . P_g = C0 + Z L(u, v), L = x Ax + y Ay + C1 (Eq. 2 expanded)
    C0 = (n_g[0] * a + n_g[1] * b) * d_p / s2
    L = (x * ((n_g[0] * b * b - n_g[1] * a * b) / s2)
         + y * ((n_g[1] * a * a - n_g[0] * a * b) / s2)
         + (n_g[2] - c * (n_g[0] * a + n_g[1] * b) / s2)).astype(np.float32)
    denom = np.float32(C0) + Z * L
    ok = valid & (denom > eps * d_p)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.float32(d_g) * Z / denom
    if near_plane_rel is not None:
        dist = np.abs(Z * (np.float32(a) * x.astype(np.float32) + np.float32(b) * y.astype(np.float32)
                           + np.float32(c)) - np.float32(d_p))
        move = dist < near_plane_rel * d_p
        if agent_mask is not None:
            move |= np.asarray(agent_mask, bool)
        ok &= move
    with np.errstate(divide="ignore", invalid="ignore"):
        r = _median_ratio(out / Z, G & ok)
    fb = valid & ~ok
    out = np.where(ok, out, Z * np.float32(r))
    out[~valid] = np.nan
    return Alignment(out.astype(np.float32, copy=False), n_p, d_p, r, int(fb.sum()), False)


# the ground mode's shift t puts the network's inverse depth t at infinity: where more than this
# share of the pixels below the agents' horizon (each ray meets the ground at a finite depth) lies
# beyond it (1/Z <= t), the fit contradicts the map it aligns and only a scale is fitted (a
# fine-tuned U-Net whose facades fell behind its compressed ground: h2, finetune.seed=1, 16% of
# them, ft-align 0.313; none on the 14 runs of i1-i4 / h1-h3; 0.2-2.1% in
# tests/test_alignment_torch.py's scenes, whose plane is another than the map's; issue 19,
# seventeenth round)
BEYOND_SHARE = 0.05
FAR_REL = 50.0      # the far limit: this x the median plane depth over the ground


def _strided(vs: np.ndarray, us: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates thinned by an even stride to at most about ``max_points``."""
    if len(vs) > max_points:
        step = -(-len(vs) // max_points)
        vs, us = vs[::step], us[::step]
    return vs, us


def fit_inverse_affine(inv: np.ndarray, target: np.ndarray, iters: int = 3,
                       k_mad: float = 3.0) -> tuple[float, float]:
    """Robust least squares ``inv ~ s target + t`` (1-D arrays): refits after dropping residuals
    beyond ``k_mad`` MADs. Raises when the targets do not vary or the slope is not positive."""
    x = np.asarray(target, dtype=np.float64)
    y = np.asarray(inv, dtype=np.float64)
    keep = np.isfinite(x) & np.isfinite(y)
    s = t = float("nan")
    for _ in range(iters):
        if keep.sum() < 3 or np.ptp(x[keep]) <= 0:
            raise InputError("the ground mask spans no range of plane depths: no scale and shift")
        A = np.stack([x[keep], np.ones(int(keep.sum()))], 1)
        s, t = np.linalg.lstsq(A, y[keep], rcond=None)[0]
        res = np.abs(y - (s * x + t))
        mad = np.median(res[keep]) + 1e-12
        keep = keep & (res <= k_mad * 1.4826 * mad)
    if not s > 0:
        raise InputError(f"the prediction's ground does not recede like the agents' plane "
                         f"(inverse-depth slope {s:.3g}): cannot align")
    return float(s), float(t)


def align_ground(depth: np.ndarray, K: np.ndarray, n_g, d_g: float, ground_mask: np.ndarray, *,
                 snap_rel: float = 0.1, max_points: int = 20000,
                 camera: AlignCamera | None = None) -> Alignment:
    """Align only what the plane explains; carry the rest with the ground's scale and shift.

    The network's inverse depth ``1/Z`` is, on the ground mask, fitted robustly as ``s q + t``
    with ``q = n_g . r / d_g`` the agents' plane's inverse depth: the unknown scale and shift of a
    MiDaS-like output (METHOD.md section 3: the shift is what tilts the predicted ground). Every
    pixel then gets ``(1/Z - t) / s``: structures keep the network's shape, only re-scaled and
    re-shifted like its ground. Pixels whose corrected inverse depth lies within ``snap_rel`` of
    the plane's (the ground the network saw as ground) take the plane's depth exactly. Pixels the
    correction pushes beyond the far limit (50x the median ground depth) are clamped there.
    When the network's ground has no positive slope against the plane (it does not recede), or
    the shift would put more than :data:`BEYOND_SHARE` of the pixels below the agents' horizon
    beyond infinity (``1/Z <= t``), only a scale is fitted (median ratio, t = 0).
    ``plane_normal``/``plane_d`` of the result hold
    (s, t, 1 if scale only else 0) and the far limit, for the summary. ``camera``: the
    :class:`AlignCamera` of (``K``, the map's size, ``n_g``, ``d_g``), else built here.
    """
    h, w = np.shape(depth)
    return _ground_fit(depth, ground_mask, snap_rel, max_points,
                       align_camera(camera, K, n_g, d_g, w, h))[0]


def align_upright(depth: np.ndarray, K: np.ndarray, n_g, d_g: float, ground_mask: np.ndarray, *,
                  snap_rel: float = 0.1, jump_rel: float = 0.08, shape: str = "network",
                  agent_mask: np.ndarray | None = None, max_points: int = 20000,
                  recede: tuple[float, float] | None = (0.1, 8.0), fill: bool = True,
                  max_pull: float = np.inf, contact_range: float | None = None,
                  recede_push: float = np.inf, walked_ratio: float = np.inf,
                  plane_bound: bool = False, extra_ground: np.ndarray | None = None,
                  keep_rel: float | None = KEEP_REL, occlude: bool = False,
                  step_occlude: bool = False, edge_below: np.ndarray | None = None,
                  image: np.ndarray | None = None, info: dict | None = None,
                  camera: AlignCamera | None = None) -> Alignment:
    """The ``ground`` mode, then every structure above the ground re-anchored at its contact with
    it (geometry/alignment_upright.py). The frame's agents (``agent_mask``) are never ground.
    ``n_fallback`` counts the pixels that were not re-anchored (neither ground nor traced to it).
    ``plane_bound``: no pixel below the agents' horizon ends farther than the plane along its
    ray (the ground is infinite: whatever a pixel sees below the horizon stands in front of the
    ground there, or is it), ``min(depth, d_g / (n_g . r))``.
    ``extra_ground``/``keep_rel``/``occlude``/``step_occlude``/``edge_below``/``image``/``info``:
    see ``upright_depth`` (pixels known to be ground by another cue; runs already standing at their
    contact kept, None: off; runs end at the frame's agents; runs cut by a nearer depth step, or
    by an image edge (benchmarks/bench_edge_stops.py), filled along rows; traced pixels whose
    colour runs on below their contact placed at their colour foot; per-pixel categories
    for diagnostics, here also ``snapped``, the ``ground_mode`` map and
    ``raw``, the map the runs are traced on). ``camera``: the :class:`AlignCamera` of (``K``,
    the map's size, ``n_g``, ``d_g``; ``image`` when it holds one), else built here.
    """
    from staticdepth.geometry.alignment_upright import upright_depth

    h, w = np.shape(depth)
    cam = align_camera(camera, K, n_g, d_g, w, h)
    g, snap, q, raw = _ground_fit(depth, ground_mask, snap_rel, max_points, cam)
    if agent_mask is not None:
        snap = snap & ~np.asarray(agent_mask, bool)
    Z = np.asarray(depth, dtype=np.float32)
    both = np.isfinite(raw) & np.isfinite(Z) & (Z > 0)
    # the network's own depth, brought to the aligned map's units (its shape is what is kept)
    unit = float(np.median((raw[both] / Z[both])[:: max(1, int(both.sum()) // max_points)])) \
        if both.any() else 1.0
    max_contact = np.inf
    if contact_range is not None:       # x the farthest plane depth over the ground mask
        qg = q[np.asarray(ground_mask, bool) & (q > 0)]
        max_contact = float(contact_range / qg.min()) if qg.size else np.inf
    new, moved = upright_depth(raw, K, n_g, d_g, snap, q, jump_rel=jump_rel, shape=shape,
                               recede=recede, native=Z * np.float32(unit), fill=fill,
                               max_pull=max_pull, max_contact=max_contact,
                               recede_push=recede_push, walked=np.asarray(ground_mask, bool),
                               walked_ratio=walked_ratio, info=info,
                               extra_ground=extra_ground, keep_rel=keep_rel, occlude=occlude,
                               step_occlude=step_occlude, edge_below=edge_below, image=image,
                               not_ground=None if agent_mask is None
                               else np.asarray(agent_mask, bool), camera=cam)
    valid = np.isfinite(g.depth)
    out = np.where(moved, new, g.depth)
    if plane_bound:
        with np.errstate(divide="ignore"):
            out = np.where(q > 0, np.minimum(out, np.float32(1.0) / np.where(q > 0, q, 1)), out)
    out[~valid] = np.nan
    if info is not None:
        info.update(snapped=snap, ground_mode=g.depth, raw=raw)
    return Alignment(out, g.plane_normal, g.plane_d, g.fallback_ratio,
                     int(np.count_nonzero(valid & ~snap & ~moved)), False)


def _ground_fit(depth, ground_mask, snap_rel, max_points, camera):
    """align_ground's work on the plane of ``camera`` (an AlignCamera of the map's size):
    (Alignment, (H, W) bool snapped pixels, (H, W) plane inverse depth, (H, W) depth before
    snapping)."""
    Z = np.asarray(depth, dtype=np.float32)
    q = camera.q
    valid = np.isfinite(Z) & (Z > 0)
    with np.errstate(divide="ignore"):
        inv = np.where(valid, 1.0 / np.where(valid, Z, 1), np.nan).astype(np.float32)
    sel = ground_mask & valid & (q > 0)
    vs, us = np.nonzero(sel)
    if len(vs) < 3:
        raise InputError("no ground pixel can be aligned (the ground mask lies above the agents' "
                         "horizon or holds no valid depth)")
    vs, us = _strided(vs, us, max_points)
    try:
        s, t = fit_inverse_affine(inv[vs, us], q[vs, us])
        below = valid & (q > 0)     # the shift refuted by the map itself (BEYOND_SHARE)
        scale_only = bool(np.count_nonzero(below & (inv - np.float32(t) <= 0))
                          > BEYOND_SHARE * max(np.count_nonzero(below), 1))
    except InputError:      # no usable slope (a network whose ground does not recede)
        scale_only = True
    if scale_only:
        s, t = float(np.median(inv[vs, us] / q[vs, us])), 0.0
    new_inv = (inv - np.float32(t)) / np.float32(s)
    floor = np.float32(np.median(q[vs, us]) / FAR_REL)
    snap = valid & (q > 0) & (np.abs(new_inv - q) <= np.float32(snap_rel) * q)
    n_fb = int(np.count_nonzero(valid & ~snap & (new_inv < floor)))
    new_inv = np.maximum(new_inv, floor)
    raw = np.where(valid, 1.0 / new_inv, np.nan).astype(np.float32)
    out = np.where(valid, 1.0 / np.where(snap, q, new_inv), np.nan).astype(np.float32)
    return (Alignment(out, np.array([s, t, float(scale_only)]), float(1.0 / floor), float("nan"),
                      n_fb, False), snap, q, raw)


def agents_at_contact(depth: np.ndarray, K: np.ndarray, n_g, d_g: float, instances: np.ndarray,
                      rows: np.ndarray, conf=None, heights=None,
                      camera: AlignCamera | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Give each agent the agents' plane depth ``d_g / (n_g . r)`` at its ground contact pixel.

    Eq. 2 moves every point within its depth slice onto the predicted plane, which distorts
    upright agents; like the pseudo labels (METHOD.md section 1: contact pixel, riders take their
    vehicle's value, accessories the nearest person's) every pixel of an agent takes one depth,
    here the plane's at the contact. depth: (H, W) aligned map in units of d_g; instances: (H, W)
    instance ids; rows: the frame's AGENT_DTYPE rows; conf: a PseudoLabelConfig (default paper).
    ``heights`` (a :class:`~staticdepth.geometry.agent_contact.PersonHeights`): people whose
    mask ends on another agent or at the image's bottom row, with their top seen, take the
    contact their top and height give (``agent_contact.contacts_from_top``) instead of the
    plane's depth at their lowest pixel, which lies behind them. Agents whose contact lies above
    the agents' horizon keep their depth. ``camera``: the :class:`AlignCamera` of (``K``, the
    map's size, ``n_g``, ``d_g``), else built here. Returns the new map and the (H, W) bool mask
    of changed pixels.
    """
    from staticdepth.geometry.agent_contact import contacts_from_top
    from staticdepth.pseudo_labels import PRESETS, pseudo_label

    Z = np.asarray(depth, dtype=np.float32)
    h, w = Z.shape
    n_g = np.asarray(n_g, dtype=np.float64)
    inv_plane = align_camera(camera, K, n_g, d_g, w, h).q
    conf = conf or PRESETS["paper"]
    contacts = None if heights is None else contacts_from_top(K, n_g, d_g, instances, rows,
                                                              heights, inv_plane, conf)
    label, mask = pseudo_label(inv_plane, instances, rows, conf, contacts=contacts)
    mask &= label > 0
    out = Z.copy()
    out[mask] = 1.0 / label[mask]
    out[~np.isfinite(Z)] = np.nan
    return out, mask & np.isfinite(Z)


def _median_ratio(ratio: np.ndarray, where: np.ndarray, max_points: int = 20000) -> float:
    vals = ratio[where]
    if len(vals) > max_points:
        vals = vals[::-(-len(vals) // max_points)]
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if len(vals) == 0:
        raise InputError("no ground pixel can be aligned (the ground mask lies above the agents' "
                         "horizon or holds no valid depth)")
    return float(np.median(vals))


#: share of the walked ground's pixels whose R^2 :func:`ground_fit_r2` takes: the 20% farthest
#: from a first least-squares line are left out (an undetected object, a shadow, a parked car)
R2_KEEP = 0.8


def ground_fit_r2(depth: np.ndarray, ground_mask: np.ndarray, camera: AlignCamera,
                  max_points: int = 20000) -> float:
    """How much of the prediction's ground the agents' plane explains: the share of the
    variance of its inverse depth ``1/Z`` over ``ground_mask`` (valid pixels below the agents'
    horizon) that the least-squares line ``1/Z ~ s q + t`` explains, ``q`` the plane's inverse
    depth (``camera.q``), over the :data:`R2_KEEP` (80%) of the pixels nearest a first line
    through them all. 1 for a network that sees that ground as the plane up to a scale and a
    shift (the scale and shift every alignment mode fits), near 0 for one whose ground is noise;
    a line that falls (the ground nearer up the image) and a ground of one depth (a network
    saturated there) count as 0. NaN when fewer than 3 pixels or no range of ``q`` remain.
    Without the trim, a near patch on 10% of the walked ground took trained networks from
    0.43-0.97 to 0.00-0.23, under ``align.min_ground_r2``; with it 0.67-0.99 clean, 0.40-0.97
    with the patch, 0.32-0.97 with 20% (docs/gains.md, twentieth round)."""
    Z = np.asarray(depth, dtype=np.float64)
    q = camera.q
    sel = np.asarray(ground_mask, bool) & np.isfinite(Z) & (Z > 0) & (q > 0)
    vs, us = np.nonzero(sel)
    vs, us = _strided(vs, us, max_points)
    x, y = q[vs, us].astype(np.float64), 1.0 / Z[vs, us]
    for trim in (True, False):
        if len(x) < 3 or np.ptp(x) <= 0:
            return float("nan")
        if np.ptp(y) <= 0:
            return 0.0
        if trim:
            A = np.stack([x, np.ones_like(x)], 1)
            r = np.abs(y - A @ np.linalg.lstsq(A, y, rcond=None)[0])
            keep = r <= np.quantile(r, R2_KEEP)
            x, y = x[keep], y[keep]
    c = np.cov(x, y)
    if c[0, 1] <= 0:
        return 0.0
    return float(c[0, 1] ** 2 / (c[0, 0] * c[1, 1]))


def plane_depth(camera: AlignCamera, ground_mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 the agents' plane's depth along every ray (units of the camera's ``d``);
    rays that meet it beyond the far limit, :data:`FAR_REL` (50) x the median plane depth over
    ``ground_mask`` (the ground mode's clamp), and those at or above its horizon take that limit:
    the scene as the plane alone describes it, with no network."""
    q = camera.q
    sel = np.asarray(ground_mask, bool) & (q > 0)
    if not sel.any():
        raise InputError("no ground pixel lies below the agents' horizon: no plane depth")
    floor = np.float32(np.median(q[sel]) / FAR_REL)
    return (1.0 / np.maximum(q, floor)).astype(np.float32)
