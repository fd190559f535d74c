"""Vectorised ray casting of upright primitives (vertical cylinders, yawed boxes) over the ground.

World frame: X east, Y north, Z up, ground at Z = 0, metres. A :class:`View` holds one pinhole
camera's centre and, per pixel, the world direction ``R_world_from_cam K^-1 [u, v, 1]`` whose
camera-frame z is 1, so the ray parameter of a hit IS its depth Z in that camera.

Objects are drawn into a :class:`Canvas` (colour, depth z-buffer, instance ids, CARLA semantic
tags) inside the screen rectangle their 3-D bounding box projects to; ``full_frame=True`` skips the
rectangle (the naive reference the benchmark compares against).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from staticdepth.dataset.synth.texture import fractal_noise, hash01

SUN_W = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])
AMBIENT, DIFFUSE = 0.45, 0.55
NEAR_M = 0.05


@dataclass(frozen=True)
class Cylinder:
    """Vertical solid cylinder: axis through (cx, cy), radius, from z0 to z1 (world, metres)."""

    cx: float
    cy: float
    radius: float
    z0: float
    z1: float

    def corners(self) -> np.ndarray:
        r = self.radius
        return _box_corners(self.cx, self.cy, 0.0, r, r, self.z0, self.z1)


@dataclass(frozen=True)
class Box:
    """Box standing on its base: centre (cx, cy), yaw about Z (rad), half sizes hx (along the yaw
    direction) and hy, from z0 to z1."""

    cx: float
    cy: float
    yaw: float
    hx: float
    hy: float
    z0: float
    z1: float

    def corners(self) -> np.ndarray:
        return _box_corners(self.cx, self.cy, self.yaw, self.hx, self.hy, self.z0, self.z1)


def _box_corners(cx, cy, yaw, hx, hy, z0, z1) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = []
    for ex in (-hx, hx):
        for ey in (-hy, hy):
            for z in (z0, z1):
                out.append((cx + c * ex - s * ey, cy + s * ex + c * ey, z))
    return np.array(out)


@dataclass(frozen=True, eq=False)
class SceneObject:
    """A rigid thing made of primitives; one instance (agents) or part of the background (id 0).

    ``tex_origin``/``tex_yaw`` fix the texture to the object so it moves with it. For agents,
    ``foot_w`` is the axis bottom on the ground, ``height_m`` the top above the ground.
    """

    prims: tuple
    albedo: tuple[float, float, float]
    tag: int
    instance_id: int = 0
    track_id: int = -1
    class_id: int = -1
    tex_seed: int = 0
    tex_origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tex_yaw: float = 0.0
    tex_cell_m: float = 0.05
    foot_w: tuple[float, float, float] | None = None
    height_m: float = float("nan")
    radius_m: float = float("nan")

    def corners(self) -> np.ndarray:
        return np.concatenate([p.corners() for p in self.prims])


@dataclass(frozen=True, eq=False)
class View:
    """A pinhole camera in the world: centre ``origin_w`` (3,), directions ``dirs_w`` (H, W, 3)."""

    origin_w: np.ndarray
    dirs_w: np.ndarray
    K: np.ndarray
    cam_from_world_R: np.ndarray

    @property
    def height(self) -> int:
        return self.dirs_w.shape[0]

    @property
    def width(self) -> int:
        return self.dirs_w.shape[1]

    def project(self, P_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixels (N, 2) and depths (N,)."""
        Pc = (np.asarray(P_w) - self.origin_w) @ self.cam_from_world_R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = Pc @ self.K.T
            return uvw[:, :2] / uvw[:, 2:3], Pc[:, 2]

    def rect(self, P_w: np.ndarray) -> tuple[int, int, int, int] | None:
        """Pixel rectangle (v0, v1, u0, u1), end-exclusive, containing the projection of the convex
        hull of points (N, 3); None when it is off-screen or behind the camera."""
        uv, z = self.project(P_w)
        if np.all(z <= NEAR_M):
            return None
        if np.any(z <= NEAR_M):
            return 0, self.height, 0, self.width
        u0 = max(int(np.floor(uv[:, 0].min())) - 1, 0)
        u1 = min(int(np.ceil(uv[:, 0].max())) + 2, self.width)
        v0 = max(int(np.floor(uv[:, 1].min())) - 1, 0)
        v1 = min(int(np.ceil(uv[:, 1].max())) + 2, self.height)
        if u0 >= u1 or v0 >= v1:
            return None
        return v0, v1, u0, u1


@dataclass(eq=False)
class Canvas:
    """What a view sees: RGB uint8 (H, W, 3), depth float32 (inf = nothing), instance ids uint16,
    CARLA semantic tags uint8."""

    rgb: np.ndarray
    depth: np.ndarray
    instances: np.ndarray
    tags: np.ndarray
    silhouettes: dict = field(default_factory=dict)

    def copy(self) -> "Canvas":
        return Canvas(self.rgb.copy(), self.depth.copy(), self.instances.copy(), self.tags.copy())


# -- intersections: t (depth) of the first hit per ray, inf for a miss, and a face code -----------
def hit_cylinder(c: Cylinder, O: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ox, oy, oz = O[0] - c.cx, O[1] - c.cy, O[2]
    dx, dy, dz = D[..., 0], D[..., 1], D[..., 2]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    disc = b * b - a * (ox * ox + oy * oy - c.radius ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = (-b - np.sqrt(disc)) / a
        z = oz + ts * dz
        t = np.where((disc >= 0) & (ts > 0) & (z >= c.z0) & (z <= c.z1), ts, np.inf)
        face = np.zeros(t.shape, np.int8)
        for zc, code, outside in ((c.z1, 1, oz > c.z1), (c.z0, 2, oz < c.z0)):
            if not outside:
                continue
            tc = (zc - oz) / dz
            x, y = ox + tc * dx, oy + tc * dy
            ok = (tc > 0) & (x * x + y * y <= c.radius ** 2) & (tc < t)
            t = np.where(ok, tc, t)
            face[ok] = code
    return t, face


def _local(b: Box, O: np.ndarray, D: np.ndarray):
    c, s = np.cos(b.yaw), np.sin(b.yaw)
    ox, oy = O[0] - b.cx, O[1] - b.cy
    lo = np.array([c * ox + s * oy, -s * ox + c * oy, O[2] - 0.5 * (b.z0 + b.z1)])
    ld = np.stack([c * D[..., 0] + s * D[..., 1], -s * D[..., 0] + c * D[..., 1], D[..., 2]], -1)
    return lo, ld


def hit_box(b: Box, O: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, ld = _local(b, O, D)
    half = (b.hx, b.hy, 0.5 * (b.z1 - b.z0))
    tmin = np.full(D.shape[:-1], -np.inf)
    tmax = np.full(D.shape[:-1], np.inf)
    axis = np.zeros(D.shape[:-1], np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):
            inv = 1.0 / np.where(ld[..., k] == 0, 1e-30, ld[..., k])
            t1, t2 = (-half[k] - lo[k]) * inv, (half[k] - lo[k]) * inv
            near, far = np.minimum(t1, t2), np.maximum(t1, t2)
            axis = np.where(near > tmin, k, axis).astype(np.int8)
            tmin = np.maximum(tmin, near)
            tmax = np.minimum(tmax, far)
    t = np.where((tmin <= tmax) & (tmin > 0), tmin, np.inf)
    sign = np.take_along_axis(ld, axis[..., None].astype(np.intp), -1)[..., 0] > 0
    return t, (axis * 2 + sign).astype(np.int8)   # face = 2 * axis + (ray runs along +axis)


def hit(prim, O, D):
    return hit_cylinder(prim, O, D) if isinstance(prim, Cylinder) else hit_box(prim, O, D)


def normals(prim, P: np.ndarray, face: np.ndarray) -> np.ndarray:
    """World normals (N, 3) at hit points P (N, 3) with face codes (N,)."""
    n = np.zeros_like(P)
    if isinstance(prim, Cylinder):
        side = face == 0
        n[side, 0] = P[side, 0] - prim.cx
        n[side, 1] = P[side, 1] - prim.cy
        n[side] /= prim.radius
        n[face == 1, 2] = 1.0
        n[face == 2, 2] = -1.0
        return n
    axis, positive_dir = face // 2, face % 2 == 1
    local = np.zeros_like(P)
    local[np.arange(len(P)), axis] = np.where(positive_dir, -1.0, 1.0)  # facing the ray
    c, s = np.cos(prim.yaw), np.sin(prim.yaw)
    n[:, 0] = c * local[:, 0] - s * local[:, 1]
    n[:, 1] = s * local[:, 0] + c * local[:, 1]
    n[:, 2] = local[:, 2]
    return n


def shade(albedo: np.ndarray, n_w: np.ndarray) -> np.ndarray:
    """Lambertian shading (view-independent, so both views agree): albedo (N, 3) -> RGB 0..255."""
    light = AMBIENT + DIFFUSE * np.clip(n_w @ SUN_W, 0.0, None)
    return np.clip(albedo * light[:, None] * 255.0, 0, 255)


def object_colors(obj: SceneObject, P: np.ndarray, n_w: np.ndarray, depth: np.ndarray,
                  focal_px: float) -> np.ndarray:
    """Colours (N, 3) uint8 of an object's surface points P (N, 3) seen at depths (N,)."""
    c, s = np.cos(obj.tex_yaw), np.sin(obj.tex_yaw)
    d = P - np.asarray(obj.tex_origin)
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], -1)
    tex = fractal_noise(local, obj.tex_cell_m, 3, obj.tex_seed, depth / focal_px)
    # coarse patches of a second hue make agents look less like flat paint
    patch = hash01(np.floor(local / 0.35).astype(np.int64), obj.tex_seed + 1)
    albedo = np.asarray(obj.albedo) * (0.55 + 0.7 * tex)[:, None] * (0.85 + 0.3 * patch)[:, None]
    return shade(albedo, n_w).astype(np.uint8)


def draw(view: View, canvas: Canvas, obj: SceneObject, focal_px: float,
         full_frame: bool = False) -> tuple[tuple[int, int, int, int] | None, int]:
    """Ray-cast ``obj`` into ``canvas`` with z-buffering.

    Returns the screen rectangle that was traced (or None) and the number of pixels of the
    object's own silhouette in it (before occlusion by anything else).
    """
    rect = (0, view.height, 0, view.width) if full_frame else view.rect(obj.corners())
    if rect is None:
        return None, 0
    v0, v1, u0, u1 = rect
    D = view.dirs_w[v0:v1, u0:u1]
    O = view.origin_w
    t_best = np.full(D.shape[:2], np.inf)
    which = np.full(D.shape[:2], -1, np.int8)
    face = np.zeros(D.shape[:2], np.int8)
    for k, prim in enumerate(obj.prims):
        t, f = hit(prim, O, D)
        closer = t < t_best
        t_best = np.where(closer, t, t_best)
        which[closer] = k
        face[closer] = f[closer]
    silhouette = int(np.count_nonzero(which >= 0))
    if silhouette == 0:
        return rect, 0
    zbuf = canvas.depth[v0:v1, u0:u1]
    win = t_best < zbuf
    if not np.any(win):
        return rect, silhouette
    vv, uu = np.nonzero(win)
    t = t_best[vv, uu]
    P = O + t[:, None] * D[vv, uu]
    n_w = np.zeros_like(P)
    w = which[vv, uu]
    for k, prim in enumerate(obj.prims):
        sel = w == k
        if np.any(sel):
            n_w[sel] = normals(prim, P[sel], face[vv, uu][sel])
    rgb = object_colors(obj, P, n_w, t, focal_px)
    vv, uu = vv + v0, uu + u0
    canvas.depth[vv, uu] = t
    canvas.rgb[vv, uu] = rgb
    canvas.instances[vv, uu] = obj.instance_id
    canvas.tags[vv, uu] = obj.tag
    return rect, silhouette
