"""Commands ``calibrate``, ``stereo`` and ``mount`` (thin shells over the library)."""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="stereo calibration from board image pairs",
                       description="Calibrate a stereo rig from image pairs of a chessboard or "
                                   "ChArUco board; writes the rig JSON every other command reads.")
    p.add_argument("--pattern", choices=("chessboard", "charuco"), default="chessboard",
                   help="calibration board type")
    p.add_argument("--board", required=True, help="inner corners (chessboard) or squares "
                                                  "(ChArUco), COLSxROWS, e.g. 9x6")
    p.add_argument("--square", type=float, required=True, help="square side in metres")
    p.add_argument("--marker", type=float, default=0.0, help="ChArUco marker side in metres")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary")
    p.add_argument("--left", required=True, help="left images: folder or glob")
    p.add_argument("--right", required=True, help="right images: folder or glob")
    p.add_argument("--min-pairs", type=int, default=5,
                   help="fewest pairs with the board found (after dropping outliers)")
    p.add_argument("--out", required=True, help="rig JSON to write")
    _overwrite(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("stereo", help="depth from stereo pairs (SGBM or an ONNX network)",
                       description="Rectify, match and triangulate a recorded stereo sequence "
                                   "into a sequence file, or match one rectified pair "
                                   "(--rectified).")
    p.add_argument("--rig", help="rig JSON (from calibrate or an import; default for --recording: "
                                 "the recording's own)")
    p.add_argument("--left", help="left frames: folder, glob, video or one image")
    p.add_argument("--right", help="right frames: folder, glob, video or one image")
    p.add_argument("--recording", help="a recorded sequence instead of --left/--right: a "
                                       "`staticdepth capture` folder or DIR/left, DIR/right")
    p.add_argument("--out", help="sequence file to write (.h5)")
    p.add_argument("--name", help="sequence name (default: the output's stem)")
    _overwrite(p)
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run (<out>.partial, or with --sequence the "
                        "prediction's .partial) with the same inputs and settings")
    p.add_argument("--restart", action="store_true",
                   help="discard an interrupted run's .partial and start over")
    p.add_argument("--rectified", action="store_true", help="one already rectified pair, no rig")
    p.add_argument("--max-disparity", type=int, help="disparity range in px (positive), rounded "
                                                     "up to 16 (sequences: default from "
                                                     "--min-depth)")
    p.add_argument("--disparity-out", help="left disparity file (.pfm, .png x256 or .npy)")
    p.add_argument("--ply", help="point cloud of the first frame (PLY)")
    p.add_argument("--matcher", default="sgbm", help="sgbm (default) or onnx")
    p.add_argument("--model", help="ONNX file (--matcher onnx)")
    p.add_argument("--contract", help="ONNX contract: crestereo, crestereo-init-next, "
                                      "crestereo-combined, hitnet, hitnet-rgb, raft-stereo, or a "
                                      "JSON file (default: chosen from the model's input names)")
    p.add_argument("--fill", action="store_true", help="dense mode: fill every pixel")
    p.add_argument("--min-depth", type=float, help="nearest depth (m): sets the disparity range")
    p.add_argument("--max-depth", type=float, default=80.0, help="depth cap (m)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="matcher option, e.g. --set uniqueness=20 (temporal fusion: "
                        "--set temporal.samples=40)")
    p.add_argument("--sequence", help="a sequence file with left/right streams: store its stereo "
                                      "depth as prediction --out-name (and NAME-confidence)")
    p.add_argument("--out-name", help="prediction name for --sequence")
    p.add_argument("--temporal", action="store_true",
                   help="--sequence: fuse the static background over the frames")
    p.add_argument("--skip-rectification-check", action="store_true",
                   help="do not check that matched features of the first (rectified) pair lie on "
                        "the same rows")
    p.set_defaults(func=cmd_stereo)

    p = sub.add_parser("mount", help="camera height and ground plane from a board on the ground",
                       description="Estimate the left camera's pose over the ground from views of "
                                   "a board lying flat on it, and store it in the rig.")
    p.add_argument("--rig", required=True, help="rig JSON (from calibrate or import-rig)")
    p.add_argument("--images", required=True, help="raw left images of the board: folder or glob")
    p.add_argument("--pattern", choices=("chessboard", "charuco"), default="chessboard",
                   help="board type")
    p.add_argument("--board", required=True, help="inner corners (chessboard) or squares "
                                                  "(ChArUco), COLSxROWS")
    p.add_argument("--square", type=float, required=True, help="square side in metres")
    p.add_argument("--marker", type=float, default=0.0, help="ChArUco marker side in metres")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary")
    p.add_argument("--thickness", type=float, default=0.0,
                   help="board thickness in metres (0 to under 0.5)")
    p.add_argument("--max-normal-spread", type=float, default=2.0, metavar="DEG",
                   help="largest angle between two views' ground normals (default 2)")
    p.add_argument("--max-height-spread", type=float, default=0.05, metavar="FRACTION",
                   help="largest spread of the views' camera heights, as a fraction of the "
                        "height (default 0.05)")
    p.add_argument("--out", required=True, help="rig JSON to write (may be --rig itself: the rig "
                                                "is updated in place)")
    _overwrite(p)
    p.set_defaults(func=cmd_mount)


def _overwrite(p) -> None:
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)


def _refuse_existing(*paths, overwrite: bool) -> None:
    from staticdepth.cli import refuse_existing

    refuse_existing(*paths, overwrite=overwrite)


def _board(args):
    from staticdepth.stereo.calibrate import Board

    kw = {"marker_m": args.marker, "dictionary": args.dictionary}
    return Board.parse(args.pattern, args.board, args.square, **kw)


def _check_out(path: str, overwrite: bool) -> None:
    """An output that cannot be written (missing folder, read-only) is refused before any work."""
    from staticdepth.fileio import check_writable

    check_writable(path)
    _refuse_existing(path, overwrite=overwrite)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from staticdepth.stereo.calibrate import MIN_PAIRS, calibrate_stereo
    from staticdepth.stereo.io import expand_images

    if args.min_pairs < MIN_PAIRS:
        raise InputError(f"--min-pairs must be at least {MIN_PAIRS} (one view of a flat board "
                         f"cannot fix the focal length), got {args.min_pairs}")
    board = _board(args)
    _check_out(args.out, args.overwrite)
    left, right = expand_images(args.left), expand_images(args.right)
    if args.min_pairs > len(left):
        raise InputError(f"--min-pairs {args.min_pairs} but only {len(left)} left images are "
                         f"given: give more pairs or a lower --min-pairs", args.left)
    cal = calibrate_stereo(left, right, board, min_pairs=args.min_pairs)
    for f in cal.not_found:
        print(f"board not found: {f}")
    for f, e in cal.dropped.items():
        print(f"dropped outlier view: {f} (RMS {e:.3f} px)")
    for f, e in cal.per_view_rms.items():
        print(f"  {os.path.basename(f)}: {e:.3f} px")
    cal.rig.save(args.out)
    print(f"stereo RMS reprojection error {cal.rig.rms_reprojection_px:.4f} px over "
          f"{len(cal.used)} pairs, baseline {cal.rig.baseline_m:.4f} m -> {args.out}")
    return 0


def cmd_mount(args: argparse.Namespace) -> int:
    from staticdepth.stereo.io import expand_images
    from staticdepth.stereo.mount import MAX_THICKNESS_M, mount_from_board

    if not (np.isfinite(args.thickness) and 0 <= args.thickness < MAX_THICKNESS_M):
        raise InputError(f"--thickness is the board's thickness in metres, from 0 to under "
                         f"{MAX_THICKNESS_M:g}; got {args.thickness}")
    for flag, value in (("--max-normal-spread", args.max_normal_spread),
                        ("--max-height-spread", args.max_height_spread)):
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"{flag} must be a non-negative number, got {value}")
    board = _board(args)
    if os.path.abspath(args.out) != os.path.abspath(args.rig):
        _check_out(args.out, args.overwrite)
    else:
        from staticdepth.fileio import check_writable

        check_writable(args.out)
    rig = StereoRig.load(args.rig)
    est = mount_from_board(rig, expand_images(args.images), board, thickness_m=args.thickness,
                           max_normal_spread_deg=args.max_normal_spread,
                           max_height_spread=args.max_height_spread, source=args.images)
    for f in est.skipped:
        print(f"board not found: {f}")
    for f, (h, a) in est.per_view.items():
        print(f"  {os.path.basename(f)}: height {h:.4f} m, normal {a:.3f} deg from the mean")
    m = est.mounting
    rig.with_mounting(m).save(args.out)
    print(f"camera height {m.height_m:.4f} m, pitch {m.pitch_deg:.3f} deg, roll {m.roll_deg:.3f} "
          f"deg ({est.method}; OpenCV cross-check {est.crosscheck_deg:.3f} deg) -> {args.out}")
    return 0


def _config(args, **extra):
    from staticdepth.cli import parse_overrides
    from staticdepth.stereo.pipeline import StereoConfig

    from staticdepth.config import from_dict, split_options

    fields, options = split_options(StereoConfig, parse_overrides(args.set), strict=False)
    if args.matcher == "onnx":
        if not args.model:
            raise InputError("--matcher onnx needs --model FILE.onnx")
        options.update(model=args.model, contract=args.contract)
    _check_depth_range(args, fields, extra)
    # the options above are valid on their own: what from_dict still refuses came with --set
    return from_dict(StereoConfig, {"max_depth_m": args.max_depth, "min_depth_m": args.min_depth,
                                    "fill": args.fill, **extra, **fields,
                                    "matcher": args.matcher, "options": options},
                     source="--set" if fields else None)


def _check_depth_range(args, fields: dict, extra: dict) -> None:
    """Refuse --max-depth / --min-depth by their names, and two ways to set one disparity range."""
    if not (np.isfinite(args.max_depth) and args.max_depth > 0):
        raise InputError(f"--max-depth must be a positive number of metres, got {args.max_depth}")
    if args.min_depth is not None and not 0 < args.min_depth < args.max_depth:
        raise InputError(f"--min-depth must be above 0 and below --max-depth ({args.max_depth:g} "
                         f"m), got {args.min_depth}")
    by_depth = [flag for flag, given in (("--min-depth", args.min_depth is not None),
                                         ("--set min_depth_m", "min_depth_m" in fields)) if given]
    by_count = [flag for flag, given in (("--max-disparity", "num_disparities" in extra),
                                         ("--set num_disparities", "num_disparities" in fields))
                if given]
    if by_depth and by_count:
        raise InputError(f"give one of {by_count[0]} or {by_depth[0]}, not both: each sets the "
                         f"disparity range (the nearest depth it reaches is f B / disparity)")


def cmd_stereo(args: argparse.Namespace) -> int:
    if args.sequence or args.out_name or args.temporal:
        return _stereo_on_sequence(args)
    if args.recording and (args.left or args.right or args.rectified):
        raise InputError("give either --recording or --left/--right, not both")
    if not args.recording and not (args.left and args.right):
        raise InputError("stereo needs --left and --right (or --recording DIR)")
    if args.resume and args.restart:
        raise InputError("give --resume or --restart, not both")
    if args.rectified:
        return _stereo_pair(args)
    if not (args.rig or args.recording) or not args.out:
        raise InputError("stereo needs --rig and --out (or --rectified for one rectified pair)")
    return _stereo_sequence(args)


def _stereo_pair(args) -> int:
    from staticdepth.stereo.io import read_rgb, write_disparity, write_ply
    from staticdepth.stereo.pipeline import StereoPipeline

    if args.max_disparity is None:
        raise InputError("--rectified needs --max-disparity N (a positive number of pixels)")
    _num_disparities(args.max_disparity)          # 0 or below: refused by name
    if not args.disparity_out:
        raise InputError("--rectified needs --disparity-out FILE (.pfm, .png or .npy)")
    if args.ply and not args.rig:
        raise InputError("--ply with --rectified needs --rig (the focal length and baseline that "
                         "make disparities metric)")
    from staticdepth.fileio import check_writable

    for out in (args.disparity_out, args.ply):
        if out:  # a folder, a read-only place: refused before any work
            check_writable(out)
    _refuse_existing(args.disparity_out, args.ply, overwrite=args.overwrite)
    left, right = read_rgb(args.left), read_rgb(args.right)
    if left.shape != right.shape:
        raise InputError(f"left is {left.shape[1]}x{left.shape[0]} but right is "
                         f"{right.shape[1]}x{right.shape[0]}", args.right)
    h, w = left.shape[:2]
    if w <= _num_disparities(args.max_disparity) or h < 16:  # before OpenCV asserts on it
        raise InputError(f"image is {w}x{h}: too small to match (at least 16 rows, and wider "
                         f"than the disparity range {_num_disparities(args.max_disparity)} px)",
                         args.left)
    check = _rectification(args, left, right, args.left)
    unit = Camera.from_intrinsics(1.0, 1.0, (w - 1) / 2, (h - 1) / 2, w, h)
    rig = StereoRig.load(args.rig) if args.rig else StereoRig.rectified(unit, 1.0)
    pipe = StereoPipeline(rig, _config(args, num_disparities=_num_disparities(args.max_disparity)),
                          rig_source=args.rig)
    res = pipe.process(left, right)
    _disparity_warnings(check, pipe, res)
    write_disparity(args.disparity_out, res.disparity)
    if args.ply:
        write_ply(args.ply, pipe.points(res), res.left_rect)
    print(f"disparity: {100 * res.valid.mean():.1f}% measured"
          f"{', filled to 100%' if args.fill else ''} -> {args.disparity_out}")
    return 0


def _stereo_on_sequence(args) -> int:
    """``--sequence SEQ.h5 --out-name NAME [--temporal] [--fill]``: see stereo/sequence.py."""
    from staticdepth.cli import parse_overrides
    from staticdepth.stereo.sequence import check_name, partial_paths, stereo_sequence
    from staticdepth.stereo.temporal import TemporalConfig

    if not (args.sequence and args.out_name):
        raise InputError("--sequence, --out-name and --temporal go together: "
                         "stereo --sequence SEQ.h5 --out-name NAME [--temporal]")
    if args.left or args.right or args.recording or args.rectified or args.out:
        raise InputError("--sequence reads the sequence's own left/right streams: drop --left, "
                         "--right, --recording, --rectified and --out")
    try:
        check_name(args.out_name)
    except InputError as e:
        raise InputError(f"--out-name: {e.problem}") from None
    overrides = parse_overrides(args.set)
    temporal = {k[len("temporal."):]: v for k, v in overrides.items() if k.startswith("temporal.")}
    if temporal and not args.temporal:
        raise InputError("temporal.* settings need --temporal")
    args.set = [f"{k}={v}" for k, v in overrides.items() if not k.startswith("temporal.")]
    extra = {} if args.max_disparity is None \
        else {"num_disparities": _num_disparities(args.max_disparity)}
    try:
        res = stereo_sequence(args.sequence, args.out_name, _config(args, **extra),
                              TemporalConfig.from_dict(temporal, "--set temporal.*")
                              if args.temporal else None, overwrite=args.overwrite,
                              resume=args.resume, restart=args.restart)
    except KeyboardInterrupt:
        for partial in partial_paths(args.sequence, args.out_name):
            print(f"note: {partial} keeps the frames written; the same command with --resume "
                  f"continues it, --restart starts over", file=sys.stderr)
        raise
    print(f"{res.frames} frames, {res.num_disparities} disparities, {100 * res.density:.1f}% "
          f"of pixels with depth{' (background model reused)' if res.background_reused else ''}"
          f" -> predictions {res.name!r} and {res.name + '-confidence'!r} in {args.sequence}")
    return 0
def _rectification(args, left_rect, right_rect, source: str):
    """The rectification check of the first rectified pair (its matches feed the warnings)."""
    from staticdepth.stereo.rectify import check_rectified, measure_rectification

    if args.skip_rectification_check:
        return measure_rectification(left_rect, right_rect)
    return check_rectified(left_rect, right_rect, source=source, warn=_warn)


def _disparity_warnings(check, pipe, res) -> None:
    """Warn when the disparity range clips the scene or the views look swapped."""
    from staticdepth.stereo.diagnose import stereo_warnings

    measured = np.where(res.valid, res.disparity, np.nan)
    for message in stereo_warnings(check, pipe.num_disparities, measured):
        _warn(f"warning: {message}")


def _warn(message: str) -> None:
    print(f"staticdepth stereo: {message}", file=sys.stderr)


def _num_disparities(max_disparity: int) -> int:
    if max_disparity <= 0:
        raise InputError(f"--max-disparity must be positive, got {max_disparity}")
    return int(16 * np.ceil(max_disparity / 16))


@dataclass
class _Frames:
    """The input pairs of a sequence: count, reader from a frame on, names, timestamps, rig."""

    count: int
    pairs: Callable[[int], Iterator[tuple[np.ndarray, np.ndarray]]]
    first: str                          # the first left frame's name (for errors)
    left_files: list[str] | None = None
    right_files: list[str] | None = None
    timestamps: list[float] | None = None
    rig: StereoRig | None = None        # a recording's own rig

    def labels(self) -> list[str]:
        return ([os.path.basename(f) for f in self.left_files] if self.left_files
                else [str(i) for i in range(self.count)])


def _stream(spec: str):
    """(count, iterator factory(start), files or None) for a folder/glob of images or a video."""
    from staticdepth.dataset.video import VideoFrames
    from staticdepth.stereo.io import expand_images, is_video, read_rgb

    if is_video(spec):
        video = VideoFrames(spec)
        return len(video), lambda start: (video[i] for i in range(start, len(video))), None
    files = expand_images(spec)
    return len(files), lambda start: (read_rgb(f) for f in files[start:]), files


def _sequence_input(args) -> _Frames:
    from staticdepth.stereo.io import read_rgb

    if args.recording:
        from staticdepth.dataset.pack import recording_tasks

        tasks, _, rig = recording_tasks(args.recording)
        if not tasks:
            raise InputError("the recording has no complete frame", args.recording)
        times = [t.timestamp for t in tasks]
        return _Frames(len(tasks),
                       lambda start: ((read_rgb(t.left), read_rgb(t.right)) for t in tasks[start:]),
                       tasks[0].left, [t.left for t in tasks], [t.right for t in tasks],
                       None if None in times else times, rig)
    n_left, left_iter, left_files = _stream(args.left)
    n_right, right_iter, right_files = _stream(args.right)
    if n_left != n_right:
        raise InputError(f"{n_left} left frames but {n_right} right frames", args.right)
    return _Frames(n_left, lambda start: zip(left_iter(start), right_iter(start)),
                   left_files[0] if left_files else args.left, left_files, right_files)


def _stereo_sequence(args) -> int:
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
    from staticdepth.progress import progress
    from staticdepth.stereo.io import check_image_headers, write_ply
    from staticdepth.stereo.pipeline import StereoPipeline

    _refuse_existing(args.ply, overwrite=args.overwrite)
    frames = _sequence_input(args)
    if args.rig:
        rig = StereoRig.load(args.rig)
    elif frames.rig is not None:
        rig = frames.rig
    else:
        raise InputError("the recording has no rig: pass --rig rig.json", args.recording)
    rig_name = args.rig or f"{args.recording} (its rig)"
    extra = {}
    if args.max_disparity is not None:
        extra["num_disparities"] = _num_disparities(args.max_disparity)
    pipe = StereoPipeline(rig, _config(args, **extra), rig_source=rig_name)
    # Every check before any work: sizes and readability of every file's header, the first pair
    # in full, and that the rig really rectifies it.
    for files in (frames.left_files, frames.right_files):
        if files:
            check_image_headers(files, rig.left.size)
    first_l, first_r = next(frames.pairs(0))
    pipe.check_frame(first_l, first_r, frames.first)
    rl, rr = pipe.rectifier.rectify(first_l, first_r)
    check = _rectification(args, rl, rr, f"{rig_name} (after rectifying {frames.first})")
    name = args.name or os.path.splitext(os.path.basename(args.out))[0]
    source = (f"stereo recording {args.recording}" if args.recording
              else f"stereo {args.left} {args.right}")
    meta = SequenceMeta(name=name, camera=pipe.camera, gt_kind="stereo", source=source,
                        rig=StereoRig.rectified(pipe.camera, pipe.baseline_m),
                        mounting=_rectified_mounting(rig),
                        provenance={**pipe.provenance(), "input_rig": rig.to_dict()})
    writer = SequenceWriter(args.out, meta, streams=("left", "right", "depth"),
                            resume=args.resume, restart=args.restart, overwrite=args.overwrite,
                            inputs=_input_identities(frames, args), labels=frames.labels())
    start = len(writer)
    try:
        pairs = frames.pairs(start)
        for i, (L, R) in enumerate(progress(pairs, total=frames.count - start, desc="stereo"),
                                   start):
            name_i = frames.left_files[i] if frames.left_files else f"frame {i} of {args.left}"
            pipe.check_frame(L, R, name_i)
            res = pipe.process(L, R)
            ts = None if frames.timestamps is None else frames.timestamps[i]
            writer.append(left=res.left_rect, right=res.right_rect, depth=res.depth, timestamp=ts)
            if i == 0:
                _disparity_warnings(check, pipe, res)
            if i == 0 and args.ply:
                write_ply(args.ply, pipe.points(res), res.left_rect)
    except BaseException:
        writer.abort()
        raise
    out = writer.close()
    print(f"{frames.count} frames ({start} resumed) -> {out}")
    return 0


def _input_identities(frames: _Frames, args) -> list[str]:
    """One identity per input pair (file paths with size and mtime; a video's by frame index)."""
    from staticdepth.dataset.resume import task_identity

    if frames.left_files and frames.right_files:
        return [task_identity((a, b)) for a, b in zip(frames.left_files, frames.right_files)]
    whole = task_identity((args.left, args.right))
    return [task_identity((whole, str(i))) for i in range(frames.count)]


def _rectified_mounting(rig: StereoRig):
    """The rig's mounting is stored in the rectified left frame already (see ``mount``)."""
    return rig.mounting
