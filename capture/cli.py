"""Command ``staticdepth capture``: record a stereo rig (or replay a recording) losslessly."""
from __future__ import annotations

import argparse
import dataclasses
import math
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

from staticdepth.errors import InputError

# no stereo camera or replay runs faster (1e9 recorded 3 frames, reported as 1.8 million missing)
MAX_FPS = 1000.0

SOURCES = ("depthai", "uvc", "sbs", "replay", "synthetic")


def register(sub) -> None:
    p = sub.add_parser(
        "capture", help="record a stereo rig losslessly (DepthAI, UVC cameras, replay)",
        description="Record synchronised stereo pairs as lossless PNGs with per-frame timestamps, "
                    "a manifest (rig and settings) and segments, into a new folder; prints a "
                    "summary (frames, drops, gaps, achieved FPS). Ctrl-C or SIGTERM stop cleanly.")
    p.add_argument("--source", choices=SOURCES, required=True,
                   help="depthai: OAK device; uvc: two UVC cameras; sbs: one side-by-side UVC "
                        "camera; replay: a recording, image folders or video; synthetic: test "
                        "pattern")
    p.add_argument("--out", required=True, help="new recording folder (must not exist or be empty)")
    p.add_argument("--numbered", action="store_true",
                   help="treat --out as a parent folder and record into the next free rec_NNNN")
    p.add_argument("--frames", type=int, help="stop after N pairs")
    p.add_argument("--duration", type=float, help="stop after S seconds (S > 0)")
    p.add_argument("--device", help="depthai: device id/name/IP; uvc: 'LEFT,RIGHT' indices or "
                                    "paths (default 0,1); sbs: index or path (default 0)")
    p.add_argument("--preset", default="mono-800p",
                   help="depthai preset (mono-800p, mono-400p, color-1200p)")
    p.add_argument("--size", help="WIDTHxHEIGHT of each view (uvc/sbs: of the camera frame; not "
                                  "for replay, which keeps the input's size)")
    p.add_argument("--fps", type=float, help="frames per second (replay of image folders or "
                                             "videos: the rate that stamps the frames)")
    p.add_argument("--color", action="store_true",
                   help="cameras: record colour (default grey); replay keeps the input's pixels "
                        "as they are (grey stays grey, colour stays colour)")
    p.add_argument("--exposure-us", type=int, help="depthai: manual exposure (with --iso)")
    p.add_argument("--iso", type=int, help="depthai: manual sensitivity")
    p.add_argument("--exposure", type=float, help="uvc/sbs: manual exposure in driver units")
    p.add_argument("--fourcc", help="uvc/sbs: pixel format, e.g. YUYV (MJPG is lossy)")
    p.add_argument("--timestamps", choices=("host", "driver"), default="host",
                   help="uvc/sbs: host clock at grab, or the driver's buffer time")
    p.add_argument("--input", help="replay: recording folder, folder with left/ right/, left "
                                   "image folder/pattern, or video (a lone video needs "
                                   "--side-by-side)")
    p.add_argument("--right", help="replay: right image folder/pattern or right video")
    p.add_argument("--side-by-side", action="store_true",
                   help="replay: the lone --input video holds the left and right views side by "
                        "side (without it a lone video is refused: use import-video for a "
                        "monocular one)")
    p.add_argument("--rig", help="rig JSON to store with the recording (replaces a DepthAI "
                                 "device's or a replayed recording's own calibration)")
    p.add_argument("--record-preset", default="fast", help="fast, zlib1, compact, fast-4")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a record setting (png_compression, png_strategy, png_filter, "
                        "segment_frames, workers, queue_frames) or a depthai setting")
    p.add_argument("--summary-json", help="also write the summary as JSON here")
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p, "replace an existing --summary-json (a recording folder is never "
                              "replaced)")
    p.set_defaults(func=_capture)


def _size(text: str | None) -> tuple[int | None, int | None]:
    if not text:
        return None, None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size expects WIDTHxHEIGHT, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise InputError(f"--size must be positive, got {text!r}")
    return w, h


def _device_list(text: str | None, default: list[str]) -> list[int | str]:
    items = default if not text else [t.strip() for t in text.split(",")]
    return [int(t) if t.isdigit() else t for t in items]


# Options that set up a camera: a replay keeps its input's pixels, size and device-free nature.
CAMERA_OPTIONS = (("size", "--size"), ("color", "--color"), ("device", "--device"),
                  ("exposure_us", "--exposure-us"), ("iso", "--iso"), ("exposure", "--exposure"),
                  ("fourcc", "--fourcc"))


def check_options(args: argparse.Namespace) -> None:
    """Refuse impossible numbers and options the source would ignore, before anything starts."""
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= MAX_FPS):
        raise InputError(f"--fps must be a number of frames per second in (0, {MAX_FPS:g}], got "
                         f"{args.fps}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration must be a positive number of seconds, got {args.duration}")
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    if args.source == "replay":
        given = [flag for name, flag in CAMERA_OPTIONS if getattr(args, name, None)]
        if given:
            raise InputError(f"--source replay records its input's pixels unchanged (size, grey "
                             f"or colour): drop {', '.join(given)} (camera settings), or convert "
                             f"the input first")


def build_source(args: argparse.Namespace, depthai_overrides: dict[str, str]):
    """The source named by ``args.source``, configured from the command line."""
    check_options(args)
    w, h = _size(args.size)
    if args.source == "depthai":
        from staticdepth import config
        from staticdepth.capture.sources.depthai_source import (DEPTHAI_PRESETS, DepthAIConfig,
                                                                DepthAISource)
        if args.preset not in DEPTHAI_PRESETS:
            raise InputError(f"unknown depthai preset {args.preset!r} "
                             f"(known: {sorted(DEPTHAI_PRESETS)})")
        values = dict(depthai_overrides)
        for key, val in (("width", w), ("height", h), ("fps", args.fps),
                         ("exposure_us", args.exposure_us), ("iso", args.iso),
                         ("device", args.device)):
            if val is not None:
                values[key] = val
        if args.color:
            values["color"] = True
        conf = config.from_dict(DepthAIConfig, values, base=DEPTHAI_PRESETS[args.preset])
        return DepthAISource(conf)
    if depthai_overrides:
        raise InputError(f"unknown record setting(s) {sorted(depthai_overrides)}")
    if args.source in ("uvc", "sbs"):
        from staticdepth.capture.sources.opencv_source import OpenCVStereoSource, SideBySideSource
        kw = dict(width=w, height=h, fps=args.fps or 30.0, fourcc=args.fourcc,
                  exposure=args.exposure, grey=not args.color, timestamps=args.timestamps)
        if args.source == "uvc":
            devs = _device_list(args.device, ["0", "1"])
            if len(devs) != 2:
                raise InputError(f"--device for uvc expects LEFT,RIGHT, got {args.device!r}")
            return OpenCVStereoSource(devs[0], devs[1], **kw)
        devs = _device_list(args.device, ["0"])
        if len(devs) != 1:
            raise InputError(f"--device for sbs expects one camera, got {args.device!r}")
        return SideBySideSource(devs[0], **kw)
    if args.source == "replay":
        from staticdepth.capture.sources.replay import open_replay
        if not args.input:
            raise InputError("--source replay needs --input")
        return open_replay(args.input, args.right, args.fps, side_by_side=args.side_by_side)
    from staticdepth.capture.sources.synthetic import SyntheticSource
    return SyntheticSource(w or 1280, h or 800, args.fps or 30.0, args.frames, color=args.color,
                           realtime=True)


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by the first Ctrl-C or SIGTERM (a second Ctrl-C interrupts at once)."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum, frame):
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _capture(args: argparse.Namespace) -> int:
    from staticdepth import config
    from staticdepth.capture.record import (RECORD_PRESETS, RecordConfig, format_summary,
                                            record)
    from staticdepth.cli import parse_overrides, refuse_existing
    from staticdepth.fileio import check_writable
    from staticdepth.geometry.camera import StereoRig
    from staticdepth.progress import progress

    check_options(args)
    if args.summary_json:
        check_writable(args.summary_json)       # before anything is recorded
    refuse_existing(args.summary_json, overwrite=args.overwrite)

    if args.record_preset not in RECORD_PRESETS:
        raise InputError(f"unknown record preset {args.record_preset!r} "
                         f"(known: {sorted(RECORD_PRESETS)})")
    overrides = parse_overrides(args.set)
    record_keys = {f.name for f in dataclasses.fields(RecordConfig)}
    conf = config.from_dict(RecordConfig, {k: v for k, v in overrides.items() if k in record_keys},
                            base=RECORD_PRESETS[args.record_preset])
    source = build_source(args, {k: v for k, v in overrides.items() if k not in record_keys})
    rig = StereoRig.load(args.rig) if args.rig else None
    with stop_on_signals() as stop, progress(total=args.frames, desc="capture",
                                             unit="pair") as bar:
        root, summary = record(source, args.out, conf, numbered=args.numbered,
                               max_frames=args.frames, duration_s=args.duration, stop=stop, rig=rig,
                               rig_name=args.rig, on_frame=lambda n, rec: bar.update(1))
    print(format_summary(root, summary))
    if args.summary_json:
        from staticdepth.fileio import atomic_write_json

        atomic_write_json(args.summary_json, {"recording": str(root), **summary})
    if summary["status"] in ("disk_full", "write_error"):
        print(f"staticdepth capture: error: recording stopped: {summary['detail']}",
              file=sys.stderr)
        return 1
    if summary["status"] == "source_lost":
        print(f"staticdepth capture: warning: source lost: {summary['detail']}", file=sys.stderr)
        return 3
    return 0
