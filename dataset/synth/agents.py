"""Moving agents: upright 3-D bodies on smooth ground paths, spawned deterministically per block.

Time is cut into blocks of ``BLOCK_S`` seconds; the agents entering during block b come from a
generator seeded by (seed, b), so any frame can be rendered without simulating the ones before it.
Each physical thing has its own ``track_id``: a pedestrian and the bag it carries, a rider and the
bicycle are two tracks. People are vertical cylinders (body radius ~0.2 m, a narrower head on
top), vehicles are boxes, so a tilted camera sees the head nearer than the feet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from staticdepth.dataset.schema import COCO
from staticdepth.dataset.synth.layout import ROAD_HALF_M, TAG, Layout
from staticdepth.dataset.synth.render import Box, Cylinder, SceneObject

BLOCK_S = 10.0
_SLOTS = 128            # agents per block at most
_BLOCK_OFFSET = 4096    # keeps track ids positive for blocks before t = 0
SPEED_MPS = {"pedestrian": (0.9, 1.6), "bicycle": (3.0, 6.0), "motorcycle": (5.0, 9.0),
             "car": (4.0, 9.0), "truck": (3.5, 7.0), "bus": (3.5, 7.0)}
HEAD_RADIUS_RATIO = 0.6   # head cylinder radius / body radius
HEAD_HEIGHT_RATIO = 0.13  # head cylinder height / person height
ACCESSORIES = ("handbag", "backpack", "umbrella", "suitcase")
_CLOTHES = np.array([[0.2, 0.25, 0.45], [0.55, 0.15, 0.15], [0.15, 0.4, 0.2], [0.75, 0.7, 0.6],
                     [0.1, 0.1, 0.12], [0.6, 0.5, 0.2], [0.45, 0.3, 0.5], [0.8, 0.4, 0.2]])
_PAINT = np.array([[0.75, 0.75, 0.78], [0.1, 0.1, 0.12], [0.6, 0.1, 0.1], [0.15, 0.25, 0.55],
                   [0.85, 0.85, 0.85], [0.35, 0.35, 0.38], [0.8, 0.6, 0.15]])


@dataclass(frozen=True, eq=False)
class Agent:
    """One agent (and its accessory or vehicle) over its lifetime."""

    kind: str                # pedestrian, bicycle, motorcycle, car, truck, bus
    track_id: int            # even; +1 is the accessory / the two-wheeler under the rider
    t0: float                # entry time, s
    speed_mps: float
    path: np.ndarray         # (K, 2) polyline on the ground, world metres
    cum_m: np.ndarray        # (K,) arc length at each vertex
    height_m: float          # top above the ground (person, rider, vehicle)
    radius_m: float          # body radius (people), half width (vehicles)
    length_m: float          # vehicles and two-wheelers
    accessory: str | None
    albedo: tuple
    albedo2: tuple
    seed: int

    @property
    def t1(self) -> float:
        return self.t0 + float(self.cum_m[-1]) / self.speed_mps

    def pose(self, t: float) -> tuple[np.ndarray, float] | None:
        """Ground position (2,) and heading (rad) at time t, or None outside its lifetime."""
        s = (t - self.t0) * self.speed_mps
        if s < 0 or s > self.cum_m[-1]:
            return None
        k = int(np.clip(np.searchsorted(self.cum_m, s) - 1, 0, len(self.cum_m) - 2))
        seg = self.path[k + 1] - self.path[k]
        a = (s - self.cum_m[k]) / max(float(self.cum_m[k + 1] - self.cum_m[k]), 1e-12)
        return self.path[k] + a * seg, math.atan2(seg[1], seg[0])

    def objects(self, t: float) -> list[SceneObject]:
        pose = self.pose(t)
        if pose is None:
            return []
        (x, y), yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)

        def at(fwd, left):  # agent-local offset -> world (x, y)
            return x + c * fwd - s * left, y + s * fwd + c * left

        def obj(part, prims, albedo, tag, cls, foot, height, radius, cell=0.04):
            tid = self.track_id + part
            return SceneObject(tuple(prims), albedo, TAG[tag], tid % 65535 + 1, tid, COCO[cls],
                               self.seed + part, (x, y, 0.0), yaw, cell,
                               (foot[0], foot[1], 0.0), float(height), float(radius))

        h, r = self.height_m, self.radius_m
        if self.kind in ("car", "truck", "bus"):
            hx, hy = self.length_m / 2, r
            if self.kind == "car":
                cx, cy = at(-0.08 * self.length_m, 0.0)
                prims = [Box(x, y, yaw, hx, hy, 0.0, 0.62 * h),
                         Box(cx, cy, yaw, 0.3 * self.length_m, 0.88 * hy, 0.62 * h, h)]
            else:
                prims = [Box(x, y, yaw, hx, hy, 0.0, h)]
            return [obj(0, prims, self.albedo, self.kind, self.kind, (x, y), h, r, cell=0.06)]
        if self.kind == "pedestrian":
            out = [obj(0, _person(x, y, h, r), self.albedo, "pedestrian", "person", (x, y), h, r)]
            if self.accessory is not None:
                out.append(self._accessory(obj, at, yaw, h, r))
            return out
        # two-wheeler with its rider sitting slightly behind the middle
        rx, ry = at(-0.15, 0.0)
        vx, vy = at(0.0, 0.0)
        if self.kind == "bicycle":
            vehicle = Box(vx, vy, yaw, 0.85, 0.16, 0.0, 1.0)
            seat = 0.6
        else:
            vehicle = Box(vx, vy, yaw, 1.05, 0.38, 0.0, 1.1)
            seat = 0.7
        return [obj(0, _person(rx, ry, h, r, z0=seat), self.albedo, "rider", "person", (rx, ry),
                    h, r),
                obj(1, [vehicle], self.albedo2, self.kind, self.kind, (vx, vy), vehicle.z1,
                    vehicle.hy, cell=0.05)]

    def _accessory(self, obj, at, yaw, h, r) -> SceneObject:
        kind = self.accessory
        if kind == "handbag":
            bx, by = at(0.0, r + 0.07)
            prim, radius = Box(bx, by, yaw, 0.14, 0.05, 0.5, 0.8), 0.14
        elif kind == "backpack":
            bx, by = at(-(r + 0.08), 0.0)
            prim, radius = Box(bx, by, yaw, 0.08, 0.15, 0.52 * h, 0.78 * h), 0.15
        elif kind == "umbrella":
            bx, by = at(0.05, 0.0)
            radius = 0.5
            prim = Cylinder(bx, by, radius, h + 0.08, h + 0.2)
        else:  # suitcase rolled behind
            bx, by = at(-(r + 0.4), 0.12)
            prim, radius = Box(bx, by, yaw, 0.2, 0.11, 0.0, 0.62), 0.2
        return obj(1, [prim], self.albedo2, "dynamic", kind, (bx, by), prim.z1, radius, cell=0.03)


def _person(x: float, y: float, h: float, r: float, z0: float = 0.0) -> list[Cylinder]:
    head_h = HEAD_HEIGHT_RATIO * h
    return [Cylinder(x, y, r, z0, h - head_h), Cylinder(x, y, HEAD_RADIUS_RATIO * r, h - head_h, h)]


# -- spawning ------------------------------------------------------------------------------------
def _bezier(p0, p1, p2, n: int = 40) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - s) ** 2 * p0 + 2 * (1 - s) * s * p1 + s ** 2 * p2


def _edge_point(side: int, region, rng) -> np.ndarray:
    x0, x1, y0, y1 = region
    if side == 0:
        return np.array([x0 - 0.5, rng.uniform(y0, y1)])
    if side == 1:
        return np.array([x1 + 0.5, rng.uniform(y0, y1)])
    return np.array([rng.uniform(x0, x1), y0 - 0.5])


def _walk_path(region, rng) -> np.ndarray:
    """Enter from the left, right or near edge, leave by another one, curving through the middle."""
    x0, x1, y0, y1 = region
    a = int(rng.integers(3))
    b = (a + 1 + int(rng.integers(2))) % 3
    mid = np.array([rng.uniform(x0 + 0.2 * (x1 - x0), x1 - 0.2 * (x1 - x0)),
                    rng.uniform(y0 + 0.1 * (y1 - y0), y1 - 0.05 * (y1 - y0))])
    return _bezier(_edge_point(a, region, rng), mid, _edge_point(b, region, rng))


def _road_path(region, road_y: float, rng, lane_m: float) -> np.ndarray:
    x0, x1 = region[0] - 6.0, region[1] + 6.0
    if rng.random() < 0.5:
        return np.array([[x0, road_y - lane_m], [x1, road_y - lane_m]])
    return np.array([[x1, road_y + lane_m], [x0, road_y + lane_m]])


def make_agent(kind: str, track_id: int, t0: float, layout: Layout, rng: np.random.Generator,
               accessory_prob: float) -> Agent:
    region = layout.region
    accessory = None
    length = 0.0
    if kind == "pedestrian":
        h, r = rng.uniform(1.5, 1.95), rng.uniform(0.17, 0.23)
        path = _walk_path(region, rng)
        if rng.random() < accessory_prob:
            accessory = str(rng.choice(ACCESSORIES, p=[0.35, 0.3, 0.2, 0.15]))
    elif kind in ("bicycle", "motorcycle"):
        h, r = rng.uniform(1.65, 1.9), rng.uniform(0.18, 0.22)
        length = 1.7 if kind == "bicycle" else 2.1
        path = (_road_path(region, layout.road_y, rng, ROAD_HALF_M * 0.75)
                if rng.random() < 0.6 else _walk_path(region, rng))
    else:
        dims = {"car": ((4.2, 4.9), (0.87, 0.95), (1.4, 1.6)),
                "truck": ((6.0, 8.0), (1.15, 1.25), (2.8, 3.4)),
                "bus": ((10.0, 12.0), (1.25, 1.28), (3.0, 3.2))}[kind]
        length, r, h = (rng.uniform(*d) for d in dims)
        path = _road_path(region, layout.road_y, rng, ROAD_HALF_M * 0.5)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    palette = _PAINT if kind in ("car", "truck", "bus") else _CLOTHES
    albedo = np.clip(palette[rng.integers(len(palette))] * rng.uniform(0.8, 1.2, 3), 0.03, 1.0)
    albedo2 = np.clip(_CLOTHES[rng.integers(len(_CLOTHES))] * rng.uniform(0.7, 1.3, 3), 0.03, 1.0)
    return Agent(kind, track_id, float(t0), float(rng.uniform(*SPEED_MPS[kind])), path, cum,
                 float(h), float(r), float(length), accessory, tuple(albedo), tuple(albedo2),
                 int(rng.integers(1 << 30)))


class AgentSpawner:
    """All agents of a scene, generated lazily block by block; ``alive(t)`` lists those present.

    ``n_agents``: the mean number present at once; ``mix``: shares of pedestrians, vehicles (car
    80%, truck 10%, bus 10%) and two-wheelers (bicycle 75%, motorcycle 25%).
    """

    def __init__(self, layout: Layout, seed: int, n_agents: float, mix, accessory_prob: float):
        self.layout, self.seed = layout, seed
        self.accessory_prob = accessory_prob
        x0, x1, y0, y1 = layout.region
        width = x1 - x0
        mix = np.asarray(mix, dtype=np.float64) / np.sum(mix)
        groups = [("pedestrian", 1.0, 1.25 * width), ("car", 0.8, width + 12),
                  ("truck", 0.1, width + 12), ("bus", 0.1, width + 12),
                  ("bicycle", 0.75, width + 6), ("motorcycle", 0.25, width + 6)]
        share = {"pedestrian": mix[0], "car": mix[1], "truck": mix[1], "bus": mix[1],
                 "bicycle": mix[2], "motorcycle": mix[2]}
        self.rates = {}   # arrivals per second: n * share / mean lifetime
        for kind, sub, length in groups:
            life = length / np.mean(SPEED_MPS[kind])
            self.rates[kind] = n_agents * share[kind] * sub / life
        longest = 2.0 * math.hypot(x1 - x0 + 12, y1 - y0 + 12)
        self.max_life_s = longest / min(v[0] for v in SPEED_MPS.values())
        self._block = lru_cache(maxsize=256)(self._make_block)

    def _make_block(self, b: int) -> tuple[Agent, ...]:
        rng = np.random.default_rng([self.seed, 1, b + _BLOCK_OFFSET])
        agents = []
        for kind, rate in self.rates.items():
            for _ in range(int(rng.poisson(rate * BLOCK_S))):
                if len(agents) >= _SLOTS:
                    break
                t0 = (b + rng.random()) * BLOCK_S
                tid = ((b + _BLOCK_OFFSET) * _SLOTS + len(agents)) * 2
                agents.append(make_agent(kind, tid, t0, self.layout, rng, self.accessory_prob))
        return tuple(agents)

    def alive(self, t: float) -> list[Agent]:
        first = math.floor((t - self.max_life_s) / BLOCK_S)
        out = []
        for b in range(first, math.floor(t / BLOCK_S) + 1):
            out.extend(a for a in self._block(b) if a.t0 <= t <= a.t1)
        return out
