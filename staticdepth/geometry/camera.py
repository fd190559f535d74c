"""Cameras, stereo rigs and camera mountings, with JSON round trips.

Conventions (see METHOD.md): OpenCV camera frame (X right, Y down, Z forward), pixel (u, v) with
the top-left pixel's centre at (0, 0). A mounting's ground plane is ``n . P = d`` in the camera
frame with ``|n| = 1`` and ``d = height_m > 0`` (``n`` points from the camera to the ground).
A rig's ``R``, ``T`` map left-camera points to right-camera points: ``P_right = R P_left + T``
(OpenCV ``stereoCalibrate``), translations in metres.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from staticdepth.errors import InputError

RIG_FORMAT = "staticdepth.rig/1"


def _arr(x, shape: tuple[int, ...], name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} has non-finite values")
    a = a.copy()
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera: 3x3 intrinsics ``K``, image size, OpenCV distortion coefficients."""

    K: np.ndarray
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self):
        object.__setattr__(self, "K", _arr(self.K, (3, 3), "K"))
        d = np.asarray(self.dist, dtype=np.float64).ravel()
        if d.size not in (0, 4, 5, 8, 12, 14):
            raise InputError(f"distortion must have 4, 5, 8, 12 or 14 coefficients, got {d.size}")
        object.__setattr__(self, "dist", _arr(d, d.shape, "dist"))
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise InputError("focal lengths must be positive")

    # -- constructors ---------------------------------------------------------------------------
    @classmethod
    def from_intrinsics(cls, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                        dist=None) -> "Camera":
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(K, width, height, np.zeros(5) if dist is None else dist)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> "Camera":
        """Square pixels, principal point at the image centre (CARLA's convention)."""
        f = width / (2.0 * math.tan(math.radians(hfov_deg) / 2.0))
        return cls.from_intrinsics(f, f, width / 2.0, height / 2.0, width, height)

    # -- properties -----------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), OpenCV's order."""
        return self.width, self.height

    @property
    def K_inv(self) -> np.ndarray:
        return np.linalg.inv(self.K)

    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    def scaled(self, sx: float, sy: float | None = None) -> "Camera":
        """The camera for an image resized by (sx, sy); pixel centres stay consistent."""
        sy = sx if sy is None else sy
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return Camera(K, round(self.width * sx), round(self.height * sy), self.dist)

    def fitted_to(self, width: int, height: int, what: str = "the frames",
                  source: str | os.PathLike | None = None) -> "Camera":
        """The camera for images of ``width`` x ``height``: itself, or :meth:`scaled` when they are
        a uniform resize of its own (a network's map at a lower resolution, a video imported
        with ``--width``); else an :class:`InputError` naming ``source`` (the camera's file) that
        says both sizes (a camera calibrated for another image: every ray would be wrong). A
        size one pixel off is the same image: a camera JSON without ``width``/``height`` gets
        ``2 c + 1`` (385 for ``cx`` 192 on a 384-wide image), and scaling by 384 / 385 would put
        a 0.26% error into the focal length."""
        if (self.width, self.height) == (int(width), int(height)):
            return self
        if abs(self.width - int(width)) <= 1 and abs(self.height - int(height)) <= 1:
            return Camera(self.K, int(width), int(height), self.dist)
        sx, sy = width / self.width, height / self.height
        if abs(sx - sy) > 0.01 * max(sx, sy):
            raise InputError(f"the camera is {self.width}x{self.height}, {what} {width}x{height}: "
                             f"not a uniform resize", source)
        return self.scaled(sx, sy)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Camera) and self.size == other.size
                and np.array_equal(self.K, other.K) and np.array_equal(self.dist, other.dist))

    # -- JSON -----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
                "cx": self.cx, "cy": self.cy, "K": self.K.tolist(), "dist": self.dist.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "Camera":
        """Accepts the toolkit's camera dict, or a bare ``{fx, fy, cx, cy[, width, height]}``."""
        try:
            if "K" in d:
                K = d["K"]
            else:
                K = [[float(d["fx"]), 0, float(d["cx"])], [0, float(d["fy"]), float(d["cy"])],
                     [0, 0, 1]]
            width = int(d.get("width", 0) or round(2 * float(np.asarray(K)[0][2]) + 1))
            height = int(d.get("height", 0) or round(2 * float(np.asarray(K)[1][2]) + 1))
            return cls(K, width, height, d.get("dist", np.zeros(5)))
        except KeyError as e:
            raise InputError(f"camera is missing the key {e.args[0]!r}", source) from None
        except (TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise InputError(e.problem, source) from None
            raise InputError(f"camera is malformed: {e}", source) from None


def normal_from_pitch_roll(pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Ground normal in the camera frame for a camera pitched down by ``pitch`` and rolled by ``roll``.

    Level camera: (0, 1, 0); pitched down by t: (0, cos t, sin t); roll rotates it about the optical
    axis: ``n = Rz(roll) (0, cos t, sin t)``.
    """
    t, r = math.radians(pitch_deg), math.radians(roll_deg)
    return np.array([-math.sin(r) * math.cos(t), math.cos(r) * math.cos(t), math.sin(t)])


def pitch_roll_from_normal(n) -> tuple[float, float]:
    """Inverse of :func:`normal_from_pitch_roll`, in degrees."""
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    pitch = math.degrees(math.asin(float(np.clip(n[2], -1.0, 1.0))))
    roll = math.degrees(math.atan2(-n[0], n[1]))
    return pitch, roll


MAX_CAMERA_HEIGHT_M = 1000.0


def check_camera_height(value: Any, what: str = "camera height",
                        path: str | os.PathLike | None = None) -> float:
    """``value`` as a camera height in metres (a float), the one check of every place that takes
    one: a finite number in (0, :data:`MAX_CAMERA_HEIGHT_M`]. A fixed camera more than 1 km above
    the scene does not watch agents on a ground plane (a person would be a pixel or two tall), so a
    larger value is a mistake (a unit, a typo) that would only give nonsense downstream.

    Otherwise one :class:`InputError` naming ``what`` (the option or key), the value and the range,
    with ``path`` (the file it came from) where there is one.
    """
    try:
        h, got = float(value), None
    except (TypeError, ValueError):
        h, got = float("nan"), repr(value)
    if isinstance(value, bool):       # not a number, though float() reads it
        got = repr(value)
    if got is not None or not (math.isfinite(h) and 0 < h <= MAX_CAMERA_HEIGHT_M):
        got = h if got is None else got
        raise InputError(f"{what} must be a height in metres in (0, {MAX_CAMERA_HEIGHT_M:g}], "
                         f"got {got}", path)
    return h


@dataclass(frozen=True, eq=False)
class Mounting:
    """Where the camera sits over the ground: the plane ``normal . P = height_m`` (camera frame)."""

    height_m: float
    normal: np.ndarray
    source: str = "unknown"

    def __post_init__(self):
        n = np.asarray(self.normal, dtype=np.float64).ravel()
        if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-12:
            raise InputError("mounting normal must be a finite non-zero 3-vector")
        object.__setattr__(self, "normal", _arr(n / np.linalg.norm(n), (3,), "normal"))
        object.__setattr__(self, "height_m", check_camera_height(self.height_m,
                                                                 "mounting height_m"))

    @classmethod
    def from_pitch_roll(cls, height_m: float, pitch_deg: float, roll_deg: float = 0.0,
                        source: str = "unknown") -> "Mounting":
        return cls(height_m, normal_from_pitch_roll(pitch_deg, roll_deg), source)

    @property
    def pitch_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[0]

    @property
    def roll_deg(self) -> float:
        return pitch_roll_from_normal(self.normal)[1]

    def to_dict(self) -> dict[str, Any]:
        return {"height_m": self.height_m, "normal": self.normal.tolist(),
                "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg, "source": self.source}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "Mounting":
        try:
            h = check_camera_height(d["height_m"], "mounting height_m", source)
            if "normal" in d:
                return cls(h, d["normal"], d.get("source", "unknown"))
            return cls.from_pitch_roll(h, float(d["pitch_deg"]),
                                       float(d.get("roll_deg", 0.0)), d.get("source", "unknown"))
        except KeyError as e:
            raise InputError(f"mounting is missing the key {e.args[0]!r}", source) from None

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Mounting) and self.height_m == other.height_m
                and np.array_equal(self.normal, other.normal))


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two cameras and the pose ``right_from_left`` (``P_r = R P_l + T``, metres).

    ``rectification`` holds OpenCV ``stereoRectify``'s outputs (R1, R2, P1, P2, Q) when known; a rig
    built from an already rectified pair has R = I, T = (-B, 0, 0) and no rectification.
    """

    left: Camera
    right: Camera
    R: np.ndarray
    T: np.ndarray
    rectification: Mapping[str, np.ndarray] | None = None
    mounting: Mounting | None = None
    rms_reprojection_px: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "R", _arr(self.R, (3, 3), "R"))
        object.__setattr__(self, "T", _arr(np.asarray(self.T, dtype=np.float64).ravel(), (3,), "T"))
        if self.rectification is not None:
            rect = {k: _arr(v, np.asarray(v).shape, k) for k, v in self.rectification.items()}
            object.__setattr__(self, "rectification", rect)
        if self.baseline_m <= 0:
            raise InputError("rig baseline must be positive")

    @classmethod
    def rectified(cls, camera: Camera, baseline_m: float, **kw) -> "StereoRig":
        """An ideal rectified pair: identical cameras, right camera ``baseline_m`` to the right."""
        return cls(camera, camera, np.eye(3), np.array([-baseline_m, 0.0, 0.0]), **kw)

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T))

    def is_rectified(self) -> bool:
        """True when the images need no rectification (identity rotation, pure x translation)."""
        return (np.allclose(self.R, np.eye(3), atol=1e-9) and abs(self.T[1]) < 1e-9
                and abs(self.T[2]) < 1e-9 and self.left == self.right
                and not self.left.has_distortion())

    def rectified_camera(self) -> Camera:
        """The left camera after rectification (P1's intrinsics), or the left camera itself."""
        if self.rectification is None:
            return self.left
        P1 = self.rectification["P1"]
        return Camera(P1[:3, :3], self.left.width, self.left.height, np.zeros(5))

    def with_mounting(self, mounting: Mounting | None) -> "StereoRig":
        return StereoRig(self.left, self.right, self.R, self.T, self.rectification, mounting,
                         self.rms_reprojection_px, dict(self.extra))

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"format": RIG_FORMAT, "left": self.left.to_dict(),
                             "right": self.right.to_dict(), "R": self.R.tolist(),
                             "T": self.T.tolist(), "baseline_m": self.baseline_m}
        if self.rectification is not None:
            d["rectification"] = {k: np.asarray(v).tolist() for k, v in self.rectification.items()}
        if self.mounting is not None:
            d["mounting"] = self.mounting.to_dict()
        if self.rms_reprojection_px is not None:
            d["rms_reprojection_px"] = float(self.rms_reprojection_px)
        if self.extra:
            d["extra"] = dict(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "StereoRig":
        try:
            if d.get("format", RIG_FORMAT) != RIG_FORMAT:
                raise InputError(f"unknown rig format {d.get('format')!r} (expected {RIG_FORMAT})",
                                 source)
            rect = d.get("rectification")
            rig = cls(Camera.from_dict(d["left"], source), Camera.from_dict(d["right"], source),
                      d["R"], d["T"],
                      None if rect is None else {k: np.asarray(v) for k, v in rect.items()},
                      None if d.get("mounting") is None else Mounting.from_dict(d["mounting"], source),
                      d.get("rms_reprojection_px"), d.get("extra", {}))
            return rig
        except KeyError as e:
            raise InputError(f"rig is missing the key {e.args[0]!r}", source) from None
        except InputError as e:
            raise InputError(e.problem, source) from None

    def save(self, path: str | os.PathLike) -> None:
        """Write the rig as JSON atomically (temporary file, then rename)."""
        from staticdepth.fileio import atomic_write_json
        atomic_write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "StereoRig":
        return cls.from_dict(read_json(path), os.fspath(path))


def read_json(path: str | os.PathLike) -> dict[str, Any]:
    """Read a JSON object, turning every failure into an :class:`InputError` naming the file."""
    try:
        with open(path) as f:
            d = json.load(f)
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except UnicodeDecodeError:
        from staticdepth.fileio import not_text

        raise InputError(not_text("a JSON file", path), path) from None
    except OSError as e:
        raise InputError(f"cannot read: {e}", path) from None
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON ({e.msg} at line {e.lineno})", path) from None
    if not isinstance(d, dict):
        raise InputError("expected a JSON object", path)
    return d


def load_camera(path: str | os.PathLike) -> Camera:
    """A camera from JSON: bare intrinsics, the toolkit's camera dict, or a rig (its rectified left)."""
    d = read_json(path)
    if "left" in d and "right" in d:
        return StereoRig.from_dict(d, os.fspath(path)).rectified_camera()
    if "camera" in d and isinstance(d["camera"], dict):
        d = d["camera"]
    return Camera.from_dict(d, os.fspath(path))
