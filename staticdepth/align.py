"""Stage: align predicted depth maps to the agents' ground plane (``staticdepth align``).

Reads one ``.npy`` prediction (H, W) or a folder of them (processed in name order), the camera,
the plane JSON written by ``staticdepth ground-plane`` and a ground mask, and writes the aligned
maps (float32, NaN = unknown) atomically. With a camera height (``--camera-height``, or the
plane's ``camera_height_m``) the output is in metres and the anchor scale of section 5 is
reported; otherwise it is in units of the camera height.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry import load_camera
from staticdepth.geometry.agent_plane import AgentPlane
from staticdepth.geometry.alignment import align_depth, depth_from_inverse
from staticdepth.geometry.camera import read_json
from staticdepth.geometry.scale import scale_from_anchor, temporal_scale
from staticdepth.ground_plane import write_json
from staticdepth.progress import progress


def load_mask(path: str | os.PathLike) -> np.ndarray:
    """A ground mask from an image (non-zero = ground) or a ``.npy`` array, as (H, W) bool."""
    path = os.fspath(path)
    if path.endswith(".npy"):
        m = _load_npy(path)
    else:
        if not os.path.exists(path):
            raise InputError("file not found", path)
        import cv2

        m = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if m is None:
            raise InputError("cannot read the mask image", path)
    if m.ndim == 3:
        m = m.max(axis=2)
    if m.ndim != 2:
        raise InputError(f"a mask must be a 2-D image, got shape {m.shape}", path)
    if not np.any(m):
        raise InputError("the ground mask is empty", path)
    return m != 0


def _load_npy(path: str) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except (OSError, ValueError) as e:
        raise InputError(f"not a readable .npy array: {e}", path) from None


def save_npy_atomic(path: str | os.PathLike, array: np.ndarray) -> None:
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "wb") as f:
        np.save(f, array)
    os.replace(tmp, path)


def align_map(pred: np.ndarray, K: np.ndarray, plane: AgentPlane, ground_mask: np.ndarray, *,
              inverse: bool = False, camera_height_m: float | None = None,
              near_plane_rel: float | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Align one predicted map; returns the map and its info (plane fit, fallback, anchor scale)."""
    pred = np.asarray(pred, dtype=np.float32)
    if pred.ndim != 2:
        raise InputError(f"a prediction must be a 2-D (H, W) map, got shape {pred.shape}")
    Z = depth_from_inverse(pred) if inverse else pred
    d_g = camera_height_m if camera_height_m is not None else 1.0
    res = align_depth(Z, K, plane.normal, d_g, ground_mask, near_plane_rel=near_plane_rel)
    info: dict[str, Any] = {"pred_plane_normal": res.plane_normal.tolist(),
                            "pred_plane_d": res.plane_d, "fallback_ratio": res.fallback_ratio,
                            "fallback_pixels": res.n_fallback, "skipped_nadir": res.skipped}
    if camera_height_m is not None:
        a = scale_from_anchor(Z, K, plane.normal, camera_height_m)
        info.update(anchor_depth_m=a.anchor_depth_m,
                    anchor_depth_parallel_m=a.anchor_depth_parallel_m,
                    scale=None if a.skipped else a.scale, scale_skipped=a.skipped)
    return res.depth, info


def register(sub) -> None:
    p = sub.add_parser("align", help="align predicted depth to the agents' ground plane",
                       description="Scene alignment (Eq. 2 and re-projection, METHOD.md section "
                                   "4); metric output with a camera height (section 5).")
    p.add_argument("--pred", required=True, help=".npy (H x W) prediction or a folder of them")
    p.add_argument("--inverse", action="store_true",
                   help="the prediction is relative inverse depth (depth = 1 / max(D, eps))")
    p.add_argument("--intrinsics", required=True, help="JSON with fx, fy, cx, cy (or a camera/rig)")
    p.add_argument("--plane", required=True, help="plane JSON from 'staticdepth ground-plane'")
    p.add_argument("--ground-mask", required=True, help="image (non-zero = ground) or .npy")
    p.add_argument("--camera-height", type=float,
                   help="camera height in metres (default: the plane's, else relative output)")
    p.add_argument("--near-plane", type=float, metavar="REL",
                   help="align only pixels within REL x d of the predicted plane; rescale others")
    p.add_argument("--out", required=True, help=".npy file (or folder for a folder of inputs)")
    p.add_argument("--json", help="write per-frame information here")
    p.set_defaults(func=_align_cmd)


def _align_cmd(args: argparse.Namespace) -> int:
    camera = load_camera(args.intrinsics)
    plane = AgentPlane.from_dict(read_json(args.plane), args.plane)
    mask = load_mask(args.ground_mask)
    height = args.camera_height if args.camera_height is not None else plane.camera_height_m
    if height is not None and not height > 0:
        raise InputError(f"camera height must be positive, got {height}")
    src = Path(args.pred)
    if src.is_dir():
        inputs = sorted(src.glob("*.npy"))
        if not inputs:
            raise InputError("no .npy files in the folder", src)
        os.makedirs(args.out, exist_ok=True)
        outputs = [Path(args.out) / p.name for p in inputs]
    else:
        inputs, outputs = [src], [Path(args.out)]
    frames = []
    for i, o in progress(list(zip(inputs, outputs)), desc="align"):
        pred = _load_npy(os.fspath(i))
        if pred.shape != mask.shape:
            raise InputError(f"prediction shape {pred.shape} differs from the ground mask's "
                             f"{mask.shape}", i)
        try:
            out, info = align_map(pred, camera.K, plane, mask, inverse=args.inverse,
                                  camera_height_m=height, near_plane_rel=args.near_plane)
        except InputError as e:
            raise InputError(e.problem, i) from None
        save_npy_atomic(o, out)
        frames.append({"input": os.fspath(i), "output": os.fspath(o), **info})
    units = "m" if height is not None else "camera heights"
    result: dict[str, Any] = {"units": units, "camera_height_m": height, "frames": frames}
    if height is not None:
        scales = [f["scale"] for f in frames if f.get("scale") is not None]
        result["scale"] = temporal_scale(scales) if scales else None
        result.update({k: frames[0][k] for k in ("anchor_depth_m", "anchor_depth_parallel_m")})
    if args.json:
        write_json(args.json, result)
    print(f"aligned {len(frames)} map(s) -> {args.out} ({units})")
    if height is not None:
        print(f"  anchor depth {result['anchor_depth_m']:.3f} m (parallel-camera baseline "
              f"{result['anchor_depth_parallel_m']:.3f} m), scale {result['scale']}")
    return 0
