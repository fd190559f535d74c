"""Stage: align predicted depth maps to the agents' ground plane (``staticdepth align``).

Inputs: one ``.npy`` prediction (H, W) or a folder of them (processed in name order), or a
sequence file's stored prediction ``<name>`` (``--sequence``, written back as the prediction
``<name>-align`` beside the sequence, frame by frame, by the adaptation's align stage writer);
the plane JSON written by ``staticdepth ground-plane``; and a ground mask: an image/.npy (``--ground-mask``), a polygon (``--ground-polygon "u1,v1 u2,v2 ..."`` or a JSON/TXT
file of vertices) or, for a sequence, a ground-truth semantic map per frame (``--ground-aux
ground``, e.g. the CARLA importer's). ``--agent-mask`` pixels are removed from the plane fit and
always aligned (Eq. 2) or never ground (``upright``). ``--mode`` (default the config's
``align.mode``, ``upright``) and ``--set align.KEY=VALUE`` choose the alignment exactly as adapt's
align stage does (``adaptation.align.upright_options``; METHOD.md section 4). Aligned maps are float32 (NaN = unknown), written
atomically. With a camera height (``--camera-height``, or the plane's ``camera_height_m``) the
output is in metres and the anchor scale of section 5 is reported; otherwise it is in units of the
camera height. As in adapt, a prediction whose inverse depth over the ground the plane does not
explain (R^2 under ``align.min_ground_r2``, the median over up to 8 maps: the adaptation split's
on a sequence) is not aligned: the output is the plane's depth along every ray, each
``--agent-mask`` component at its contact (``adaptation.align.plane_frame``'s rule), with a
warning; the JSON holds ``ground_r2`` and ``plane_only``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from staticdepth.errors import InputError
from staticdepth.fileio import not_text, read_npy
from staticdepth.geometry import load_camera
from staticdepth.geometry.camera import check_camera_height, read_json
from staticdepth.geometry.scale import scale_from_anchor, temporal_scale
from staticdepth.metrics import check_prediction
from staticdepth.progress import progress

if TYPE_CHECKING:  # the plane and the alignment import scipy: loaded when run, not for --help
    from staticdepth.geometry.agent_plane import AgentPlane


def load_mask(path: str | os.PathLike, what: str = "ground", allow_empty: bool = False
              ) -> np.ndarray:
    """A mask from an image (non-zero = set) or a ``.npy`` array, as (H, W) bool; raises when it
    is empty unless ``allow_empty``. ``what`` names the mask in messages."""
    path = os.fspath(path)
    if path.endswith(".npy"):
        m = read_npy(path)
    else:
        from staticdepth.fileio import read_image

        m = read_image(path)
    if m.ndim == 3:
        m = m.max(axis=2)
    if m.ndim != 2:
        raise InputError(f"a mask must be a 2-D image, got shape {m.shape}", path)
    if not allow_empty and not np.any(m):
        raise InputError(f"the {what} mask is empty", path)
    return m != 0


def parse_polygon(text: str) -> np.ndarray:
    """Vertices (N, 2) from ``"u1,v1 u2,v2 ..."`` or from a file: JSON (a list of [u, v] pairs, or
    an object with ``vertices`` or ``points``) or text (one ``u v`` or ``u,v`` pair per line)."""
    source = None
    if os.path.isfile(text):
        source = text
        try:
            with open(text) as f:
                body = f.read()
        except UnicodeDecodeError:
            raise InputError(not_text("a polygon (JSON or text)", text), text) from None
        except OSError as e:
            raise InputError(f"cannot read: {e}", text) from None
        if text.lower().endswith(".json"):
            try:
                obj = json.loads(body)
            except json.JSONDecodeError as e:
                raise InputError(f"not valid JSON ({e.msg} at line {e.lineno})", text) from None
            if isinstance(obj, dict):
                obj = obj.get("vertices", obj.get("points"))
            pairs = obj
        else:
            pairs = [ln.replace(",", " ").split() for ln in body.splitlines() if ln.strip()]
    else:
        pairs = [p.split(",") for p in text.split()]
    try:
        P = np.array(pairs, dtype=np.float64)
    except (TypeError, ValueError):
        P = np.zeros((0, 3))
    if P.ndim != 2 or P.shape[1] != 2:
        raise InputError("a ground polygon is a list of u,v pairs (\"u1,v1 u2,v2 ...\" or a "
                         f"JSON/TXT file of them), got {text[:60]!r}", source)
    return P


def save_npy_atomic(path: str | os.PathLike, array: np.ndarray) -> None:
    from staticdepth.fileio import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, array)


def map_ground_r2(pred: np.ndarray, K: np.ndarray, plane: AgentPlane, ground_mask: np.ndarray,
                  agent_mask: np.ndarray | None = None, inverse: bool = False) -> float:
    """:func:`~staticdepth.geometry.alignment.ground_fit_r2` of one predicted map over the
    ground less the agents, as adapt's align stage measures it."""
    from staticdepth.geometry.alignment import depth_from_inverse, ground_fit_r2
    from staticdepth.geometry.alignment_upright import AlignCamera

    pred = np.asarray(pred, dtype=np.float32)
    Z = depth_from_inverse(pred) if inverse else pred
    g = np.asarray(ground_mask, bool)
    if agent_mask is not None:
        g = g & ~np.asarray(agent_mask, bool)
    h, w = Z.shape
    return ground_fit_r2(Z, g, AlignCamera(K, w, h, plane.normal, 1.0))


def plane_map(K: np.ndarray, plane: AgentPlane, ground_mask: np.ndarray, shape, d_g: float,
              agent_mask: np.ndarray | None = None, align_conf=None) -> np.ndarray:
    """The output for a prediction under ``align.min_ground_r2``, by adapt's rule
    (:func:`staticdepth.adaptation.align.plane_frame`): the plane's depth along every ray, each
    connected component of ``agent_mask`` an agent at its contact; units of ``d_g``."""
    import dataclasses

    import cv2

    from staticdepth.adaptation.align import plane_frame
    from staticdepth.adaptation.config import build_config
    from staticdepth.detectors.base import rows_from_masks

    conf = build_config({})
    if align_conf is not None:
        conf = dataclasses.replace(conf, align=align_conf)
    masks = []
    if agent_mask is not None and np.any(agent_mask):
        n, labels = cv2.connectedComponents(np.asarray(agent_mask, np.uint8), connectivity=8)
        masks = [labels == k for k in range(1, n)]
    inst, rows = rows_from_masks(0, masks, [0] * len(masks), [1.0] * len(masks), tuple(shape))
    return d_g * plane_frame(conf, K, plane.normal, np.asarray(ground_mask, bool), inst, rows)


def align_map(pred: np.ndarray, K: np.ndarray, plane: AgentPlane, ground_mask: np.ndarray, *,
              inverse: bool = False, camera_height_m: float | None = None,
              near_plane_rel: float | None = None, agent_mask: np.ndarray | None = None,
              align_conf=None, image: np.ndarray | None = None, plane_only: bool = False
              ) -> tuple[np.ndarray, dict[str, Any]]:
    """Align one predicted map; returns the map and its info (plane fit, fallback, anchor scale).
    ``agent_mask`` (H, W) pixels leave the plane fit, are always aligned (eq2) or never ground
    (upright) and skip the anchor. ``align_conf``: an adaptation ``AlignConfig`` (default: the
    config's defaults) whose mode and settings are used as adapt's align stage uses them.
    ``image``: the static scene (adaptation.align.static_image) for ``align.colour_foot``; without
    it (a single map, no frames) the rule is not applied and the info says so. ``plane_only``:
    the prediction does not see the ground (``align.min_ground_r2``): the map is
    :func:`plane_map`, the info's ``mode`` is ``plane``."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import AlignConfig
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse

    pred = np.asarray(pred, dtype=np.float32)
    if pred.ndim != 2:
        raise InputError(f"a prediction must be a 2-D (H, W) map, got shape {pred.shape}")
    Z = depth_from_inverse(pred) if inverse else pred
    d_g = camera_height_m if camera_height_m is not None else 1.0
    conf = AlignConfig() if align_conf is None else align_conf
    use_image = conf.uses_image and image is not None
    if near_plane_rel is not None and conf.mode != "eq2":
        raise InputError(f"--near-plane selects pixels for Eq. 2: it needs --mode eq2, not "
                         f"{conf.mode!r}")
    info: dict[str, Any] = {"ground_r2": _r2_value(map_ground_r2(Z, K, plane, ground_mask,
                                                                 agent_mask))}
    if plane_only:
        A = plane_map(K, plane, ground_mask, Z.shape, d_g, agent_mask, conf)
        A[~np.isfinite(Z)] = np.nan
        info["mode"] = "plane"
        if camera_height_m is not None:
            info.update(_anchor_info(Z, K, plane, camera_height_m, agent_mask))
        return A, info
    res = align_depth(Z, K, plane.normal, d_g, ground_mask, near_plane_rel=near_plane_rel,
                      agent_mask=agent_mask, mode=conf.mode, snap_rel=conf.snap_rel,
                      image=image if use_image else None, **upright_options(conf))
    info["mode"] = conf.mode
    if conf.uses_image and not use_image:
        info["colour_foot"] = "not applied: no frames (on a sequence, --sequence applies it)"
    if conf.mode == "eq2":
        info.update(pred_plane_normal=res.plane_normal.tolist(), pred_plane_d=res.plane_d,
                    fallback_ratio=res.fallback_ratio, fallback_pixels=res.n_fallback,
                    skipped_nadir=res.skipped)
    else:   # the ground fit's inverse-depth scale and shift (alignment.align_ground)
        s, t, scale_only = (float(x) for x in res.plane_normal)
        info.update(inverse_scale=s, inverse_shift=t, scale_only=bool(scale_only),
                    far_limit=res.plane_d, not_reanchored_pixels=res.n_fallback)
    if camera_height_m is not None:
        info.update(_anchor_info(Z, K, plane, camera_height_m, agent_mask))
    return res.depth, info


def _r2_value(r2: float) -> float | None:
    return round(float(r2), 4) if np.isfinite(r2) else None


def _anchor_info(Z, K, plane: AgentPlane, camera_height_m: float, agent_mask) -> dict[str, Any]:
    a = scale_from_anchor(Z, K, plane.normal, camera_height_m, agent_mask=agent_mask)
    return {"anchor_depth_m": a.anchor_depth_m,
            "anchor_depth_parallel_m": a.anchor_depth_parallel_m,
            "scale": None if a.skipped else a.scale, "scale_skipped": a.skipped}


def ground_decision(r2_values, align_conf) -> tuple[float, bool]:
    """(the median R^2, whether it is under ``align.min_ground_r2``), warning when it is."""
    import sys

    from staticdepth.adaptation.align import median_r2

    r2 = median_r2(r2_values)
    bar = align_conf.min_ground_r2
    under = bool(r2 < bar)
    if under:
        print(f"warning: the prediction does not see the agents' ground (its inverse depth over "
              f"the ground: R^2 {r2:.3f} against the plane's, under align.min_ground_r2 {bar:g}); "
              f"the output is the plane's depth with the agents at their contact, without the "
              f"network (--set align.min_ground_r2=0 aligns it anyway)", file=sys.stderr)
    return r2, under


def align_config(mode: str | None, sets: list[str]):
    """The adaptation's ``AlignConfig`` from its defaults, ``--set align.KEY=VALUE`` and
    ``--mode`` (built by adapt's own config builder: one set of defaults and checks)."""
    from staticdepth.adaptation.config import build_config
    from staticdepth.config import parse_set

    settings = parse_set(sets)      # the one --set grammar; only align.* keys belong here
    for key in settings:
        if not key.startswith("align."):
            raise InputError(f"--set takes align.KEY=VALUE, got {key!r}")
    if mode is not None:
        settings["align.mode"] = mode
    return build_config(settings).align


def register(sub) -> None:
    p = sub.add_parser("align", help="align predicted depth to the agents' ground plane",
                       description="Scene alignment (METHOD.md section 4; --mode upright, ground "
                                   "or the paper's Eq. 2, as adapt aligns); metric output with a "
                                   "camera height (section 5).")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--pred", help=".npy (H x W) prediction or a folder of them")
    src.add_argument("--sequence", help="sequence file (.h5): align its stored prediction "
                                        "pred/<--pred-name>/depth")
    p.add_argument("--pred-name", default="base", help="stored prediction to align (--sequence)")
    p.add_argument("--out-name", help="prediction to write (--sequence; default <pred-name>-align)")
    p.add_argument("--inverse", action="store_true",
                   help="the prediction is relative inverse depth (depth = 1 / max(D, eps))")
    p.add_argument("--intrinsics", help="JSON with fx, fy, cx, cy (or a camera/rig); default "
                                        "with --sequence: the sequence's camera")
    p.add_argument("--plane", required=True, help="plane JSON from 'staticdepth ground-plane'")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--ground-mask", help="image (non-zero = ground) or .npy")
    g.add_argument("--ground-polygon", metavar="VERTICES",
                   help='ground polygon "u1,v1 u2,v2 ..." (pixels) or a JSON/TXT file of vertices')
    g.add_argument("--ground-aux", metavar="NAME",
                   help="with --sequence: the per-frame ground-truth ground map aux/NAME "
                        "(e.g. 'ground' from the CARLA importer)")
    p.add_argument("--agent-mask", help="image or .npy of agent pixels: left out of the plane "
                                        "fit, always aligned")
    p.add_argument("--camera-height", type=float,
                   help="camera height in metres (default: the plane's, else relative output)")
    p.add_argument("--mode", default=None, metavar="upright|ground|eq2",
                   help="alignment mode, as adapt's align stage (default: the config's align.mode"
                        ", upright): upright, ground or the paper's Eq. 2 (eq2)")
    p.add_argument("--set", action="append", default=[], metavar="align.KEY=VALUE",
                   help="an align.* setting over the config's defaults (e.g. align.jump_rel=0.1)")
    p.add_argument("--near-plane", type=float, metavar="REL",
                   help="with --mode eq2: align only pixels within REL x d of the predicted "
                        "plane; rescale others")
    p.add_argument("--out", help=".npy file (or folder for a folder of inputs); not with "
                                 "--sequence")
    p.add_argument("--json", help="write per-frame information here")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)
    p.set_defaults(func=_align_cmd)


class _Masks:
    """The ground mask of a frame (fixed, or per frame from a sequence) and the agent mask."""

    def __init__(self, args: argparse.Namespace):
        self.fixed = load_mask(args.ground_mask) if args.ground_mask else None
        self.polygon = parse_polygon(args.ground_polygon) if args.ground_polygon else None
        self.aux = args.ground_aux
        self.agents = (load_mask(args.agent_mask, "agent", allow_empty=True)
                       if args.agent_mask else None)
        self.agent_path = args.agent_mask
        self.source = args.ground_mask or args.ground_polygon

    def ground(self, shape: tuple[int, int], reader=None, i: int = 0) -> np.ndarray:
        from staticdepth.geometry.alignment import (ground_mask_from_polygon,
                                                    ground_mask_from_semantics)

        if self.aux is not None:
            try:
                return ground_mask_from_semantics(reader.aux(self.aux, i))
            except InputError as e:
                raise InputError(f"frame {i}: aux/{self.aux}: {e.problem}", reader.path) from None
        if self.polygon is not None:
            return ground_mask_from_polygon(self.polygon, shape[1], shape[0])
        return fit_mask(self.fixed, shape, "ground", self.source)

    def agent(self, shape: tuple[int, int]) -> np.ndarray | None:
        if self.agents is None:
            return None
        return fit_mask(self.agents, shape, "agent", self.agent_path)


def fit_mask(mask: np.ndarray, shape: tuple[int, int], what: str, source) -> np.ndarray:
    """``mask`` for a prediction of ``shape`` (H, W): itself, or resized (nearest) when the map is
    a uniform resize of the mask's image, by the rule the camera follows
    (:meth:`staticdepth.geometry.camera.Camera.fitted_to`: a pixel off is the same image, else
    the two scales within 1%; a mask under 16 px a side is never resized); any other shape is
    one line naming the mask."""
    h, w = mask.shape
    H, W = int(shape[0]), int(shape[1])
    if (h, w) == (H, W):
        return mask
    sx, sy = W / w, H / h
    if min(h, w) < 16 or (abs(sx - sy) > 0.01 * max(sx, sy)
                          and not (abs(W - w) <= 1 and abs(H - h) <= 1)):
        raise InputError(f"prediction shape {tuple(shape)} differs from the {what} mask's "
                         f"{mask.shape}: not a uniform resize", source)
    import cv2

    return cv2.resize(mask.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0


def _align_cmd(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing
    from staticdepth.fileio import atomic_write_json, check_writable
    from staticdepth.geometry.agent_plane import AgentPlane

    if args.json:  # before any map is written
        check_writable(args.json)
    if args.pred and args.out and not os.path.isdir(args.pred):
        check_writable(args.out)   # one map: a file (a folder of maps goes to a folder)
    refuse_existing(args.json, None if args.sequence else args.out, overwrite=args.overwrite)
    if args.camera_height is not None:
        check_camera_height(args.camera_height, "--camera-height")
    plane = AgentPlane.from_dict(read_json(args.plane), args.plane)   # checks its camera_height_m
    height = args.camera_height if args.camera_height is not None else plane.camera_height_m
    if args.ground_aux and not args.sequence:
        raise InputError("--ground-aux reads a sequence's per-frame maps: it needs --sequence")
    if args.pred and args.out:
        folder = os.path.isdir(args.pred)
        if folder == args.out.lower().endswith(".npy"):
            raise InputError("a folder of maps is aligned into a folder (not a name ending in "
                             ".npy)" if folder else "one map is written as a .npy file: end "
                             "--out in .npy", args.out)
    if args.near_plane is not None and not (math.isfinite(args.near_plane)
                                            and args.near_plane > 0):
        raise InputError(f"--near-plane must be a positive number, got {args.near_plane}")
    args.align_conf = align_config(args.mode, args.set)
    if args.near_plane is not None and args.align_conf.mode != "eq2":
        raise InputError(f"--near-plane selects pixels for Eq. 2: it needs --mode eq2, not "
                         f"{args.align_conf.mode!r}")
    masks = _Masks(args)
    if args.sequence:
        frames, out_desc = _align_sequence(args, plane, height, masks)
    else:
        frames, out_desc = _align_files(args, plane, height, masks)
    units = "m" if height is not None else "camera heights"
    result: dict[str, Any] = {"units": units, "camera_height_m": height,
                              "ground_r2": _r2_value(args.ground_r2),
                              "plane_only": args.plane_only, "frames": frames}
    if height is not None:
        scales = [f["scale"] for f in frames if f.get("scale") is not None]
        result["scale"] = temporal_scale(scales) if scales else None
        result.update({k: frames[0][k] for k in ("anchor_depth_m", "anchor_depth_parallel_m")})
    if args.json:
        atomic_write_json(args.json, result)
    print(f"aligned {len(frames)} map(s) -> {out_desc} ({units})")
    if height is not None:
        print(f"  anchor depth {result['anchor_depth_m']:.3f} m (parallel-camera baseline "
              f"{result['anchor_depth_parallel_m']:.3f} m), scale {result['scale']}")
    return 0


def _align_files(args, plane: AgentPlane, height, masks: _Masks):
    if args.intrinsics is None or args.out is None:
        raise InputError("--pred needs --intrinsics and --out")
    camera = load_camera(args.intrinsics)
    src = Path(args.pred)
    if src.is_dir():
        inputs = sorted(src.glob("*.npy"))
        if not inputs:
            raise InputError("no .npy files in the folder", src)
        os.makedirs(args.out, exist_ok=True)
        outputs = [Path(args.out) / p.name for p in inputs]
    else:
        inputs, outputs = [src], [Path(args.out)]

    def load(i: Path) -> np.ndarray:
        pred = check_prediction(read_npy(os.fspath(i)), i)  # real, no +-inf (NaN = unknown)
        if pred.ndim != 2:
            raise InputError(f"a prediction must be a 2-D (H, W) map, got shape {pred.shape}", i)
        return pred

    from staticdepth.adaptation.align import r2_frames

    def K_of(pred: np.ndarray, i: Path) -> np.ndarray:
        """The intrinsics for this map (scaled when the map is a uniform resize of the
        camera's image, as import-video does; else one line naming both sizes)."""
        return camera.fitted_to(pred.shape[1], pred.shape[0], f"the map {i}",
                                args.intrinsics).K

    def r2_of(i: Path) -> float:
        pred = load(i)
        return map_ground_r2(pred, K_of(pred, i), plane, masks.ground(pred.shape),
                             masks.agent(pred.shape), args.inverse)

    args.ground_r2, args.plane_only = ground_decision(
        (r2_of(inputs[k]) for k in r2_frames([], len(inputs))), args.align_conf)
    frames = []
    for i, o in progress(list(zip(inputs, outputs)), desc="align"):
        pred = load(i)
        ground, agents = masks.ground(pred.shape), masks.agent(pred.shape)
        try:
            out, info = align_map(pred, K_of(pred, i), plane, ground, inverse=args.inverse,
                                  camera_height_m=height, near_plane_rel=args.near_plane,
                                  agent_mask=agents, align_conf=args.align_conf,
                                  plane_only=args.plane_only)
        except InputError as e:
            raise InputError(e.problem, i) from None
        save_npy_atomic(o, out)
        frames.append({"input": os.fspath(i), "output": os.fspath(o), **info})
    return frames, args.out


def _align_sequence(args, plane: AgentPlane, height, masks: _Masks):
    """The adaptation's align stage writer (streamed, frame by frame) with this command's maps."""
    from staticdepth.adaptation.align import align_prediction
    from staticdepth.adaptation.common import Workspace

    if args.out is not None:
        raise InputError("--sequence writes a prediction of the sequence: use --out-name, not --out")
    out_name = args.out_name or f"{args.pred_name}-align"
    if out_name == args.pred_name:
        raise InputError(f"--out-name {out_name!r} would overwrite the prediction being aligned")
    seq = os.fspath(args.sequence)
    frames: list[dict[str, Any]] = []
    ws = Workspace(seq, log=lambda m: None)
    with ws.reader() as r:
        K = (load_camera(args.intrinsics).fitted_to(r.camera.width, r.camera.height,
                                                    "the sequence's frames", args.intrinsics).K
             if args.intrinsics else r.camera.K)
        if args.pred_name not in r.predictions():
            raise InputError(f"sequence has no prediction {args.pred_name!r} (has "
                             f"{r.predictions()})", seq)
        if masks.aux is not None and masks.aux not in r.aux_names():
            raise InputError(f"sequence has no aux map {masks.aux!r} (has {r.aux_names()})", seq)

        from staticdepth.adaptation.align import align_image, r2_frames

        image = align_image(args.align_conf, r)         # as adapt's align stage

        def r2_of(i: int) -> float:
            pred = r.prediction(args.pred_name, i)
            return map_ground_r2(pred, K, plane, masks.ground(pred.shape, r, i),
                                 masks.agent(pred.shape), args.inverse)

        args.ground_r2, args.plane_only = ground_decision(
            (r2_of(i) for i in r2_frames(r.split("adapt"), len(r))), args.align_conf)

        def aligned(i: int, pred: np.ndarray) -> np.ndarray:
            try:
                out, info = align_map(pred, K, plane, masks.ground(pred.shape, r, i),
                                      inverse=args.inverse, camera_height_m=height,
                                      near_plane_rel=args.near_plane,
                                      agent_mask=masks.agent(pred.shape),
                                      align_conf=args.align_conf, image=image,
                                      plane_only=args.plane_only)
            except InputError as e:
                if e.path:
                    raise
                raise InputError(f"frame {i}: {e.problem}", seq) from None
            frames.append({"frame": i, **info})
            return out

        attrs = {"source_prediction": f"pred/{args.pred_name}", "plane": os.fspath(args.plane),
                 "align_mode": "plane" if args.plane_only else args.align_conf.mode,
                 "units": "m" if height is not None else "camera heights"}
        align_prediction(ws, {out_name: (args.pred_name, aligned)},
                         f"align-command-{os.urandom(6).hex()}", attrs, rewrite=True)
    return frames, f"{seq}.pred/{out_name}"
