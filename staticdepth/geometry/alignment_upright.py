"""The ``upright`` alignment mode: structures standing on the ground take its depth at their base.

After the ``ground`` mode (alignment.align_ground: one scale and shift of the network's inverse
depth fitted on the ground, pixels the plane explains snapped to it), whatever the network gets
wrong on a wall, pole or facade, or on a far ground it squashed, stays wrong by that global
correction. The upright-world prior the method uses for agents extends to them:

1. Ground: the snapped pixels, plus pixels whose depth grows up the image of the vertical (the
   lines through the vertical vanishing point ``K n``) ``recede`` times as fast as the plane's
   (0.1-8x: a squashed far ground still recedes, a structure gets nearer or stays); a snapped pixel
   that does not recede, nor the pixels above it, is a structure the network put at the plane's
   depth (it keeps its unsnapped depth unless re-anchored). Those unsnapped ground pixels take the
   plane's depth. The recession is measured on the ``ground`` map and on the shape a traced run
   keeps (``native``): ground where either recedes, so that a run re-anchored here is not taken
   for ground when the result is aligned again.
2. Every other pixel is traced down its vertical, row by row, while the aligned depth has no step
   (relative ``jump_rel``); the first ground pixel below is the structure's contact, moved down to
   the structure's foot where the foot fell within the snapping tolerance (the network nearer than
   the plane there) and placed between rows where that run's depth meets the plane's. A run that
   already stands at the plane's depth there (within ``keep_rel``: an aligned map's structure,
   whose lowest pixels snap) walks on to that contact and keeps its depth.
3. With ``shape="network"`` every pixel of the run takes the network's own depth (brought to the
   aligned map's units by one global factor) times the run's ratio (plane depth at the contact) /
   (network depth there): the network's shape is kept inside, the scale is fixed at the base. With
   ``shape="vertical"`` the pixel takes the depth of the vertical line through the contact instead.
Runs without a contact (cut by the image's bottom, standing on something that is not ground, or
behind a depth step) keep the ``ground`` result (``fill=True``: they take the ratio of a
continuous neighbour in the same row first). Ratios are clipped to ``[1 / max_ratio, max_ratio]``.
Contacts not to trust keep the ``ground`` result too: beyond ``max_contact`` (where no agent
walked, the plane's depth is uncertain) or pulling the run nearer than its ``ground`` depth /
``max_pull``; a receding pixel takes the plane only within ``recede_push`` x its ``ground`` depth.
Inside the walked region (``walked``: the ground mask, where the agents' feet were), a traced pixel
whose plane depth exceeds ``walked_ratio`` x its contact's is ground the network did not let recede
(a structure standing there would be taller than ``1 - 1 / walked_ratio`` camera heights): it takes
the plane, and the contacts are traced again over it. With ``occlude`` a run does not pass
through the frame's agents (``not_ground``): a blurred network continues a wall's depth into the
agent in front of it, and the wall took the agent's contact, nearer than its own hidden foot; the
runs an agent cuts take a row neighbour's ratio (the same wall beside the agent). With
``step_occlude`` so do the runs that end at a depth step down to a nearer pixel that is not ground:
a network that resolves a nearer wall hiding a far wall's foot stops the far wall's run there, and
that run kept the ground mode's scale, the ground's, not its own; an exported graph sees such steps
(it has no agent mask). Afterwards (``align_upright``'s
``plane_bound``) no pixel below the horizon ends farther than the plane along its ray.

A pure function of (depth, K, plane, ground mask[, agent mask]); ``geometry/alignment.py``
dispatches ``mode="upright"`` here. The image of the vertical (steps down it, the recession test)
is in ``geometry/alignment_vertical.py``. Sequential over rows (the march) and columns (the fill).
What depends only on the camera, the plane and the static image (rays, the plane's inverse depth,
the image of the vertical, the colour feet) is an :class:`AlignCamera`: built once per run by
adapt's align stage and passed to every frame, else by each call.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.alignment_vertical import (colour_codes, colour_foot, down_step,
                                                    ground_coloured, receding, static_colour_feet,
                                                    static_surface, vertical_depth, vertical_walk)
from staticdepth.geometry.projection import ray_grid

SHAPES = ("network", "vertical")
RECEDE = (0.1, 8.0)     # ground: the network's depth grows up the vertical 0.1-8x as fast as the plane's
KEEP_REL = 0.02         # a run standing within this of the plane's depth at its contact keeps it
FOOT_DIFF = 0.2         # colour_foot: a channel step (0-1) this large ends a structure's colour run
FOOT_PULL = 10.0        # colour_foot: a foot at most this x nearer than the re-anchored depth
FOOT_GROUND_SHARE = 0.005   # colour_foot: not from a colour this common on the walked ground
FOOT_LEVELS = 16            # ... in bins of this many levels per channel (colour_codes)


def rows_below(du: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For rows ``0 .. H-2`` ((H-1, W) each): the column of the pixel one row down each pixel's
    vertical (rounded, clipped into the image) and whether that step exists (``du`` finite) and
    lands inside the image."""
    w = du.shape[1]
    step = du[:-1]
    ub = np.rint(np.arange(w) + np.nan_to_num(step))
    inside = np.isfinite(step) & (ub >= 0) & (ub < w)
    return np.clip(ub, 0, w - 1).astype(np.int64), inside


def _read_only(x):
    """``x`` (an array, or tuples of them) made read-only: constants every frame shares."""
    if isinstance(x, np.ndarray):
        x.setflags(write=False)
    elif isinstance(x, tuple):
        for y in x:
            _read_only(y)
    return x


def _owned(x, dtype=np.float64) -> np.ndarray:
    """``x`` as a read-only array of ``dtype`` that nothing else can write: itself when it is
    one already (an AlignCamera's own), else a copy."""
    if (isinstance(x, np.ndarray) and x.dtype == dtype and x.base is None
            and not x.flags.writeable):
        return x
    return _read_only(np.array(x, dtype=dtype))


@dataclass(frozen=True, eq=False)
class AlignCamera:
    """The alignment's per-camera constants: what depends only on the camera (``K``, the image's
    ``width`` x ``height``), the plane ``normal . P = d`` (``normal`` exactly as the alignment's
    functions are given it: they check it, :meth:`check`) and the static scene's ``image``
    ((H, W, C) 0-1, or None), not on the frame. Built once per run and passed to every frame
    (adapt's align stage), else by each call. Each constant is computed on first use, once,
    read-only: :attr:`rays`, :attr:`q`, :attr:`unit`, :attr:`du`, :meth:`walk`,
    :meth:`colour_feet`, :meth:`colour_codes` and :meth:`normalised` (the camera of the unit
    normal that ``align_depth`` passes on). ``K``, ``normal`` and ``image`` are kept as read-only
    float64 copies."""

    K: np.ndarray
    width: int
    height: int
    normal: np.ndarray
    d: float
    image: np.ndarray | None = None
    _memo: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self):
        K, n = _owned(self.K), _owned(self.normal)
        if K.shape != (3, 3) or n.shape != (3,):
            raise InputError(f"an alignment camera needs a 3x3 K and a 3-vector normal, got "
                             f"{K.shape} and {n.shape}")
        image = None if self.image is None else _owned(self.image)
        if image is not None and image.shape[:2] != (self.height, self.width):
            raise InputError(f"the static image is {image.shape[:2]}, the camera "
                             f"{self.width}x{self.height}")
        for name, value in (("K", K), ("normal", n), ("image", image), ("d", float(self.d)),
                            ("width", int(self.width)), ("height", int(self.height))):
            object.__setattr__(self, name, value)

    def check(self, K, n_g, d_g: float, width: int, height: int) -> "AlignCamera":
        """Itself, when it was built for exactly these (``K``, plane ``n_g . P = d_g``, a
        ``width`` x ``height`` frame); InputError otherwise: another camera's or plane's constants
        would misplace every pixel."""
        if not ((int(width), int(height)) == (self.width, self.height)
                and np.array_equal(np.asarray(K, dtype=np.float64), self.K)
                and np.array_equal(np.asarray(n_g, dtype=np.float64), self.normal)
                and float(d_g) == self.d):
            raise InputError(
                f"the alignment camera was built for another camera or plane: {self.width}x"
                f"{self.height}, normal {self.normal.tolist()}, d {self.d}, K "
                f"{self.K.tolist()}; the frame's {width}x{height}, normal "
                f"{np.asarray(n_g).tolist()}, d {d_g}, K {np.asarray(K).tolist()}")
        return self

    def _get(self, key, make):
        if key not in self._memo:
            self._memo[key] = _read_only(make())
        return self._memo[key]

    @property
    def rays(self) -> np.ndarray:
        """(H, W, 3) every pixel's ray (projection.ray_grid, r_z = 1)."""
        return self._get("rays", lambda: ray_grid(self.K, self.width, self.height))

    @property
    def q(self) -> np.ndarray:
        """(H, W) float32 the plane's inverse depth ``n . r / d`` (n: ``normal`` made unit)."""
        return self._get("q", lambda: (self.rays @ (
            self.normal / (np.linalg.norm(self.normal) * self.d))).astype(np.float32))

    @property
    def unit(self) -> np.ndarray:
        """The unit normal ``normal / |normal|``."""
        return self._get("unit", lambda: self.normal / np.linalg.norm(self.normal))

    @property
    def du(self) -> np.ndarray:
        """(H, W) the column step per row down the image of the vertical (``down_step``)."""
        return self._get("du", lambda: down_step(self.K, self.unit, self.width, self.height))

    def walk(self, span: int) -> tuple:
        """``alignment_vertical.vertical_walk`` of :attr:`du` over ``span`` rows."""
        return self._get(("walk", span), lambda: vertical_walk(self.du, span))

    def colour_feet(self, image: np.ndarray, max_diff: float) -> np.ndarray:
        """``alignment_vertical.static_colour_feet`` of ``image`` on :attr:`du`: kept here when
        ``image`` is the camera's own (:attr:`image`, not hashed again for each frame)."""
        if self._own(image):
            return self._get(("feet", max_diff),
                             lambda: static_colour_feet(self.image, self.du, max_diff))
        return static_colour_feet(image, self.du, max_diff)

    def colour_surface(self, image: np.ndarray, max_diff: float, feet: np.ndarray
                       ) -> np.ndarray:
        """``alignment_vertical.static_surface`` of ``image`` (the colour foot's lawn test of
        every pixel) from its :meth:`colour_feet` ``feet``: kept here when ``image`` is the
        camera's own."""
        if self._own(image):
            return self._get(("surface", max_diff),
                             lambda: static_surface(self.image, self.du, max_diff, feet))
        return static_surface(image, self.du, max_diff, feet)

    def colour_codes(self, image: np.ndarray, levels: int) -> np.ndarray:
        """``alignment_vertical.colour_codes`` of ``image``: kept here when ``image`` is the
        camera's own."""
        if self._own(image):
            return self._get(("codes", levels), lambda: colour_codes(self.image, levels))
        return colour_codes(image, levels)

    def _own(self, image) -> bool:
        """Whether ``image`` is the camera's :attr:`image`; InputError for another image when
        the camera holds one."""
        if self.image is None:
            return False
        if image is not self.image:
            raise InputError("the alignment camera holds a static image and was given another: "
                             "pass its own (AlignCamera.image)")
        return True

    def normalised(self) -> "AlignCamera":
        """The camera of the plane with normal :attr:`unit` (as ``align_depth`` passes the normal
        on), sharing :attr:`rays` and the image; itself when that is ``normal`` to the bit (not
        kept: a camera referring to itself would outlive a call that dropped it)."""
        if np.array_equal(self.unit, self.normal):
            return self

        def make():
            cam = AlignCamera(self.K, self.width, self.height, self.unit, self.d, self.image)
            cam._memo["rays"] = self.rays
            return cam

        return self._get("normalised", make)


def align_camera(camera: AlignCamera | None, K, n_g, d_g: float, width: int,
                 height: int) -> AlignCamera:
    """``camera`` checked against these arguments (:meth:`AlignCamera.check`), or, when None, a
    new camera for them."""
    if camera is None:
        return AlignCamera(K, width, height, n_g, d_g)
    return camera.check(K, n_g, d_g, width, height)


def chain_ends(link: np.ndarray) -> np.ndarray:
    """Each entry of a flat pointer array (``link[i]``: the next pixel of ``i``'s chain, ``i``
    itself at a chain's end) moved to the end of its chain, by pointer doubling: ``log2`` of the
    longest chain gathers over the whole array instead of one step per row."""
    while True:
        nxt = link[link]
        if np.array_equal(nxt, link):
            return link
        link = nxt


def contact_ratios(A: np.ndarray, ground: np.ndarray, q: np.ndarray, du: np.ndarray,
                   jump_rel: float, cut: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The march up the rows: each non-ground pixel inherits the contact of the pixel below it on
    its vertical line when their depths are continuous (and ``cut``, (H, W) bool an edge between
    a pixel and the one below, is not set), or becomes a contact when that pixel is ground.
    Returns (H, W) the contact's plane inverse depth ``qc`` and the contact's flat pixel index
    (NaN / -1 where a pixel has no contact). Each pixel links to the pixel below or ends its
    chain; :func:`chain_ends` follows the links for every pixel at once (the result is the
    row-by-row march's, from the bottom up)."""
    h, w = A.shape
    qc = np.full(h * w, np.nan, np.float64)
    idx = np.full(h * w, -1, np.int64)
    if h < 2:
        return qc.reshape(h, w), idx.reshape(h, w)
    ub, inside = rows_below(du)
    rows = np.arange(1, h)[:, None]
    ok = inside & ~ground[:-1] & np.isfinite(A[:-1])
    below, a_b, a = ground[rows, ub], A[rows, ub], A[:-1]
    qv = 0.5 * (q[:-1] + q[rows, ub])
    contact = (ok & below & (qv > 0)).ravel()
    with np.errstate(invalid="ignore"):
        cont = ok & ~below & (np.abs(a - a_b) <= jump_rel * np.minimum(a, a_b))
    if cut is not None:
        cont &= ~cut[:-1]
    top = (h - 1) * w
    link = np.arange(h * w)
    link[:top][cont.ravel()] = (rows * w + ub).ravel()[cont.ravel()]
    end = chain_ends(link)
    is_contact = np.zeros(h * w, bool)
    is_contact[:top] = contact
    hit = np.flatnonzero(is_contact[end])
    qc[hit] = qv.ravel()[end[hit]]
    idx[hit] = end[hit]
    return qc.reshape(h, w), idx.reshape(h, w)


def occluded_runs(A: np.ndarray, occluder: np.ndarray, ground: np.ndarray, du: np.ndarray,
                  jump_rel: float, steps: bool = False,
                  cut: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels whose run (continuous depth down the vertical, not ground) ends on an
    ``occluder`` pixel: whatever stands behind an agent has its foot hidden by it. With
    ``steps``, also those whose run ends at a depth step down to a nearer pixel that is not
    ground: what stands in front hides the foot. With ``cut`` ((H, W) bool, an image edge
    between a pixel and the one below), also those whose run ends at such an edge above a pixel
    that is not ground (the edge of a nearer occluder the network blurred through). The runs'
    links are followed as in :func:`contact_ratios`."""
    h, w = A.shape
    if h < 2:
        return np.zeros((h, w), bool)
    ub, inside = rows_below(du)
    rows = np.arange(1, h)[:, None]
    ok = inside & ~ground[:-1] & ~occluder[:-1] & np.isfinite(A[:-1])
    a, a_b, g_b, hidden = A[:-1], A[rows, ub], ground[rows, ub], occluder[rows, ub]
    with np.errstate(invalid="ignore"):
        cont = ~g_b & ~hidden & (np.abs(a - a_b) <= jump_rel * np.minimum(a, a_b))
        if steps:
            hidden = hidden | (~g_b & (a > (1.0 + jump_rel) * a_b))
        if cut is not None:
            hidden = hidden | (~g_b & cut[:-1])
            cont &= ~cut[:-1]
    top = (h - 1) * w
    ends_hidden = np.zeros(h * w, bool)
    ends_hidden[:top] = (ok & hidden).ravel()
    lk = (ok & ~hidden & cont).ravel()
    link = np.arange(h * w)
    link[:top][lk] = (rows * w + ub).ravel()[lk]
    return ends_hidden[chain_ends(link)].reshape(h, w)


def _walk_down(A, ground, q, du, cv, cu, nearer: float, steps: int, jump_rel: float):
    """Move each base pixel (cv, cu) down its vertical line over ground pixels with ``A q`` below
    ``nearer`` (nearer than the plane) and continuous with it, at most ``steps`` rows. Returns the
    new bases and, per step, the pixels walked over and the indices of the bases that walked.
    Only the bases still walking are looked at in each step (a stopped walk stays stopped)."""
    h, w = A.shape
    cv, cu = np.array(cv, dtype=np.int64), np.array(cu, dtype=np.int64)
    idx = np.arange(len(cv))
    walked_pix, walked_c = [], []
    for _ in range(steps):
        v, u = cv[idx], cu[idx]
        step = du[v, u]
        bv = v + 1
        bu = np.rint(u + np.nan_to_num(step)).astype(np.int64)
        act = np.isfinite(step) & (bv < h) & (bu >= 0) & (bu < w)
        bv, bu = np.where(act, bv, 0), np.clip(bu, 0, w - 1)
        a, a_b, qb = A[v, u], A[bv, bu], q[bv, bu]
        with np.errstate(invalid="ignore", divide="ignore"):
            act &= ground[bv, bu] & (qb > 0) & (a_b * qb < nearer) \
                & (np.abs(a - a_b) <= jump_rel * np.minimum(a, a_b))
        if not act.any():
            break
        idx, bv, bu = idx[act], bv[act], bu[act]
        cv[idx], cu[idx] = bv, bu
        walked_pix.append(bv * w + bu)
        walked_c.append(idx)
    return cv, cu, walked_pix, walked_c


def _contact_q(A, q, du, cv, cu, S):
    """The contact's plane inverse depth of runs based at (cv, cu): where the run's ``A q`` (1 on
    the plane, < 1 on a structure nearer than the plane) extrapolated from its two lowest pixels
    reaches 1, at most one row below the base (fraction ``x``), set so that the run scaled to
    ``1 / qc`` at its base has ``S q`` reaching 1 at that same ``x`` (``S``: the shape the run
    keeps): an aligned run, traced again, finds its contact where it was."""
    w = A.shape[1]
    av = np.maximum(cv - 1, 0)
    au = np.clip(np.rint(cu - np.nan_to_num(du[av, cu])), 0, w - 1).astype(np.int64)
    r0, ra = A[cv, cu] * q[cv, cu], A[av, au] * q[av, au]
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where((r0 - ra > 1e-6) & (av < cv), (1.0 - r0) / (r0 - ra), 0.5)
        x = np.clip(np.nan_to_num(x, nan=0.5), 0.0, 1.0)
        return q[cv, cu] * (1.0 + x) - x * q[av, au] * S[av, au] / S[cv, cu]


def refine_contacts(A: np.ndarray, ground: np.ndarray, q: np.ndarray, du: np.ndarray,
                    qc: np.ndarray, idx: np.ndarray, jump_rel: float, near_rel: float,
                    max_walk: int, src: np.ndarray | None = None,
                    keep_rel: float | None = None) -> None:
    """In place: move each contact down its vertical line over ground pixels that the network
    sees nearer than the plane (by more than ``near_rel``) and continuous with it, at most
    ``max_walk`` rows: the foot of a wall whose depth fell within the snapping tolerance. With
    ``keep_rel``, a run walks on (at most ``2 max_walk`` rows more) over ground nearer than the
    plane by any amount when it then stands at the plane's depth at its contact within
    ``keep_rel``: a structure already placed on its foot (an aligned map, whose lowest pixels
    snap), kept there. The pixels walked over join the run; every pixel of the run takes the
    lower contact, whose plane inverse depth is :func:`_contact_q`'s (``src``: the shape the
    run keeps, default ``A``)."""
    h, w = A.shape
    S = A if src is None else src
    used = np.zeros(h * w, bool)
    used[idx[idx >= 0]] = True
    C = np.flatnonzero(used)            # the contacts, sorted (np.unique's, without a sort)
    if len(C) == 0:
        return
    cv, cu = np.divmod(C, w)
    cv, cu, walked_pix, walked_c = _walk_down(A, ground, q, du, cv, cu, 1.0 - near_rel,
                                              max_walk, jump_rel)
    if keep_rel is not None:
        lv, lu, lp, lc = _walk_down(A, ground, q, du, cv, cu, 1.0 - 1e-4, 2 * max_walk,
                                    jump_rel)
        with np.errstate(invalid="ignore"):
            ok = (lv != cv) & (np.abs(_contact_q(A, q, du, lv, lu, S) * S[lv, lu] - 1.0)
                               <= keep_rel)
        cv, cu = np.where(ok, lv, cv), np.where(ok, lu, cu)
        for pix, k in zip(lp, lc):
            walked_pix.append(pix[ok[k]])
            walked_c.append(k[ok[k]])
    base = cv * w + cu
    new_q = _contact_q(A, q, du, cv, cu, S)
    lut_i = np.full(h * w, -1, np.int64)
    lut_q = np.full(h * w, np.nan)
    lut_i[C], lut_q[C] = base, new_q
    have = idx >= 0
    qc[have], idx[have] = lut_q[idx[have]], lut_i[idx[have]]
    # a pixel walked over by several contacts takes the one that reached it first (the longest
    # walk; contacts reaching it at the same step share the rest of the walk): latest write wins
    for pix, k in zip(walked_pix[::-1], walked_c[::-1]):
        qc.ravel()[pix], idx.ravel()[pix] = new_q[k], base[k]


def fill_along_rows(ratio: np.ndarray, A: np.ndarray, todo: np.ndarray, jump_rel: float) -> None:
    """In place: pixels of ``todo`` without a ratio take their left, then right, neighbour's when
    their depths are continuous (one sweep each way). In each sweep a pixel to fill links to its
    neighbour and every chain takes the value at its end, the k-th link-less pixel of its row
    (cumulative sums: one scatter and one gather per sweep, as the sequential sweep gives)."""
    h, w = A.shape
    with np.errstate(invalid="ignore"):
        c = np.abs(A[:, 1:] - A[:, :-1]) <= jump_rel * np.minimum(A[:, 1:], A[:, :-1])
    none = np.zeros((h, 1), bool)
    for left in (True, False):
        cond = np.concatenate([none, c] if left else [c, none], 1)
        end = ~(cond & todo & ~np.isfinite(ratio))
        cs = np.cumsum(end, 1)
        k = cs - 1 if left else cs - end          # the chain's end: at or before / after
        ends = np.full((h, w + 1), np.nan)
        r, u = np.nonzero(end)
        ends[r, cs[r, u] - 1] = ratio[r, u]
        ratio[...] = np.take_along_axis(ends, k, 1)


def upright_depth(A: np.ndarray, K: np.ndarray, n_g: np.ndarray, d_g: float, ground: np.ndarray,
                  q: np.ndarray, *, jump_rel: float = 0.08, shape: str = "network",
                  max_ratio: float = 4.0, near_rel: float = 0.02,
                  recede: tuple[float, float] | None = RECEDE, span: int = 3,
                  not_ground: np.ndarray | None = None, native: np.ndarray | None = None,
                  fill: bool = True, max_pull: float = np.inf, max_contact: float = np.inf,
                  recede_push: float = np.inf, walked: np.ndarray | None = None,
                  walked_ratio: float = np.inf, extra_ground: np.ndarray | None = None,
                  keep_rel: float | None = KEEP_REL, occlude: bool = False,
                  step_occlude: bool = False, edge_below: np.ndarray | None = None,
                  image: np.ndarray | None = None, foot_diff: float = FOOT_DIFF,
                  foot_pull: float = FOOT_PULL, info: dict | None = None,
                  camera: AlignCamera | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Re-anchor the non-ground pixels of an aligned depth map ``A`` (H, W; units of d_g) at their
    contact with the ground (module docstring). ``ground``: (H, W) bool pixels on the plane;
    ``q``: the plane's inverse depth ``n_g . r / d_g`` per pixel; ``not_ground``: pixels never
    ground (the frame's agents); ``native``: the depth whose shape a run keeps (default ``A``);
    ``walked``: (H, W) bool the walked region of ``walked_ratio``; ``extra_ground``: (H, W) bool
    pixels another cue says are ground (below the horizon, not ``not_ground``): they take the
    plane and structures find their contacts on them (benchmarks/bench_align_regions.py feeds it
    the true ground to bound what a better ground cue could give); ``info``: a dict that receives
    the per-pixel categories ``ground``, ``planar`` (took the plane), ``traced`` (has a contact),
    ``moved`` (re-anchored) and ``contact`` (flat index of each pixel's contact, -1: none);
    ``keep_rel``: :func:`refine_contacts`' (None: off); ``occlude``: runs end at ``not_ground``
    (an agent hides the foot of what stands behind it) and those cut take a row neighbour's
    ratio (:func:`fill_along_rows`, as ``fill`` does for every run without a contact);
    ``step_occlude``: so do the runs that end at a depth step down to a nearer pixel that is not
    ground (what stands in front of a structure hides its foot; no agent mask needed);
    ``edge_below``: (H, W) bool, an image edge between a pixel and the one below it on its
    vertical: runs do not cross it to a pixel that is not ground, and those it cuts take a row
    neighbour's ratio (an occluder the network blurred through shows in the image, not in its
    depth; benchmarks/bench_edge_stops.py's oracle, no setting: it did not help on i1-i4, even
    cut at the true occluding edges, docs/gains.md); ``image``: (H, W, C) the static scene's
    colours, 0-1 (e.g. the median of the adaptation frames): traced pixels whose colour run goes
    on below their contact stand at its foot (:func:`colour_foot`, ``foot_diff``, ``foot_pull``;
    benchmarks/bench_near_structures.py); ``info`` also receives ``planar_walked`` (the
    walked-region rule's pixels), ``contact_q`` and ``colour_foot``; ``camera``: the
    :class:`AlignCamera` of (``K``, ``A``'s size, ``n_g``, ``d_g``; the static image when it is
    ``image``), else built here. Returns the new map and the (H, W) bool mask of the pixels it
    set (re-anchored, planar, or snapped pixels found to be structures, which keep ``A``)."""
    if shape not in SHAPES:
        raise InputError(f"upright alignment shape must be one of {SHAPES}, got {shape!r}")
    if not (np.isfinite(jump_rel) and jump_rel > 0):
        raise InputError(f"upright alignment jump_rel must be > 0, got {jump_rel}")
    if not (np.isfinite(max_ratio) and max_ratio >= 1):
        raise InputError(f"upright alignment max_ratio must be >= 1, got {max_ratio}")
    h, w = A.shape
    cam = align_camera(camera, K, n_g, d_g, w, h)
    A = np.asarray(A, dtype=np.float64)
    n, du = cam.unit, cam.du
    src = A if native is None else np.asarray(native, dtype=np.float64)
    max_walk = max(2, h // 16)

    cut = occlude and not_ground is not None
    # runs stop at the frame's agents (NaN ends a run): the foot behind an agent is hidden
    A_tr = np.where(not_ground, np.nan, A) if cut else A

    def trace(g):
        qc, idx = contact_ratios(A_tr, g, q, du, jump_rel, edge_below)
        refine_contacts(A_tr, g, q, du, qc, idx, jump_rel, near_rel, max_walk, src, keep_rel)
        return qc, idx, idx >= 0

    snapped = ground
    planar = np.zeros((h, w), bool)
    if recede is not None:
        # measured on the map the decisions are taken on and on the shape a traced run keeps:
        # ground where either recedes, a structure on the plane's depth where neither does, so
        # that a run this alignment re-anchored is not taken for ground when aligned again
        flat, recedes = receding((A,) if native is None else (A, src), q, du, span,
                                 jump_rel, recede, cam.walk(span))
        with np.errstate(invalid="ignore"):
            planar = recedes & ~ground
            # the plane at most recede_push x farther than the pixel's ground-mode depth
            planar &= q * (recede_push * A) >= 1.0
        if not_ground is not None:
            planar &= ~not_ground
        ground = (ground & ~flat) | planar
    if extra_ground is not None:        # pixels another cue says are ground: the plane
        extra = extra_ground & ~ground & (q > 0)
        if not_ground is not None:
            extra &= ~not_ground
        planar |= extra
        ground = ground | extra
    qc, idx, have = trace(ground)
    if walked is not None and np.isfinite(walked_ratio):
        # inside the walked region, a pixel that would stand more than walked_ratio x its
        # contact's plane depth away is no structure there: ground the network did not recede
        with np.errstate(invalid="ignore"):
            wg = walked & have & ~ground & (q > 0) & (q * walked_ratio < qc)
        if not_ground is not None:
            wg &= ~not_ground
        if info is not None:
            info["planar_walked"] = wg
        if wg.any():
            planar |= wg
            ground = ground | wg
            qc, idx, have = trace(ground)
    ratio = np.full((h, w), np.nan)
    rays = cam.rays.reshape(-1, 3)
    if shape == "network":
        ratio[have] = (1.0 / qc[have]) / src.ravel()[idx[have]]
    else:
        ratio[have] = vertical_depth(rays, n, idx[have], qc[have],
                                     np.flatnonzero(have)) / src[have]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio[~(ratio > 0)] = np.nan
        # contacts not to trust keep the ground mode: beyond max_contact (the plane's depth
        # uncertain there) or pulling the run nearer than its ground-mode depth / max_pull
        ratio[have & ~(1.0 / qc <= max_contact)] = np.nan
        cand = src * np.clip(ratio, 1.0 / max_ratio, max_ratio)
        ratio[cand * max_pull < A] = np.nan
    todo = (~ground | have) & np.isfinite(A)
    if fill:
        fill_along_rows(ratio, A, todo, jump_rel)
    elif cut or step_occlude or edge_below is not None:
        # runs an agent (or, with step_occlude, a nearer step; with edge_below, an image edge)
        # cut take a row neighbour's ratio (the same wall beside it)
        occ = not_ground if cut else np.zeros((h, w), bool)
        fill_along_rows(ratio, A, todo & occluded_runs(A, occ, ground, du, jump_rel,
                                                       step_occlude, edge_below), jump_rel)
    moved = todo & np.isfinite(ratio)
    if info is not None:    # per-pixel categories, for diagnostics (benchmarks/)
        info.update(ground=ground, planar=planar, traced=have, moved=moved, contact=idx,
                    contact_q=qc)
    ratio = np.clip(np.nan_to_num(ratio, nan=1.0), 1.0 / max_ratio, max_ratio)
    out = np.where(moved, src * ratio, A)
    with np.errstate(divide="ignore"):
        out = np.where(planar & ~moved, 1.0 / q, out)
    if image is not None:
        # not the ground's own colours: a smooth road the network keeps flat is traced like a
        # wall, and its colour runs on down to a marking or a kerb
        cand = moved & (idx >= 0) & ~ground_coloured(image, ground & (
            walked if walked is not None else True), FOOT_GROUND_SHARE, FOOT_LEVELS,
            cam.colour_codes(image, FOOT_LEVELS))
        all_feet = cam.colour_feet(image, foot_diff)
        feet = colour_foot(out, image, q, du, rays, n, ground, cand, idx, not_ground,
                           foot_diff, foot_pull, all_feet, surface_check=snapped,
                           surface=cam.colour_surface(image, foot_diff, all_feet))
        moved = moved | feet
        if info is not None:
            info["colour_foot"] = feet
    # snapped pixels found to be structures keep their unsnapped depth where not re-anchored
    return out.astype(np.float32), moved | planar | (snapped & ~ground)
