"""Command ``import-rig``: a rig JSON from a DepthAI, Middlebury or KITTI calibration file."""
from __future__ import annotations

import argparse


def register(sub) -> None:
    p = sub.add_parser("import-rig",
                       help="rig JSON from a DepthAI, Middlebury or KITTI calibration",
                       description="Convert another tool's stereo calibration into the rig JSON "
                                   "that calibrate writes and stereo, pack and mount read.")
    p.add_argument("file", help="calibration file: DepthAI eepromToJson JSON, Middlebury "
                                "calib.txt or KITTI calib_cam_to_cam.txt")
    p.add_argument("--from", dest="kind", required=True, choices=("depthai", "middlebury", "kitti"),
                   help="the calibration file's format")
    p.add_argument("--camera", type=int, help="KITTI: left camera of the pair, 2 (colour, "
                                              "default) or 0 (grey)")
    p.add_argument("--size", help="WIDTHxHEIGHT of the recorded images when they are a resized "
                                  "version of the calibrated ones")
    p.add_argument("--out", required=True, help="rig JSON to write")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p)
    p.set_defaults(func=cmd_import_rig)


def cmd_import_rig(args: argparse.Namespace) -> int:
    from staticdepth.stereo.rectify import Rectifier
    from staticdepth.stereo.rig_import import import_rig, parse_size

    from staticdepth.cli import refuse_existing

    refuse_existing(args.out, overwrite=args.overwrite)
    size = parse_size(args.size) if args.size else None
    rig = import_rig(args.kind, args.file, camera=args.camera, size=size)
    rect = Rectifier(rig)          # validates the rig and gives the camera depth is computed in
    cam = rect.camera
    rig.save(args.out)
    extra = f", doffs {rig.extra['doffs_px']:.3f} px" if "doffs_px" in rig.extra else ""
    print(f"{args.kind} rig {cam.width}x{cam.height}: baseline {rect.baseline_m:.5f} m, rectified "
          f"focal {cam.fx:.3f} px, principal point ({cam.cx:.3f}, {cam.cy:.3f}){extra} "
          f"-> {args.out}")
    return 0
