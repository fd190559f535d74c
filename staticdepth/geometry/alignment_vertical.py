"""The image of the vertical, for the ``upright`` alignment (geometry/alignment_upright.py) and
its torch twin: the column step per row down it, a walk up it from every pixel, and how fast a
depth map recedes along it compared with the ground plane's (the recession test that tells ground,
which recedes, from a structure standing on it, which does not), and a colour run down it to a
structure's foot in the image (``colour_feet``, ``colour_foot``) and the vertical line through
a foot (``vertical_depth``).

Pure numpy functions of (K, plane normal, depth maps, an image); no I/O.
"""
from __future__ import annotations

import hashlib

import numpy as np

#: the colour foot's lawn test (:func:`reaches_bottom`): a run's colour "resumes" below what
#: ended it when a pixel within ``max(2, H // RESUME_ROWS_DIV)`` rows further down its vertical
#: is within RESUME_DIFF of its foot's colour on every channel
RESUME_DIFF = 0.1
RESUME_ROWS_DIV = 16


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


def vertical_walk(du: np.ndarray, span: int) -> tuple[tuple, np.ndarray]:
    """What :func:`receding` walks over, constants of the camera and plane: :func:`walk_up`'s
    steps from every pixel of rows ``[0, H - span)`` (a tuple of ``(rows, columns, inside)``,
    each step's ``inside`` its own array; none when ``span >= H``) and the (H, W) column of the
    pixel ``span`` rows up each pixel's vertical (its own ``du`` times ``span``, rounded, clipped
    into the image)."""
    h, w = du.shape
    steps = () if span >= h else tuple((rows, ui, inside.copy())
                                       for rows, ui, inside in walk_up(du, h - span, span))
    up = np.clip(np.rint(np.arange(w)[None, :] - span * np.nan_to_num(du)), 0, w - 1)
    return steps, up.astype(np.int64)


def recession(maps, q: np.ndarray, du: np.ndarray, span: int,
              jump_rel: float, steps: tuple | None = None) -> list[np.ndarray]:
    """Per map of ``maps`` (each (H, W)), how fast the depth grows up the image's vertical
    relative to the plane's: the ratio of the ``ln A`` to the ``ln (1 / q)`` difference over
    ``span`` rows; NaN where that is not measurable or a single row's step exceeds the plane's by
    more than a depth step (``jump_rel``). About 1 on the ground (also where the network has it at
    the wrong depth), 0 or below on a structure standing on it (it gets nearer or stays going up).
    The maps share one walk up the verticals (``steps``: :func:`vertical_walk`'s, default walked
    here)."""
    h, w = q.shape
    outs = [np.full((h, w), np.nan) for _ in maps]
    if span >= h:
        return outs
    n = h - span
    oks = [np.ones((n, w), bool) for _ in maps]
    inside = oks[0]
    a_prev, q_prev = [A[:n] for A in maps], q[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        for rows, ui, inside in vertical_walk(du, span)[0] if steps is None else steps:
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
             recede: tuple[float, float], walk: tuple | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool: ``flat`` (on no map of ``maps`` does the pixel or the pixel ``span`` rows
    above it recede: a structure, if the plane's depth snapped it) and ``recedes`` (on some map
    the depth grows up the vertical ``recede`` times as fast as the plane's, measured from above
    at a step). ``walk``: :func:`vertical_walk` of (``du``, ``span``), default computed here."""
    h, w = q.shape
    vu = np.arange(h)[:, None] - span
    steps, uu = vertical_walk(du, span) if walk is None else walk
    flat, recedes = np.ones((h, w), bool), np.zeros((h, w), bool)
    for k in recession(maps, q, du, span, jump_rel, steps):
        k_up = np.where(vu >= 0, k[np.maximum(vu, 0), uu], np.nan)
        k_any = np.where(np.isfinite(k), k, k_up)
        with np.errstate(invalid="ignore"):
            flat &= (k < recede[0]) & ~(k_up >= recede[0])
            recedes |= (k_any >= recede[0]) & (k_any <= recede[1])
    return flat, recedes


def _step_down(du: np.ndarray, v: np.ndarray, uf: np.ndarray, act: np.ndarray):
    """One row down the image of the vertical for the walks ``act`` at rows ``v`` and sub-pixel
    columns ``uf``: (the walks still inside the image, their next row, column and sub-pixel
    column)."""
    h, w = du.shape
    va, fa = v[act], uf[act]
    step = du[va, np.clip(np.rint(fa), 0, w - 1).astype(np.int64)]
    un = fa + np.nan_to_num(step)
    ui = np.rint(un).astype(np.int64)
    ok = np.isfinite(step) & (va + 1 < h) & (ui >= 0) & (ui < w)
    return act[ok], va[ok] + 1, ui[ok], un[ok]


def colour_feet(image: np.ndarray, du: np.ndarray, pix: np.ndarray,
                max_diff: float) -> np.ndarray:
    """Flat index of the lowest pixel of each flat ``pix``'s colour run down its vertical: the
    walk follows the image of the vertical at sub-pixel precision (``du`` accumulated: a thin pole
    slants across columns) while the next pixel's colour differs from the current one by at most
    ``max_diff`` on every channel (``image`` (H, W, C), 0-1). A structure the network does not
    resolve keeps its own colour down to its foot, where the ground's begins."""
    h, w = du.shape
    img = np.asarray(image, dtype=np.float64).reshape(h, w, -1)
    v, u = np.divmod(np.asarray(pix, dtype=np.int64), w)
    uf = u.astype(np.float64)
    cur = img[v, u]
    act = np.arange(len(v))             # the walks still going: each step looks at those only
    while len(act):
        act, va, ui, un = _step_down(du, v, uf, act)
        nxt = img[va, ui]
        ok = np.abs(nxt - cur[act]).max(-1) <= max_diff
        act, va, ui, un, nxt = act[ok], va[ok], ui[ok], un[ok], nxt[ok]
        v[act], u[act], uf[act], cur[act] = va, ui, un, nxt
    return v * w + u


_FEET_CACHE: dict = {}       # static_colour_feet's last results: a run's one image (and one more)


def static_colour_feet(image: np.ndarray, du: np.ndarray, max_diff: float) -> np.ndarray:
    """:func:`colour_feet` of every pixel (flat (H W,)), computed once per (image, ``du``,
    ``max_diff``) and kept: a static camera aligns every frame with the same median image and
    plane, and each pixel's walk does not depend on the others'. Keyed by the arrays' contents."""
    img = np.ascontiguousarray(image, dtype=np.float64)
    d = np.ascontiguousarray(du, dtype=np.float64)
    # hashed in place (the contiguous arrays' own buffers, not a copy of their bytes); sha1
    # hashes 2x as fast as blake2b here, and a cache key needs no security
    key = (img.shape, d.shape, float(max_diff),
           *(hashlib.sha1(a.data, usedforsecurity=False).hexdigest() for a in (img, d)))
    feet = _FEET_CACHE.get(key)
    if feet is None:
        feet = colour_feet(img, d, np.arange(d.size), max_diff)
        feet.setflags(write=False)
        if len(_FEET_CACHE) >= 2:     # an int64 per pixel each: bounded memory
            _FEET_CACHE.pop(next(iter(_FEET_CACHE)))
        _FEET_CACHE[key] = feet
    return feet


def colour_codes(image: np.ndarray, levels: int) -> np.ndarray:
    """(H, W) int64 colour bin of each pixel of ``image`` (H, W, C), 0-1: each channel in
    ``levels`` bins."""
    img = np.asarray(image, dtype=np.float64)
    img = img.reshape(img.shape[0], img.shape[1], -1)
    q = np.clip((img * levels).astype(np.int64), 0, levels - 1)
    code = np.zeros(q.shape[:2], np.int64)
    for c in range(q.shape[2]):
        code = code * levels + q[..., c]
    return code


def ground_coloured(image: np.ndarray, ground: np.ndarray, share: float,
                    levels: int, code: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels whose colour bin (:func:`colour_codes`) holds at least ``share`` of
    the ``ground`` pixels' colours (``code``: ``colour_codes(image, levels)``, when known)."""
    code = colour_codes(image, levels) if code is None else code
    g = np.asarray(ground, bool)
    if not g.any():
        return np.zeros(code.shape, bool)
    hist = np.bincount(code[g], minlength=int(code.max()) + 1)
    return hist[code] >= share * g.sum()


def resumes_below(image: np.ndarray, du: np.ndarray, feet: np.ndarray, max_diff: float,
                  rows: int) -> np.ndarray:
    """(len(feet),) flat index of the first pixel within ``rows`` rows below each flat ``feet``
    pixel on its vertical whose colour is within ``max_diff`` of the foot's on every channel
    (-1: none): where the colour that ended at the foot comes back, past what ended the run (a
    stone or a sheet of paper on a lawn, a speckle on a wall)."""
    h, w = du.shape
    img = np.asarray(image, dtype=np.float64).reshape(h, w, -1)
    f, back = np.unique(np.asarray(feet, dtype=np.int64), return_inverse=True)
    v, u = np.divmod(f, w)
    uf = u.astype(np.float64)
    colour = img[v, u]
    out = np.full(len(f), -1, np.int64)
    act = np.arange(len(f))
    for _ in range(max(int(rows), 0)):
        act, va, ui, un = _step_down(du, v, uf, act)
        v[act], uf[act] = va, un
        hit = np.abs(img[va, ui] - colour[act]).max(-1) <= max_diff
        out[act[hit]] = va[hit] * w + ui[hit]
        act = act[~hit]
        if not len(act):
            break
    return out[back.reshape(-1)]


def reaches_bottom(image: np.ndarray, du: np.ndarray, feet: np.ndarray, all_feet: np.ndarray,
                   chain: int = 16) -> np.ndarray:
    """(len(feet),) bool: whether the colour run ending at each flat ``feet`` pixel, resumed
    past each small object that ends it (:func:`resumes_below`, :data:`RESUME_DIFF`, over
    ``max(2, H // RESUME_ROWS_DIV)`` rows; the resumed run's foot from ``all_feet``, every
    pixel's :func:`static_colour_feet`), goes on to the image's last row within ``chain``
    objects: a surface coming toward the camera (a lawn), not a structure standing on the
    ground, whose colour ends for good at its foot."""
    h, w = du.shape
    rows = max(2, h // RESUME_ROWS_DIV)
    cur = np.asarray(feet, dtype=np.int64).copy()
    out = np.zeros(len(cur), bool)
    act = np.arange(len(cur))
    for _ in range(chain):
        if not len(act):
            break
        out[act[cur[act] // w + 1 >= h]] = True
        act = act[cur[act] // w + 1 < h]
        r = resumes_below(image, du, cur[act], RESUME_DIFF, rows)
        act, r = act[r >= 0], r[r >= 0]
        cur[act] = all_feet[r]
    return out


def static_surface(image: np.ndarray, du: np.ndarray, max_diff: float,
                   feet: np.ndarray | None = None) -> np.ndarray:
    """(H W,) bool :func:`reaches_bottom` of every pixel's colour run (``feet``: every pixel's
    :func:`static_colour_feet`, computed when not given): a constant of the static image, as its
    feet are (the upright alignment keeps it on its camera, the exported graph as a buffer)."""
    all_feet = static_colour_feet(image, du, max_diff) if feet is None else feet.ravel()
    return reaches_bottom(image, du, all_feet, all_feet)


def below_feet(feet: np.ndarray, du: np.ndarray) -> np.ndarray:
    """Flat index of the pixel one row below each flat ``feet`` pixel on its vertical (the last
    row: the same row)."""
    h, w = du.shape
    fv, fu = np.divmod(np.asarray(feet, dtype=np.int64), w)
    bu = np.clip(np.rint(fu + np.nan_to_num(du[fv, fu])), 0, w - 1).astype(np.int64)
    return np.minimum(fv + 1, h - 1) * w + bu


def vertical_depth(rays: np.ndarray, n: np.ndarray, foot: np.ndarray, q_foot: np.ndarray,
                   pix: np.ndarray) -> np.ndarray:
    """Depth of each flat ``pix`` on the vertical line through its flat ``foot`` pixel's point on
    the plane (plane inverse depth ``q_foot`` there; ``rays`` (H W, 3) with r_z = 1, ``n`` the
    unit normal): the point of the pixel's ray closest to that line."""
    F = rays[foot] / q_foot[:, None]               # the foot's point (r_z = 1: P = Z r)
    rp = rays[pix]
    rn = rp @ n
    return (np.einsum("ij,ij->i", rp, F) - rn * (F @ n)) / np.maximum(
        np.einsum("ij,ij->i", rp, rp) - rn * rn, 1e-12)


def colour_foot(out: np.ndarray, image: np.ndarray, q: np.ndarray, du: np.ndarray,
                rays: np.ndarray, n: np.ndarray, ground: np.ndarray, traced: np.ndarray,
                idx: np.ndarray, not_ground: np.ndarray | None, max_diff: float,
                max_pull: float, feet: np.ndarray | None = None,
                surface_check: np.ndarray | None = None,
                surface: np.ndarray | None = None) -> np.ndarray:
    """In place on ``out`` (the re-anchored map): a ``traced`` pixel whose colour run down the
    vertical (alignment_vertical.colour_feet, ``image``) goes on below its contact (flat ``idx``)
    and ends above a ``ground`` pixel that is no agent (``not_ground``) stands there: it takes the
    vertical line through that foot, unless that is more than ``max_pull`` x nearer than
    ``out``. A pole or crate the network does not resolve carries what stands behind it, and its
    lower part recedes like the ground, so its run took a contact behind its foot; its colour does
    not. ``feet``: :func:`colour_feet` of every pixel (default :func:`static_colour_feet`'s).
    ``surface_check``: (H, W) bool pixels (upright passes the snapped ones: the network's depth
    there is the plane's) whose run must not go on, past small objects, to the image's bottom
    (:func:`reaches_bottom`): a lawn the walked ground's colour test does not know, ended by a
    sheet of paper on it, is not a wall standing on the paper (vtest.avi: 382 lawn pixels of a
    frame 1.8x too near; a speckled wall's run ends at its own foot and keeps the rule);
    ``surface``: :func:`static_surface` of every pixel (computed when not given).
    Returns the (H, W) bool pixels it set."""
    h, w = out.shape
    pix = np.flatnonzero(traced)
    done = np.zeros(h * w, bool)
    if not len(pix):
        return done.reshape(h, w)
    all_feet = static_colour_feet(image, du, max_diff) if feet is None else feet.ravel()
    feet = all_feet[pix]
    fv, fu = np.divmod(feet, w)
    bv, bu = np.divmod(below_feet(feet, du), w)
    ok = (fv + 1 < h) & ground[bv, bu] & (q[fv, fu] > 0) & (fv > idx.ravel()[pix] // w)
    if surface_check is not None:     # a lawn's run that a small object ended is no contact
        if surface is None:
            surface = static_surface(image, du, max_diff, all_feet)
        ok &= ~(np.asarray(surface_check, bool).ravel()[pix] & surface.ravel()[pix])
    if not_ground is not None:
        ok &= ~not_ground[bv, bu]
    qf = 0.5 * (q[fv, fu] + q[bv, bu])             # the foot lies between the two rows
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(ok, vertical_depth(rays, n, fv * w + fu, np.where(ok, qf, 1.0), pix),
                     np.nan)
        ok &= (d > 0) & (d * max_pull >= out.ravel()[pix])
    out.ravel()[pix[ok]] = d[ok]
    done[pix[ok]] = True
    return done.reshape(h, w)
