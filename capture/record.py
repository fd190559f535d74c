"""Record a stereo source losslessly: PNG frames, per-frame timestamps, segments, manifest, summary.

The capture loop (:func:`record`) hands each pair to a :class:`Recorder`, which encodes and writes
the PNGs on a thread pool (OpenCV releases the GIL while encoding) and commits frames *in order* on
a committer thread: a frame's CSV row is appended only after both of its images are on disk.
Memory is bounded by ``queue_frames`` pairs in flight; when the disk cannot keep up the capture loop
blocks (and the time it spent blocked is reported) rather than frames being silently discarded.

Stopping: the source ending (replay), a frame or time limit, a stop event (Ctrl-C, SIGTERM), the
source failing (:class:`SourceLost`) or a write failing (disk full) all end in
:meth:`Recorder.close`, which drains the writers, closes the CSV files and rewrites the manifest
with the status and summary. Any other error (a corrupt input frame) leaves status ``failed`` with
the reason, never ``complete``.
The on-disk layout is described in :mod:`staticdepth.capture.layout`.
"""
from __future__ import annotations

import contextlib
import datetime
import errno
import itertools
import os
import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, BinaryIO, Callable

import cv2
import numpy as np

from staticdepth import __version__
from staticdepth.capture import layout
from staticdepth.capture.sources.base import SourceLost, StereoFrame, StereoSource
from staticdepth.capture.sync import stream_summary
from staticdepth.errors import InputError
from staticdepth.fileio import atomic_path, temporary_path
from staticdepth.geometry.camera import StereoRig


PNG_STRATEGIES = {"default": cv2.IMWRITE_PNG_STRATEGY_DEFAULT, "rle": cv2.IMWRITE_PNG_STRATEGY_RLE,
                  "huffman": cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
                  "filtered": cv2.IMWRITE_PNG_STRATEGY_FILTERED}
PNG_FILTERS = {"none": cv2.IMWRITE_PNG_FILTER_NONE, "sub": cv2.IMWRITE_PNG_FILTER_SUB,
               "up": cv2.IMWRITE_PNG_FILTER_UP, "avg": cv2.IMWRITE_PNG_FILTER_AVG,
               "paeth": cv2.IMWRITE_PNG_FILTER_PAETH, "fast": cv2.IMWRITE_PNG_FAST_FILTERS,
               "all": cv2.IMWRITE_PNG_ALL_FILTERS}


@dataclass(frozen=True)
class RecordConfig:
    """How frames are written.

    png_compression: zlib level 0-9 (1: fast; higher only saves a little space).
    png_strategy: zlib strategy, ``huffman`` (entropy coding only: about 3x faster than ``default``
        at level 1 on camera-like images, files about 5% larger), ``rle``, ``default``,
        ``filtered``.
    png_filter: PNG row filter, ``up`` (fast, good with ``huffman``), ``sub``, ``paeth``, ``none``,
        ``fast`` (libpng's fast set), ``all`` (adaptive).
    Every setting is lossless; they trade CPU time against file size only.
    segment_frames: frames per ``seg_NNNN`` folder (9000 = 5 min at 30 FPS).
    workers: encoder/writer threads.
    queue_frames: pairs in flight at most (memory bound; 64 x 2 x 1280x800 grey = 131 MB).
    """

    png_compression: int = 1
    png_strategy: str = "huffman"
    png_filter: str = "up"
    segment_frames: int = 9000
    workers: int = 2
    queue_frames: int = 64

    def __post_init__(self):
        if not 0 <= self.png_compression <= 9:
            raise InputError(f"png_compression must be 0-9, got {self.png_compression}")
        if self.segment_frames < 1 or self.workers < 1 or self.queue_frames < 1:
            raise InputError("segment_frames, workers and queue_frames must be at least 1")
        if self.png_strategy not in PNG_STRATEGIES:
            raise InputError(f"png_strategy must be one of {sorted(PNG_STRATEGIES)}, "
                             f"got {self.png_strategy!r}")
        if self.png_filter not in PNG_FILTERS:
            raise InputError(f"png_filter must be one of {sorted(PNG_FILTERS)}, "
                             f"got {self.png_filter!r}")

    def png_params(self) -> list[int]:
        """``cv2.imencode`` parameters."""
        return [cv2.IMWRITE_PNG_COMPRESSION, self.png_compression,
                cv2.IMWRITE_PNG_STRATEGY, PNG_STRATEGIES[self.png_strategy],
                cv2.IMWRITE_PNG_FILTER, PNG_FILTERS[self.png_filter]]


RECORD_PRESETS: dict[str, RecordConfig] = {
    "fast": RecordConfig(),                                            # Huffman + up filter
    "zlib1": RecordConfig(png_strategy="default", png_filter="fast"),  # classic level 1
    "compact": RecordConfig(png_strategy="rle", png_filter="paeth"),   # ~10% smaller, ~2x CPU
    "fast-4": RecordConfig(workers=4, queue_frames=128),               # machines with more cores
}


class RecordingFailed(RuntimeError):
    """Writing failed (disk full, I/O error); frames committed before it are intact."""

    def __init__(self, cause: BaseException):
        self.cause = cause
        super().__init__(f"writing failed: {cause}")

    @property
    def disk_full(self) -> bool:
        return isinstance(self.cause, OSError) and self.cause.errno in (errno.ENOSPC, errno.EDQUOT)


def write_file(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`staticdepth.fileio.atomic_path` (a temporary file
    and a rename: no half-written final names). No fsync per image: the frame's CSV row, written
    after both images, is the commit. A failure raises the ``OSError`` itself, so that a full disk
    is told apart (:attr:`RecordingFailed.disk_full`)."""
    try:
        with atomic_path(path, "png", fsync=False) as tmp, open(tmp, "wb") as f:
            f.write(data)
    except InputError as e:
        if isinstance(e.__cause__, OSError):
            raise e.__cause__ from None
        raise


def encode_png(image: np.ndarray, params: list[int]) -> bytes:
    ok, buf = cv2.imencode(".png", image, params)
    if not ok:
        raise RuntimeError(f"PNG encoding failed for an image of shape {image.shape}")
    return buf.tobytes()


class Recorder:
    """Writes frames into a new recording folder (``layout.create_recording_dir``).

    ``write(frame)`` blocks only when ``queue_frames`` pairs are in flight, and raises
    :class:`RecordingFailed` once a write has failed. ``close(status)`` returns the summary.
    ``write_bytes`` is the file writer (tests inject failures through it).
    """

    def __init__(self, root: str | os.PathLike, conf: RecordConfig = RecordConfig(), *,
                 rig: StereoRig | None = None, source_settings: dict[str, Any] | None = None,
                 nominal_fps: float | None = None,
                 write_bytes: Callable[[str, bytes], None] = write_file):
        self.root = Path(root)
        self.conf = conf
        self.nominal_fps = nominal_fps
        self._write_bytes = write_bytes
        self._png_params = conf.png_params()
        self._manifest: dict[str, Any] = {
            "format": layout.RECORDING_FORMAT, "status": "recording",
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            "toolkit_version": __version__,
            "source": {**(source_settings or {}), "nominal_fps": nominal_fps},
            "record": asdict(conf), "rig": None if rig is None else rig.to_dict(),
            "layout": {"segment": "seg_NNNN", "images": "seg_NNNN/{left,right}/FFFFFFFF.png",
                       "timestamps": f"seg_NNNN/{layout.TIMESTAMPS}",
                       "csv_header": layout.CSV_HEADER, "timestamps_unit": "s"},
        }
        if rig is not None:
            rig.save(self.root / layout.RIG_FILE)
        layout.write_json_atomic(self.root / layout.MANIFEST, self._manifest)
        self._pool = ThreadPoolExecutor(conf.workers, thread_name_prefix="capture-writer")
        self._slots = threading.Semaphore(conf.queue_frames)
        self._pending: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self.failure: RecordingFailed | None = None
        self.submitted = 0
        self.committed = 0
        self.max_queue_depth = 0
        self.blocked_s = 0.0
        self._timestamps: list[float] = []
        self._sequences: list[int] = []
        self._segments: dict[int, list[int]] = {}  # segment -> [first frame, last frame, count]
        self._made_segments: set[int] = set()
        self._csv: BinaryIO | None = None
        self._csv_segment = -1
        self._csv_good = 0                         # bytes of whole lines in the current CSV
        self._closed = False
        self._committer = threading.Thread(target=self._commit_loop, name="capture-committer",
                                           daemon=True)
        self._committer.start()

    # -- capture side ---------------------------------------------------------------------------
    @property
    def queue_depth(self) -> int:
        return self.submitted - self.committed

    def write(self, frame: StereoFrame) -> None:
        if self.failure is not None:
            raise self.failure
        t0 = time.perf_counter()
        self._slots.acquire()
        self.blocked_s += time.perf_counter() - t0
        if self.failure is not None:
            self._slots.release()
            raise self.failure
        index = self.submitted
        segment = index // self.conf.segment_frames
        if segment not in self._made_segments:
            seg = self.root / layout.segment_name(segment)
            (seg / "left").mkdir(parents=True, exist_ok=True)
            (seg / "right").mkdir(parents=True, exist_ok=True)
            self._made_segments.add(segment)
        future = self._pool.submit(self._encode_and_write, index, segment, frame.left, frame.right)
        self._pending.put((index, segment, future, frame))
        self.submitted += 1
        self.max_queue_depth = max(self.max_queue_depth, self.queue_depth)

    def _encode_and_write(self, index: int, segment: int, left: np.ndarray,
                          right: np.ndarray) -> None:
        if self.failure is not None:
            return
        for image, path in zip((left, right), layout.frame_paths(self.root, segment, index)):
            self._write_bytes(os.fspath(path), encode_png(image, self._png_params))

    # -- committer ------------------------------------------------------------------------------
    def _commit_loop(self) -> None:
        while True:
            item = self._pending.get()
            if item is None:
                break
            index, segment, future, frame = item
            try:
                future.result()
                if self.failure is None:
                    self._append_row(index, segment, frame)
            except BaseException as e:  # noqa: BLE001 - any write error stops the recording
                if self.failure is None:
                    self.failure = RecordingFailed(e)
            if self.failure is not None:
                self._remove_uncommitted(index, segment)
            self.committed += 1
            self._slots.release()

    def _append_row(self, index: int, segment: int, frame: StereoFrame) -> None:
        if segment != self._csv_segment:
            self._close_csv()
            path = self.root / layout.segment_name(segment) / layout.TIMESTAMPS
            self._csv = open(path, "wb", buffering=0)      # unbuffered: nothing left to flush
            self._csv_segment, self._csv_good = segment, 0
            self._write_row((layout.CSV_HEADER + "\n").encode())
        self._write_row(f"{index},{frame.timestamp_s:.9f},{frame.left_timestamp_s:.9f},"
                        f"{frame.right_timestamp_s:.9f},{frame.sequence}\n".encode())
        self._timestamps.append(frame.timestamp_s)
        self._sequences.append(frame.sequence)
        s = self._segments.setdefault(segment, [index, index, 0])
        s[1], s[2] = index, s[2] + 1

    def _write_row(self, data: bytes) -> None:
        """Append one whole line or nothing: a partial write is cut off again before raising."""
        assert self._csv is not None
        try:
            written = self._csv.write(data)
            if written != len(data):
                raise OSError(errno.ENOSPC, f"short write to {layout.TIMESTAMPS} "
                                            f"({written} of {len(data)} bytes)")
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self._csv.fileno(), self._csv_good)
            raise
        self._csv_good += len(data)

    def _close_csv(self) -> None:
        if self._csv is not None:
            try:
                os.fsync(self._csv.fileno())
            except OSError as e:
                if self.failure is None:
                    self.failure = RecordingFailed(e)
            finally:
                with contextlib.suppress(OSError):
                    self._csv.close()
                self._csv = None

    def _remove_uncommitted(self, index: int, segment: int) -> None:
        for p in layout.frame_paths(self.root, segment, index):
            for q in (p, Path(temporary_path(p, "png"))):
                with contextlib.suppress(OSError):
                    q.unlink()

    # -- end ------------------------------------------------------------------------------------
    def close(self, status: str = "complete", *, detail: str | None = None,
              source_stats: dict[str, Any] | None = None) -> dict[str, Any]:
        """Drain the writers, close the files, write the final manifest; returns the summary."""
        if self._closed:
            return self._manifest.get("summary", {})
        self._closed = True
        self._pending.put(None)
        self._committer.join()
        self._pool.shutdown(wait=True)
        self._close_csv()
        if self.failure is not None:
            status = "disk_full" if self.failure.disk_full else "write_error"
            detail = str(self.failure.cause)
        summary = self.summary(status, detail, source_stats)
        self._manifest.update(status=status, summary=summary, segments=[
            {"name": layout.segment_name(s), "first_frame": a, "last_frame": b, "frames": n}
            for s, (a, b, n) in sorted(self._segments.items())])
        try:
            layout.write_json_atomic(self.root / layout.MANIFEST, self._manifest)
        except (OSError, InputError) as e:  # disk full: the first manifest and every CSV row stay valid
            summary["manifest_error"] = str(e)
        return summary

    def summary(self, status: str, detail: str | None = None,
                source_stats: dict[str, Any] | None = None) -> dict[str, Any]:
        out = {"status": status, "detail": detail, "frames_written": len(self._timestamps),
               **stream_summary(self._timestamps, self.nominal_fps),
               "max_queue_depth": self.max_queue_depth, "capture_blocked_s": self.blocked_s,
               "source": source_stats or {}}
        seq = np.asarray([s for s in self._sequences if s >= 0], dtype=np.int64)
        out["sequence_gaps"] = int(np.sum(np.maximum(np.diff(seq) - 1, 0))) if seq.size > 1 else 0
        return out


def record(source: StereoSource, out: str | os.PathLike, conf: RecordConfig = RecordConfig(), *,
           numbered: bool = False, max_frames: int | None = None, duration_s: float | None = None,
           stop: threading.Event | None = None, rig: StereoRig | None = None,
           rig_name: str | None = None, on_frame: Callable[[int, Recorder], None] | None = None,
           write_bytes: Callable[[str, bytes], None] = write_file) -> tuple[Path, dict[str, Any]]:
    """Open ``source``, record it into a new folder, close everything; returns (folder, summary).

    The folder is created only after the source opened and gave its first pair (a missing device
    leaves nothing behind), and only when that pair has the size the rig was calibrated for
    (else :class:`InputError` naming ``rig_name``, the rig's file).
    ``rig`` overrides the source's own calibration. Stops at the source's end, ``max_frames``,
    ``duration_s``, ``stop`` being set, Ctrl-C, the source failing or a write failing; in every
    case the frames committed so far are complete on disk and the manifest says why it stopped.
    """
    with source:
        t_start = time.monotonic()
        frames = source.frames()
        try:
            first, lost = [next(frames)], None
        except StopIteration:
            first, lost = [], None
        except SourceLost as e:
            first, lost = [], e
        rig = rig or source.rig
        if first and rig is not None:
            check_rig_size(rig, first[0], rig_name)
        root = layout.create_recording_dir(out, numbered)
        rec = Recorder(root, conf, rig=rig, source_settings=source.settings(),
                       nominal_fps=source.nominal_fps, write_bytes=write_bytes)
        status, detail = "failed", None  # "complete" only when the source ends normally
        try:
            if lost is not None:
                raise lost
            for frame in itertools.chain(first, frames):
                rec.write(frame)
                if on_frame is not None:
                    on_frame(rec.submitted, rec)
                if max_frames is not None and rec.submitted >= max_frames:
                    status = "frame_limit"
                    break
                if duration_s is not None and time.monotonic() - t_start >= duration_s:
                    status = "time_limit"
                    break
                if stop is not None and stop.is_set():
                    status = "stopped"
                    break
            else:
                status = "complete"
        except SourceLost as e:
            status, detail = "source_lost", str(e)
        except RecordingFailed:
            pass                                     # close() reports the cause
        except KeyboardInterrupt:
            status = "stopped"
        except Exception as e:  # e.g. a corrupt input frame: recorded as the reason, then raised
            detail = f"{type(e).__name__}: {e}"
            raise
        finally:
            with contextlib.suppress(Exception):
                frames.close()
            summary = rec.close(status, detail=detail, source_stats=source.stats.to_dict())
    return root, summary


def check_rig_size(rig: StereoRig, frame: StereoFrame, rig_name: str | None = None) -> None:
    """Raise :class:`InputError` (naming ``rig_name``) unless both views of ``frame`` have the
    image size ``rig`` was calibrated for: a rig of another camera or resolution is useless."""
    for side, cam, image in (("left", rig.left, frame.left), ("right", rig.right, frame.right)):
        h, w = image.shape[:2]
        if (w, h) != tuple(cam.size):
            raise InputError(f"the rig's {side} camera is {cam.width}x{cam.height} but the "
                             f"source's {side} frames are {w}x{h}: use the rig calibrated for "
                             f"these frames", rig_name)


def format_summary(root: Path, s: dict[str, Any]) -> str:
    """Human-readable summary lines."""
    fps = "n/a" if s.get("achieved_fps") is None else f"{s['achieved_fps']:.2f}"
    src = s.get("source", {})
    lines = [f"recording {root}: {s['status']}" + (f" ({s['detail']})" if s.get("detail") else ""),
             f"  frames {s['frames_written']}, {s['duration_s']:.1f} s, achieved {fps} FPS",
             f"  dropped by the source {src.get('dropped', 0)} (unpaired left "
             f"{src.get('unpaired_left', 0)}, right {src.get('unpaired_right', 0)}), "
             f"sequence gaps {s['sequence_gaps']}",
             f"  timestamp gaps {s['gaps']} (about {s['missing_frames_estimate']} frames missing), "
             f"max interval {s['interval_max_s'] or 0:.3f} s",
             f"  writer queue max {s['max_queue_depth']} pairs, capture blocked "
             f"{s['capture_blocked_s']:.2f} s"]
    if s.get("manifest_error"):
        lines.append(f"  final manifest not written: {s['manifest_error']}")
    return "\n".join(lines)
