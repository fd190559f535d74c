"""The ``upright`` alignment mode (geometry/alignment_upright.py) in torch operations that export
to ONNX: the twin of ``align_depth(Z, K, n_g, d_g, G, mode="upright", ...)`` with no agent mask,
for a fixed camera (every input depth valid, as in alignment_torch.py).

Everything that depends only on the camera and the plane is a constant of the graph: the image of
the vertical through each pixel (``down_step``), hence for every pixel the pixel one row down its
vertical (``nxt``), the pixels the recession is measured over, the plane's inverse depth ``q``.
The numpy version's sequential scans become fixed-size index gathers:

- the march up the rows (``contact_ratios``): each non-ground pixel either is a contact (ground
  below it), links to the pixel below (continuous depth) or ends a run without contact; following
  the links by pointer doubling (``link = link[link]``, ceil(log2 H) times) gives every pixel its
  chain's end, hence its contact;
- the walk of a contact down to the structure's foot (``refine_contacts``): ``max(2, H // 16)``
  steps (then ``2 max(2, H // 16)`` for ``keep_rel``'s walk on) for the contacts only, a
  data-sized index list (NonZero: a few thousand of the H x W pixels; the step count is fixed,
  so the exported graph follows any frame); a walked-over ground pixel takes the contact that
  reached it at the earliest step (ScatterElements: the contacts reaching it at one step share
  the rest of the walk, so their writes are equal);
- the fill along rows (``fill_along_rows``): left then right links, pointer doubling over W;
  with ``step_occlude`` only the runs whose chain ends at a step down to a nearer pixel that is
  not ground (``occluded_runs(..., steps=True)``: the chain's end, read through the same links).
The trust rules (``fill``, ``max_pull``, ``contact_range``, ``recede_push``, ``walked_ratio``),
the colour foot (``image``: the static scene's colours, whose feet are constants of the graph;
geometry/colour_foot_torch.py) and the plane's bound (``plane_bound``: a constant map of the
plane's depth, an elementwise minimum) are those of the numpy version (the walked region is the
ground mask). The arithmetic runs in float64, as the numpy version's does, so that its threshold
decisions (recession, depth steps) come out the same.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from staticdepth.geometry.alignment_torch import GroundAlignment, masked_median
from staticdepth.geometry.alignment_upright import KEEP_REL, RECEDE, SHAPES
from staticdepth.geometry.alignment_vertical import down_step, walk_up
from staticdepth.geometry.colour_foot_torch import ColourFoot
from staticdepth.geometry.projection import ray_grid


def follow(link: torch.Tensor, steps: int) -> torch.Tensor:
    """Each entry of a (N,) pointer array moved to the end of its chain (chains of at most
    ``2 ** steps`` links; an end points at itself)."""
    for _ in range(steps):
        link = torch.index_select(link, 0, link)
    return link


def _doublings(n: int) -> int:
    return max(1, math.ceil(math.log2(max(n, 2))))


def _tables(K, n, w, h, q, span, jump_rel):
    """The camera's constants: pixel below on the vertical, its validity, the recession paths,
    the pixel ``span`` rows up the vertical, the pixel above (for the contact's interpolation)."""
    du = down_step(K, n, w, h)
    cols = np.arange(w)
    N = h * w
    nxt = np.arange(N).reshape(h, w).copy()
    ok_n = np.zeros((h, w), bool)
    for v in range(h - 1):
        ub = np.where(np.isfinite(du[v]), np.rint(cols + np.nan_to_num(du[v])), -1).astype(np.int64)
        ok_n[v] = np.isfinite(du[v]) & (ub >= 0) & (ub < w)
        nxt[v] = (v + 1) * w + np.clip(ub, 0, w - 1)
    nxt, ok_n = nxt.ravel(), ok_n.ravel()
    qf = q.ravel()
    qv = 0.5 * (qf + qf[nxt])
    # the recession: span rows up from each pixel of rows [0, h - span)
    m = max(h - span, 0)
    okr = np.ones((m, w), bool)
    inside = okr
    q_prev = q[:m]
    paths, consts = [], []
    with np.errstate(invalid="ignore", divide="ignore"):
        for rows, ui, inside in walk_up(du, m, span):
            q_j = q[rows, ui]
            c = np.log1p(jump_rel) + np.log(q_j / q_prev)
            okr &= (q_j > 0) & np.isfinite(c)
            paths.append((rows * w + ui).ravel())
            consts.append(np.nan_to_num(c).ravel())
            q_prev = q_j
        okr &= inside
        g_pl = np.log(q_prev / q[:m])
        okr &= (q[:m] > 0) & (g_pl > 1e-6)
    vu = np.arange(h)[:, None] - span
    uu = np.clip(np.rint(cols[None, :] - span * np.nan_to_num(du)), 0, w - 1).astype(np.int64)
    up = (np.maximum(vu, 0) * w + uu).ravel()
    up_ok = np.broadcast_to(vu >= 0, (h, w)).ravel()
    # the pixel above a contact's final position (refine_contacts' interpolation)
    vv = np.repeat(np.arange(h), w)
    uf = np.tile(cols, h)
    av = np.maximum(vv - 1, 0)
    au = np.clip(np.rint(uf - np.nan_to_num(du[av, uf])), 0, w - 1).astype(np.int64)
    return dict(du=du, nxt=nxt, ok_n=ok_n, qv=qv, paths=paths, path_consts=consts,
                rec_ok=okr.ravel(), g_pl=np.nan_to_num(g_pl, nan=1.0).ravel(), m=m, up=up,
                up_ok=up_ok, above=av * w + au, has_above=vv > 0)


class UprightAlignment(nn.Module):
    """(H, W) relative depth -> depth in units of ``d_g`` by the upright mode (module doc)."""

    def __init__(self, K: np.ndarray, width: int, height: int, n_g, d_g: float,
                 ground_mask: np.ndarray, *, snap_rel: float = 0.1, jump_rel: float = 0.08,
                 shape: str = "network", recede: tuple[float, float] | None = RECEDE,
                 max_ratio: float = 4.0, near_rel: float = 0.02, span: int = 3,
                 fill: bool = True, max_pull: float = float("inf"),
                 contact_range: float | None = None, recede_push: float = float("inf"),
                 walked_ratio: float = float("inf"), plane_bound: bool = False,
                 keep_rel: float | None = KEEP_REL, occlude: bool = False,
                 step_occlude: bool = False, image: np.ndarray | None = None,
                 max_points: int = 20000):
        super().__init__()
        del occlude     # runs end at the frame's agents: an exported graph has no agent mask
        if shape not in SHAPES:
            raise ValueError(f"upright alignment shape must be one of {SHAPES}, got {shape!r}")
        self.ground = GroundAlignment(K, width, height, n_g, d_g, ground_mask, snap_rel=snap_rel,
                                      max_points=max_points)
        K = np.asarray(K, dtype=np.float64)
        n = np.asarray(n_g, dtype=np.float64)
        n = n / np.linalg.norm(n)
        q = self.ground.q.numpy().reshape(height, width)        # float32, as the numpy one's
        t = _tables(K, n, width, height, q, span, jump_rel)
        f64, i64 = torch.float64, torch.int64
        N = width * height
        self.h, self.w, self.N = height, width, N
        self.register_buffer("q64", torch.tensor(q.ravel(), dtype=f64))
        self.register_buffer("ar", torch.arange(N, dtype=i64))
        self.register_buffer("nxt", torch.tensor(t["nxt"], dtype=i64))
        self.register_buffer("ok_n", torch.tensor(t["ok_n"]))
        self.register_buffer("contact_ok", torch.tensor(t["ok_n"] & (t["qv"] > 0)))
        self.register_buffer("walk_ok", torch.tensor(t["ok_n"] & (q.ravel()[t["nxt"]] > 0)))
        self.register_buffer("q_nxt", torch.tensor(q.ravel()[t["nxt"]], dtype=f64))
        self.register_buffer("q_above", torch.tensor(q.ravel()[t["above"]], dtype=f64))
        for j, (p, c) in enumerate(zip(t["paths"], t["path_consts"])):
            self.register_buffer(f"path{j}", torch.tensor(p, dtype=i64))
            self.register_buffer(f"pathc{j}", torch.tensor(c, dtype=f64))
        self.span, self.m = span, t["m"]
        self.register_buffer("rec_ok", torch.tensor(t["rec_ok"]))
        self.register_buffer("g_pl", torch.tensor(t["g_pl"], dtype=f64))
        self.register_buffer("up", torch.tensor(t["up"], dtype=i64))
        self.register_buffer("up_ok", torch.tensor(np.ascontiguousarray(t["up_ok"])))
        self.register_buffer("above", torch.tensor(t["above"], dtype=i64))
        self.register_buffer("has_above", torch.tensor(t["has_above"]))
        cols = np.tile(np.arange(width), height)
        ar = np.arange(N)
        self.register_buffer("left", torch.tensor(np.where(cols > 0, ar - 1, ar), dtype=i64))
        self.register_buffer("right", torch.tensor(np.where(cols < width - 1, ar + 1, ar),
                                                   dtype=i64))
        r = ray_grid(K, width, height).reshape(-1, 3)
        rn = r @ n
        self.register_buffer("rays", torch.tensor(r, dtype=f64))
        self.register_buffer("n", torch.tensor(n, dtype=f64))
        self.register_buffer("rn", torch.tensor(rn, dtype=f64))
        self.register_buffer("rden", torch.tensor(np.maximum((r * r).sum(1) - rn * rn, 1e-12),
                                                  dtype=f64))
        stride = max(1, N // max_points)           # align_upright's sample of raw / Z
        self.register_buffer("unit_idx", torch.arange(0, N, stride, dtype=i64))
        self.shape, self.jump_rel, self.near_rel = shape, float(jump_rel), float(near_rel)
        self.recede = None if recede is None else (float(recede[0]), float(recede[1]))
        self.max_ratio = float(max_ratio)
        self.fill, self.max_pull = bool(fill), float(max_pull)
        self.recede_push = float(recede_push)
        qg = q[np.asarray(ground_mask, bool) & (q > 0)]      # align_upright's contact limit
        self.max_contact = (float(contact_range / qg.min()) if contact_range is not None
                            and qg.size else float("inf"))
        self.max_walk = max(2, height // 16)
        self.walked_ratio = float(walked_ratio)
        self.keep_rel = None if keep_rel is None else float(keep_rel)
        self.register_buffer("walked", torch.tensor(np.asarray(ground_mask, bool).ravel()))
        self.plane_bound = bool(plane_bound)
        self.step_occlude = bool(step_occlude)
        with np.errstate(divide="ignore"):       # align_upright's bound: the plane's depth
            bound = np.where(q > 0, np.float32(1.0) / np.where(q > 0, q, 1), np.inf)
        self.register_buffer("bound", torch.tensor(bound.astype(np.float32)))
        # the colour foot: the static image's constants (geometry/colour_foot_torch.py)
        self.colour = None if image is None else ColourFoot(image, t["du"], q, r, n)

    def _cont(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return torch.abs(a - b) <= self.jump_rel * torch.minimum(a, b)

    def _take(self, x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return torch.index_select(x, 0, idx)

    def _recession(self, A: torch.Tensor) -> torch.Tensor:
        m, w = self.m, self.w
        nan = torch.full((self.N,), float("nan"), dtype=A.dtype)
        if m <= 0:
            return nan
        a0 = A[: m * w]
        ok = self.rec_ok
        a_prev = a0
        for j in range(self.span):
            a_j = self._take(A, getattr(self, f"path{j}"))
            ok = ok & (torch.log(a_prev / a_j) <= getattr(self, f"pathc{j}"))
            a_prev = a_j
        k = torch.where(ok, torch.log(a0 / a_prev) / self.g_pl, nan[: m * w])
        return torch.cat([k, nan[m * w:]])

    def _receding(self, M: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """numpy's ``receding`` (alignment_vertical.py): (flat, recedes) of the map ``M``."""
        lo, hi = self.recede
        k = self._recession(M)
        k_up = torch.where(self.up_ok, self._take(k, self.up), torch.full_like(k, float("nan")))
        k_any = torch.where(torch.isnan(k), k_up, k)
        return (k < lo) & ~(k_up >= lo), (k_any >= lo) & (k_any <= hi)

    def forward(self, Z: torch.Tensor) -> torch.Tensor:
        h, w, N = self.h, self.w, self.N
        g_out, snap, raw = self.ground.parts(Z)
        z_flat, raw_flat = Z.reshape(-1), raw.reshape(-1)
        sample = self._take(raw_flat / z_flat, self.unit_idx)
        unit = masked_median(sample, torch.ones_like(sample, dtype=torch.bool))
        src = (z_flat * unit).to(torch.float64)
        A = raw_flat.to(torch.float64)
        q = self.q64
        ground = snapped = snap.reshape(-1)
        nan = torch.full((N,), float("nan"), dtype=torch.float64)
        planar = torch.zeros_like(ground)
        if self.recede is not None:
            # on the ground map and on the shape a run keeps (numpy: upright_depth)
            flat, recedes = self._receding(A)
            f_src, r_src = self._receding(src)
            flat, recedes = flat & f_src, recedes | r_src
            planar = recedes & ~ground
            if self.recede_push < float("inf"):
                planar = planar & (q * (self.recede_push * A) >= 1.0)
            ground = (ground & ~flat) | planar
        have, foot, qc, cut = self._contacts(A, ground, src)
        if self.walked_ratio < float("inf"):
            # inside the walked region, a pixel more than walked_ratio x its contact's plane
            # depth away is ground the network did not recede (numpy: upright_depth)
            wg = self.walked & have & ~ground & (q > 0) & (q * self.walked_ratio < qc)
            planar = planar | wg
            ground = ground | wg
            have, foot, qc, cut = self._contacts(A, ground, src)
        # the run's ratio at every pixel with a contact
        if self.shape == "network":
            ratio = (1.0 / qc) / self._take(src, foot)
        else:
            F = self._take(self.rays, foot) / qc[:, None]
            lam = ((self.rays * F).sum(1) - self.rn * (F @ self.n)) / self.rden
            ratio = lam / src
        ratio = torch.where(have & (ratio > 0), ratio, nan)
        if self.max_contact < float("inf"):
            ratio = torch.where(have & ~(1.0 / qc <= self.max_contact), nan, ratio)
        if self.max_pull < float("inf"):
            cand = src * torch.clamp(ratio, 1.0 / self.max_ratio, self.max_ratio)
            ratio = torch.where(cand * self.max_pull < A, nan, ratio)
        ratio = ratio.reshape(h, w)
        todo = (~ground | have).reshape(h, w)
        if self.fill:
            ratio = self._fill(ratio, A.reshape(h, w), todo)
        elif self.step_occlude:     # runs a nearer step cut: a row neighbour's ratio
            ratio = self._fill(ratio, A.reshape(h, w), todo & cut.reshape(h, w))
        moved = (todo & torch.isfinite(ratio)).reshape(-1)
        ratio = torch.clamp(torch.where(moved, ratio.reshape(-1), torch.ones_like(A)),
                            1.0 / self.max_ratio, self.max_ratio)
        out = torch.where(moved, src * ratio, A)
        out = torch.where(planar & ~moved, 1.0 / q, out)
        if self.colour is not None:
            out, moved = self.colour(out, moved, have, foot, ground, self.walked, snapped)
        out = out.to(torch.float32).reshape(h, w)
        # snapped pixels found to be structures keep their unsnapped depth (numpy: upright_depth)
        out = torch.where((moved | planar | (snapped & ~ground)).reshape(h, w), out, g_out)
        if self.plane_bound:
            out = torch.minimum(out, self.bound)
        return out

    def _contacts(self, A: torch.Tensor, ground: torch.Tensor, src: torch.Tensor):
        """contact_ratios + refine_contacts: (pixels with a contact, each one's walked contact
        pixel, the contact's plane inverse depth, pixels whose run ends at a step down to a
        nearer pixel that is not ground: ``occluded_runs(..., steps=True)``)."""
        h, N = self.h, self.N
        # the march up the rows: contacts, links to the pixel below, chain ends
        below = self._take(ground.to(torch.int64), self.nxt) > 0
        a_b = self._take(A, self.nxt)
        c_b = self._cont(A, a_b)
        ok = self.ok_n & ~ground
        contact = ok & below & self.contact_ok
        link = follow(torch.where(ok & ~below & c_b, self.nxt, self.ar), _doublings(h))
        # a chain ending at a step down to a nearer pixel (not ground): its foot is hidden
        cut = self._take(ok & ~below & (A > (1.0 + self.jump_rel) * a_b), link) \
            if self.step_occlude else None
        cid = self._take(torch.where(contact, self.ar, -torch.ones_like(self.ar)), link)
        # every contact walks down to the structure's foot: over ground the network sees nearer
        # than the plane, continuous with it, at most max_walk rows; a walk that stops stays.
        # Only the contacts walk (a data-sized index list, NonZero in the graph): the walks are
        # a few thousand entries, not H x W, and the step count stays fixed
        c_idx = torch.nonzero(contact).reshape(-1)
        r_b = a_b * self.q_nxt
        edge = self.walk_ok & below & c_b
        step = torch.where(edge & (r_b < 1.0 - self.near_rel), self.nxt, self.ar)
        pos, walks = c_idx, []
        for _ in range(self.max_walk):
            nxt = self._take(step, pos)
            walks.append((nxt != pos, nxt))
            pos = nxt
        if self.keep_rel is not None:
            # walk on over ground nearer than the plane by any amount, kept where the run then
            # stands at the plane's depth at its contact (numpy: refine_contacts)
            step = torch.where(edge & (r_b < 1.0 - 1e-4), self.nxt, self.ar)
            pos_l, loose = pos, []
            for _ in range(2 * self.max_walk):
                nxt = self._take(step, pos_l)
                loose.append((nxt != pos_l, nxt))
                pos_l = nxt
            ok = (pos_l != pos) & (torch.abs(self._contact_q(A, src, pos_l)
                                             * self._take(src, pos_l) - 1.0) <= self.keep_rel)
            pos = torch.where(ok, pos_l, pos)
            walks += [(act & ok, p) for act, p in loose]
        # a walked-over ground pixel takes the contact that reached it first: written last
        wk = -torch.ones(N + 1, dtype=torch.int64)
        dummy = torch.full_like(c_idx, N)
        for act, p in walks[::-1]:          # in place: a copy of H x W per step cost 10%
            wk.scatter_(0, torch.where(act, p, dummy), c_idx)
        cid = torch.where(wk[:N] >= 0, wk[:N], cid)
        have = cid >= 0
        # each pixel's contact, walked, and its plane inverse depth (pixels without a contact:
        # pixel 0's entries, never read)
        cid = torch.clamp(cid, min=0)
        foot = self._take(self.ar.scatter(0, c_idx, pos), cid)
        qc = torch.zeros_like(self.q64).scatter(0, c_idx, self._contact_q(A, src, pos))
        return have, foot, self._take(qc, cid), cut

    def _contact_q(self, A: torch.Tensor, src: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
        """numpy's ``_contact_q`` at the base positions ``at`` (flat indices): the walked contacts
        only, not every pixel."""
        q, q_above, above = self._take(self.q64, at), self._take(self.q_above, at), \
            self._take(self.above, at)
        a0, s0 = self._take(A, at), self._take(src, at)
        r0, ra = a0 * q, self._take(A, above) * q_above
        sel = (r0 - ra > 1e-6) & self._take(self.has_above, at)
        x = torch.where(sel, (1.0 - r0) / torch.where(sel, r0 - ra, torch.ones_like(r0)),
                        torch.full_like(r0, 0.5))
        x = torch.clamp(torch.where(torch.isnan(x), torch.full_like(x, 0.5), x), 0.0, 1.0)
        # src q extrapolated to x reaches 1 once the run is scaled to 1 / new_q at its base
        return q * (1.0 + x) - x * q_above * self._take(src, above) / s0

    def _fill(self, ratio: torch.Tensor, A: torch.Tensor, todo: torch.Tensor) -> torch.Tensor:
        """fill_along_rows: a pixel to fill links to its left (then right) neighbour; every
        chain takes the value at its end, the k-th link-less pixel of the row (cumulative sums,
        one scatter and one gather per sweep)."""
        h, w = A.shape
        none = torch.zeros((h, 1), dtype=torch.bool)
        for left in (True, False):
            a, b = (A[:, 1:], A[:, :-1]) if left else (A[:, :-1], A[:, 1:])
            c = self._cont(a, b)
            cond = torch.cat([none, c], 1) if left else torch.cat([c, none], 1)
            end = ~(cond & todo & ~torch.isfinite(ratio))
            cs = torch.cumsum(end.to(torch.int64), 1)
            k = cs - 1 if left else cs - end.to(torch.int64)    # the end at or before / after
            slot = torch.where(end, cs - 1, torch.full_like(cs, w))
            ends = torch.full((h, w + 1), float("nan"), dtype=ratio.dtype).scatter(1, slot, ratio)
            ratio = torch.gather(ends, 1, k)
        return ratio
