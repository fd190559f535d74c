"""Per-frame array files: written frame by frame, resumable, checksummed, renamed when complete.

The mechanism behind the prediction store (:mod:`staticdepth.dataset.predictions`) and the
adaptation stages' own files. A file holds one dataset of ``n`` frames (one frame per chunk, the
sequence files' compression), ``crc32`` (per-frame CRC-32), optional per-frame ``rows``, and the
attributes ``config_hash``, ``sequence_id``, ``n_frames``, ``n_written``, ``complete``. It is
written as ``<path>.partial`` under :func:`staticdepth.fileio.exclusive_lock`; ``n_written``
moves after each flushed chunk; a resumed write keeps the frames whose checksum verifies when the
partial file has the same config hash and sequence identity (else it starts over); a finished
file is fsynced and renamed onto ``<path>``. The partial is written as the sequence writer's is
(:mod:`staticdepth.dataset.resume`: HDF5's 1.8 superblock, an undo journal, a commit after each
flush), so a run killed even by SIGKILL, even in the middle of a flush, resumes after its last
flushed frame.
"""
from __future__ import annotations

import contextlib
import json
import os
from typing import Any, Mapping

import h5py
import numpy as np

from staticdepth.dataset import resume as rs
from staticdepth.dataset.integrity import checksum as frame_checksum  # the one CRC-32 of a frame
from staticdepth.errors import InputError
from staticdepth.fileio import exclusive_lock, fsync_file, os_error, remove_stale_temporaries

PARTIAL = ".partial"


def _compression(kind: str) -> dict[str, Any]:
    from staticdepth.dataset.h5 import _compression as comp

    return comp(kind)


def _attr(v: Any) -> Any:
    return v if isinstance(v, (int, float, str, np.number, np.bool_, bool)) else json.dumps(v)


class FrameFileWriter:
    """Write ``n`` frames of one array (``shape``, ``dtype``) to ``path`` in order; resumable.

    >>> w = FrameFileWriter(path, n=100, shape=(H, W), dtype=np.float32, identity=sid,
    ...                     config_hash=h)
    >>> with w:                      # lock, open (resume or start), finish on success
    ...     for i in range(w.start, w.n):
    ...         w.write(i, depth_i)

    ``w.done`` is True when ``path`` is already complete with the same identity and config hash
    (nothing to write; ``with`` then does nothing). ``rows_dtype`` adds a ``rows`` table of
    per-frame records (field ``frame``) written with :meth:`write`'s ``rows``.
    """

    def __init__(self, path: str | os.PathLike, *, n: int, shape: tuple[int, ...], dtype,
                 identity: str, config_hash: str, key: str = "depth",
                 attrs: Mapping[str, Any] | None = None, rows_dtype=None, chunk: int = 1,
                 rewrite: bool = False):
        self.path = os.fspath(path)
        self.partial = self.path + PARTIAL
        self.n, self.shape, self.dtype = int(n), tuple(shape), np.dtype(dtype)
        self.identity, self.config_hash, self.key = identity, str(config_hash), key
        self.attrs = dict(attrs or {})
        self.rows_dtype = None if rows_dtype is None else np.dtype(rows_dtype)
        self.chunk = max(1, int(chunk))     # frames between flushes (n_written moves then)
        self._f: h5py.File | None = None
        self._io: rs.UndoableFile | None = None
        self._stack = contextlib.ExitStack()
        self.start = 0
        self.rewrite = rewrite              # write even when a complete file has the same hash
        self.done = not rewrite and is_complete(self.path, identity, self.config_hash)

    # -- lifecycle ----------------------------------------------------------------------------------
    def __enter__(self) -> "FrameFileWriter":
        if self.done:
            return self
        folder = os.path.dirname(os.path.abspath(self.path))
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError as e:
            raise os_error(e, folder) from None
        self._stack.enter_context(exclusive_lock(self.path))
        remove_stale_temporaries(self.path)
        self.done = not self.rewrite and is_complete(self.path, self.identity, self.config_hash)
        if not self.done:
            self._open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None and not self.done:
                self.finish()
            else:
                self.abort()
        finally:
            self._stack.close()

    def _open(self) -> None:
        if os.path.exists(self.partial):
            f = io_ = None
            try:
                rs.recover_journal(self.partial)
                io_ = rs.UndoableFile(self.partial, create=False)
                f = h5py.File(io_, "r+", libver=rs.LIBVER)
                ok = (f.attrs.get("config_hash") == self.config_hash
                      and f.attrs.get("sequence_id") == self.identity
                      and f[self.key].shape[1:] == self.shape and f[self.key].dtype == self.dtype
                      and int(f.attrs["n_frames"]) == self.n)
            except (OSError, KeyError, ValueError, RuntimeError):
                ok = False
            if ok:
                self._set_file(f, io_)
                self.start = self._verified_frames()
                self._truncate(self.start)
                self._flush()
                return
            for h in (f, io_):
                if h is not None:
                    with contextlib.suppress(Exception):
                        h.close()
            os.remove(self.partial)     # derived data: written again
            rs.remove_journal(self.partial)
        self._create()

    def _create(self) -> None:
        try:
            f, io_ = rs.create_partial(self.partial)
        except OSError as e:
            raise os_error(e, self.partial) from None
        kind = "float" if self.dtype.kind == "f" else "int"
        f.create_dataset(self.key, shape=(0,) + self.shape, maxshape=(None,) + self.shape,
                         chunks=(1,) + self.shape, dtype=self.dtype, **_compression(kind))
        f.create_dataset("crc32", shape=(0,), maxshape=(None,), dtype=np.uint32, chunks=(4096,))
        if self.rows_dtype is not None:
            f.create_dataset("rows", shape=(0,), maxshape=(None,), dtype=self.rows_dtype,
                             chunks=(4096,))
        for k, v in self.attrs.items():
            f.attrs[k] = _attr(v)
        f.attrs.update({"config_hash": self.config_hash, "sequence_id": self.identity,
                        "n_frames": self.n, "n_written": 0, "complete": False, "key": self.key})
        self._set_file(f, io_)
        self.start = 0
        self._flush()

    def _set_file(self, f: h5py.File, io_: rs.UndoableFile) -> None:
        self._f, self._io = f, io_
        self._ds, self._crc = f[self.key], f["crc32"]
        self._rows = f["rows"] if self.rows_dtype is not None else None

    def _verified_frames(self) -> int:
        """Frames at the start of the partial file whose data read back with their checksum."""
        f = self._f
        n = min(int(f.attrs.get("n_written", 0)), len(f[self.key]), len(f["crc32"]))
        crc = f["crc32"][:n]
        for i in range(n):
            try:
                if frame_checksum(f[self.key][i]) != int(crc[i]):
                    return i
            except (OSError, ValueError):
                return i
        return n

    def _truncate(self, n: int) -> None:
        f = self._f
        f[self.key].resize(n, axis=0)
        f["crc32"].resize(n, axis=0)
        if self.rows_dtype is not None:
            rows = f["rows"]
            keep = int(np.count_nonzero(rows["frame"][:] < n)) if len(rows) else 0
            rows.resize(keep, axis=0)
        f.attrs["n_written"] = n

    # -- writing --------------------------------------------------------------------------------------
    @property
    def written(self) -> int:
        return self.n if self.done else (0 if self._f is None else len(self._crc))

    def write(self, i: int, frame: np.ndarray, rows: np.ndarray | None = None) -> None:
        """Write frame ``i`` (the next one); ``rows`` are its records (their ``frame`` is set)."""
        f = self._f
        if f is None:
            raise RuntimeError("writer is not open")
        k = len(self._crc)
        if i != k:
            raise RuntimeError(f"frames are written in order: expected {k}, got {i}")
        if k >= self.n:
            raise InputError(f"more than {self.n} frames written", self.path)
        a = np.asarray(frame)
        if a.shape != self.shape:
            raise InputError(f"frame {i}: shape {a.shape}, expected {self.shape}", self.path)
        a = np.ascontiguousarray(a, dtype=self.dtype)
        self._ds.resize(k + 1, axis=0)
        self._ds[k] = a
        self._crc.resize(k + 1, axis=0)
        self._crc[k] = frame_checksum(a)
        if rows is not None and len(rows) and self.rows_dtype is not None:
            r = np.asarray(rows).astype(self.rows_dtype)
            r["frame"] = i
            t = self._rows
            m = len(t)
            t.resize(m + len(r), axis=0)
            t[m:] = r
        if (k + 1) % self.chunk == 0 or k + 1 == self.n:
            f.attrs["n_written"] = k + 1
            self._flush()

    def _flush(self) -> None:
        """Flush and commit (the partial is complete as it is); a failed write (disk full) puts
        the partial back as it was at the last commit, closes it for a resume, and raises one
        line."""
        try:
            self._f.flush()
        except (OSError, RuntimeError) as e:        # h5py raises RuntimeError for some
            if self._io.failed is None:
                self._io.failed = e if isinstance(e, OSError) else OSError(str(e))
        self._commit()

    def _commit(self) -> None:
        """The partial as it is now is complete, unless a write failed: then it is put back as
        it was at the last commit, closed for a resume, and one line raised."""
        if self._io.failed is not None:
            e = self._io.failed
            with contextlib.suppress(OSError):
                self._io.rollback()
            self._close_file()
            raise os_error(e, self.partial) from None
        self._io.commit()

    def _close_file(self) -> None:
        for h in (self._f, self._io):
            if h is not None:
                with contextlib.suppress(Exception):
                    h.close()
        self._f = self._io = None

    def finish(self) -> str:
        f = self._f
        if f is None:
            return self.path
        k = len(f["crc32"])
        if k != self.n:
            self.abort()
            raise InputError(f"{k} frames written, the sequence has {self.n}", self.path)
        f.attrs["n_written"] = k
        f.attrs["complete"] = True
        self._flush()
        f.close()
        self._f = None
        self._flush_close()
        try:
            fsync_file(self.partial)
            os.replace(self.partial, self.path)
            fsync_file(self.path)
        except OSError as e:
            raise os_error(e, self.path) from None
        self.done = True
        return self.path

    def _flush_close(self) -> None:
        """After HDF5 closed the file: its last writes are committed, the journal removed."""
        self._commit()
        self._close_file()

    def abort(self) -> None:
        """Close, keeping the ``.partial`` file for a later resume."""
        if self._f is not None:
            with contextlib.suppress(Exception):     # a clean stop: every frame written counts
                self._f.attrs["n_written"] = len(self._f["crc32"])
                self._flush()
                self._f.close()                      # a clean close: committed, journal gone
                self._f = None
                self._flush_close()
        self._close_file()


def is_complete(path: str | os.PathLike, identity: str, config_hash: str | None = None) -> bool:
    """``path`` is a complete frame file of this sequence (and of ``config_hash`` when given)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        return False
    try:
        with h5py.File(path, "r") as f:
            return (bool(f.attrs.get("complete", False)) and f.attrs.get("sequence_id") == identity
                    and (config_hash is None or f.attrs.get("config_hash") == config_hash))
    except OSError:
        return False


def frames_left(path: str | os.PathLike, identity: str, config_hash: str, n: int) -> int:
    """Frames a :class:`FrameFileWriter` of ``path`` with this identity and hash would still
    write: 0 when the file is complete, ``n - n_written`` when it would resume a partial file,
    else ``n`` (a complete file of other settings stays until the new one replaces it)."""
    path = os.fspath(path)
    if is_complete(path, identity, config_hash):
        return 0
    if rs.journal_pending(path + PARTIAL):
        return n      # killed in a flush: not read before its writer puts it back
    try:
        with h5py.File(path + PARTIAL, "r") as f:
            a = f.attrs
            if (a.get("config_hash") == config_hash and a.get("sequence_id") == identity
                    and int(a.get("n_frames", -1)) == n):
                return n - min(max(int(a.get("n_written", 0)), 0), n)
    except (OSError, ValueError):
        pass
    return n


class FrameFile:
    """Read a complete frame file written by :class:`FrameFileWriter` (lazily, frame by frame)."""

    def __init__(self, path: str | os.PathLike, identity: str | None = None,
                 shape: tuple[int, ...] | None = None):
        self.path = os.fspath(path)
        try:
            self._f = h5py.File(self.path, "r")
        except OSError as e:
            raise InputError(f"not a readable HDF5 file ({e})", self.path) from None
        a = self._f.attrs
        self.key = str(a.get("key", "depth"))
        try:
            if not bool(a.get("complete", False)) or self.key not in self._f:
                raise InputError("incomplete prediction file", self.path)
            if identity is not None and a.get("sequence_id") != identity:
                raise InputError("this prediction file belongs to another sequence (its "
                                 "sequence_id differs); delete it or write it again", self.path)
            if shape is not None and self._f[self.key].shape != tuple(shape):
                raise InputError(f"prediction has shape {self._f[self.key].shape}, expected "
                                 f"{tuple(shape)}", self.path)
        except Exception:
            self._f.close()
            raise
        self._rows: np.ndarray | None = None
        self._crc: np.ndarray | None = None
        self._ds = self._f[self.key]

    def __len__(self) -> int:
        return len(self._ds)

    def __getitem__(self, i: int) -> np.ndarray:
        """Frame ``i``, checked against its stored checksum (a damaged frame is an
        InputError naming the file, never used)."""
        a = self._ds[i]
        if self._crc is None:
            self._crc = self._f["crc32"][:] if "crc32" in self._f else np.zeros(0, np.uint32)
        j = int(i) % len(self._ds) if len(self._ds) else 0
        if j < len(self._crc) and frame_checksum(a) != int(self._crc[j]):
            raise InputError(f"frame {j} does not match its checksum, the file is damaged; "
                             "check the sequence with 'staticdepth verify'", self.path)
        return a

    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self._f.attrs)

    def rows(self, i: int) -> np.ndarray:
        """Per-frame records of frame ``i`` (the whole table is read once: it is small)."""
        if self._rows is None:
            self._rows = self._f["rows"][:]
        return self._rows[self._rows["frame"] == i]

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "FrameFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
