"""Scene configuration (a frozen dataclass with named presets) and :class:`SyntheticScene`.

A scene is a fixed, rectified stereo pair at ``camera_height_m`` over a textured ground plane,
pitched down by ``pitch_deg`` (and rolled by ``roll_deg``) per ``normal_from_pitch_roll``, with
static structures and moving agents. Everything follows from the config, seed included.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

import numpy as np

from staticdepth.dataset.schema import empty_agents
from staticdepth.dataset.synth.agents import AgentSpawner
from staticdepth.dataset.synth.layout import TAG, make_layout, render_static
from staticdepth.dataset.synth.render import View, draw
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, Mounting, StereoRig
from staticdepth.geometry.projection import ray_grid

# Bounds on the image size: a 100000x100000 request otherwise fails inside numpy (MemoryError).
MAX_SIDE_PX = 8192
MAX_PIXELS = 4096 * 4096

@dataclass(frozen=True)
class SceneConfig:
    """Everything that defines a synthetic sequence. Lengths in metres, angles in degrees."""

    name: str = "custom"
    width: int = 800
    height: int = 400
    hfov_deg: float = 90.0          # horizontal field of view (CARLA's ``fov``)
    focal_px: float = 0.0           # > 0: use this focal length instead of hfov_deg
    camera_height_m: float = 5.0
    pitch_deg: float = 25.0         # down from level
    roll_deg: float = 0.0
    baseline_m: float = 0.27        # right camera this far along the left camera's +X
    fps: float = 10.0
    n_agents: float = 24.0          # mean number of agents in the activity region at once
    agent_mix: tuple[float, float, float] = (0.65, 0.2, 0.15)  # pedestrians, vehicles, 2-wheelers
    accessory_prob: float = 0.3     # share of pedestrians with a bag, backpack, umbrella, suitcase
    max_range_m: float = 25.0       # agents move on the visible ground up to this far ahead
    n_buildings: int = 8
    n_props: int = 12               # poles, trees, benches
    texture_m: float = 0.04         # finest ground texture cell
    seed: int = 0

    def __post_init__(self):
        checks = [
            (self.width >= 16 and self.height >= 16, f"image size must be at least 16x16, got "
                                                     f"{self.width}x{self.height}"),
            (self.width <= MAX_SIDE_PX, f"width must be at most {MAX_SIDE_PX}, got {self.width}"),
            (self.height <= MAX_SIDE_PX,
             f"height must be at most {MAX_SIDE_PX}, got {self.height}"),
            (self.width * self.height <= MAX_PIXELS,
             f"width x height must be at most {MAX_PIXELS:,} pixels (e.g. 4096x4096), got "
             f"{self.width}x{self.height}"),
            (10.0 <= self.hfov_deg <= 160.0, f"hfov_deg must be in [10, 160], got {self.hfov_deg}"),
            (self.focal_px >= 0, f"focal_px must be >= 0 (0 = from hfov_deg), got {self.focal_px}"),
            (0.3 <= self.camera_height_m <= 100, "camera_height_m must be in [0.3, 100], got "
                                                 f"{self.camera_height_m}"),
            (-10.0 <= self.pitch_deg <= 80.0,
             f"pitch_deg must be in [-10, 80], got {self.pitch_deg}"),
            (abs(self.roll_deg) <= 30.0, f"roll_deg must be within +-30, got {self.roll_deg}"),
            (0 < self.baseline_m <= 5, f"baseline_m must be in (0, 5], got {self.baseline_m}"),
            (self.fps > 0, f"fps must be positive, got {self.fps}"),
            (0 <= self.n_agents <= 200, f"n_agents must be in [0, 200], got {self.n_agents}"),
            (len(self.agent_mix) == 3 and min(self.agent_mix) >= 0 and sum(self.agent_mix) > 0,
             f"agent_mix must be 3 non-negative shares (pedestrians, vehicles, two-wheelers) with "
             f"a positive sum, got {self.agent_mix}"),
            (0 <= self.accessory_prob <= 1, f"accessory_prob must be in [0, 1], got "
                                            f"{self.accessory_prob}"),
            (5 <= self.max_range_m <= 200, f"max_range_m must be in [5, 200], got "
                                           f"{self.max_range_m}"),
            (self.n_buildings >= 0 and self.n_props >= 0, "n_buildings and n_props must be >= 0"),
            (0.005 <= self.texture_m <= 1.0, f"texture_m must be in [0.005, 1], got "
                                             f"{self.texture_m}"),
        ]
        for ok, message in checks:
            if not ok:
                raise InputError(f"scene config: {message}")

    @property
    def focal(self) -> float:
        """Focal length in pixels (square pixels)."""
        if self.focal_px > 0:
            return float(self.focal_px)
        return self.width / (2.0 * math.tan(math.radians(self.hfov_deg) / 2.0))

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["agent_mix"] = list(self.agent_mix)
        return d


_FIELD_TYPES = typing.get_type_hints(SceneConfig)


def _coerce(key: str, value: Any) -> Any:
    """A value from YAML, JSON or ``--set key=value`` (strings) into the field's type."""
    kind = _FIELD_TYPES[key]
    try:
        if kind is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(float(value)) if isinstance(value, str) else int(value)
        if kind is float:
            return float(value)
        if kind is str:
            return str(value)
        parts = value.replace("(", "").replace(")", "").split(",") if isinstance(value, str) \
            else list(value)
        return tuple(float(p) for p in parts)
    except (TypeError, ValueError):
        raise InputError(f"scene config: {key} expects {getattr(kind, '__name__', kind)}, "
                         f"got {value!r}") from None


def config_from_dict(d: Mapping[str, Any], base: SceneConfig | None = None) -> SceneConfig:
    """A config from ``base`` (default: the defaults) with the keys of ``d``; unknown keys raise."""
    names = [f.name for f in dataclasses.fields(SceneConfig)]
    unknown = sorted(set(d) - set(names))
    if unknown:
        raise InputError(f"scene config: unknown setting(s) {', '.join(map(repr, unknown))}; "
                         f"known: {', '.join(names)}")
    values = {k: _coerce(k, v) for k, v in d.items()}
    return dataclasses.replace(base or SceneConfig(), **values)


PRESETS: dict[str, SceneConfig] = {
    # level camera at eye height, the kind of view off-the-shelf depth networks are trained on
    "street": SceneConfig(name="street", hfov_deg=80.0, camera_height_m=1.6, pitch_deg=0.0,
                          n_agents=25, max_range_m=30.0),
    # CARLA-like (800x400, 90 deg fov, f = 400): heights from the paper's Table 2
    "c1": SceneConfig(name="c1", camera_height_m=5.4, pitch_deg=25.0),
    "c2": SceneConfig(name="c2", camera_height_m=9.7, pitch_deg=35.0, n_agents=30,
                      max_range_m=35.0),
    "c3": SceneConfig(name="c3", camera_height_m=5.3, pitch_deg=20.0),
    # the paper's real outdoor scene R2: about 5 m up, tilted, a little roll
    "r2": SceneConfig(name="r2", hfov_deg=70.0, camera_height_m=5.0, pitch_deg=30.0,
                      roll_deg=1.5, agent_mix=(0.85, 0.05, 0.1)),
    # small and fast, for the demo and the tests
    "demo": SceneConfig(name="demo", width=400, height=200, camera_height_m=5.0, pitch_deg=25.0,
                        n_agents=14, max_range_m=20.0, n_buildings=6, n_props=6),
}


def preset(name: str, **overrides: Any) -> SceneConfig:
    """A named preset with some fields replaced, e.g. ``preset("c1", seed=3, width=400)``."""
    if name not in PRESETS:
        raise InputError(f"unknown scene preset {name!r}; known: {', '.join(PRESETS)}")
    return config_from_dict(overrides, PRESETS[name])


def cam_from_world_rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """R with P_cam = R (P_world - C): camera looking along world +Y, pitched down, then rolled
    about its optical axis, so that R (0, 0, -1) = normal_from_pitch_roll(pitch, roll)."""
    t, r = math.radians(pitch_deg), math.radians(roll_deg)
    x_c = np.array([1.0, 0.0, 0.0])                        # camera axes in the world, level roll
    y_c = np.array([0.0, -math.sin(t), -math.cos(t)])
    z_c = np.array([0.0, math.cos(t), -math.sin(t)])
    R_pitch = np.stack([x_c, y_c, z_c])                    # rows: camera axes
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return Rz @ R_pitch


class SyntheticScene:
    """A deterministic synthetic fixed-camera stereo sequence; frames are rendered on demand.

    World frame: X east, Y north (the camera looks north), Z up, ground Z = 0, left camera at
    (0, 0, camera_height_m).
    """

    def __init__(self, config: SceneConfig | None = None):
        self.config = cfg = config or SceneConfig()
        f = cfg.focal
        self.camera = Camera.from_intrinsics(f, f, cfg.width / 2.0, cfg.height / 2.0, cfg.width,
                                             cfg.height)
        self.mounting = Mounting.from_pitch_roll(cfg.camera_height_m, cfg.pitch_deg, cfg.roll_deg,
                                                 source="synthetic")
        self.rig = StereoRig.rectified(self.camera, cfg.baseline_m, mounting=self.mounting)
        self.cam_from_world_R = cam_from_world_rotation(cfg.pitch_deg, cfg.roll_deg)
        self.camera_center_w = np.array([0.0, 0.0, cfg.camera_height_m])
        dirs = ray_grid(self.camera.K, cfg.width, cfg.height) @ self.cam_from_world_R
        right_c = self.camera_center_w + cfg.baseline_m * self.cam_from_world_R[0]
        self.views = (View(self.camera_center_w, dirs, self.camera.K, self.cam_from_world_R),
                      View(right_c, dirs, self.camera.K, self.cam_from_world_R))
        self.layout = make_layout(self.views[0], cfg.max_range_m, cfg.n_buildings, cfg.n_props,
                                  np.random.default_rng([cfg.seed, 0]))
        self.spawner = AgentSpawner(self.layout, cfg.seed, cfg.n_agents, cfg.agent_mix,
                                    cfg.accessory_prob)
        self._static = None

    # -- geometry ---------------------------------------------------------------------------------
    @property
    def ground_plane(self) -> tuple[np.ndarray, float]:
        """The true ground ``n . P = d`` in the left camera frame (|n| = 1, d = camera height)."""
        return self.mounting.normal.copy(), self.mounting.height_m

    @property
    def camera_height_m(self) -> float:
        return self.config.camera_height_m

    def cam_from_world(self, P_w: np.ndarray) -> np.ndarray:
        """World points (..., 3) into the left camera frame."""
        return (np.asarray(P_w) - self.camera_center_w) @ self.cam_from_world_R.T

    def config_dict(self) -> dict[str, Any]:
        return self.config.to_dict()

    def timestamp(self, i: int) -> float:
        return i / self.config.fps

    # -- rendering --------------------------------------------------------------------------------
    def static_canvases(self):
        """The static scene in both views (rendered once, then reused)."""
        if self._static is None:
            cfg = self.config
            self._static = tuple(render_static(v, self.layout, cfg.seed, cfg.focal, cfg.texture_m)
                                 for v in self.views)
        return self._static

    def agents_at(self, i: int):
        """Scene objects of the agents present at frame i (list of SceneObject)."""
        t = self.timestamp(i)
        return [o for a in self.spawner.alive(t) for o in a.objects(t)]

    def render(self, i: int, full_frame: bool = False) -> dict[str, Any]:
        """Frame i: ``left``/``right`` uint8 (H, W, 3) RGB, ``depth`` and ``depth_right`` float32
        metres (NaN = sky), ``instances`` uint16 (0 = static), ``semantic`` uint8 CARLA tags,
        ``ground_mask`` bool (ground not covered by anything), ``agents`` (AGENT_DTYPE rows of the
        instances visible in the left view), ``visibility`` float32 per row (visible share of
        the agent's silhouette inside the image), ``timestamp`` s, ``index``.

        ``full_frame=True`` renders everything over the whole image, static scene included: the
        slow reference the benchmark compares against (same pixels).
        """
        if i < 0:
            raise InputError(f"frame index must be >= 0, got {i}")
        cfg = self.config
        if full_frame:
            canvases = [render_static(v, self.layout, cfg.seed, cfg.focal, cfg.texture_m,
                                      full_frame=True) for v in self.views]
        else:
            canvases = [c.copy() for c in self.static_canvases()]
        objs = self.agents_at(i)
        drawn = []
        for obj in objs:
            rect, sil = draw(self.views[0], canvases[0], obj, cfg.focal, full_frame)
            draw(self.views[1], canvases[1], obj, cfg.focal, full_frame)
            if rect is not None and sil > 0:
                drawn.append((obj, rect, sil))
        left, right = canvases
        agents, visibility = self._agent_rows(i, left.instances, drawn)
        return {"index": i, "timestamp": self.timestamp(i), "left": left.rgb, "right": right.rgb,
                "depth": _nan_inf(left.depth), "depth_right": _nan_inf(right.depth),
                "instances": left.instances, "semantic": left.tags,
                "ground_mask": left.tags == TAG["road"], "agents": agents,
                "visibility": visibility}

    def frames(self, n: int, start: int = 0) -> Iterator[dict[str, Any]]:
        for i in range(start, start + n):
            yield self.render(i)

    def _agent_rows(self, i: int, instances: np.ndarray, drawn) -> tuple[np.ndarray, np.ndarray]:
        rows = empty_agents(len(drawn))
        vis = np.zeros(len(drawn), np.float32)
        keep = np.zeros(len(drawn), bool)
        for k, (obj, (v0, v1, u0, u1), sil) in enumerate(drawn):
            mask = instances[v0:v1, u0:u1] == obj.instance_id
            rows_with = np.nonzero(mask.any(axis=1))[0]
            if len(rows_with) == 0:
                continue
            keep[k] = True
            bottom = rows_with[-1]
            cols = np.nonzero(mask[bottom])[0]
            foot_w = np.array(obj.foot_w)
            head_w = foot_w + np.array([0.0, 0.0, obj.height_m])
            foot_c, head_c = self.cam_from_world(np.stack([foot_w, head_w]))
            r = rows[k]
            r["frame"], r["instance_id"], r["class_id"] = i, obj.instance_id, obj.class_id
            r["track_id"] = obj.track_id
            r["foot_u"] = u0 + float(np.median(cols))
            r["foot_v"], r["top_v"] = v0 + bottom, v0 + rows_with[0]
            r["top_u"] = u0 + float(np.median(np.nonzero(mask[rows_with[0]])[0]))
            r["foot_x"], r["foot_y"], r["foot_z"] = foot_c
            r["head_x"], r["head_y"], r["head_z"] = head_c
            r["height_m"], r["radius_m"] = obj.height_m, obj.radius_m
            vis[k] = np.count_nonzero(mask) / sil
        return rows[keep], vis[keep]


def _nan_inf(depth: np.ndarray) -> np.ndarray:
    out = depth.astype(np.float32, copy=True)
    out[~np.isfinite(out)] = np.nan
    return out
