"""The sequence file: one HDF5 file per sequence (schema in ``staticdepth.dataset.schema``).

This module alone talks to h5py. Guarantees:
- a writer builds ``<out>.partial`` and only a finished file is renamed onto ``<out>`` (after the
  ``complete`` attribute is set, flushed and fsynced), so a killed write leaves either the previous
  complete file or nothing at ``<out>``, and the ``.partial`` file is rejected by the reader;
- ``SequenceWriter(..., resume=True)`` continues a ``.partial`` file after the last frame that was
  fully written;
- one frame per chunk, so reading frame i decodes frame i only;
- predictions are added to a copy that replaces the file atomically (:func:`add_prediction`).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, Mapping, Sequence

import h5py
import numpy as np

from staticdepth import __version__
from staticdepth.dataset import schema
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, Mounting, StereoRig

try:  # Blosc-lz4 when hdf5plugin is importable, gzip otherwise (readable everywhere).
    import hdf5plugin

    def _compression(kind: str) -> dict[str, Any]:
        # Blosc-lz4 level 5 with byte shuffle: measured (benchmarks/bench_dataset.py) 172 frames/s
        # written, ~1000 random reads/s, 29% of raw at 800x400 left+depth; zstd-3 was 18% of raw
        # but 26 frames/s written and 178 reads/s.
        return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
except ImportError:  # pragma: no cover - hdf5plugin is a dependency; kept for minimal installs
    def _compression(kind: str) -> dict[str, Any]:
        return {"compression": "gzip", "compression_opts": 1, "shuffle": True}

PARTIAL_SUFFIX = ".partial"


def _fsync_path(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    dfd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


@dataclass(frozen=True)
class SequenceMeta:
    """Per-sequence metadata stored as root attributes."""

    name: str
    camera: Camera
    gt_kind: str = "none"
    source: str = ""
    adapt_frames: int = 0
    rig: StereoRig | None = None
    mounting: Mounting | None = None
    camera_height_m: float | None = None
    provenance: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if self.gt_kind not in schema.GT_KINDS:
            raise InputError(f"gt_kind must be one of {schema.GT_KINDS}, got {self.gt_kind!r}")
        if self.adapt_frames < 0:
            raise InputError(f"adapt_frames must be >= 0, got {self.adapt_frames}")
        if self.camera_height_m is None and self.mounting is not None:
            object.__setattr__(self, "camera_height_m", self.mounting.height_m)

    def to_attrs(self) -> dict[str, Any]:
        a: dict[str, Any] = {
            "format": schema.FORMAT, "name": self.name,
            "camera": json.dumps(self.camera.to_dict()), "gt_kind": self.gt_kind,
            "source": self.source, "adapt_frames": int(self.adapt_frames),
            "width": self.camera.width, "height": self.camera.height,
            "toolkit_version": __version__,
            "provenance": json.dumps(dict(self.provenance), default=str),
            "camera_height_m": np.nan if self.camera_height_m is None else float(self.camera_height_m),
        }
        if self.rig is not None:
            a["rig"] = json.dumps(self.rig.to_dict())
        if self.mounting is not None:
            a["mounting"] = json.dumps(self.mounting.to_dict())
        return a

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, Any], path: str) -> "SequenceMeta":
        try:
            cam = Camera.from_dict(json.loads(attrs["camera"]), path)
            rig = StereoRig.from_dict(json.loads(attrs["rig"]), path) if "rig" in attrs else None
            mnt = Mounting.from_dict(json.loads(attrs["mounting"]), path) if "mounting" in attrs else None
            h = float(attrs.get("camera_height_m", np.nan))
            return cls(name=str(attrs["name"]), camera=cam, gt_kind=str(attrs["gt_kind"]),
                       source=str(attrs["source"]), adapt_frames=int(attrs["adapt_frames"]),
                       rig=rig, mounting=mnt, camera_height_m=None if np.isnan(h) else h,
                       provenance=json.loads(attrs.get("provenance", "{}")))
        except KeyError as e:
            raise InputError(f"missing attribute {e.args[0]!r}", path) from None
        except (json.JSONDecodeError, TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(f"malformed attribute: {e}", path) from None


def _frame_checksum(a: np.ndarray) -> int:
    from staticdepth.dataset.integrity import checksum

    return checksum(a)


def _write_error(e: BaseException, path: str) -> InputError:
    """An HDF5 or OS write error as one line (HDF5 hides the errno in its message)."""
    from staticdepth.fileio import os_error

    code = getattr(e, "errno", None)
    if code is None:
        m = re.search(r"errno = (\d+)", str(e))
        code = int(m.group(1)) if m else None
    if code is not None:
        return os_error(OSError(code, os.strerror(code)), path)
    return InputError(f"cannot write: {str(e).splitlines()[0][:160]}", path)


def check_replaceable_sequence(path: str) -> None:
    """``--overwrite`` replaces only a sequence file (one this toolkit can open); anything else
    is refused and left untouched."""
    why = None
    if os.path.islink(path) or not os.path.isfile(path):
        why = "is not a regular file"
    else:
        try:
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") != schema.FORMAT:
                    why = "is not a staticdepth sequence file"
        except OSError:
            why = "is not a readable HDF5 file"
    if why:
        raise InputError(f"exists and {why}; --overwrite replaces only a sequence file, so it "
                         "is left untouched (move it away yourself)", path)


class SequenceWriter:
    """Append frames to a new sequence file; finish atomically.

    >>> with SequenceWriter("seq.h5", meta, streams=("left", "depth")) as w:
    ...     w.append(left=rgb, depth=depth, timestamp=t)

    Leaving the ``with`` block through an exception keeps ``seq.h5.partial`` for ``resume=True``
    and does not touch ``seq.h5``.
    """

    def __init__(self, path: str | os.PathLike, meta: SequenceMeta,
                 streams: Iterable[str] = ("left", "depth"), *, resume: bool = False,
                 overwrite: bool = False, aux: Mapping[str, Any] | None = None,
                 restart: bool = False, settings: Mapping[str, Any] | None = None,
                 inputs: Sequence[str] | None = None, labels: Sequence[str] | None = None,
                 warn=print):
        """``settings``: what else changes the output (beside ``meta``); ``inputs``: one identity
        per input frame (:func:`staticdepth.dataset.resume.task_identity`), ``labels`` their names;
        both are stored and a ``resume`` with others is refused (see :mod:`.resume`)."""
        from staticdepth.dataset import resume as rs
        from staticdepth.fileio import exclusive_lock, remove_stale_temporaries

        self.path = os.fspath(path)
        self.partial = self.path + PARTIAL_SUFFIX
        self.meta = meta
        self.streams = tuple(streams)
        self.aux = {k: np.dtype(v) for k, v in (aux or {}).items()}  # extra maps: aux/<name>
        unknown = set(self.streams) - set(schema.FRAME_STREAMS)
        if unknown or "left" not in self.streams:
            raise InputError(f"streams must include 'left' and be among {schema.FRAME_STREAMS}, "
                             f"got {self.streams}")
        if os.path.lexists(self.path) and not overwrite:
            raise InputError("output exists (use --overwrite to replace it)", self.path)
        if os.path.lexists(self.path):
            check_replaceable_sequence(self.path)
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise InputError("output folder does not exist", parent)
        self._f: h5py.File | None = None
        self._io = None  # the partial's UndoableFile (see resume.py)
        self.n = 0
        self.resumed_from = 0
        self._fingerprint = rs.settings_fingerprint(meta.to_attrs(), self.streams, self.aux,
                                                    settings)
        self._inputs = None if inputs is None else list(inputs)
        self._lock = contextlib.ExitStack()
        self._lock.enter_context(exclusive_lock(self.path, what="writing"))
        try:
            remove_stale_temporaries(self.path)
            if os.path.exists(self.partial) and not (resume or restart):
                raise InputError("an interrupted run left this file: --resume continues it, "
                                 "--restart starts over", self.partial)
            opened = rs.open_partial(self.partial, warn) if resume and os.path.exists(
                self.partial) else None
            if opened is not None:
                self._f, self._io = opened
                self._resume(self._f, rs, labels)
            else:
                self._create()
            self._install_sigterm()
        except BaseException:
            self._close_file()
            self._lock.close()
            raise

    # -- setup ----------------------------------------------------------------------------------
    def _create(self) -> None:
        from staticdepth.dataset import resume as rs

        try:
            self._f, self._io = f, _ = rs.create_partial(self.partial)
        except OSError as e:
            raise _write_error(e, self.partial) from None
        try:
            self._layout(f)
            rs.store(f, self._fingerprint, self._inputs)
            f.flush()
            self._commit()
        except (OSError, RuntimeError) as e:  # h5py raises RuntimeError for some write errors
            self._fail(e)

    def _layout(self, f: h5py.File) -> None:
        w, h = self.meta.camera.width, self.meta.camera.height
        for name in self.streams:
            shape = (h, w, 3) if name in ("left", "right") else (h, w)
            kind = "float" if name == "depth" else "int"
            f.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape,
                             chunks=(1,) + shape, dtype=schema.STREAM_DTYPES[name],
                             **_compression(kind))
            f.create_dataset(f"crc32/{name}", shape=(0,), maxshape=(None,), dtype=np.uint32,
                             chunks=(4096,))
        for name, dt in self.aux.items():
            f.create_dataset(f"aux/{name}", shape=(0, h, w), maxshape=(None, h, w),
                             chunks=(1, h, w), dtype=dt, **_compression("int"))
            f.create_dataset(f"crc32/aux/{name}", shape=(0,), maxshape=(None,), dtype=np.uint32,
                             chunks=(4096,))
        f.create_dataset("timestamps", shape=(0,), maxshape=(None,), dtype=np.float64,
                         chunks=(4096,))
        f.create_dataset("agents", shape=(0,), maxshape=(None,), dtype=schema.AGENT_DTYPE,
                         chunks=(4096,))
        for k, v in self.meta.to_attrs().items():
            f.attrs[k] = v
        f.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        f.attrs["complete"] = False
        f.attrs["n_frames"] = 0
        f.attrs["n_written"] = 0
        f.attrs["streams"] = json.dumps(list(self.streams))
        f.attrs["aux"] = json.dumps(sorted(self.aux))

    def _resume(self, f: h5py.File, rs, labels) -> None:
        self._f = f
        try:
            n = int(f.attrs["n_written"])
            stored = tuple(json.loads(f.attrs["streams"]))
            stored_aux = json.loads(f.attrs.get("aux", "[]"))
        except (OSError, KeyError, ValueError) as e:
            raise InputError(f"cannot resume: the partial file is damaged ({e}); --restart "
                             "starts over", self.partial) from None
        if (stored != self.streams or stored_aux != sorted(self.aux)
                or int(f.attrs["width"]) != self.meta.camera.width):
            raise InputError(f"cannot resume: the partial file has streams {stored} and aux "
                             f"{stored_aux}, not {self.streams} and {sorted(self.aux)}",
                             self.partial)
        diff = rs.differences(f, self._fingerprint, self._inputs, labels)
        if diff:
            raise rs.refuse(self.partial, diff)
        rs.store(f, self._fingerprint, self._inputs)
        n = rs.last_complete(f, n, _frame_checksum,
                             list(self.streams) + [f"aux/{a}" for a in self.aux])
        for name in self.streams:
            f[name].resize(n, axis=0)
            f[f"crc32/{name}"].resize(n, axis=0)
        for name in self.aux:
            f[f"aux/{name}"].resize(n, axis=0)
            f[f"crc32/aux/{name}"].resize(n, axis=0)
        f["timestamps"].resize(n, axis=0)
        agents = f["agents"]
        keep = int(np.count_nonzero(agents["frame"][:] < n)) if len(agents) else 0
        agents.resize(keep, axis=0)
        f.attrs["n_written"] = n
        runs = json.loads(f.attrs.get("resumed_after", "[]"))
        f.attrs["resumed_after"] = json.dumps(runs + [n])
        f.flush()
        self._commit()
        self.n = self.resumed_from = n

    def _install_sigterm(self) -> None:
        """SIGTERM ends the run like Ctrl-C: the partial is flushed and closed for ``--resume``."""
        self._old_term = None
        if threading.current_thread() is not threading.main_thread():
            return
        if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
            return

        def on_term(signum, frame):
            print(f"terminated (SIGTERM): {self.partial} keeps {self.n} frames; run again with "
                  "--resume to continue", file=sys.stderr, flush=True)
            raise SystemExit(128 + signal.SIGTERM)

        self._old_term = signal.signal(signal.SIGTERM, on_term)

    def _restore_sigterm(self) -> None:
        if getattr(self, "_old_term", None) is not None:
            signal.signal(signal.SIGTERM, self._old_term)
            self._old_term = None

    def _fail(self, e: BaseException) -> None:
        """A write failed (disk full, read-only, file-size limit): close, keep or remove the
        partial, release the lock, and raise one line."""
        n = self.n
        if self._io is not None:
            with contextlib.suppress(OSError):
                self._io.rollback()  # back to the file as it was after the last complete frame
        self._close_file()
        self._restore_sigterm()
        err = _write_error(e, self.partial)
        if n == 0:
            with contextlib.suppress(OSError):
                os.remove(self.partial)
            self._lock.close()
            raise InputError(f"{err.problem}; nothing was kept", self.partial) from None
        self._lock.close()
        raise InputError(f"{err.problem}; the {n} frames written are kept: make room and run "
                         "again with --resume (or delete the file)", self.partial) from None

    def _commit(self) -> None:
        """After a flush: the file is complete as it is, unless a write failed (then raise)."""
        if self._io.failed is not None:
            raise self._io.failed
        self._io.commit()

    def _close_file(self) -> None:
        """Close the HDF5 file and its file object (errors ignored: used on the error paths)."""
        if self._f is not None:
            with contextlib.suppress(Exception):
                self._f.close()
            self._f = None
        if self._io is not None:
            with contextlib.suppress(Exception):
                self._io.close()
            self._io = None

    # -- writing --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.n

    def set_attr(self, key: str, value: Any) -> None:
        """Store a root attribute in the file being written (kept across ``resume``)."""
        if self._f is None:
            raise RuntimeError("writer is closed")
        self._f.attrs[key] = value

    def get_attr(self, key: str, default: Any = None) -> Any:
        if self._f is None:
            raise RuntimeError("writer is closed")
        return self._f.attrs.get(key, default)

    def append(self, *, timestamp: float | None = None, agents: np.ndarray | None = None,
               aux: Mapping[str, np.ndarray] | None = None, **frames: np.ndarray) -> int:
        """Append one frame (arrays per stream, ``aux`` maps); returns its index.

        Checks shapes and dtypes; the ``n_written`` counter moves last, so a frame interrupted
        half-way is dropped by ``resume``.
        """
        f = self._f
        if f is None:
            raise RuntimeError("writer is closed")
        if set(aux or {}) != set(self.aux):
            raise InputError(f"frame {self.n}: expected aux maps {sorted(self.aux)}, "
                             f"got {sorted(aux or {})}")
        missing = set(self.streams) - set(frames)
        extra = set(frames) - set(self.streams)
        if missing or extra:
            raise InputError(f"frame {self.n}: expected streams {self.streams}, got {sorted(frames)}")
        i = self.n
        arrays = {}
        for name in self.streams:
            a = np.asarray(frames[name])
            ds = f[name]
            if a.shape != ds.shape[1:]:
                raise InputError(f"frame {i}: {name} has shape {a.shape}, expected {ds.shape[1:]}")
            arrays[name] = a.astype(ds.dtype, copy=False)
        for name in self.aux:
            a = np.asarray(aux[name])
            ds = f[f"aux/{name}"]
            if a.shape != ds.shape[1:]:
                raise InputError(f"frame {i}: aux {name} has shape {a.shape}, "
                                 f"expected {ds.shape[1:]}")
            arrays[f"aux/{name}"] = a.astype(ds.dtype, copy=False)
        try:
            for key, a in arrays.items():
                ds = f[key]
                ds.resize(i + 1, axis=0)
                ds[i] = a
                crc = f[f"crc32/{key}"]
                crc.resize(i + 1, axis=0)
                crc[i] = _frame_checksum(a)
            ts = f["timestamps"]
            ts.resize(i + 1, axis=0)
            ts[i] = float(i) if timestamp is None else float(timestamp)
            if agents is not None and len(agents):
                rows = np.asarray(agents).astype(schema.AGENT_DTYPE)
                rows["frame"] = i
                ds = f["agents"]
                k = len(ds)
                ds.resize(k + len(rows), axis=0)
                ds[k:] = rows
            f.attrs["n_written"] = i + 1
            f.flush()  # every frame on disk: a killed run's partial reopens (see resume.py)
            self._commit()
        except (OSError, RuntimeError) as e:  # h5py raises RuntimeError for some write errors
            self._fail(e)
        self.n = i + 1
        return i

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> str:
        """Mark complete, fsync, and rename onto the final path. Returns the final path."""
        f = self._f
        if f is None:
            return self.path
        if self.n == 0:
            self._close_file()
            os.remove(self.partial)
            self.abort()
            raise InputError("no frames were written", self.path)
        if self.meta.adapt_frames > self.n:
            self.abort()
            raise InputError(f"adapt_frames = {self.meta.adapt_frames} exceeds the "
                             f"{self.n} frames written", self.path)
        try:
            for key in ("timestamps", "agents"):  # whole-dataset checksums (verify reads them)
                f[key].attrs["crc32"] = _frame_checksum(f[key][:])
            f.attrs["n_frames"] = self.n
            f.attrs["complete"] = True
            f.flush()
            self._commit()
            f.close()
            self._f = None
            self._commit()
            self._io.close()
            self._io = None
            _fsync_path(self.partial)
            os.replace(self.partial, self.path)
            _fsync_path(self.path)
        except (OSError, RuntimeError) as e:
            self.n = max(self.n, 1)
            self._fail(e)
        finally:
            self._restore_sigterm()
            self._lock.close()
        return self.path

    def abort(self) -> None:
        """Close without finishing: the ``.partial`` file stays for a later ``resume``."""
        try:
            if self._f is not None:
                with contextlib.suppress(Exception):
                    self._f.flush()
            self._close_file()
        finally:
            self._restore_sigterm()
            self._lock.close()

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class SequenceReader:
    """Read a complete sequence file; every structural problem is an :class:`InputError`."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise InputError("file not found", self.path)
        try:
            self._f = h5py.File(self.path, "r")
        except OSError as e:
            raise InputError(f"not a readable HDF5 file ({e})", self.path) from None
        try:
            self._check()
        except Exception:
            self._f.close()
            raise

    def _check(self) -> None:
        from staticdepth.dataset.integrity import link_problems

        f, p = self._f, self.path
        if f.attrs.get("format") != schema.FORMAT:
            raise InputError(f"not a staticdepth sequence (format attribute "
                             f"{f.attrs.get('format')!r})", p)
        outside = link_problems(f)
        if outside:
            raise InputError(outside[0], p)
        for k in schema.REQUIRED_ATTRS:
            if k not in f.attrs:
                raise InputError(f"missing attribute {k!r}", p)
        if not bool(f.attrs["complete"]):
            raise InputError("incomplete sequence (the writer did not finish; "
                             "resume the command that wrote it)", p)
        self.meta = SequenceMeta.from_attrs(f.attrs, p)
        n, w, h = int(f.attrs["n_frames"]), int(f.attrs["width"]), int(f.attrs["height"])
        if n <= 0:
            raise InputError("sequence has no frames", p)
        if "left" not in f:
            raise InputError("missing dataset 'left'", p)
        for name in schema.FRAME_STREAMS:
            if name not in f:
                continue
            want = (n, h, w, 3) if name in ("left", "right") else (n, h, w)
            if f[name].shape != want:
                raise InputError(f"dataset {name!r} has shape {f[name].shape}, expected {want}", p)
            if f[name].dtype != schema.STREAM_DTYPES[name]:
                raise InputError(f"dataset {name!r} has dtype {f[name].dtype}", p)
        if "timestamps" not in f or f["timestamps"].shape != (n,):
            raise InputError("missing or wrong-length 'timestamps'", p)
        if self.meta.adapt_frames > n:
            raise InputError(f"adapt_frames {self.meta.adapt_frames} > {n} frames", p)
        if (self.meta.camera.width, self.meta.camera.height) != (w, h):
            raise InputError("camera size differs from the frame size", p)
        for name in (sorted(f["aux"]) if "aux" in f else []):
            if f[f"aux/{name}"].shape != (n, h, w):
                raise InputError(f"aux map {name!r} has shape {f[f'aux/{name}'].shape}", p)
        for name in self.predictions():
            if f[f"pred/{name}/depth"].shape != (n, h, w):
                raise InputError(f"prediction {name!r} has shape {f[f'pred/{name}/depth'].shape}", p)
        self.n_frames, self.width, self.height = n, w, h

    # -- access ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.n_frames

    def __enter__(self) -> "SequenceReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._f.close()

    @property
    def camera(self) -> Camera:
        return self.meta.camera

    @property
    def attrs(self) -> Mapping[str, Any]:
        return self._f.attrs

    def has(self, stream: str) -> bool:
        return stream in self._f

    def streams(self) -> list[str]:
        return [s for s in schema.FRAME_STREAMS if s in self._f]

    def split(self, name: str) -> range:
        """Frame indices of the ``adapt`` split (first N frames) or the ``eval`` split (the rest)."""
        if name == "adapt":
            return range(0, self.meta.adapt_frames)
        if name == "eval":
            return range(self.meta.adapt_frames, self.n_frames)
        if name == "all":
            return range(self.n_frames)
        raise InputError(f"unknown split {name!r} (adapt, eval, all)", self.path)

    def _index(self, i: int) -> int:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i} out of range 0..{self.n_frames - 1}")
        return i % self.n_frames

    def read(self, stream: str, i: int) -> np.ndarray:
        if stream not in self._f:
            raise InputError(f"sequence has no {stream!r} stream", self.path)
        return self._f[stream][self._index(i)]

    def left(self, i: int) -> np.ndarray:
        return self.read("left", i)

    def right(self, i: int) -> np.ndarray:
        return self.read("right", i)

    def depth(self, i: int) -> np.ndarray:
        return self.read("depth", i)

    def instances(self, i: int) -> np.ndarray:
        return self.read("instances", i)

    def aux_names(self) -> list[str]:
        return sorted(self._f["aux"]) if "aux" in self._f else []

    def aux(self, name: str, i: int) -> np.ndarray:
        key = f"aux/{name}"
        if key not in self._f:
            raise InputError(f"sequence has no aux map {name!r} (has {self.aux_names()})",
                             self.path)
        return self._f[key][self._index(i)]

    def timestamps(self) -> np.ndarray:
        return self._f["timestamps"][:]

    def agents(self, i: int | None = None) -> np.ndarray:
        """Agent rows of frame ``i`` (all frames when None)."""
        rows = self._f["agents"][:] if "agents" in self._f else schema.empty_agents(0)
        return rows if i is None else rows[rows["frame"] == self._index(i)]

    def frame(self, i: int) -> dict[str, Any]:
        i = self._index(i)
        out: dict[str, Any] = {s: self._f[s][i] for s in self.streams()}
        out["timestamp"] = float(self._f["timestamps"][i])
        out["agents"] = self.agents(i)
        out["index"] = i
        return out

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for i in range(self.n_frames):
            yield self.frame(i)

    def predictions(self) -> list[str]:
        if "pred" not in self._f:
            return []
        return sorted(k for k in self._f["pred"] if "depth" in self._f["pred"][k])

    def prediction(self, name: str, i: int) -> np.ndarray:
        key = f"pred/{name}/depth"
        if key not in self._f:
            raise InputError(f"sequence has no prediction {name!r} (has {self.predictions()})",
                             self.path)
        return self._f[key][self._index(i)]

    def prediction_attrs(self, name: str) -> dict[str, Any]:
        return dict(self._f[f"pred/{name}"].attrs)

    def checksum_errors(self) -> list[str]:
        """Recompute the checksum of every dataset (frames, timestamps, agents, aux maps,
        predictions); a line per mismatch or dataset without one (empty when intact)."""
        from staticdepth.dataset.integrity import checksum_problems

        return checksum_problems(self._f)


def add_prediction(path: str | os.PathLike, name: str, depth_maps: Iterable[np.ndarray],
                   attrs: Mapping[str, Any] | None = None, *, overwrite: bool = True) -> None:
    """Store ``pred/<name>/depth`` (N, H, W float32) in a complete sequence file, atomically.

    The file is copied, the prediction written into the copy, and the copy renamed over the
    original, so an interruption never damages the sequence.
    """
    path = os.fspath(path)
    with SequenceReader(path) as r:
        n, h, w = r.n_frames, r.height, r.width
        exists = name in r.predictions()
    if exists and not overwrite:
        raise InputError(f"prediction {name!r} already exists", path)
    tmp = f"{path}.pred{os.getpid()}.tmp"
    shutil.copyfile(path, tmp)
    try:
        with h5py.File(tmp, "a") as f:
            key = f"pred/{name}"
            if key in f:
                del f[key]
            g = f.create_group(key)
            ds = g.create_dataset("depth", shape=(n, h, w), dtype=np.float32, chunks=(1, h, w),
                                  **_compression("float"))
            k = 0
            for k, d in enumerate(depth_maps, start=1):
                d = np.asarray(d, dtype=np.float32)
                if d.shape != (h, w):
                    raise InputError(f"prediction {name!r} frame {k - 1}: shape {d.shape}, "
                                     f"expected {(h, w)}", path)
                if k > n:
                    raise InputError(f"prediction {name!r} has more than {n} frames", path)
                ds[k - 1] = d
            if k != n:
                raise InputError(f"prediction {name!r} has {k} frames, the sequence {n}", path)
            crc_key = f"crc32/{key}/depth"  # per-frame checksums, read by verify
            if crc_key in f:
                del f[crc_key]
            f.create_dataset(crc_key, data=np.array([_frame_checksum(ds[i]) for i in range(n)],
                                                    np.uint32))
            for a, v in (attrs or {}).items():
                g.attrs[a] = v if isinstance(v, (int, float, str, np.number)) else json.dumps(v)
        _fsync_path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
