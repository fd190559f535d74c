"""Commands ``synth``, ``inspect`` and ``verify``."""
from __future__ import annotations

import argparse
import json
import os

from staticdepth.errors import InputError


def register(sub) -> None:
    from staticdepth.cli import add_overwrite_argument

    p = sub.add_parser("synth", help="render a synthetic fixed-camera stereo sequence",
                       description="Render a synthetic sequence (known geometry) to a sequence "
                                   "file.")
    p.add_argument("--preset", default="demo", help="scene preset (demo, street, c1, c2, c3, r2)")
    p.add_argument("--frames", type=int, default=60,
                   help="number of frames to render (at most 1,000,000; refused when the "
                        "output cannot fit in its folder's free space)")
    p.add_argument("--adapt-frames", type=int, default=None,
                   help="first N frames form the adaptation split (default: 40%%)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (agents, textures)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scene setting, e.g. --set camera_height_m=6")
    p.add_argument("--out", required=True, help="output sequence file (.h5)")
    add_overwrite_argument(p)
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run (<out>.partial)")
    p.add_argument("--restart", action="store_true",
                   help="discard an interrupted run's <out>.partial and start over")
    p.set_defaults(func=_synth)

    p = sub.add_parser("inspect", help="summarise and check a sequence file",
                       description="Print a summary of a sequence file; fails on a truncated or "
                                   "inconsistent file. Optionally writes a thumbnail sheet.")
    p.add_argument("file", help="sequence file (.h5)")
    p.add_argument("--sheet", help="write a PNG sheet of frames and depth here")
    p.add_argument("--pred", action="append", default=[], metavar="NAME",
                   help="add a stored prediction's row to the sheet (repeatable; works without "
                        "ground truth)")
    p.add_argument("--frames", type=int, default=6, help="frames (columns) on the sheet")
    p.add_argument("--json", help="write the summary as JSON here")
    add_overwrite_argument(p)
    p.set_defaults(func=_inspect)

    p = sub.add_parser("verify", help="check integrity and checksums of sequences or a release",
                       description="Re-read every frame and compare its checksum; on a release "
                                   "folder, check the SHA-256 manifest too.")
    p.add_argument("paths", nargs="+", help="sequence files or release folders")
    p.set_defaults(func=_verify)


def _synth(args: argparse.Namespace) -> int:
    from staticdepth.cli import parse_overrides
    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.dataset.writer import check_sequence_output

    check_sequence_output(args.out)
    info = render_to_file(args.out, preset_name=args.preset, n_frames=args.frames,
                          adapt_frames=args.adapt_frames, seed=args.seed,
                          overrides=parse_overrides(args.set), overwrite=args.overwrite,
                          resume=args.resume, restart=args.restart)
    print(f"wrote {info['frames']} frames ({info['size']}, adapt {info['adapt_frames']}) "
          f"to {args.out} in {info['seconds']:.1f} s")
    return 0


def _inspect(args: argparse.Namespace) -> int:
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.dataset.inspect import format_summary, summarize, thumbnail_sheet

    from staticdepth.cli import refuse_existing
    from staticdepth.fileio import atomic_write_text, check_writable, write_image

    if args.pred and not args.sheet:
        raise InputError("--pred adds rows to the sheet: pass --sheet FILE.png too")
    if args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    refuse_existing(args.sheet, args.json, overwrite=args.overwrite)
    for out in (args.sheet, args.json):     # before the summary is printed, not after it
        if out:
            check_writable(out)
    with SequenceReader(args.file) as r:
        info = summarize(r)
        print(format_summary(info))
        if args.sheet:
            write_image(args.sheet, thumbnail_sheet(r, n=args.frames, preds=args.pred))
            print(f"  sheet            {args.sheet}")
    if args.json:
        atomic_write_text(args.json, json.dumps(info, indent=2, default=str))
    return 0


def _verify(args: argparse.Namespace) -> int:
    from staticdepth.dataset.h5 import SequenceReader

    failed = 0
    for path in args.paths:
        if os.path.isdir(path):
            from staticdepth.dataset.publish import verify_release

            problems = verify_release(path)
        else:
            try:
                with SequenceReader(path) as r:
                    problems = r.checksum_errors()
                from staticdepth.dataset.predictions import verify_predictions

                problems += verify_predictions(path)
            except InputError as e:
                problems = [e.problem]
        if problems:
            failed += 1
            for p in problems[:20]:
                print(f"{path}: {p}")
            if len(problems) > 20:
                print(f"{path}: ... {len(problems) - 20} more problems")
        else:
            print(f"{path}: OK")
    if failed:
        raise InputError(f"{failed} of {len(args.paths)} failed verification")
    return 0
