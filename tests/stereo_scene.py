"""An independent stereo scene with exact depth, for the temporal-fusion tests and benchmark.

Deliberately shares nothing with ``staticdepth.dataset.synth``: its own ray caster (a ground
plane, static boxes, moving upright cylinders for people), its own texture model (sums of
world-space sinusoidal gratings and a few hard-edged painted tiles instead of fractal value
noise), its own camera convention (world Z up, camera pitched down about its X axis), and
per-frame sensor noise (Gaussian, independent per view and frame), which a real camera has and
which makes each frame's match differ while the background stays put.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Scene:
    width: int = 320
    height: int = 160
    focal_px: float = 200.0
    camera_height_m: float = 7.0
    pitch_deg: float = 32.0
    baseline_m: float = 0.27
    n_people: int = 8
    noise_dn: float = 4.0
    fps: float = 10.0
    seed: int = 0


def _rotation(pitch_deg: float) -> np.ndarray:
    """Rows: camera x (right), y (down), z (forward) in world coordinates (Z up, looking +Y)."""
    t = math.radians(pitch_deg)
    return np.array([[1.0, 0.0, 0.0],
                     [0.0, -math.sin(t), -math.cos(t)],
                     [0.0, math.cos(t), -math.sin(t)]])


def _texture(P: np.ndarray, seed: int) -> np.ndarray:
    """Grey level in [20, 235] of world points (N, 3): gratings plus painted tiles."""
    rng = np.random.default_rng(seed)
    g = np.zeros(len(P))
    for _ in range(7):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        wavelength = rng.uniform(0.25, 1.6)
        g += np.sin(2 * np.pi * (P @ d) / wavelength + rng.uniform(0, 2 * np.pi))
    g = g / 7 * 3.0
    cell = np.floor(P / 0.9).astype(np.int64)
    h = (cell[:, 0] * 73856093 ^ cell[:, 1] * 19349663 ^ cell[:, 2] * 83492791 ^ seed) % 1000
    tile = (h < 250).astype(float) * 0.8 - (h > 850).astype(float) * 0.8
    return np.clip(128 + 45 * np.tanh(g + tile), 20, 235)


class SceneRenderer:
    """Renders frame i: left/right RGB uint8, left depth (m), left instance ids (0 = static)."""

    def __init__(self, scene: Scene = Scene()):
        self.s = s = scene
        rng = np.random.default_rng(s.seed)
        self._static: dict = {}
        self.R = _rotation(s.pitch_deg)                      # cam_from_world rotation
        self.C = np.array([0.0, 0.0, s.camera_height_m])     # left camera centre (world)
        # static boxes: (centre x, centre y, half x, half y, height)
        self.boxes = [(rng.uniform(-6, 6), rng.uniform(12, 30), rng.uniform(0.6, 1.8),
                       rng.uniform(0.6, 1.8), rng.uniform(1.0, 4.0)) for _ in range(4)]
        # people: start point, velocity (m/s), radius, height
        self.people = []
        for _ in range(s.n_people):
            p0 = np.array([rng.uniform(-5, 5), rng.uniform(7, 20)])
            a = rng.uniform(0, 2 * np.pi)
            self.people.append((p0, 1.3 * np.array([math.cos(a), math.sin(a)]),
                                rng.uniform(0.22, 0.32), rng.uniform(1.6, 1.9)))

    def _rays(self, cx_offset_m: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.s
        u, v = np.meshgrid(np.arange(s.width), np.arange(s.height))
        d_cam = np.stack([(u - (s.width - 1) / 2) / s.focal_px,
                          (v - (s.height - 1) / 2) / s.focal_px, np.ones_like(u, float)], -1)
        D = d_cam.reshape(-1, 3) @ self.R                     # world directions (z_cam = 1)
        O = self.C + self.R[0] * cx_offset_m                 # right camera: along camera +x
        return O, D

    def _cast_static(self, O: np.ndarray, D: np.ndarray) -> np.ndarray:
        """Ray parameter of the first hit on the ground or a box (inf = sky)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -O[2] / D[:, 2]
        t_best = np.where(t > 0, t, np.inf)
        for (bx, by, hx, hy, hz) in self.boxes:
            lo, hi = np.array([bx - hx, by - hy, 0.0]), np.array([bx + hx, by + hy, hz])
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - O) / D, (hi - O) / D
            a, b = np.minimum(t1, t2), np.maximum(t1, t2)
            tn = np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])
            tf = np.minimum(np.minimum(b[:, 0], b[:, 1]), b[:, 2])
            hit = (tn <= tf) & (tn > 0) & (tn < t_best)
            t_best = np.where(hit, tn, t_best)
        return t_best

    def _cast(self, O: np.ndarray, D: np.ndarray, t_s: float):
        key = tuple(O)
        if key not in self._static:
            self._static[key] = self._cast_static(O, D)
        t_best = self._static[key]
        ident = np.zeros(len(D), np.int64)                    # 0 static, k > 0 person k
        for k, (p0, vel, r, hgt) in enumerate(self.people, start=1):
            c = p0 + vel * t_s
            c = np.array([((c[0] + 7) % 14) - 7, 7 + (c[1] - 7) % 16])   # wrap in the area
            ox, oy = O[0] - c[0], O[1] - c[1]
            a = D[:, 0] ** 2 + D[:, 1] ** 2
            b = 2 * (ox * D[:, 0] + oy * D[:, 1])
            cc = ox ** 2 + oy ** 2 - r * r
            disc = b * b - 4 * a * cc
            with np.errstate(invalid="ignore"):
                tn = (-b - np.sqrt(disc)) / (2 * a)
            z = O[2] + tn * D[:, 2]
            hit = (disc > 0) & (tn > 0) & (z >= 0) & (z <= hgt) & (tn < t_best)
            # the head's top cap
            with np.errstate(divide="ignore", invalid="ignore"):
                tc = (hgt - O[2]) / D[:, 2]
            pc = O[:2] + tc[:, None] * D[:, :2]
            cap = (tc > 0) & (np.sum((pc - c) ** 2, axis=1) <= r * r) & (tc < t_best)
            cap &= ~hit | (tc < tn)
            t_new = np.where(cap, tc, np.where(hit, tn, t_best))
            ident[hit | cap] = k
            t_best = t_new
        return t_best, ident

    def render(self, i: int) -> dict:
        s = self.s
        t_s = i / s.fps
        out = {}
        noise = np.random.default_rng([s.seed, i, 7])
        for view, off in (("left", 0.0), ("right", s.baseline_m)):
            O, D = self._rays(off)
            t, ident = self._cast(O, D, t_s)
            P = O + t[:, None] * D
            sky = ~np.isfinite(t)
            grey = np.where(sky, 200.0, _texture(np.where(sky[:, None], 0, P), s.seed))
            tint = np.where(ident[:, None] > 0, np.array([1.1, 0.8, 0.7]), np.array([1.0, 1.0, 0.9]))
            rgb = grey[:, None] * tint + noise.normal(0, s.noise_dn, (len(t), 3))
            out[view] = np.clip(np.round(rgb), 0, 255).astype(np.uint8).reshape(
                s.height, s.width, 3)
            if view == "left":
                z = np.where(sky, np.nan, t)                  # direction has z_cam = 1
                out["depth"] = z.reshape(s.height, s.width).astype(np.float32)
                out["instances"] = ident.reshape(s.height, s.width).astype(np.uint16)
        return out

    @property
    def disparity_scale(self) -> float:
        """f B: disparity = f B / depth."""
        return self.s.focal_px * self.s.baseline_m


def region_scores(disparity: np.ndarray, gt_disparity: np.ndarray, mask: np.ndarray,
                  fB: float) -> tuple[int, int, int, float]:
    """(pixels in mask with truth, with a prediction, with error > 1 px, sum of |dZ| / Z).

    Pixels whose true match lies outside the right image (column u < d) have no stereo truth
    and are left out, as in the stereo benchmarks' non-occluded masks."""
    u = np.arange(gt_disparity.shape[1])[None, :]
    with np.errstate(invalid="ignore"):
        known = mask & np.isfinite(gt_disparity) & (u - gt_disparity >= 0)
    have = known & np.isfinite(disparity) & (disparity > 0)
    err = np.abs(disparity[have] - gt_disparity[have])
    z, z_gt = fB / disparity[have], fB / gt_disparity[have]
    return int(known.sum()), int(have.sum()), int((err > 1).sum()), float(
        np.sum(np.abs(z - z_gt) / z_gt))


class Tally:
    """Pooled bad-1, AbsRel and hole share of one method on one region over frames."""

    def __init__(self):
        self.known = self.have = self.bad = 0
        self.rel = 0.0

    def add(self, scores: tuple[int, int, int, float]) -> None:
        k, h, b, r = scores
        self.known += k
        self.have += h
        self.bad += b
        self.rel += r

    @property
    def bad1(self) -> float:
        return self.bad / max(self.have, 1)

    @property
    def abs_rel(self) -> float:
        return self.rel / max(self.have, 1)

    @property
    def holes(self) -> float:
        return 1 - self.have / max(self.known, 1)


def confidence_halves(confidence: np.ndarray, errors_px: np.ndarray, rel_errors: np.ndarray
                      ) -> dict[str, tuple[float, float]]:
    """(top half, bottom half) by confidence of: bad-1 rate, mean |error| px, AbsRel."""
    order = np.argsort(-confidence, kind="stable")
    top, bottom = order[: len(order) // 2], order[len(order) // 2:]
    return {"bad1": (float(np.mean(errors_px[top] > 1)), float(np.mean(errors_px[bottom] > 1))),
            "mae": (float(np.mean(errors_px[top])), float(np.mean(errors_px[bottom]))),
            "abs_rel": (float(np.mean(rel_errors[top])), float(np.mean(rel_errors[bottom])))}


class FusionScore:
    """Per-frame against fused disparities on one scene: tallies per region (``frame_bg``,
    ``fused_bg``, ``frame_agents``, ``fused_agents``) and the fused confidence's halves."""

    def __init__(self, fB: float):
        self.fB = fB
        self.t = {k: Tally() for k in ("frame_bg", "fused_bg", "frame_agents", "fused_agents")}
        self._conf, self._err, self._rel = [], [], []

    def add(self, frame: dict, disparity: np.ndarray, fused) -> None:
        """One frame (its ``depth`` and ``instances``), its own disparity and its FusedFrame."""
        fB, depth = self.fB, frame["depth"]
        gd = fB / depth
        bg = frame["instances"] == 0
        for name, dd in (("frame", disparity), ("fused", fused.disparity)):
            self.t[f"{name}_bg"].add(region_scores(dd, gd, bg, fB))
            self.t[f"{name}_agents"].add(region_scores(dd, gd, ~bg, fB))
        u = np.arange(gd.shape[1])[None, :]
        v = np.isfinite(fused.disparity) & np.isfinite(gd) & (u >= gd)
        self._conf.append(fused.confidence[v])
        self._err.append(np.abs(fused.disparity - gd)[v])
        self._rel.append(np.abs(fB / fused.disparity[v] - depth[v]) / depth[v])

    def halves(self) -> dict[str, tuple[float, float]]:
        return confidence_halves(*(np.concatenate(x) for x in (self._conf, self._err,
                                                                self._rel)))
