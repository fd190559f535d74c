"""An independent scene generator for checking the method on scenes it was not built on.

It shares nothing with ``staticdepth.dataset.synth`` but the file writer: its own world model
(ground z = 0, Z up), vectorised analytic ray casting (plane, yawed boxes, ellipsoids), its own
textures (value noise, brick and window grids, tiles and lane dashes, all in world coordinates so
the two views agree), people as an ellipsoid body + a sphere head (no cylinders), vehicles as two
boxes (body + cabin), static walls, poles, crates and building facades above the ground, and a
27 cm stereo pair. Exact depth, instance ids and AGENT_DTYPE rows (true foot and head points).

    python tests/indep_scenes.py OUT_DIR [--frames 90] [--size 320x160]

writes ``OUT_DIR/<scene>.h5`` for each of SCENES.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass

import numpy as np

from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.geometry.camera import Camera, Mounting, StereoRig

BASELINE_M = 0.27
DT_S = 0.25                        # seconds between frames
SUN = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


@dataclass(frozen=True)
class SceneSpec:
    name: str
    height_m: float
    pitch_deg: float
    seed: int
    people: int = 14
    vehicles: int = 3
    hfov_deg: float = 90.0
    roll_deg: float = 0.0


# C1/C2/C3-like mounts of the paper (CARLA 90 deg field of view) and a low one
SCENES = (SceneSpec("i1", 5.4, 25.0, 1), SceneSpec("i2", 9.7, 35.0, 2),
          SceneSpec("i3", 5.3, 20.0, 3), SceneSpec("i4", 3.0, 15.0, 4))


# -- textures ------------------------------------------------------------------------------------
def _hash(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    h = (ix.astype(np.int64) * 374761393 + iy.astype(np.int64) * 668265263 + salt * 982451653)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(np.float32) / 65535.0


def value_noise(x: np.ndarray, y: np.ndarray, scale: float, salt: int) -> np.ndarray:
    """Smooth noise in [0, 1] on a lattice of ``scale`` metres (bilinear, smoothstep)."""
    x, y = x / scale, y / scale
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = x - ix, y - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    a, b = _hash(ix, iy, salt), _hash(ix + 1, iy, salt)
    c, d = _hash(ix, iy + 1, salt), _hash(ix + 1, iy + 1, salt)
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


def ground_albedo(x, y, road_half: float, salt: int) -> np.ndarray:
    n = 0.55 * value_noise(x, y, 0.9, salt) + 0.3 * value_noise(x, y, 0.17, salt + 1) \
        + 0.15 * value_noise(x, y, 0.04, salt + 2)
    road = np.abs(x) < road_half
    g = np.where(road, 0.22 + 0.22 * n, 0.45 + 0.25 * n)
    tile = (np.abs(((x / 0.6) % 1) - 0.5) > 0.46) | (np.abs(((y / 0.6) % 1) - 0.5) > 0.46)
    g = np.where(~road & tile, g * 0.6, g)
    dash = (np.abs(x) < 0.08) & (((y / 3.0) % 1) < 0.5)
    g = np.where(dash, 0.9, g)
    rgb = np.stack([g, g * 0.97, g * (0.92 + 0.1 * road)], -1)
    grass = (~road) & (value_noise(x, y, 6.0, salt + 3) > 0.7)
    rgb[grass] = rgb[grass] * np.array([0.6, 1.1, 0.5], np.float32)
    return rgb


def wall_albedo(p: np.ndarray, colour: np.ndarray, salt: int) -> np.ndarray:
    """Bricks on walls and crates, windows on facades: a grid in (horizontal, z)."""
    h = p[:, 0] + p[:, 1]
    z = p[:, 2]
    row = np.floor(z / 0.25)
    off = (row % 2) * 0.25
    mortar = (((z / 0.25) % 1) < 0.1) | ((((h + off) / 0.5) % 1) < 0.06)
    n = 0.75 + 0.5 * value_noise(h, z, 0.3, salt)
    rgb = colour[None, :] * n[:, None]
    rgb[mortar] = 0.75
    return rgb


# -- ray casting ---------------------------------------------------------------------------------
def _box_hit(o, d, centre, half, yaw):
    """Ray parameter and world normal of a yawed box; t = inf where missed."""
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], np.float32)        # world -> local
    ol = (o - centre) @ R.T
    dl = d @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dl
        t1 = (-half - ol) * inv
        t2 = (half - ol) * inv
    tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
    tn = np.nan_to_num(tn, nan=-np.inf)
    tf = np.nan_to_num(tf, nan=np.inf)
    t_near, t_far = tn.max(-1), tf.min(-1)
    hit = (t_near <= t_far) & (t_near > 1e-4)
    t = np.where(hit, t_near, np.inf)
    axis = tn.argmax(-1)
    nl = np.zeros_like(dl)
    nl[np.arange(len(dl)), axis] = -np.sign(dl[np.arange(len(dl)), axis])
    return t, nl @ R


def _ellipsoid_hit(o, d, centre, radii):
    ol = (o - centre) / radii
    dl = d / radii
    a = (dl * dl).sum(-1)
    b = 2 * (ol * dl).sum(-1)
    c = (ol * ol).sum(-1) - 1
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    t = np.where((disc > 0) & (t > 1e-4), t, np.inf)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    nrm = (p - centre) / radii ** 2
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True) + 1e-12
    return t, nrm


class Scene:
    """A static camera over a street with moving people and vehicles."""

    def __init__(self, spec: SceneSpec, width: int = 320, height: int = 160):
        self.spec = spec
        rng = np.random.default_rng(spec.seed)
        self.camera = Camera.from_fov(width, height, spec.hfov_deg)
        t, p = math.radians(spec.pitch_deg), math.radians(spec.roll_deg)
        # camera axes in the world (X right, Y forward, Z up): columns right, down, forward,
        # rolled by roll_deg about the forward axis
        R = np.array([[1, 0, 0], [0, -math.sin(t), math.cos(t)],
                      [0, -math.cos(t), -math.sin(t)]])
        R = R @ np.array([[math.cos(p), -math.sin(p), 0], [math.sin(p), math.cos(p), 0],
                          [0, 0, 1]])
        self.R = R.astype(np.float32)
        # the ground's normal (down) in the camera frame is R^T (0, 0, -1): staticdepth's roll
        # has the other sign (tests/test_indep_scenes.py)
        self.mounting = Mounting.from_pitch_roll(spec.height_m, spec.pitch_deg, -spec.roll_deg,
                                                 "generator")
        self.origin = np.array([0.0, 0.0, spec.height_m], np.float32)
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        K = self.camera.K
        r = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        self.dirs = (r.reshape(-1, 3) @ self.R.T).astype(np.float32)   # camera z = 1: t = depth
        # the walkable area: the ground seen in the image's lower three quarters, within 30 m
        near = spec.height_m / math.tan(t + math.atan(0.5 * height / K[1, 1]))
        self.y_range = (near + 1.0, min(near + 18.0, 30.0))
        self.x_half = 0.9 * self.y_range[0] * width / (2 * K[0, 0]) + 4.0
        self.road_half = 3.5
        self.salt = spec.seed * 17
        self._layout(rng)
        self._static = {side: self._cast_static(self._eye(side)) for side in (0, 1)}

    # -- layout ----------------------------------------------------------------------------------
    def _layout(self, rng):
        y0, y1 = self.y_range
        xh = self.x_half
        s = []   # static boxes: (centre, half, yaw, colour)
        far = y1 + rng.uniform(8, 20)
        for k in range(6):                          # facades across the back, windows
            cx = -30 + 12 * k + rng.uniform(-2, 2)
            hgt = rng.uniform(6, 16)
            s.append((np.array([cx, far + 4, hgt / 2]), np.array([5.5, 4, hgt / 2]), 0.0,
                      rng.uniform(0.35, 0.8, 3)))
        for side in (-1, 1):                        # side walls along the pavement
            s.append((np.array([side * (xh + 2), (y0 + y1) / 2, 1.2]),
                      np.array([0.2, (y1 - y0) / 2, 1.2]), 0.0, rng.uniform(0.4, 0.8, 3)))
        for _ in range(4):                          # poles
            s.append((np.array([rng.choice([-1, 1]) * (self.road_half + 0.6),
                                rng.uniform(y0, y1), 2.5]), np.array([0.08, 0.08, 2.5]), 0.0,
                      np.array([0.3, 0.3, 0.32])))
        for _ in range(3):                          # crates
            e = rng.uniform(0.4, 0.7)
            s.append((np.array([rng.choice([-1, 1]) * rng.uniform(self.road_half + 1, xh),
                                rng.uniform(y0, y1), e]), np.array([e, e, e]),
                      rng.uniform(0, math.pi), np.array([0.55, 0.4, 0.2])))
        self.statics = s
        self.people = []
        for k in range(self.spec.people):
            h = rng.uniform(1.5, 1.9)
            self.people.append(dict(p0=np.array([rng.uniform(-xh, xh), rng.uniform(y0, y1)]),
                                    v=rng.uniform(0.8, 1.6) * np.array([math.cos(a := rng.uniform(0, 2 * math.pi)), math.sin(a)]),
                                    h=h, w=rng.uniform(0.17, 0.24), shirt=rng.uniform(0.1, 0.9, 3),
                                    legs=rng.uniform(0.05, 0.5, 3)))
        self.vehicles = []
        for k in range(self.spec.vehicles):
            lane = (-1.75 if k % 2 else 1.75)
            self.vehicles.append(dict(x=lane, y0=rng.uniform(y0 - 5, y1), v=rng.uniform(3, 6) * (1 if lane > 0 else -1),
                                      L=rng.uniform(3.8, 4.8), W=rng.uniform(1.7, 1.9),
                                      H=rng.uniform(1.4, 1.7), colour=rng.uniform(0.1, 0.9, 3)))

    def _eye(self, side: int) -> np.ndarray:
        return self.origin + side * BASELINE_M * self.R[:, 0]

    def agents_at(self, time_s: float):
        """[(kind, id, centre/extent...)] of the people and vehicles at a time."""
        y0, y1 = self.y_range
        out = []
        for k, p in enumerate(self.people):
            pos = p["p0"] + p["v"] * time_s
            for ax, (lo, hi) in enumerate(((-self.x_half, self.x_half), (y0, y1))):
                span = hi - lo
                q = (pos[ax] - lo) % (2 * span)
                pos[ax] = lo + (q if q < span else 2 * span - q)     # bounce off the edges
            out.append(("person", k + 1, pos, p))
        for k, c in enumerate(self.vehicles):
            span = (y1 + 10) - (y0 - 10)
            y = (y0 - 10) + (c["y0"] - (y0 - 10) + c["v"] * time_s) % span
            out.append(("car", 100 + k, np.array([c["x"], y]), c))
        return out

    # -- casting ---------------------------------------------------------------------------------
    def _cast_static(self, eye):
        d = self.dirs
        n = len(d)
        o = np.broadcast_to(eye, d.shape)
        t = np.full(n, np.inf, np.float32)
        with np.errstate(divide="ignore"):
            tg = np.where(d[:, 2] < -1e-6, -eye[2] / d[:, 2], np.inf)
        t = np.minimum(t, tg)
        rgb = np.zeros((n, 3), np.float32)
        nrm = np.tile(np.array([0, 0, 1], np.float32), (n, 1))
        ground = np.isfinite(t)
        p = eye + t[ground, None] * d[ground]
        rgb[ground] = ground_albedo(p[:, 0], p[:, 1], self.road_half, self.salt)
        for j, (c, half, yaw, col) in enumerate(self.statics):
            tb, nb = _box_hit(o, d, c.astype(np.float32), half.astype(np.float32), yaw)
            m = tb < t
            if m.any():
                t[m] = tb[m]
                nrm[m] = nb[m]
                p = eye + tb[m, None] * d[m]
                rgb[m] = wall_albedo(p, col.astype(np.float32), self.salt + 10 + j)
        return t, rgb, nrm

    def _footprint(self, eye, pos, reach: float, top: float):
        """Flat pixel indices of the image rectangle that can see an agent standing at ``pos``
        (a box ``reach`` around it up to ``top``); None when it is out of view."""
        cx, cy = np.meshgrid([pos[0] - reach, pos[0] + reach], [pos[1] - reach, pos[1] + reach])
        corners = np.array([[x, y, z] for x, y in zip(cx.ravel(), cy.ravel()) for z in (0.0, top)])
        P = (corners - eye) @ self.R                       # camera frame
        if (P[:, 2] < 0.2).any():
            return np.arange(len(self.dirs))
        K, w, h = self.camera.K, self.camera.width, self.camera.height
        u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]
        v = K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
        u0, u1 = max(int(u.min()) - 1, 0), min(int(u.max()) + 2, w)
        v0, v1 = max(int(v.min()) - 1, 0), min(int(v.max()) + 2, h)
        if u0 >= u1 or v0 >= v1:
            return None
        return (np.arange(v0, v1)[:, None] * w + np.arange(u0, u1)[None, :]).ravel()

    def _cast_agents(self, side, time_s):
        eye = self._eye(side)
        t_st, rgb_st, n_st = self._static[side]
        t, rgb, nrm = t_st.copy(), rgb_st.copy(), n_st.copy()
        ids = np.zeros(len(self.dirs), np.uint16)
        for kind, iid, pos, a in self.agents_at(time_s):
            sel = self._footprint(eye, pos, a["h"] if kind == "person" else a["L"] / 2 + 0.3,
                                  a["h"] if kind == "person" else 2.0)
            if sel is None:
                continue
            o, d = np.broadcast_to(eye, (len(sel), 3)), self.dirs[sel]
            parts = []
            if kind == "person":
                body_h = a["h"] - 0.22
                parts.append(_ellipsoid_hit(o, d, np.array([pos[0], pos[1], body_h / 2], np.float32),
                                            np.array([a["w"], 0.7 * a["w"], body_h / 2], np.float32))
                             + ("body",))
                parts.append(_ellipsoid_hit(o, d, np.array([pos[0], pos[1], a["h"] - 0.11], np.float32),
                                            np.array([0.1, 0.1, 0.11], np.float32)) + ("head",))
            else:
                yaw = math.pi / 2
                parts.append(_box_hit(o, d, np.array([pos[0], pos[1], 0.15 + 0.3 * a["H"]], np.float32),
                                      np.array([a["L"] / 2, a["W"] / 2, 0.3 * a["H"]], np.float32), yaw)
                             + ("car",))
                parts.append(_box_hit(o, d, np.array([pos[0], pos[1] - 0.2 * np.sign(a["v"]), 0.15 + 0.8 * a["H"]], np.float32),
                                      np.array([0.3 * a["L"], 0.45 * a["W"], 0.2 * a["H"]], np.float32), yaw)
                             + ("cabin",))
                parts.append(_box_hit(o, d, np.array([pos[0], pos[1], 0.075], np.float32),
                                      np.array([0.45 * a["L"], 0.45 * a["W"], 0.075], np.float32), yaw)
                             + ("wheels",))
            for tp, npart, what in parts:
                ms = tp < t[sel]
                if not ms.any():
                    continue
                m = sel[ms]
                t[m], nrm[m], ids[m] = tp[ms], npart[ms], iid
                z = eye[2] + tp[ms] * d[ms, 2]
                if what == "body":
                    col = np.where((z > 0.45 * a["h"])[:, None], a["shirt"], a["legs"])
                elif what == "head":
                    col = np.tile([0.8, 0.6, 0.45], (len(m), 1))
                elif what == "cabin":
                    col = np.tile(a["colour"] * 0.35, (len(m), 1))
                elif what == "wheels":
                    col = np.tile([0.05, 0.05, 0.05], (len(m), 1))
                else:
                    col = np.tile(a["colour"], (len(m), 1))
                rgb[m] = col
        return t, rgb, nrm, ids

    def render(self, i: int) -> dict:
        time_s = i * DT_S
        h, w = self.camera.height, self.camera.width
        out = {}
        for side, key in ((0, "left"), (1, "right")):
            t, rgb, nrm, ids = self._cast_agents(side, time_s)
            shade = 0.3 + 0.7 * np.clip(nrm @ SUN, 0, 1)
            col = np.clip(rgb * shade[:, None], 0, 1)
            sky = ~np.isfinite(t)
            col[sky] = np.array([0.55, 0.7, 0.9]) * (1 - 0.3 * self.dirs[sky, 2:3])
            out[key] = (col.reshape(h, w, 3) * 255 + 0.5).astype(np.uint8)
            if side == 0:
                out["depth"] = np.where(sky, np.nan, t).reshape(h, w).astype(np.float32)
                out["instances"] = ids.reshape(h, w)
        out["agents"] = self._rows(i, out["instances"], time_s)
        return out

    def _rows(self, i, inst, time_s):
        rows = []
        Rt = self.R.T
        for kind, iid, pos, a in self.agents_at(time_s):
            vs, us = np.nonzero(inst == iid)
            if len(vs) == 0:
                continue
            r = schema.empty_agents(1)
            r["frame"], r["instance_id"], r["track_id"] = i, iid, iid
            r["class_id"] = schema.COCO["person"] if kind == "person" else schema.COCO["car"]
            low, top = vs.max(), vs.min()
            r["foot_v"], r["top_v"] = low, top
            r["foot_u"] = 0.5 * (us.min() + us.max())
            r["top_u"] = float(np.median(us[vs == top]))
            height = a["h"] if kind == "person" else a["H"]
            foot = Rt @ (np.array([pos[0], pos[1], 0.0]) - self.origin)
            head = Rt @ (np.array([pos[0], pos[1], height]) - self.origin)
            r["foot_x"], r["foot_y"], r["foot_z"] = foot
            r["head_x"], r["head_y"], r["head_z"] = head
            r["height_m"] = height
            r["radius_m"] = a["w"] if kind == "person" else a["W"] / 2
            rows.append(r)
        return np.concatenate(rows) if rows else schema.empty_agents(0)


def write_scene(path: str, spec: SceneSpec, frames: int = 90, adapt_frames: int | None = None,
                width: int = 320, height: int = 160, overwrite: bool = True) -> str:
    """Render ``frames`` of one scene into a sequence file (first 45% for adaptation)."""
    scene = Scene(spec, width, height)
    adapt_frames = int(round(0.45 * frames)) if adapt_frames is None else adapt_frames
    meta = SequenceMeta(name=f"indep-{spec.name}", camera=scene.camera, gt_kind="synthetic",
                        source="tests/indep_scenes.py", adapt_frames=adapt_frames,
                        rig=StereoRig.rectified(scene.camera, BASELINE_M),
                        mounting=scene.mounting, provenance={"spec": spec.__dict__})
    with SequenceWriter(path, meta, streams=("left", "right", "depth", "instances"),
                        overwrite=overwrite) as wr:
        for i in range(frames):
            f = scene.render(i)
            wr.append(left=f["left"], right=f["right"], depth=f["depth"],
                      instances=f["instances"], agents=f["agents"], timestamp=i * DT_S)
    return path


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--size", default="320x160")
    ap.add_argument("--scenes", default=",".join(s.name for s in SCENES))
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    os.makedirs(args.out, exist_ok=True)
    for s in SCENES:
        if s.name in args.scenes.split(","):
            p = write_scene(os.path.join(args.out, f"{s.name}.h5"), s, args.frames, width=w, height=h)
            print(p, file=sys.stderr)
