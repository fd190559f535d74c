"""The prediction store: each prediction is its own HDF5 file beside the sequence.

``<SEQ>.h5`` -> ``<SEQ>.h5.pred/<name>.h5`` with dataset ``depth`` (N, H, W) float32 (one frame
per chunk, the sequence files' compression), ``crc32`` (N,) per-frame CRC-32 checksums and
attributes: the prediction's own, ``config_hash`` (the settings that produced it), ``sequence_id``
(:func:`sequence_id`: a prediction file of another sequence is refused), ``n_frames``,
``complete``.

A prediction is written frame by frame into ``<name>.h5.partial`` under
:func:`staticdepth.fileio.exclusive_lock`, with ``n_written`` moving after each flushed chunk; an
interrupted write resumes after the last frame whose checksum verifies when the partial file has
the same config hash and sequence identity (another hash: that prediction starts over). A
finished file is fsynced and renamed onto ``<name>.h5``, so a reader sees either the previous
complete prediction or the new one. Removing a prediction is removing its file.

:class:`FrameFileWriter` is the same mechanism for any per-frame array (the adaptation stages keep
their instance maps, inverse depths and labels in such files, with optional per-frame rows).
"""
from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import re
import zlib
from typing import Any, Iterable, Mapping

import h5py
import numpy as np

from staticdepth.errors import InputError
from staticdepth.fileio import exclusive_lock, fsync_file, os_error, remove_stale_temporaries

STORE_SUFFIX = ".pred"
PARTIAL = ".partial"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")


def frame_checksum(a: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).data) & 0xFFFFFFFF


def _compression(kind: str) -> dict[str, Any]:
    from staticdepth.dataset.h5 import _compression as comp

    return comp(kind)


def store_dir(seq_path: str | os.PathLike) -> str:
    """``<SEQ>.h5.pred``: the folder of a sequence's predictions."""
    return os.fspath(seq_path) + STORE_SUFFIX


def check_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME_RE.match(name) or name.endswith(".h5"):
        raise InputError(f"bad prediction name {name!r} (letters, digits, '.', '_', '+', '-'; "
                         "starting with a letter or digit)")
    return name


def prediction_path(seq_path: str | os.PathLike, name: str) -> str:
    return os.path.join(store_dir(seq_path), check_name(name) + ".h5")


def sequence_id(f: h5py.File) -> str:
    """Identity of an open sequence file: SHA-256 over its frame count, size and the stored
    per-frame checksums of its streams (cheap: no frame is decoded)."""
    h = hashlib.sha256()
    h.update(json.dumps([int(f.attrs["n_frames"]), int(f.attrs["width"]),
                         int(f.attrs["height"])]).encode())
    if "crc32" in f:
        for name in sorted(f["crc32"]):
            h.update(name.encode())
            h.update(np.asarray(f["crc32"][name][:], dtype="<u4").tobytes())
    return h.hexdigest()[:32]


def sequence_id_of(seq_path: str | os.PathLike) -> str:
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(seq_path) as r:
        return r.sequence_id()


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
            try:
                f = h5py.File(self.partial, "a")
                ok = (f.attrs.get("config_hash") == self.config_hash
                      and f.attrs.get("sequence_id") == self.identity
                      and f[self.key].shape[1:] == self.shape and f[self.key].dtype == self.dtype
                      and int(f.attrs["n_frames"]) == self.n)
            except (OSError, KeyError, ValueError):
                ok, f = False, None
            if ok:
                self._set_file(f)
                self.start = self._verified_frames()
                self._truncate(self.start)
                return
            if f is not None:
                f.close()
            os.remove(self.partial)
        self._create()

    def _create(self) -> None:
        try:
            f = h5py.File(self.partial, "w", libver="latest")
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
        self._set_file(f)
        self.start = 0

    def _set_file(self, f: h5py.File) -> None:
        self._f = f
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
            f.flush()

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
        f.flush()
        f.close()
        self._f = None
        try:
            fsync_file(self.partial)
            os.replace(self.partial, self.path)
            fsync_file(self.path)
        except OSError as e:
            raise os_error(e, self.path) from None
        self.done = True
        return self.path

    def abort(self) -> None:
        """Close, keeping the ``.partial`` file for a later resume."""
        if self._f is not None:
            with contextlib.suppress(Exception):     # a clean stop: every frame written counts
                self._f.attrs["n_written"] = len(self._f["crc32"])
                self._f.flush()
            self._f.close()
            self._f = None


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
        self._ds = self._f[self.key]

    def __len__(self) -> int:
        return len(self._ds)

    def __getitem__(self, i: int) -> np.ndarray:
        return self._ds[i]

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


# -- predictions of a sequence ---------------------------------------------------------------------
def prediction_names(seq_path: str | os.PathLike) -> list[str]:
    """Names of the complete sidecar predictions (``.partial`` and lock files are not listed)."""
    folder = store_dir(seq_path)
    if not os.path.isdir(folder):
        return []
    return sorted(os.path.basename(p)[:-3] for p in glob.glob(os.path.join(glob.escape(folder),
                                                                          "*.h5")))


def prediction_writer(seq_path: str | os.PathLike, name: str, *, n: int, height: int, width: int,
                      identity: str, attrs: Mapping[str, Any] | None = None,
                      config_hash: str = "", chunk: int = 1, rewrite: bool = False
                      ) -> FrameFileWriter:
    """A :class:`FrameFileWriter` for ``<SEQ>.h5.pred/<name>.h5`` (float32 depth maps)."""
    attrs = {k: v for k, v in dict(attrs or {}).items() if k != "config_hash"}
    return FrameFileWriter(prediction_path(seq_path, name), n=n, shape=(height, width),
                           dtype=np.float32, identity=identity, config_hash=config_hash,
                           attrs={"name": name, **attrs}, chunk=chunk, rewrite=rewrite)


def write_prediction(seq_path: str | os.PathLike, name: str, depth_maps: Iterable[np.ndarray],
                     attrs: Mapping[str, Any] | None = None) -> str:
    """Store a prediction from an iterable of (H, W) maps, frame by frame (bounded memory).

    The maps are always written (replacing a complete file). With ``attrs["config_hash"]`` an
    interrupted write of the same hash resumes: the frames already written are taken from the
    iterable without being written again; without one, a partial file is never resumed.
    """
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(seq_path) as r:
        n, h, w, sid = r.n_frames, r.height, r.width, r.sequence_id()
    attrs = dict(attrs or {})
    chash = str(attrs.get("config_hash", ""))
    w_ = prediction_writer(seq_path, name, n=n, height=h, width=w, identity=sid, attrs=attrs,
                           config_hash=chash or f"unhashed-{os.urandom(6).hex()}", chunk=8,
                           rewrite=True)
    with w_:
        k = -1
        for k, d in enumerate(depth_maps):
            if k >= n:
                raise InputError(f"prediction {name!r} has more than {n} frames", seq_path)
            d = np.asarray(d, dtype=np.float32)
            if d.shape != (h, w):
                raise InputError(f"prediction {name!r} frame {k}: shape {d.shape}, expected "
                                 f"{(h, w)}", seq_path)
            if k >= w_.start:
                w_.write(k, d)
        if k + 1 != n:
            raise InputError(f"prediction {name!r} has {k + 1} frames, the sequence {n}",
                             seq_path)
    return w_.path


def remove_prediction(seq_path: str | os.PathLike, name: str) -> bool:
    """Delete a sidecar prediction (and its partial file); True when something was removed."""
    p = prediction_path(seq_path, name)
    removed = False
    with exclusive_lock(p):
        for q in (p, p + PARTIAL):
            if os.path.exists(q):
                os.remove(q)
                removed = True
    return removed


def clean_store(seq_path: str | os.PathLike) -> list[str]:
    """Remove temporaries of dead processes and ``.partial`` files nobody is writing."""
    from staticdepth.fileio import OutputLocked

    folder = store_dir(seq_path)
    removed: list[str] = []
    for part in glob.glob(os.path.join(glob.escape(folder), "*.h5" + PARTIAL)):
        final = part[:-len(PARTIAL)]
        removed += remove_stale_temporaries(final)
        try:
            with exclusive_lock(final):
                os.remove(part)
                removed.append(part)
        except OutputLocked:
            continue
    return removed


def verify_predictions(seq_path: str | os.PathLike) -> list[str]:
    """Problems of a sequence's sidecar predictions (empty when intact): identity, shape, every
    frame's checksum."""
    from staticdepth.dataset.h5 import SequenceReader

    names = prediction_names(seq_path)
    if not names:
        return []
    with SequenceReader(seq_path) as r:
        sid, shape = r.sequence_id(), (r.n_frames, r.height, r.width)
    bad: list[str] = []
    for name in names:
        tag = f"{STORE_SUFFIX[1:]}/{name}"
        try:
            with FrameFile(prediction_path(seq_path, name), sid, shape) as ff:
                crc = ff._f["crc32"][:]
                if len(crc) != shape[0]:
                    bad.append(f"{tag}: {len(crc)} checksums for {shape[0]} frames")
                    continue
                for i in range(shape[0]):
                    try:
                        ok = frame_checksum(ff[i]) == int(crc[i])
                    except (OSError, ValueError) as e:
                        bad.append(f"{tag}[{i}]: unreadable ({e})")
                        continue
                    if not ok:
                        bad.append(f"{tag}[{i}]: checksum mismatch")
        except InputError as e:
            bad.append(f"{tag}: {e.problem}")
    return bad
