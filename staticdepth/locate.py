"""``staticdepth locate``: where the agents of a fixed camera's video are, in metres.

For each frame, each agent's ground contact (the bottom of its silhouette, moved half a pixel to
the silhouette's edge) becomes a point in the camera frame and in a ground frame (origin under the
camera, x right, y forward; :mod:`staticdepth.geometry.ground_frame`), with its distance to the
camera, its speed along its track and the distances between people.

Where a position comes from (column ``source``):
- ``plane``: the contact pixel's ray meets the agents' ground plane scaled by the camera height,
  then moves by the body radius (people, ``person_radius_m``) away from the camera, from the near
  edge of the feet to the body's axis. No depth network.
- ``depth``: the contact is not visible (``occluded``: another instance touches the silhouette's
  lowest row, or it is cut by the image's bottom edge) and an adapted metric depth map is stored
  in the sequence: the median depth of the agent's own pixels, back-projected through the contact
  pixel and dropped onto the plane (plus the body radius). Without a map such rows keep ``plane``
  and ``occluded = 1``.

Agents: the sequence's own instances (synthetic scenes, CARLA) or a detector (``motion``,
``yolox``), tracked by box overlap (:func:`staticdepth.tracking.link_tracks`). The plane and the
camera height: the adapt summary (``SEQ.adapt.json``; keys ``plane.normal``, ``camera_height_m``,
or ``planes.agents.{normal, d}``; one written for another sequence is refused,
:func:`check_summary_of`), or ``--plane plane.json`` (``staticdepth ground-plane``) with
``--camera-height``.
"""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from staticdepth.dataset.schema import AGENT_CLASSES, COCO, RIDEABLE_CLASSES
from staticdepth.errors import InputError

CLASS_NAMES = {v: k for k, v in COCO.items()}
PERSON = COCO["person"]
METRIC_PREDICTIONS = ("ft-align-metric", "align-metric")
MAX_PERSON_RADIUS_M = 1.0            # --person-radius: wider than any person's half-width

POS_DTYPE = np.dtype([("frame", np.int32), ("time_s", np.float64), ("track", np.int32),
                      ("class_id", np.int16), ("score", np.float32), ("u", np.float32),
                      ("v", np.float32), ("X", np.float64), ("Y", np.float64), ("Z", np.float64),
                      ("ground_x", np.float64), ("ground_y", np.float64),
                      ("distance_m", np.float64), ("source", "U5"), ("occluded", np.bool_),
                      ("rider", np.bool_),
                      ("speed_mps", np.float64), ("left", np.float32), ("right", np.float32),
                      ("top_v", np.float32)])


@dataclass(frozen=True)
class LocateConfig:
    person_radius_m: float = 0.2     # contact pixel = near edge of the feet; the axis is behind
    edge_px: float = 0.5             # lowest mask row -> silhouette's lowest point
    min_score: float = 0.3
    speed_window_s: float = 1.0      # centred window of the line fit giving the speed
    close_m: float = 2.0             # pairs of people closer than this are "close"
    contact_px: int = 2              # rows below the feet checked for another instance


def plane_from_summary(summary: dict[str, Any], where: str) -> tuple[np.ndarray, float]:
    """(normal, camera height) from an adapt summary, read defensively."""
    plane = summary.get("plane") if isinstance(summary.get("plane"), dict) else {}
    agents = (summary.get("planes") or {}).get("agents") if isinstance(summary.get("planes"),
                                                                        dict) else None
    n = plane.get("normal") or (agents or {}).get("normal")
    h = summary.get("camera_height_m") or plane.get("camera_height_m") or (agents or {}).get("d")
    if n is None or h is None:
        raise InputError("the summary has no ground plane (plane.normal) and camera height "
                         "(camera_height_m)", where)
    from staticdepth.geometry.camera import check_camera_height

    return np.asarray(n, dtype=np.float64), check_camera_height(h, "camera_height_m", where)


def check_summary_of(summary: dict[str, Any], summary_path: str, reader) -> None:
    """Refuse an adapt summary written for another sequence than ``reader``'s (its plane and
    scale are that scene's), in one line naming both files. The proof, first that applies: the
    summary's ``sequence_id`` against the sequence's; its ``size`` [W, H] and ``frames``; its
    recorded ``sequence`` path: an existing file that is neither this one nor a copy of it (same
    identity) is another sequence; a missing one (a run folder moved as a whole) passes when its
    file name is this one's (as ``report``'s check_summaries). A summary recording none passes."""
    seq = reader.path
    recorded = summary.get("sequence")
    other = recorded if isinstance(recorded, str) else "another sequence"
    sid, size, frames = summary.get("sequence_id"), summary.get("size"), summary.get("frames")
    why = None
    if isinstance(sid, str) and sid != reader.sequence_id():
        why = "another sequence identity"
    elif (isinstance(size, list) and len(size) == 2
          and all(isinstance(v, (int, float)) for v in size)
          and list(size) != [reader.width, reader.height]):
        why = f"{size[0]}x{size[1]}, this one is {reader.width}x{reader.height}"
    elif isinstance(frames, int) and frames != reader.n_frames:
        why = f"{frames} frames, this one has {reader.n_frames}"
    elif isinstance(recorded, str):
        if os.path.exists(recorded):
            if not os.path.samefile(recorded, seq) and not _same_identity(recorded, reader):
                why = "another file"
        elif os.path.basename(recorded) != os.path.basename(seq):
            why = "another file name"
    if why is not None:
        raise InputError(f"this adapt summary was written for {other} ({why}), not for {seq}: "
                         f"its plane and scale are that sequence's; give {seq}'s own summary",
                         summary_path)


def _same_identity(path: str, reader) -> bool:
    """Whether the sequence file ``path`` is a copy of ``reader``'s (same identity)."""
    from staticdepth.dataset.h5 import SequenceReader

    try:
        with SequenceReader(path) as r:
            return r.sequence_id() == reader.sequence_id()
    except InputError:
        return False


def load_plane(summary_path: str | None, plane_path: str | None, camera_height: float | None,
               seq_path: str) -> tuple[np.ndarray, float, str]:
    """(normal, camera height, what it came from); ``--camera-height`` overrides the summary's."""
    from staticdepth.geometry.camera import check_camera_height, read_json

    if camera_height is not None:
        camera_height = check_camera_height(camera_height, "--camera-height")
    if plane_path:
        d = read_json(plane_path)
        if "normal" not in d:
            raise InputError("the plane JSON has no 'normal'", plane_path)
        h = camera_height if camera_height is not None else d.get("camera_height_m")
        if h is None:
            raise InputError("the plane JSON has no camera_height_m: give --camera-height",
                             plane_path)
        if camera_height is None:
            h = check_camera_height(h, "camera_height_m", plane_path)
        return np.asarray(d["normal"], dtype=np.float64), h, f"plane {plane_path}"
    path = summary_path or f"{os.path.splitext(seq_path)[0]}.adapt.json"
    if not os.path.isfile(path):
        raise InputError("no adapt summary (run `staticdepth adapt` first, or give --summary, or "
                         "--plane with --camera-height)", path)
    from staticdepth.dataset.h5 import SequenceReader

    summary = read_json(path)
    with SequenceReader(seq_path) as r:
        check_summary_of(summary, path, r)
    n, h = plane_from_summary(summary, path)
    return n, (camera_height if camera_height is not None else h), f"summary {path}"


def metric_predictions(reader) -> list[str]:
    """The sequence's predictions in metres, as evaluate's metric protocol takes them (named
    ``*-metric``, the stereo baseline, attribute ``metric``); not confidence maps."""
    from staticdepth.evaluate import default_protocol

    out = []
    for name in reader.predictions():
        attrs = reader.prediction_attrs(name)
        if attrs.get("kind") != "confidence" and default_protocol(name, attrs) == "metric":
            out.append(name)
    return out


def _instances_and_rows(reader, detector: str | None, detector_model: str | None,
                        detector_mask: str):
    """Yield (frame, instance map, rows or None) from the sequence's instances or a detector."""
    if detector in (None, "gt") and reader.has("instances"):
        for i in range(len(reader)):
            yield i, reader.instances(i), reader.agents(i)
        return
    if detector == "gt":
        raise InputError("--detector gt needs the sequence's 'instances' stream", reader.path)
    from staticdepth.detectors import make_detector
    from staticdepth.detectors.frames import SequenceFrames

    name = detector or "motion"
    opts = {"model": detector_model or "", "mask": detector_mask} if name == "yolox" else {}
    det = make_detector(name, **opts)
    for i, (inst, rows) in enumerate(det.detect_sequence(SequenceFrames(reader))):
        yield i, inst, rows


def locate(seq_path: str, normal, camera_height_m: float, conf: LocateConfig = LocateConfig(), *,
           detector: str | None = None, detector_model: str | None = None,
           detector_mask: str = "box", depth_pred: str | None = "auto") -> np.ndarray:
    """Positions (:data:`POS_DTYPE`, sorted by frame, track) of every agent in every frame."""
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.geometry import ground_frame as gf
    from staticdepth.progress import progress
    from staticdepth.tracking import DET_DTYPE, TrackingConfig, link_tracks

    gframe = gf.GroundFrame.from_plane(normal, camera_height_m)
    n, d = gframe.normal, gframe.camera_height_m
    chunks = []
    with SequenceReader(seq_path) as r:
        K, H, W = r.camera.K, r.height, r.width
        times = r.timestamps()
        pred = None
        if depth_pred == "auto":
            pred = next((p for p in METRIC_PREDICTIONS if p in r.predictions()), None)
        elif depth_pred:
            if depth_pred not in r.predictions():
                raise InputError(f"no prediction {depth_pred!r} in the sequence (has: "
                                 f"{', '.join(r.predictions()) or 'none'})", seq_path)
            metric = metric_predictions(r)
            if depth_pred not in metric:
                raise InputError(f"prediction {depth_pred!r} is not metric depth (metric "
                                 f"ones: {', '.join(metric) or 'none'}; named *-metric or "
                                 f"with the attribute metric)", seq_path)
            pred = depth_pred
        static = _static_map(r, pred) if pred is not None else None
        frames = _instances_and_rows(r, detector, detector_model, detector_mask)
        for i, inst, rows in progress(frames, total=len(r), desc="locate", unit="frame"):
            det = _detections(inst, rows, i, conf.contact_px)
            det = det[(det["score"] >= conf.min_score)
                      & (np.isin(det["class_id"], list(AGENT_CLASSES)) | (det["class_id"] < 0))]
            if not len(det):
                continue
            out = np.zeros(len(det), POS_DTYPE)
            for f in ("frame", "track", "class_id", "score", "left", "right", "top_v"):
                out[f] = det[f]
            out["time_s"] = times[i]
            out["u"] = det["foot_u"]
            out["v"] = det["foot_v"] + conf.edge_px
            radius = np.where(det["class_id"] == PERSON, conf.person_radius_m, 0.0)
            below = [_ids_below(inst, det[k], conf.contact_px) for k in range(len(det))]
            cut = (det["left"] <= 0) | (det["right"] >= W - 1) | (det["foot_v"] >= H - 1)
            occl = np.array([bool(b) for b in below]) | cut      # cut by the image's edge
            P = gf.contact_points(K, n, d, out["u"], out["v"], radius)
            # a rider stands on its bicycle or motorcycle: it takes the vehicle's contact
            cls_of = dict(zip(det["instance_id"].tolist(), det["class_id"].tolist()))
            row_of = {iid: k for k, iid in enumerate(det["instance_id"].tolist())}
            for k in np.flatnonzero(occl & (det["class_id"] == PERSON)):
                # its own: the one under the middle of its silhouette (another may touch it)
                mid = 0.5 * (det["left"][k] + det["right"][k])
                ride = [row_of[b] for b in below[k] if cls_of.get(b) in RIDEABLE_CLASSES
                        and det["left"][row_of[b]] <= mid <= det["right"][row_of[b]]]
                if ride:
                    j = min(ride, key=lambda c: abs(0.5 * (det["left"][c] + det["right"][c]) - mid))
                    out["u"][k], out["v"][k] = out["u"][j], out["v"][j]
                    P[k] = gf.rider_point(inst, det["instance_id"][k], det["instance_id"][j], K,
                                          gframe, conf.person_radius_m)
                    occl[k] = occl[j]
                    out["rider"][k] = True
            Z = r.prediction(pred, i) if pred is not None else None
            if Z is not None:               # a static object (bench, kerb) hides the feet
                occl |= _static_occluder(static, K, n, d, out["u"], out["v"] - conf.edge_px,
                                         conf.contact_px) & ~out["rider"]
            out["occluded"] = occl
            out["source"] = "plane"
            if Z is not None and occl.any():
                for k in np.flatnonzero(occl):
                    z = Z[inst == det["instance_id"][k]]
                    z = z[np.isfinite(z) & (z > 0)]
                    if not len(z):
                        continue
                    ray = np.linalg.inv(K) @ np.array([out["u"][k], out["v"][k], 1.0])
                    Q = gf.drop_to_ground((np.median(z) * ray)[None], n, d)
                    # the map's depth is the body's near surface: step to its axis as for plane
                    P[k] = Q[0] + radius[k] * _horizontal_dir(Q[0], n, d)
                    out["source"][k] = "depth"
            out["X"], out["Y"], out["Z"] = P[:, 0], P[:, 1], P[:, 2]
            g = gframe.to_ground(P)
            out["ground_x"], out["ground_y"] = g[:, 0], g[:, 1]
            out["distance_m"] = np.linalg.norm(P, axis=1)
            chunks.append(out)
    pos = np.concatenate(chunks) if chunks else np.zeros(0, POS_DTYPE)
    if len(pos) and np.any(pos["track"] < 0):
        dets = np.zeros(len(pos), DET_DTYPE)
        dets["frame"], dets["instance_id"] = pos["frame"], np.arange(len(pos))
        dets["class_id"], dets["foot_u"], dets["foot_v"] = pos["class_id"], pos["u"], pos["v"]
        dets["top_v"], dets["left"], dets["right"] = pos["top_v"], pos["left"], pos["right"]
        linked = link_tracks(dets, TrackingConfig(max_gap=2))
        pos["track"][linked["instance_id"]] = linked["track"]
    pos = np.sort(pos, order=["track", "frame"])
    for t in np.unique(pos["track"]):
        sel = np.flatnonzero(pos["track"] == t)
        xy = np.stack([pos["ground_x"][sel], pos["ground_y"][sel]], 1)
        pos["speed_mps"][sel] = gf.track_speeds(pos["time_s"][sel], xy, conf.speed_window_s)
    return np.sort(pos, order=["frame", "track"])


def _detections(inst: np.ndarray, rows, frame: int, contact_px: int) -> np.ndarray:
    """The frame's detections, riders apart from their two-wheelers.

    ``detections_from_instances`` merges a rider into the two-wheeler under it when its rows hold
    both (``tracking.merge_riders``: one rigid agent for the ground plane); here the rider stays a
    person (it is located at its vehicle's contact below), so the two groups are detected apart."""
    from staticdepth.tracking import detections_from_instances

    if rows is None or not len(rows):
        return detections_from_instances(inst, rows, frame, 1, contact_px)
    rows = np.asarray(rows)
    cls = rows["class_id"] if rows.dtype.names else rows.reshape(-1, 3)[:, 1].astype(np.int64)
    wheels = np.isin(cls, list(RIDEABLE_CLASSES))
    return np.concatenate([detections_from_instances(inst, rows[sel], frame, 1, contact_px)
                           for sel in (~wheels, wheels) if sel.any()])


def _static_map(reader, pred: str, max_frames: int = 32) -> np.ndarray:
    """The per-pixel median of the metric map over up to ``max_frames`` evenly spaced frames: the
    static scene. A network's error that moves with the agents (their feet, their shadows) is not
    in it, so it does not pass for a static occluder."""
    idx = np.unique(np.linspace(0, len(reader) - 1, min(max_frames, len(reader))).astype(int))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # all-NaN pixels stay NaN
        return np.nanmedian(np.stack([reader.prediction(pred, int(i)) for i in idx]), axis=0)


def _static_occluder(Z: np.ndarray, K, n, d: float, u, v_low, rows: int,
                     ratio: float = 0.9, step: int = 2) -> np.ndarray:
    """Whether the static metric map (:func:`_static_map`), ``rows`` rows under each lowest row,
    sees something that stands up, clearly nearer than the ground plane there (< ``ratio`` x the
    plane's depth): a static occluder that no instance map shows. Standing up: over the next
    ``step`` rows down the map's depth changes by less than half the plane's (a vertical face
    keeps its depth; a ground the map gets wrong by a smooth factor, as a weak network's, still
    recedes like the plane and flags nothing)."""
    from staticdepth.geometry.plane import plane_depth_at_pixels

    h, w = Z.shape
    uu = np.clip(np.round(np.asarray(u)).astype(int), 0, w - 1)
    vv = np.asarray(v_low).astype(int) + rows
    inside = vv + step < h
    vv = np.minimum(vv, h - 1 - step)
    zp = plane_depth_at_pixels(K, n, d, uu, vv)
    zp2 = plane_depth_at_pixels(K, n, d, uu, vv + step)
    zm, zm2 = Z[vv, uu], Z[vv + step, uu]
    with np.errstate(invalid="ignore"):
        return (inside & np.isfinite(zm) & np.isfinite(zm2) & np.isfinite(zp) & (zp > 0)
                & (zm < ratio * zp) & (np.abs(zm - zm2) < 0.5 * np.abs(zp - zp2)))


def _ids_below(inst: np.ndarray, det, contact_px: int, side_px: int = 2) -> list[int]:
    """Other instance ids that touch the silhouette's lowest row: within ``contact_px`` rows under
    it or ``side_px`` rows above it, in its columns +- ``side_px`` (a nearer agent beside or in
    front of the feet). The contact is then hidden (or, for a rider, on its vehicle)."""
    h, w = inst.shape
    v = int(det["foot_v"])
    row = inst[v]
    cols = np.flatnonzero(row == det["instance_id"])
    if len(cols) == 0:
        return []
    patch = inst[max(v - side_px, 0):min(v + 1 + contact_px, h),
                 max(cols.min() - side_px, 0):min(cols.max() + side_px + 1, w)]
    ids = np.unique(patch)
    return [int(i) for i in ids if i != 0 and i != det["instance_id"]]


def _horizontal_dir(P: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    h = P - d * n
    s = np.linalg.norm(h)
    return h / s if s > 1e-9 else np.zeros(3)


def pairs(pos: np.ndarray, close_m: float = 2.0, classes=(PERSON,)) -> list[dict[str, Any]]:
    """Per frame, every pair of agents of ``classes`` with their ground distance (m)."""
    from staticdepth.geometry.ground_frame import pairwise_distances

    out = []
    sel_cls = np.isin(pos["class_id"], list(classes))
    for f in np.unique(pos["frame"][sel_cls]):
        idx = np.flatnonzero(sel_cls & (pos["frame"] == f))
        if len(idx) < 2:
            continue
        D = pairwise_distances(np.stack([pos["ground_x"][idx], pos["ground_y"][idx]], 1))
        for a in range(len(idx)):
            for b in range(a + 1, len(idx)):
                out.append({"frame": int(f), "time_s": float(pos["time_s"][idx[a]]),
                            "track_a": int(pos["track"][idx[a]]),
                            "track_b": int(pos["track"][idx[b]]),
                            "distance_m": float(D[a, b]), "close": int(D[a, b] < close_m)})
    return out


def speed_summary(pos: np.ndarray, min_track_s: float = 2.0) -> dict[str, float]:
    """Distribution of the people's median speed per track (tracks seen >= ``min_track_s``)."""
    med = []
    for t in np.unique(pos["track"][pos["class_id"] == PERSON]):
        sel = (pos["track"] == t) & (pos["class_id"] == PERSON)
        ts = pos["time_s"][sel]
        s = pos["speed_mps"][sel]
        s = s[np.isfinite(s)]
        if ts.max() - ts.min() >= min_track_s and len(s):
            med.append(float(np.median(s)))
    if not med:
        return {"tracks": 0}
    q = np.percentile(med, [10, 25, 50, 75, 90])
    return {"tracks": len(med), "p10": q[0], "p25": q[1], "median": q[2], "p75": q[3],
            "p90": q[4]}


# -- command line ----------------------------------------------------------------------------------
def register(sub) -> None:
    p = sub.add_parser("locate",
                       help="agents' positions in metres, speeds, distances between people",
                       description="Per frame and agent: the ground contact in the camera and "
                                   "ground frames (from the agents' plane and the camera height; "
                                   "the adapted depth map where the contact is hidden), distance, "
                                   "speed along the track; pairwise distances; bird's-eye plot and "
                                   "annotated frames.")
    p.add_argument("sequence", help="sequence file (.h5)")
    p.add_argument("--out", required=True,
                   help="positions table: .csv, or .parquet (needs pyarrow: staticdepth[parquet])")
    p.add_argument("--summary", help="adapt summary (default: SEQ.adapt.json)")
    p.add_argument("--plane", help="plane JSON (`staticdepth ground-plane`) instead of a summary")
    p.add_argument("--camera-height", type=float, help="camera height (m); overrides the summary's")
    p.add_argument("--detector", help="gt (the sequence's instances; default when it has them), "
                                      "motion, yolox (default: the summary's)")
    p.add_argument("--detector-model", help="YOLOX ONNX file (default: the summary's)")
    p.add_argument("--detector-mask", default="box", choices=("box", "motion", "grabcut"),
                   help="yolox: the agent's silhouette (box: the contact is the box's bottom)")
    p.add_argument("--depth", default="auto",
                   help="metric prediction for hidden contacts (auto: ft-align-metric or "
                        "align-metric when stored; none: plane only)")
    p.add_argument("--pairs", help="pairwise distances table (.csv or .parquet)")
    p.add_argument("--close-m", type=float, default=2.0, help="close-pair threshold (m)")
    p.add_argument("--bev", help="bird's-eye-view PNG")
    p.add_argument("--annotate", help="annotated frames: .gif or .mp4 (and a PNG sheet beside)")
    p.add_argument("--annotate-frames", type=int, default=12, help="how many frames to annotate")
    p.add_argument("--person-radius", type=float, default=0.2, help="body radius of people (m)")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)
    p.set_defaults(func=_run)


def _run(args) -> int:
    from staticdepth.geometry.camera import read_json
    from staticdepth.locate_tables import check_table_path, write_pairs, write_positions

    from staticdepth import locate_draw
    from staticdepth.cli import refuse_existing

    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.fileio import check_writable

    # every option and every output before any work and before any file is written: a refusal
    # after the table was written left it behind, and the corrected rerun was 'exists already'
    for path in (args.out, args.pairs):
        check_table_path(path)          # before the work: a .parquet path without pyarrow
    if args.annotate:
        locate_draw.check_annotate_path(args.annotate)
    if args.bev:
        locate_draw.check_image_path(args.bev, "--bev")
    if not args.close_m > 0:
        raise InputError(f"--close-m must be positive, got {args.close_m}")
    if not 0 <= args.person_radius <= MAX_PERSON_RADIUS_M:
        raise InputError(f"--person-radius must be a body radius from 0 to "
                         f"{MAX_PERSON_RADIUS_M:g} m, got {args.person_radius:g}")
    if args.annotate_frames < 1:
        raise InputError(f"--annotate-frames must be at least 1, got {args.annotate_frames}")
    outputs = [p for p in (args.out, args.pairs, args.bev, args.annotate,
                           args.annotate and locate_draw.sheet_path(args.annotate)) if p]
    refuse_existing(*outputs, overwrite=args.overwrite)
    for path in outputs:
        check_writable(path)            # its folder exists, a file can be created there
    with SequenceReader(args.sequence):
        pass                            # a damaged sequence is said as such, before its summary
    n, h, src = load_plane(args.summary, args.plane, args.camera_height, args.sequence)
    detector, model = args.detector, args.detector_model
    if detector is None and not args.plane:
        path = args.summary or f"{os.path.splitext(args.sequence)[0]}.adapt.json"
        from staticdepth.config import setting_from

        cfg = read_json(path).get("config") or {}
        if setting_from(cfg, "detector.name") not in (None, "gt"):
            detector = setting_from(cfg, "detector.name")
            model = model or setting_from(cfg, "detector.model")
    conf = LocateConfig(person_radius_m=args.person_radius, close_m=args.close_m)
    pos = locate(args.sequence, n, h, conf, detector=detector, detector_model=model,
                 detector_mask=args.detector_mask,
                 depth_pred=None if args.depth == "none" else args.depth)
    write_positions(args.out, pos)
    pr = pairs(pos, args.close_m)
    if args.pairs:
        write_pairs(args.pairs, pr)
    if args.bev:
        locate_draw.write_bev(args.bev, pos)
    if args.annotate:
        locate_draw.write_annotated(args.annotate, args.sequence, pos, pr, args.annotate_frames)
    src_counts = {s: int(np.count_nonzero(pos["source"] == s)) for s in ("plane", "depth")}
    print(f"plane from {src}; camera height {h:.2f} m")
    print(f"{len(pos)} positions of {len(np.unique(pos['track']))} tracks in "
          f"{len(np.unique(pos['frame']))} frames (source: {src_counts['plane']} plane, "
          f"{src_counts['depth']} depth; {int(pos['occluded'].sum())} hidden contacts)")
    sp = speed_summary(pos)
    if sp["tracks"]:
        print(f"people's speeds (median per track, {sp['tracks']} tracks >= 2 s): p10 "
              f"{sp['p10']:.2f}, p25 {sp['p25']:.2f}, median {sp['median']:.2f}, p75 "
              f"{sp['p75']:.2f}, p90 {sp['p90']:.2f} m/s")
    print(f"{sum(p['close'] for p in pr)} close pairs (< {args.close_m:g} m) over {len(pr)} pairs")
    print(f"positions: {args.out}")
    return 0
