"""The static part of a synthetic scene: where agents may walk, a road, buildings, poles, trees,
benches, the textured ground and the sky. Rendered once per sequence and view."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from staticdepth.dataset.synth.render import (AMBIENT, DIFFUSE, SUN_W, Box, Canvas, Cylinder,
                                              SceneObject, View, draw)
from staticdepth.dataset.synth.texture import fractal_noise, hash01
from staticdepth.errors import InputError

# CARLA 0.9.14+ semantic tags (LibCarla/source/carla/rpc/ObjectLabel.h).
TAG = {"none": 0, "road": 1, "sidewalk": 2, "building": 3, "wall": 4, "fence": 5, "pole": 6,
       "vegetation": 9, "terrain": 10, "sky": 11, "pedestrian": 12, "rider": 13, "car": 14,
       "truck": 15, "bus": 16, "motorcycle": 18, "bicycle": 19, "static": 20, "dynamic": 21}

ROAD_HALF_M = 3.5
_MARGIN_M = 1.0


@dataclass(frozen=True, eq=False)
class Layout:
    """``region``: the rectangle (x0, x1, y0, y1) of ground, metres, where agents move (the visible
    ground up to ``max_range_m`` plus a margin, so agents enter and leave the view); a road along X
    at ``road_y``; the static objects."""

    region: tuple[float, float, float, float]
    road_y: float
    objects: tuple[SceneObject, ...]


def activity_region(view: View, max_range_m: float) -> tuple[float, float, float, float]:
    """Bounding rectangle of the ground seen by ``view`` no farther than ``max_range_m`` ahead."""
    D = view.dirs_w[::4, ::4].reshape(-1, 3)
    down = D[:, 2] < -1e-9
    t = -view.origin_w[2] / D[down, 2]
    P = view.origin_w + t[:, None] * D[down]
    P = P[(P[:, 1] <= view.origin_w[1] + max_range_m) & (P[:, 1] > view.origin_w[1])]
    if len(P) < 4:
        raise InputError(f"the camera sees no ground within max_range_m={max_range_m} m: "
                         "pitch it down or raise max_range_m")
    return (float(P[:, 0].min()) - _MARGIN_M, float(P[:, 0].max()) + _MARGIN_M,
            float(P[:, 1].min()) - _MARGIN_M, float(P[:, 1].max()))


def _clamp01(c) -> tuple[float, float, float]:
    return tuple(float(x) for x in np.clip(c, 0.02, 1.0))


def make_layout(view: View, max_range_m: float, n_buildings: int, n_props: int,
                rng: np.random.Generator) -> Layout:
    x0, x1, y0, y1 = region = activity_region(view, max_range_m)
    road_y = float(rng.uniform(y0 + 0.3 * (y1 - y0), y0 + 0.7 * (y1 - y0)))
    objs: list[SceneObject] = []
    seed = int(rng.integers(1 << 30))

    def add(prims, albedo, tag, cell=0.06):
        objs.append(SceneObject(tuple(prims), _clamp01(albedo), TAG[tag], tex_seed=seed + len(objs),
                                tex_cell_m=cell))

    # Buildings: a row beyond the far edge, the rest beyond the sides.
    n_far = max(1, (n_buildings + 1) // 2) if n_buildings else 0
    xs = np.linspace(x0 - 20.0, x1 + 20.0, n_far + 1)
    for k in range(n_far):
        w = (xs[k + 1] - xs[k]) * rng.uniform(0.7, 0.95)
        depth = rng.uniform(8, 15)
        add([Box(float(xs[k] + xs[k + 1]) / 2, y1 + 3.0 + depth / 2 + rng.uniform(0, 6), 0.0,
                 w / 2, depth / 2, 0.0, rng.uniform(6, 22))],
            rng.uniform(0.35, 0.8) * np.array([1.0, rng.uniform(0.85, 1.0), rng.uniform(0.7, 1.0)]),
            "building", cell=0.15)
    for k in range(n_buildings - n_far):
        side = -1 if k % 2 == 0 else 1
        w = rng.uniform(6, 12)
        y = rng.uniform(y0 + 0.2 * (y1 - y0), y1)
        x = (x0 - 3.0 - w / 2) if side < 0 else (x1 + 3.0 + w / 2)
        add([Box(x, y, 0.0, w / 2, rng.uniform(4, 9), 0.0, rng.uniform(5, 18))],
            rng.uniform(0.35, 0.8) * np.array([rng.uniform(0.8, 1.0), 1.0, rng.uniform(0.8, 1.0)]),
            "building", cell=0.15)

    # Props on the pavement, off the road: poles, trees, benches.
    for _ in range(n_props):
        for _try in range(20):
            x, y = rng.uniform(x0 + 1, x1 - 1), rng.uniform(y0 + 1, y1 - 1)
            if abs(y - road_y) > ROAD_HALF_M + 1.0:
                break
        kind = rng.choice(["pole", "tree", "bench"], p=[0.35, 0.4, 0.25])
        if kind == "pole":
            add([Cylinder(x, y, rng.uniform(0.07, 0.12), 0.0, rng.uniform(3.5, 6.0))],
                (0.45, 0.45, 0.48), "pole")
        elif kind == "tree":
            top = rng.uniform(4.0, 6.5)
            add([Cylinder(x, y, rng.uniform(0.12, 0.2), 0.0, 2.4),
                 Cylinder(x, y, rng.uniform(1.0, 1.8), 2.2, top)],
                (0.25, 0.45, 0.18), "vegetation", cell=0.08)
        else:
            add([Box(x, y, rng.uniform(0, np.pi), 0.9, 0.25, 0.0, 0.5)], (0.5, 0.35, 0.2),
                "static")
    return Layout(region, road_y, tuple(objs))


def ground_sky(view: View, layout: Layout, seed: int, focal_px: float,
               finest_m: float) -> Canvas:
    """The ground plane and the sky over the whole view, as a fresh canvas."""
    h, w = view.height, view.width
    D = view.dirs_w.reshape(-1, 3)
    rgb = np.zeros((h * w, 3))
    depth = np.full(h * w, np.inf)
    tags = np.full(h * w, TAG["sky"], np.uint8)
    g = D[:, 2] < -1e-9
    t = -view.origin_w[2] / D[g, 2]
    P = view.origin_w + t[:, None] * D[g]
    depth[g] = t
    tags[g] = TAG["road"]
    cos_in = -D[g, 2] / np.linalg.norm(D[g], axis=1)
    footprint = t / focal_px / np.maximum(cos_in, 0.1)
    noise = fractal_noise(P[:, :2], finest_m, 6, seed, footprint)
    on_road = np.abs(P[:, 1] - layout.road_y) < ROAD_HALF_M
    tile = np.floor(P[:, :2] / 0.6).astype(np.int64)
    tile_light = hash01(tile, seed + 11)
    paving = np.array([0.62, 0.57, 0.5]) * (0.88 + 0.2 * tile_light)[:, None]
    slab = hash01(np.floor(P[:, :2] / 3.0).astype(np.int64), seed + 12)
    asphalt = np.array([0.32, 0.32, 0.34]) * (0.9 + 0.2 * slab)[:, None]
    albedo = np.where(on_road[:, None], asphalt, paving) * (0.55 + 0.9 * noise)[:, None]
    rgb[g] = albedo * (AMBIENT + DIFFUSE * SUN_W[2]) * 255.0
    e = np.clip(D[~g, 2] / np.linalg.norm(D[~g], axis=1), 0.0, 1.0)
    top, horizon = np.array([70, 130, 210.0]), np.array([200, 215, 230.0])
    rgb[~g] = horizon + (top - horizon) * np.clip(e * 2.5, 0, 1)[:, None]
    return Canvas(np.clip(rgb, 0, 255).astype(np.uint8).reshape(h, w, 3),
                  depth.astype(np.float32).reshape(h, w),
                  np.zeros((h, w), np.uint16), tags.reshape(h, w))


def render_static(view: View, layout: Layout, seed: int, focal_px: float, finest_m: float,
                  full_frame: bool = False) -> Canvas:
    """Ground, sky and every static object, z-buffered."""
    canvas = ground_sky(view, layout, seed, focal_px, finest_m)
    for obj in layout.objects:
        draw(view, canvas, obj, focal_px, full_frame=full_frame)
    return canvas
