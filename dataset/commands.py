"""Commands ``pack``, ``import-kitti``, ``import-carla``, ``export``, ``publish`` (thin shells)."""
from __future__ import annotations

import argparse
import os

from staticdepth.dataset import schema
from staticdepth.errors import InputError
from staticdepth.geometry.camera import check_camera_height


def _writer_options(p: argparse.ArgumentParser, executors: bool = True) -> None:
    p.add_argument("--out", required=True, help="output sequence file (.h5)")
    p.add_argument("--adapt-frames", type=int, default=None,
                   help="the first N >= 1 frames form the adaptation split, the rest the "
                        "evaluation (default: none, every frame is for evaluation)")
    p.add_argument("--skip-bad", action="store_true",
                   help="skip unreadable frames (listed and counted) instead of stopping")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run (<out>.partial)")
    p.add_argument("--restart", action="store_true",
                   help="discard an interrupted run's <out>.partial and start over")
    p.add_argument("--overwrite", action="store_true",
                   help="replace outputs that exist already (refused otherwise)")
    if executors:
        p.add_argument("--workers", type=int, default=1,
                       help="local worker processes (1 to 256)")
        p.add_argument("--executor", default="serial", choices=("serial", "process", "ray"),
                       help="where frames are processed (same file either way)")
        p.add_argument("--address", default=None,
                       help="Ray cluster address (with --executor ray; default: a local Ray)")


def register(sub) -> None:
    p = sub.add_parser("pack",
                       help="pack a stereo recording into a sequence file with stereo depth",
                       description="Run the stereo pipeline on every pair of a recording and store "
                                   "images, depth (NaN where the stereo check failed), timestamps, "
                                   "rig, camera height, splits and provenance.")
    p.add_argument("--recording", required=True,
                   help="recording folder: a `staticdepth capture` recording, or DIR/left/*.png, "
                        "DIR/right/*.png with an optional DIR/timestamps.csv")
    p.add_argument("--rig", default=None, help="stereo rig JSON (default: the recording's own rig)")
    p.add_argument("--camera-height", type=float, default=None,
                   help="camera height over the ground (m)")
    p.add_argument("--matcher", default="sgbm", help="stereo matcher (sgbm, onnx, ...)")
    p.add_argument("--model", default=None,
                   help="matcher model file (e.g. a CREStereo ONNX export)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="stereo setting override")
    p.add_argument("--no-right", action="store_true", help="do not store the right image")
    p.add_argument("--name", default=None, help="sequence name (default: the recording's folder)")
    p.add_argument("--skip-rectification-check", action="store_true",
                   help="do not check that matched features of the first (rectified) pair lie on "
                        "the same rows (nor that the views look swapped)")
    _writer_options(p)
    p.set_defaults(func=_pack)

    p = sub.add_parser("import-kitti", help="import KITTI raw drives with LiDAR ground truth",
                       description="Concatenate KITTI raw drives (left colour camera) into one "
                                   "sequence file; depth from the LiDAR scans projected into "
                                   "camera 2, or from the official depth-completion maps.")
    p.add_argument("--root", required=True, help="KITTI raw root (holding <date>/ folders)")
    p.add_argument("--drives", nargs="+", required=True, help="e.g. 2011_09_28_drive_0016")
    p.add_argument("--name", default=None, help="sequence name (default: the output's stem)")
    p.add_argument("--right", action="store_true", help="also import image_03 as the right view")
    p.add_argument("--depth-maps", default=None,
                   help="root of the official depth-completion maps (used instead of the scans; "
                        "a drive's first and last 5 frames, which they leave out, are imported "
                        "with unknown depth and counted; a map missing elsewhere is a bad frame)")
    p.add_argument("--camera-height", type=float, default=1.65,
                   help="camera height over the road (m; KITTI's camera 2)")
    _writer_options(p)
    p.set_defaults(func=_import_kitti)

    p = sub.add_parser("import-carla", help="import frames saved from CARLA's sensors",
                       description="Import rgb/, depth/, instance/ (and right/) PNGs and "
                                   "sensor.json "
                                   "saved from CARLA's Python API into a sequence file.")
    p.add_argument("dir", help="CARLA export folder")
    p.add_argument("--name", default=None, help="sequence name (default: the output's stem)")
    p.add_argument("--legacy-tags", action="store_true",
                   help="semantic tags use CARLA's pre-0.9.14 numbering (Pedestrian 4, Vehicle 10)")
    _writer_options(p)
    p.set_defaults(func=_import_carla)

    p = sub.add_parser("export", help="export a sequence file to KITTI-style folders",
                       description="Write PNG images, uint16 depth x256 (0 = unknown), timestamps, "
                                   "calibration and split lists, one file per frame in frame "
                                   "order.")
    p.add_argument("file", help="sequence file (.h5)")
    p.add_argument("--format", default="kitti", choices=("kitti",), help="export layout")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace outputs that exist already (refused otherwise)")
    p.set_defaults(func=_export)

    p = sub.add_parser("publish", help="make a release folder: sequences, export, card, manifest",
                       description="Copy sequence files into a release folder with their "
                                   "KITTI-style export, a dataset card (Markdown + JSON) and a "
                                   "SHA-256 manifest that `staticdepth verify DIR` checks.")
    p.add_argument("files", nargs="+", help="sequence files (.h5)")
    p.add_argument("--out", required=True, help="release folder")
    p.add_argument("--title", default=None, help="dataset title on the card")
    p.add_argument("--licence", default="unspecified", help="licence of the data (e.g. CC-BY-4.0)")
    p.add_argument("--citation", default=None, help="citation text or BibTeX")
    p.add_argument("--no-export", action="store_true", help="leave out the KITTI-style export")
    p.add_argument("--overwrite", action="store_true",
                   help="replace outputs that exist already (refused otherwise)")
    p.set_defaults(func=_publish)


def _write_with_executor(args: argparse.Namespace, write, *pos, **kw) -> int:
    """Check the writer options (before any work), run a writer (``import_kitti``,
    ``import_carla``, ``pack_recording``) with the executor they ask for, close the executor,
    print the report."""
    from staticdepth.dataset.executors import make_executor
    from staticdepth.dataset.pack import format_report
    from staticdepth.dataset.writer import check_sequence_output

    if args.resume and args.restart:
        raise InputError("give --resume or --restart, not both")
    check_sequence_output(args.out)
    schema.check_adapt_frames(args.adapt_frames, schema.ADAPT_NONE)
    ex = make_executor(args.executor, args.workers, args.address)    # checks --workers
    try:
        rep = write(*pos, skip_bad=args.skip_bad, resume=args.resume, overwrite=args.overwrite,
                    executor=ex, restart=args.restart, adapt_frames=args.adapt_frames or 0, **kw)
    finally:
        ex.close()
    print(format_report(rep))
    return 0


def _import_kitti(args: argparse.Namespace) -> int:
    from staticdepth.dataset.kitti import import_kitti

    check_camera_height(args.camera_height, "--camera-height")     # before any heavy work
    schema.check_name(args.name)
    return _write_with_executor(args, import_kitti, args.root, args.drives, args.out,
                                name=args.name, right=args.right,
                                depth_maps=args.depth_maps, camera_height_m=args.camera_height)


def _import_carla(args: argparse.Namespace) -> int:
    from staticdepth.dataset.carla import import_carla

    schema.check_name(args.name)
    return _write_with_executor(args, import_carla, args.dir, args.out, name=args.name,
                                legacy_tags=args.legacy_tags)


def _pack(args: argparse.Namespace) -> int:
    from staticdepth.cli import parse_overrides
    from staticdepth.dataset.pack import pack_recording

    if args.camera_height is not None:
        check_camera_height(args.camera_height, "--camera-height")
    schema.check_name(args.name)
    return _write_with_executor(args, pack_recording, args.recording, args.rig, args.out,
                                camera_height_m=args.camera_height, matcher=args.matcher,
                                model=args.model, overrides=parse_overrides(args.set),
                                store_right=not args.no_right, name=args.name,
                                check_rectification=not args.skip_rectification_check)


def _export(args: argparse.Namespace) -> int:
    from staticdepth.dataset.export import beyond_range_note, export_kitti

    info = export_kitti(args.file, args.out, overwrite=args.overwrite)
    print(f"exported {info['frames']} frames to {info['path']}")
    if info["depth_beyond_range_px"]:
        print(f"warning: {info['path']}: {beyond_range_note(info['depth_beyond_range_px'])}")
    return 0


def _publish(args: argparse.Namespace) -> int:
    from staticdepth.dataset.export import beyond_range_note
    from staticdepth.dataset.publish import publish

    if args.out in args.files:
        raise InputError("--out must be a folder, not one of the input files", args.out)
    info = publish(args.files, args.out, title=args.title, licence=args.licence,
                   citation=args.citation, export=not args.no_export, overwrite=args.overwrite)
    print(f"published {len(info['sequences'])} sequence(s), {info['files']} files, "
          f"to {info['path']}")
    for rel, pixels in info["depth_beyond_range_px"].items():
        print(f"warning: {os.path.join(info['path'], rel)}: {beyond_range_note(pixels)}")
    return 0
