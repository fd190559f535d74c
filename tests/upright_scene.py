"""An independent scene generator for the locate tests (it does not use dataset/synth).

A ground plane z = 0 (world, z up), a camera ``height_m`` over the origin looking along +y,
pitched down by ``pitch_deg`` and rolled by ``roll_deg``; upright people as solid vertical
cylinders (radius 0.15-0.25 m, height 1.5-1.95 m) walking straight at constant velocity. Every
pixel's ray is intersected with every cylinder's side and top cap in closed form; the nearest hit
paints the instance map. Truth: each person's axis foot (its contact point) in the camera frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class UprightScene:
    width: int = 320
    height: int = 160
    focal_px: float = 240.0
    height_m: float = 5.0
    pitch_deg: float = 30.0
    roll_deg: float = 0.0
    n_people: int = 10
    fps: float = 10.0
    seed: int = 0
    bench: bool = False        # a static box (no instance) hiding person 0's feet in frame 0

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        t, r = math.radians(self.pitch_deg), math.radians(self.roll_deg)
        # world -> camera: camera axes (x right, y down, z forward) for a level camera facing +y
        # are x_w, -z_w, y_w; then pitch down about the camera's x axis, roll about its z axis.
        level = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
        pitch = np.array([[1, 0, 0], [0, math.cos(t), -math.sin(t)], [0, math.sin(t), math.cos(t)]])
        roll = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
        self.R = roll @ pitch @ level                     # cam_from_world rotation
        self.C = np.array([0.0, 0.0, self.height_m])      # camera centre (world)
        self.K = np.array([[self.focal_px, 0, (self.width - 1) / 2],
                           [0, self.focal_px, (self.height - 1) / 2], [0, 0, 1]])
        # people start where the camera sees the ground, 3-20 m ahead
        fwd = self.height_m / math.tan(t + math.atan((self.height / 2) / self.focal_px))
        y0 = rng.uniform(max(fwd + 1.0, 3.0), min(fwd + 14.0, 20.0), self.n_people)
        half_w = y0 * (self.width / 2) / self.focal_px * 0.8
        x0 = rng.uniform(-1, 1, self.n_people) * half_w
        ang = rng.uniform(0, 2 * math.pi, self.n_people)
        speed = rng.uniform(0.8, 1.8, self.n_people)
        self.start = np.stack([x0, y0], 1)
        self.velocity = speed[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
        self.radius = rng.uniform(0.15, 0.25, self.n_people)
        self.body_h = rng.uniform(1.5, 1.95, self.n_people)

    @property
    def normal(self) -> np.ndarray:
        """Ground normal in the camera frame (pointing to the ground); d = height_m."""
        return self.R @ np.array([0.0, 0.0, -1.0])

    def positions(self, i: int) -> np.ndarray:
        return self.start + self.velocity * (i / self.fps)

    def cam_from_world(self, P: np.ndarray) -> np.ndarray:
        return (np.asarray(P) - self.C) @ self.R.T

    def render(self, i: int) -> dict:
        """instances (H, W) uint16 (person k has id k + 1), contacts (N, 3) camera frame."""
        h, w = self.height, self.width
        vs, us = np.mgrid[0:h, 0:w]
        rays_c = np.stack([(us - self.K[0, 2]) / self.focal_px,
                           (vs - self.K[1, 2]) / self.focal_px, np.ones((h, w))], -1)
        D = rays_c.reshape(-1, 3) @ self.R                # world directions (R^T r)
        best = np.full(len(D), np.inf)
        inst = np.zeros(len(D), np.uint16)
        ox, oy, oz = self.C
        for k, (px, py) in enumerate(self.positions(i)):
            rad, top = self.radius[k], self.body_h[k]
            a = D[:, 0] ** 2 + D[:, 1] ** 2
            b = 2 * (D[:, 0] * (ox - px) + D[:, 1] * (oy - py))
            c = (ox - px) ** 2 + (oy - py) ** 2 - rad ** 2
            disc = b * b - 4 * a * c
            with np.errstate(invalid="ignore", divide="ignore"):
                s = (-b - np.sqrt(disc)) / (2 * a)        # entering the side
                z = oz + s * D[:, 2]
                side = (disc >= 0) & (s > 0) & (z >= 0) & (z <= top)
                s_cap = (top - oz) / D[:, 2]               # the top cap (seen from above)
                xc, yc = ox + s_cap * D[:, 0], oy + s_cap * D[:, 1]
                cap = (s_cap > 0) & ((xc - px) ** 2 + (yc - py) ** 2 <= rad ** 2)
            t_hit = np.where(side, s, np.inf)
            t_hit = np.minimum(t_hit, np.where(cap, s_cap, np.inf))
            nearer = t_hit < best
            best[nearer] = t_hit[nearer]
            inst[nearer] = k + 1
        if self.bench:                                     # axis-aligned box, slab method
            lo, hi = self.bench_box()
            with np.errstate(invalid="ignore", divide="ignore"):
                t0 = (lo - self.C) / D
                t1 = (hi - self.C) / D
            t_near = np.nanmax(np.minimum(t0, t1), axis=1)
            t_far = np.nanmin(np.maximum(t0, t1), axis=1)
            hit = (t_near <= t_far) & (t_near > 0) & (t_near < best)
            best[hit] = t_near[hit]
            inst[hit] = 0
        with np.errstate(invalid="ignore", divide="ignore"):
            t_ground = np.where(D[:, 2] < 0, -oz / D[:, 2], np.inf)
        depth = np.minimum(best, t_ground)                  # camera z of the hit (r_z = 1)
        feet_w = np.column_stack([self.positions(i), np.zeros(self.n_people)])
        return {"instances": inst.reshape(h, w), "contacts": self.cam_from_world(feet_w),
                "depth": np.where(np.isfinite(depth), depth, np.nan).reshape(h, w)}

    def bench_box(self) -> tuple[np.ndarray, np.ndarray]:
        """A 1.6 m wide, 0.3 m deep, 0.6 m high box 0.7 m in front of person 0 at frame 0."""
        px, py = self.start[0]
        toward = -np.array([px, py]) / np.hypot(px, py)       # from the person to the camera
        cx, cy = np.array([px, py]) + 0.7 * toward
        return np.array([cx - 0.8, cy - 0.15, 0.0]), np.array([cx + 0.8, cy + 0.15, 0.6])

    def write(self, path: str, frames: int) -> list[np.ndarray]:
        """A sequence file with the instances and agent rows (track = person); returns the true
        contacts per frame."""
        from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
        from staticdepth.dataset.schema import empty_agents
        from staticdepth.geometry.camera import Camera

        cam = Camera(self.K, self.width, self.height)
        meta = SequenceMeta(name="upright", camera=cam, gt_kind="none", source="test",
                            adapt_frames=frames, camera_height_m=self.height_m)
        truth = []
        rng = np.random.default_rng(self.seed + 1)
        background = rng.integers(40, 110, (self.height, self.width, 3), dtype=np.uint8)
        colours = rng.integers(190, 255, (self.n_people + 1, 3), dtype=np.uint8)
        with SequenceWriter(path, meta, streams=("left", "instances")) as wr:
            for i in range(frames):
                out = self.render(i)
                ids = np.unique(out["instances"])
                ids = ids[ids > 0]
                rows = empty_agents(len(ids))
                rows["instance_id"] = ids
                rows["class_id"] = 0
                rows["track_id"] = ids.astype(int) - 1
                img = np.where(out["instances"][..., None] > 0, colours[out["instances"]],
                               background)
                wr.append(left=img, instances=out["instances"], agents=rows,
                          timestamp=i / self.fps)
                truth.append(out["contacts"])
        return truth
