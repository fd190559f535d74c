"""A small rectified stereo scene with known geometry for the stereo-baseline tests.

A camera ``height_m`` above a textured ground plane, pitched down, looking at a textured wall,
with an optional textured box (an "agent") standing on the ground. Both views are ray-cast
exactly (3x3 supersampled), so the true left depth and disparity are known everywhere.
The tests in this file check the scene itself against closed forms.
"""
from __future__ import annotations

import math

import numpy as np

from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.geometry.camera import Camera, Mounting, StereoRig

WIDTH, HEIGHT, FOCAL = 192, 96, 100.0
HEIGHT_M, PITCH_DEG, BASELINE_M, WALL_M = 3.0, 25.0, 0.5, 15.0


def camera(width: int = WIDTH, height: int = HEIGHT, focal: float = FOCAL) -> Camera:
    return Camera.from_intrinsics(focal, focal, (width - 1) / 2, (height - 1) / 2, width, height)


def _texture(seed: int, a: np.ndarray, b: np.ndarray, freq: tuple[float, float]) -> np.ndarray:
    """Smooth random colour texture of plane coordinates (a, b) in metres -> (..., 3) in [0, 1]."""
    g = np.random.default_rng(seed)
    out = np.full(a.shape + (3,), 0.5)
    for _ in range(6):
        fa, fb = g.uniform(*freq, 2) * g.choice([-1, 1], 2)
        phase = g.uniform(0, 2 * math.pi)
        amp = g.uniform(0.3, 1.0, 3) * 0.08
        out += amp * np.sin(2 * math.pi * (fa * a + fb * b) + phase)[..., None]
    return np.clip(out, 0, 1)


def _cast(cam: Camera, centre_x: float, box: tuple[float, float, float, float] | None,
          ss: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) float image and (H, W) depth at pixel centres, camera at (centre_x, 0, 0)."""
    t = math.radians(PITCH_DEG)
    n = np.array([0.0, math.cos(t), math.sin(t)])       # ground normal, camera frame
    fwd = np.array([0.0, -math.sin(t), math.cos(t)])    # horizontal forward
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    u = np.arange(cam.width)[None, :, None, None] + offs[None, None, None, :]
    v = np.arange(cam.height)[:, None, None, None] + offs[None, None, :, None]
    u, v = np.broadcast_arrays(u, v)
    r = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    nr, fr = r @ n, r @ fwd
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_g = np.where(nr > 1e-9, HEIGHT_M / nr, np.inf)
        lam_w = np.where(fr > 1e-9, WALL_M / fr, np.inf)
        lam_b = np.full_like(lam_g, np.inf)
        if box is not None:
            x0, x1, dist, top = box
            lb = np.where(fr > 1e-9, dist / fr, np.inf)
            p = lb[..., None] * r
            x, up = p[..., 0] + centre_x, HEIGHT_M - p @ n
            lam_b = np.where((x >= x0) & (x <= x1) & (up >= 0) & (up <= top), lb, np.inf)
    lam = np.minimum(np.minimum(lam_g, lam_w), lam_b)
    p = lam[..., None] * r
    x, along, up = p[..., 0] + centre_x, p @ fwd, HEIGHT_M - p @ n
    img = np.where((lam == lam_g)[..., None], _texture(1, x, along, (0.2, 0.9)),
                   _texture(2, x, up, (0.1, 0.5)))
    if box is not None:
        img = np.where((lam == lam_b)[..., None], _texture(3, x, up, (0.8, 1.6)), img)
    mid = ss // 2
    return img.mean((2, 3)), lam[:, :, mid, mid]  # depth = lam, since r_z = 1


def render_pair(frame: int | None = None, cam: Camera | None = None, ss: int = 3) -> dict:
    """Left/right uint8 views and their depths (metres) of the scene; ``frame`` places a box
    (None: no box)."""
    cam = cam or camera()
    box = None
    if frame is not None:
        x0 = -3.0 + 1.1 * (frame % 6)
        box = (x0, x0 + 1.2, 6.0 + 0.8 * (frame % 4), 1.8)
    left, depth = _cast(cam, 0.0, box, ss)
    right, depth_right = _cast(cam, BASELINE_M, box, ss)
    u8 = lambda a: np.round(a * 255).astype(np.uint8)  # noqa: E731
    return {"left": u8(left), "right": u8(right), "depth": depth.astype(np.float32),
            "depth_right": depth_right.astype(np.float32)}


def write_sequence(path, n_frames: int = 12, adapt_frames: int = 8, *, stereo: bool = True,
                   rig: bool = True, cam: Camera | None = None) -> str:
    """A sequence file of the scene, the box moving from frame to frame."""
    cam = cam or camera()
    meta = SequenceMeta(name="baseline-test", camera=cam, gt_kind="synthetic",
                        adapt_frames=adapt_frames,
                        rig=StereoRig.rectified(cam, BASELINE_M) if rig else None,
                        mounting=Mounting.from_pitch_roll(HEIGHT_M, PITCH_DEG))
    streams = ("left", "right", "depth") if stereo else ("left", "depth")
    with SequenceWriter(path, meta, streams=streams) as w:
        for i in range(n_frames):
            fr = render_pair(i, cam)
            w.append(**{k: fr[k] for k in streams})
    return str(path)


def test_scene_depth_matches_closed_forms():
    d = render_pair(None)["depth"]
    cam = camera()
    t = math.radians(PITCH_DEG)
    v = HEIGHT - 1                      # bottom row sees the ground: Z = H / (n . r)
    y = (v - cam.cy) / cam.fy
    np.testing.assert_allclose(d[v], HEIGHT_M / (math.cos(t) * y + math.sin(t)), rtol=1e-5)
    y0 = (0 - cam.cy) / cam.fy          # top row sees the wall: Z = D / (fwd . r)
    np.testing.assert_allclose(d[0], WALL_M / (-math.sin(t) * y0 + math.cos(t)), rtol=1e-5)
    assert 3.0 < np.nanmin(d) and np.nanmax(d) < 20.0


def test_scene_views_are_a_rectified_pair():
    """The right view at column u - f B / Z shows what the left view shows at u."""
    fr = render_pair(None, ss=1)
    cam = camera()
    disp = cam.fx * BASELINE_M / fr["depth"]
    v, u = 60, 120
    ur = u - disp[v, u]
    k = int(math.floor(ur))
    a = ur - k
    right = fr["right"].astype(float)
    interp = (1 - a) * right[v, k] + a * right[v, k + 1]
    np.testing.assert_allclose(interp, fr["left"][v, u], atol=3.0)
    assert np.abs(right[v, u] - fr["left"][v, u]).max() > 3.0   # the views do differ there
