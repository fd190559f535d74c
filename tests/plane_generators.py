"""Independent scene and observation generators for the ground-plane tests (issue 13).

Nothing here imports the library or ``dataset/synth``: cameras, bodies and detections are built
from first principles. A scene is a camera (3-12 m up, pitched 10-50 degrees, rolled +-5, f
500-900 px at 960x540) over the plane ``n . P = d``, with agents walking or driving on it. One body
model per generator, each a cloud of surface points in the agent's own frame (up, forward, side):

- ``thin``: the head-foot axis only (two points);
- ``tapered``: narrow at the foot (4 cm) and the crown (5 cm), 22 cm at the shoulders;
- ``cylinder``: a wide cylinder (0.3 m radius) from the ground to the crown;
- ``ellipsoid``: torso and head ellipsoids on two legs swinging +-20 degrees (the body bobs);
- ``vehicles``: boxes (cars 4.2-4.8 x 1.7-1.9 x 1.4-1.6 m, buses 10-12 x 2.5 x 3.0-3.3 m) driving
  straight, and a third of the tracks cyclists (1.8 x 0.6 m box as tall as the rider).

People's heights: 90% adults N(1.72, 0.08) m, 10% children U(1.0, 1.45) m. A detection is the
projection of the body's points: as a mask, its lowest point (foot) and highest point (top), each
with the median column of the points within half a pixel of that row (a mask's extreme row is a
run of pixels; a person's foot is both feet's mean where the bottom profile of the union of its
pieces' convex hulls shows two feet apart, as ``staticdepth.tracking.walker_foot`` takes it from
a mask; ``feet`` says how many), 1 px Gaussian noise on all four; as a box, the extreme rows and
columns each jittered by U(-2, 2) px, the foot column the box centre and no top column. Both
record the extreme columns (``left``, ``right``; a mask's with 1 px noise from a generator of
their own, so the other observations stay as they were). Outliers
(``outliers`` = share of observations): sitting people (whole tracks, 55-70% of the height),
detections cut by the image top (the top row moved down by 15-50% of the height) and partly
occluded feet (the foot row moved up by 15-40%).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

W, H = 960, 540
OBS = [("frame", "i4"), ("track", "i4"), ("class_id", "i2"), ("foot_u", "f8"), ("foot_v", "f8"),
       ("height_px", "f8"), ("top_v", "f8"), ("top_u", "f8"), ("score", "f4"), ("feet", "u1"),
       ("left", "f8"), ("right", "f8")]
GENERATORS = ("thin", "tapered", "cylinder", "ellipsoid", "vehicles")
PERSON, BICYCLE, CAR, BUS = 0, 1, 2, 5
FOOT_BAND, FOOT_DIP = 0.25, 0.03   # a walker's second foot, as staticdepth.tracking takes it


@dataclass
class Scene:
    K: np.ndarray
    normal: np.ndarray           # camera frame, pointing to the ground
    height_m: float              # camera height d
    obs: np.ndarray              # observation table (OBS)
    agent_heights: dict          # track -> true height (m)
    pitch_deg: float
    roll_deg: float
    foot_true: np.ndarray | None = None   # (N, 3) per observation: the agent's axis foot (m,
    #                                       camera frame; the ground point under its body)


def camera(rng, pitch_deg: float | None = None) -> tuple[np.ndarray, np.ndarray, float, float,
                                                        float]:
    """(K, n, d, pitch, roll): a random camera of the issue's range (``pitch_deg`` overrides the
    drawn pitch, e.g. a nadir camera)."""
    f = rng.uniform(500, 900)
    pitch, roll, d = rng.uniform(10, 50), rng.uniform(-5, 5), rng.uniform(3, 12)
    pitch = pitch if pitch_deg is None else pitch_deg
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
    t, r = math.radians(pitch), math.radians(roll)
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return K, Rz @ np.array([0.0, math.cos(t), math.sin(t)]), d, pitch, roll


def _rings(radii, zs, k=72):
    """Points (M, 3) in the agent frame (forward, side, up) of horizontal rings."""
    a = np.linspace(0, 2 * math.pi, k, endpoint=False)
    return np.concatenate([np.stack([r * np.cos(a), r * np.sin(a), np.full(k, z)], 1)
                           for r, z in zip(radii, zs)])


def _ellipsoid(c, ax, k=12):
    th, ph = np.meshgrid(np.linspace(0, math.pi, k), np.linspace(0, 2 * math.pi, 2 * k))
    p = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    return c + p * ax


def parts(kind: str, height: float, frame: int, phase: float, dims=None,
          gait: float = 1.3) -> list[np.ndarray]:
    """The body as convex pieces, surface points (M, 3) each in the agent frame (forward, side,
    up), feet on z = 0; a mask is the union of their projections' convex hulls (``gait``: the
    walkers' leg phase per frame, radians)."""
    Hh = height
    if kind == "thin":
        return [np.array([[0, 0, 0.0], [0, 0, Hh]])]
    if kind == "tapered":            # frustums between consecutive rings
        z = np.linspace(0, 1, 21)
        r = 0.04 + 0.18 * np.sin(math.pi * np.minimum(z / 0.8, 1.0)) ** 0.6
        r = np.where(z > 0.8, 0.05 + (0.11 - 0.05) * np.sin(math.pi * (1 - z) / 0.4), r)
        return [_rings(r[i:i + 2], z[i:i + 2] * Hh) for i in range(len(z) - 1)]
    if kind == "cylinder":
        return [_rings(np.full(11, 0.3), np.linspace(0, Hh, 11))]
    if kind == "ellipsoid":
        hip, swing = 0.5 * Hh, math.radians(20) * math.sin(phase + gait * frame)
        drop = hip * (1 - math.cos(swing))                   # both feet on the ground: body bobs
        torso = _ellipsoid(np.array([0, 0, 0.72 * Hh - drop]), np.array([0.14, 0.22, 0.23 * Hh]))
        head = _ellipsoid(np.array([0, 0, 0.935 * Hh - drop]), np.array([0.09, 0.08, 0.065 * Hh]))
        out = [torso, head]
        ring = _rings([0.06], [0.0], 8)
        for sgn, side in ((1, 0.1), (-1, -0.1)):
            t = np.linspace(0, 1, 9)[:, None]
            foot = np.array([sgn * hip * math.sin(swing), side, 0.0])
            leg = np.array([0, side, hip - drop]) * (1 - t) + foot * t
            out.append((leg[:, None, :] + ring[None]).reshape(-1, 3))
        return out
    if kind == "box":
        length, width = dims
        return [np.array([[sx * length / 2, sy * width / 2, z] for sx in (-1, 1)
                          for sy in (-1, 1) for z in (0.0, Hh)])]
    raise ValueError(kind)


def body(kind: str, height: float, frame: int, phase: float, dims=None,
         gait: float = 1.3) -> np.ndarray:
    """Surface points (M, 3) in the agent frame (forward, side, up), feet on z = 0 (each once:
    the tapered body's frustums share their rings)."""
    pieces = parts(kind, height, frame, phase, dims, gait)
    if kind == "tapered":
        return np.concatenate([pieces[0][:len(pieces[0]) // 2]] + [p[len(p) // 2:] for p in pieces])
    return np.concatenate(pieces)


def _bottom_profile(pieces) -> tuple[np.ndarray, np.ndarray]:
    """(columns, lowest row per column) of the union of the convex hulls of projected pieces
    [(u, v), ...], sampled at whole-pixel columns as a mask is (a piece narrower than a pixel, or
    degenerate, by its points; one above the band the feet are searched in by its lowest row)."""
    cols, lows = [], []
    top = min(v.min() for _, v in pieces)
    bottom = max(v.max() for _, v in pieces)
    for u, v in pieces:
        c = np.arange(math.ceil(u.min()), math.floor(u.max()) + 1)
        if v.max() < bottom - FOOT_BAND * (bottom - top) - 1:
            cols.append(c.astype(np.float64))     # above the band the feet are searched in:
            lows.append(np.full(len(c), v.max()))  # its lowest point bounds its columns
            continue
        try:
            hull = ConvexHull(np.stack([u, v], 1)).vertices if len(c) and len(u) > 2 else None
        except QhullError:
            hull = None
        if hull is None:
            cols.append(u)
            lows.append(v)
            continue
        pu, pv = u[hull], v[hull]
        qu, qv = np.roll(pu, -1), np.roll(pv, -1)
        du = np.where(qu == pu, np.nan, qu - pu)
        t = (c[None] - pu[:, None]) / du[:, None]
        vv = np.where((t >= 0) & (t <= 1), pv[:, None] + t * (qv - pv)[:, None], -np.inf)
        cols.append(c.astype(np.float64))
        lows.append(vv.max(0))
    cols, lows = np.concatenate(cols), np.concatenate(lows)
    uniq, inv = np.unique(cols, return_inverse=True)
    low = np.full(len(uniq), -np.inf)
    np.maximum.at(low, inv, lows)
    return uniq, low


def _project(K, P):
    q = P @ K.T
    return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]


def _walker_foot(u, v, cols, low) -> tuple[float, float, int]:
    """A person's foot point from its mask's bottom profile, as ``staticdepth.tracking.
    walker_foot`` takes it: the mean of both feet's lowest points when the profile has a second
    peak within ``FOOT_BAND`` of the height that a dip of ``FOOT_DIP`` (at least 1 px) separates
    from the lowest one, else the lowest point (of the points (u, v) on its side of the dip: the
    lowest, its column the median of those within half a pixel of its row)."""
    hgt = v.max() - v.min()
    k1 = int(np.argmax(low))
    gap = np.array([low[j] - low[min(j, k1):max(j, k1) + 1].min() for j in range(len(cols))])
    ok = (gap >= max(1.0, FOOT_DIP * hgt)) & (low >= low[k1] - FOOT_BAND * hgt)
    sides = [np.ones(len(u), bool)]
    if ok.any():
        k2 = int(np.flatnonzero(ok)[np.argmax(low[ok])])
        lo, hi = min(k1, k2), max(k1, k2)
        cut = cols[lo + int(np.argmin(low[lo:hi + 1]))]
        sides = [u < cut - 0.5, u > cut + 0.5]
    pts = [(np.median(u[p & (v >= v[p].max() - 0.5)]), v[p].max()) for p in sides]
    return (*np.mean(pts, axis=0), len(pts))


def _agent_spec(kind: str, rng):
    """(body kind, class, height, dims, speed m/frame, turn sd) of one agent."""
    if kind != "vehicles":
        adult = rng.random() >= 0.1
        hgt = rng.normal(1.72, 0.08) if adult else rng.uniform(1.0, 1.45)
        return kind, PERSON, hgt, None, rng.uniform(0.5, 0.9), 0.25
    r = rng.random()
    if r < 1 / 3:
        return "box", BICYCLE, rng.normal(1.72, 0.06), (1.8, 0.6), rng.uniform(1.0, 2.0), 0.0
    if r < 0.85:
        return ("box", CAR, rng.uniform(1.4, 1.6), (rng.uniform(4.2, 4.8), rng.uniform(1.7, 1.9)),
                rng.uniform(1.5, 3.0), 0.0)
    return "box", BUS, rng.uniform(3.0, 3.3), (rng.uniform(10, 12), 2.5), rng.uniform(1.5, 3.0), 0.0


def scene(kind: str, seed: int, *, detection: str = "mask", outliers: float = 0.0,
          n_tracks: int = 24, frames: tuple[int, int] = (6, 10), noise_px: float = 1.0,
          pitch_deg: float | None = None, box_jitter_px: float = 2.0,
          gait: float = 1.3) -> Scene:
    """A random camera and ``n_tracks`` tracks of ``kind`` agents; see the module doc
    (``box_jitter_px``: the boxes' sides and rows jittered by U(-this, this); ``gait``: the
    walkers' leg phase per frame, radians, 1.3 a step every 2.4 frames)."""
    rng, side_rng = np.random.default_rng(seed), np.random.default_rng([seed, 1])
    K, n, d, pitch, roll = camera(rng, pitch_deg)
    up = -n
    e1 = np.cross(n, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    rows, heights, track, tries, truth = [], {}, 0, 0, []
    while track < n_tracks and tries < 5000:
        tries += 1
        u0, v0 = rng.uniform(60, W - 60), rng.uniform(0.25 * H, H - 20)
        ray = np.linalg.solve(K, [u0, v0, 1.0])
        if ray @ n <= 1e-3 or (ray * d / (ray @ n))[2] > 60:
            continue
        pos = ray * d / (ray @ n)
        bkind, cls, hgt, dims, speed, turn = _agent_spec(kind, rng)
        heading, phase, out = rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi), []
        feet_true = []
        for i in range(int(rng.integers(frames[0], frames[1] + 1))):
            heading += rng.normal(0, turn) if turn else 0.0
            fwd = math.cos(heading) * e1 + math.sin(heading) * e2
            pos = pos + speed * fwd
            side = np.cross(up, fwd)
            pieces = [pos + P[:, :1] * fwd + P[:, 1:2] * side + P[:, 2:3] * up
                      for P in parts(bkind, hgt, i, phase, dims, gait)]
            P = body(bkind, hgt, i, phase, dims, gait)
            X = pos + P[:, :1] * fwd + P[:, 1:2] * side + P[:, 2:3] * up
            if X[:, 2].min() < 0.3:
                break
            u, v = _project(K, X)
            if u.min() < 2 or u.max() > W - 3 or v.min() < 2 or v.max() > H - 3:
                continue
            if detection == "mask":      # a mask's extreme row: the median column of its run
                e = rng.normal(0, noise_px, 4)
                ub, vb, feet = (np.median(u[v >= v.max() - 0.5]), v.max(), 0) if cls != PERSON \
                    else _walker_foot(u, v, *_bottom_profile([_project(K, p) for p in pieces]))
                ut = np.median(u[v <= v.min() + 0.5])
                es = side_rng.normal(0, noise_px, 2)
                out.append((track, i, cls, ub + e[0], vb + e[1], v.min() + e[2], ut + e[3], feet,
                            u.min() + es[0], u.max() + es[1]))
            else:
                j = rng.uniform(-1, 1, 4) * box_jitter_px
                lo, hi = u.min() + j[0], u.max() + j[1]
                out.append((track, i, cls, (lo + hi) / 2, v.max() + j[2], v.min() + j[3], np.nan,
                            0, lo, hi))
            feet_true.append(pos)
        if len(out) >= 3:
            rows += out
            truth += feet_true
            heights[track] = hgt
            track += 1
    if not rows:        # e.g. vehicles under a steep, low camera: none fits in the image
        raise ValueError(f"no whole {kind} track fits in the image of camera {seed} (pitch "
                         f"{pitch:.0f} deg, {d:.1f} m high)")
    a = np.array(rows, dtype=np.float64)
    obs = np.zeros(len(a), OBS)
    for k, name in enumerate(("track", "frame", "class_id", "foot_u", "foot_v", "top_v", "top_u",
                              "feet", "left", "right")):
        obs[name] = a[:, k]
    obs["score"] = 1.0
    if outliers > 0:
        _corrupt(rng, obs, outliers)
    obs["height_px"] = obs["foot_v"] - obs["top_v"]
    return Scene(K, n, d, obs, heights, pitch, roll, np.array(truth))


def _corrupt(rng, obs: np.ndarray, share: float) -> None:
    """Corrupt ``share`` of the observations in place: a third sitting (whole person tracks),
    the rest cut at the top or occluded at the feet."""
    target = int(round(share * len(obs)))
    done = np.zeros(len(obs), bool)
    people = np.unique(obs["track"][obs["class_id"] == PERSON])
    for t in rng.permutation(people):
        sel = obs["track"] == t
        if done.sum() + sel.sum() > target / 3:
            break
        h = obs["foot_v"][sel] - obs["top_v"][sel]
        obs["top_v"][sel] = obs["foot_v"][sel] - h * rng.uniform(0.55, 0.7)
        done |= sel
    rest = rng.permutation(np.flatnonzero(~done))[:max(target - int(done.sum()), 0)]
    for i in rest:
        h = obs["foot_v"][i] - obs["top_v"][i]
        if rng.random() < 0.5:
            obs["top_v"][i] += h * rng.uniform(0.15, 0.5)
            obs["top_u"][i] = np.nan if np.isnan(obs["top_u"][i]) else obs["top_u"][i]
        else:
            obs["foot_v"][i] -= h * rng.uniform(0.15, 0.4)
