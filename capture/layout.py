"""The recording layout on disk: names, the directory rules, and the reader.

::

    DIR/manifest.json                 format "staticdepth.recording/1": status, source settings,
                                      record settings, rig (or null), segments, summary
    DIR/rig.json                      the rig as StereoRig JSON (only when the source knows it)
    DIR/seg_0000/timestamps.csv       header + one row per complete frame, in frame order:
                                      frame,timestamp_s,left_timestamp_s,right_timestamp_s,sequence
    DIR/seg_0000/left/00000000.png    lossless PNG, named by the global frame number (8 digits)
    DIR/seg_0000/right/00000000.png
    DIR/seg_0001/...                  a new segment every ``segment_frames`` frames

A row is appended to ``timestamps.csv`` only after both PNGs of that frame are complete (each is
written to a temporary file beside it and renamed by :func:`staticdepth.fileio.atomic_path`), so a recording killed at any moment reads back to its last
complete frame: every listed frame's images exist and decode; a torn last line is ignored.
``manifest.json`` is rewritten atomically at the end; ``status`` stays ``"recording"`` when the
process was killed, and readers then trust the CSV files alone.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from staticdepth.errors import InputError
from staticdepth.geometry.camera import StereoRig, read_json

RECORDING_FORMAT = "staticdepth.recording/1"
MANIFEST = "manifest.json"
RIG_FILE = "rig.json"
TIMESTAMPS = "timestamps.csv"
CSV_HEADER = "frame,timestamp_s,left_timestamp_s,right_timestamp_s,sequence"
NUMBERED_PREFIX = "rec_"


def segment_name(segment: int) -> str:
    return f"seg_{segment:04d}"


def frame_name(frame: int) -> str:
    return f"{frame:08d}.png"


def frame_paths(root: str | os.PathLike, segment: int, frame: int) -> tuple[Path, Path]:
    seg = Path(root) / segment_name(segment)
    return seg / "left" / frame_name(frame), seg / "right" / frame_name(frame)


def create_recording_dir(path: str | os.PathLike, numbered: bool = False) -> Path:
    """Make the folder for a new recording; an earlier recording is never overwritten.

    ``numbered=False``: ``path`` itself, which must not exist or be empty (else
    :class:`InputError`). ``numbered=True``: a new ``path/rec_NNNN`` with the next free number
    (created exclusively, so two recorders started at once get different folders).
    """
    path = Path(path)
    if not numbered:
        if path.exists():
            if not path.is_dir():
                raise InputError("exists and is not a folder", path)
            if any(path.iterdir()):
                raise InputError("already exists and is not empty; recordings are never "
                                 "overwritten (choose a new folder, or use --numbered)", path)
        path.mkdir(parents=True, exist_ok=True)
        return path
    path.mkdir(parents=True, exist_ok=True)
    used = [int(p.name[len(NUMBERED_PREFIX):]) for p in path.iterdir()
            if p.name.startswith(NUMBERED_PREFIX) and p.name[len(NUMBERED_PREFIX):].isdigit()]
    n = max(used, default=-1) + 1
    while True:
        candidate = path / f"{NUMBERED_PREFIX}{n:04d}"
        try:
            candidate.mkdir()
            return candidate
        except FileExistsError:
            n += 1


def write_json_atomic(path: str | os.PathLike, data: dict[str, Any]) -> None:
    """Write JSON atomically (:func:`staticdepth.fileio.atomic_write_json`: temporary file,
    fsync, rename over ``path``); a failure raises :class:`InputError` naming ``path``."""
    from staticdepth.fileio import atomic_write_json

    atomic_write_json(path, data)


@dataclass(frozen=True)
class RecordedFrame:
    """One complete frame of a recording: its files and timestamps."""

    frame: int
    segment: int
    left_path: Path
    right_path: Path
    timestamp_s: float
    left_timestamp_s: float
    right_timestamp_s: float
    sequence: int


@dataclass(frozen=True)
class Recording:
    """A recording read back: manifest, rig (or None) and every complete frame in order."""

    root: Path
    manifest: dict[str, Any]
    rig: StereoRig | None
    frames: tuple[RecordedFrame, ...]

    @property
    def status(self) -> str:
        return str(self.manifest.get("status", "unknown"))

    @property
    def nominal_fps(self) -> float | None:
        fps = (self.manifest.get("source") or {}).get("nominal_fps")
        return None if fps is None else float(fps)


def _read_segment_csv(root: Path, segment: int) -> list[RecordedFrame]:
    csv = root / segment_name(segment) / TIMESTAMPS
    try:
        text = csv.read_text()
    except FileNotFoundError:
        return []
    lines = text.split("\n")
    if not lines or lines[0].strip() != CSV_HEADER:
        raise InputError(f"unexpected header {lines[0][:80]!r} (expected {CSV_HEADER!r})", csv)
    out: list[RecordedFrame] = []
    # The last element is '' after a final newline, or a torn line from a killed writer: skip it.
    for lineno, line in enumerate(lines[1:-1], start=2):
        parts = line.split(",")
        try:
            frame, seq = int(parts[0]), int(parts[4])
            t, tl, tr = float(parts[1]), float(parts[2]), float(parts[3])
        except (ValueError, IndexError):
            raise InputError(f"line {lineno} is malformed: {line[:80]!r}", csv) from None
        lp, rp = frame_paths(root, segment, frame)
        out.append(RecordedFrame(frame, segment, lp, rp, t, tl, tr, seq))
    return out


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a recording folder (see the module docstring for the layout).

    Raises :class:`InputError` for a folder without ``manifest.json``, an unknown format, a
    malformed CSV, or frames out of order; a torn last CSV line (killed recorder) is not an error.
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError("recording folder not found", root)
    manifest = read_json(root / MANIFEST)
    if manifest.get("format") != RECORDING_FORMAT:
        raise InputError(f"unknown recording format {manifest.get('format')!r} "
                         f"(expected {RECORDING_FORMAT})", root / MANIFEST)
    rig = None
    if manifest.get("rig") is not None:
        rig = StereoRig.from_dict(manifest["rig"], os.fspath(root / MANIFEST))
    segments = sorted(int(p.name[4:]) for p in root.iterdir()
                      if p.is_dir() and p.name.startswith("seg_") and p.name[4:].isdigit())
    frames: list[RecordedFrame] = []
    for s in segments:
        frames += _read_segment_csv(root, s)
    for a, b in zip(frames, frames[1:]):
        if b.frame <= a.frame:
            raise InputError(f"frame numbers not increasing ({a.frame} then {b.frame})",
                             root / segment_name(b.segment) / TIMESTAMPS)
    return Recording(root, manifest, rig, tuple(frames))
