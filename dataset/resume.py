"""Resuming a sequence writer safely: the input fingerprint, and reopening a killed run's partial.

A writer stores in its ``<out>.partial`` file

- ``fingerprint`` (root attribute, JSON): one entry per setting that changes the output (every
  sequence attribute, the provenance's entries, the streams, the aux maps and the caller's extra
  settings such as the frame count), short values kept as they are, long ones as a digest;
- ``fingerprint/inputs`` (dataset): one digest per input frame: the frame's task (paths, numbers)
  with each input file's size and modification time. Only the frames already used (written or
  skipped) must match: a broken input file after them may be repaired before resuming.

``--resume`` compares both with the new run's and refuses with one line naming what differs; a
partial without a fingerprint (written by an older version) is refused too.

Reopening: the file is written with HDF5's version-1.8 superblock (no "file is open for write"
consistency flag, which the newer superblock leaves set after SIGKILL and h5py cannot clear) and
flushed after every frame, so a killed run's partial opens again (benchmarks/bench_crash_resume.py:
12 of 12 partials killed at random moments reopened and resumed to verified files; 0 of 12 with
the old settings, ``libver="latest"`` without flushes; throughput ratio 0.95-1.07 at 800x400).
A kill in the middle of a flush is undone first by the partial's undo journal
(:class:`UndoableFile`, :func:`recover_journal`; 1.4-4.2% of the writer's time at 800x400, 72 kB
per frame). The last frames are checked against their stored CRC-32 and dropped back to the last
complete one. A partial that cannot be opened at all is renamed aside (``<partial>.damaged-<time>``) and
the user told, never deleted.
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import io
import json
import os
import struct
import time
import zlib
from typing import Any, Callable, Iterable, Mapping, Sequence

import h5py
import numpy as np

from staticdepth.errors import InputError

#: Superblock v0..v2 (HDF5 1.8 format): reopenable after a kill; read by every HDF5 since 1.8.
LIBVER = ("earliest", "v108")
INPUTS = "fingerprint/inputs"
_SHORT = 60


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def file_identity(path: str) -> str:
    """``size:mtime_ns`` of an existing file (``missing`` otherwise)."""
    try:
        st = os.stat(path)
    except OSError:
        return "missing"
    return f"{st.st_size}:{st.st_mtime_ns}"


def task_identity(task: Any) -> str:
    """A digest of one frame's task: every field, and size/mtime of every file it names."""
    parts: list[str] = []

    def walk(v: Any) -> None:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            for f in dataclasses.fields(v):
                parts.append(f.name)
                walk(getattr(v, f.name))
        elif isinstance(v, (str, os.PathLike)):
            s = os.fspath(v)
            parts.append(s)
            if os.path.isfile(s):
                parts.append(file_identity(s))
        elif isinstance(v, np.ndarray):
            parts.append(_digest(np.ascontiguousarray(v).tobytes()) + str(v.shape) + str(v.dtype))
        elif isinstance(v, (list, tuple)):
            for x in v:
                walk(x)
        else:
            parts.append(repr(v))

    walk(task)
    return _digest("\0".join(parts).encode())


def callable_identity(fn: Any) -> str:
    """A function's module and name, or a dataclass instance's fields (no memory addresses)."""
    if dataclasses.is_dataclass(fn) and not isinstance(fn, type):
        return repr(fn)
    return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', type(fn).__qualname__)}"


def settings_fingerprint(meta_attrs: Mapping[str, Any], streams: Sequence[str],
                         aux: Iterable[str], extra: Mapping[str, Any] | None = None
                         ) -> dict[str, str]:
    """``{setting: value or digest}`` for every setting that changes the output."""
    items: dict[str, Any] = {}
    for k, v in meta_attrs.items():
        if k == "provenance":
            prov = json.loads(v) if isinstance(v, str) else dict(v)
            for pk, pv in prov.items():
                items[f"provenance.{pk}"] = pv
        else:
            items[k] = v.item() if isinstance(v, np.generic) else v
    items["streams"] = list(streams)
    items["aux"] = sorted(aux)
    items.update(dict(extra or {}))
    out = {}
    for k, v in items.items():
        s = json.dumps(v, sort_keys=True, default=str)
        out[k] = s if len(s) <= _SHORT else "sha256:" + _digest(s.encode())
    return out


def store(f: h5py.File, fingerprint: Mapping[str, str], inputs: Sequence[str] | None) -> None:
    f.attrs["fingerprint"] = json.dumps(dict(fingerprint), sort_keys=True)
    if inputs is not None:
        if INPUTS in f:
            del f[INPUTS]
        f.create_dataset(INPUTS, data=np.array([s.encode() for s in inputs], dtype="S16"))


def differences(f: h5py.File, fingerprint: Mapping[str, str], inputs: Sequence[str] | None,
                labels: Sequence[str] | None = None) -> list[str]:
    """What differs between the partial ``f`` and the new run (empty: resumable)."""
    if "fingerprint" not in f.attrs:
        return ["the partial has no input fingerprint (written by an older version)"]
    old = json.loads(f.attrs["fingerprint"])
    diff = []
    for k in sorted(set(old) | set(fingerprint)):
        a, b = old.get(k), fingerprint.get(k)
        if a == b:
            continue
        if a is None or b is None:
            diff.append(f"{k} {'added' if a is None else 'removed'}")
        elif a.startswith("sha256:") or b.startswith("sha256:"):
            diff.append(f"{k} differs")
        else:
            diff.append(f"{k}: {a} in the partial, {b} now")
    if inputs is not None:
        stored = [s.decode() for s in f[INPUTS][:]] if INPUTS in f else None
        consumed = int(f.attrs.get("n_written", 0)) + len(json.loads(f.attrs.get("skipped", "[]")))
        if stored is None:
            diff.append("the partial has no per-frame input identities")
        elif len(inputs) < consumed:
            diff.append(f"the input has {len(inputs)} frames, the partial already used {consumed}")
        else:
            bad = [i for i in range(consumed) if stored[i] != inputs[i]]
            if bad:
                name = labels[bad[0]] if labels is not None else str(bad[0])
                diff.append(f"input frame {name} (and {len(bad) - 1} more) changed"
                            if len(bad) > 1 else f"input frame {name} changed")
    return diff


def create_partial(partial: str) -> tuple[h5py.File, "UndoableFile"]:
    io_ = UndoableFile(partial, create=True)
    try:
        return h5py.File(io_, "w", libver=LIBVER), io_
    except BaseException:
        io_.close()
        raise


def open_partial(partial: str, warn: Callable[[str], Any]
                 ) -> tuple[h5py.File, "UndoableFile"] | None:
    """Open a killed run's partial for appending; None (renamed aside, told) when impossible."""
    io_ = None
    try:
        recover_journal(partial)
        io_ = UndoableFile(partial, create=False)
        return h5py.File(io_, "r+", libver=LIBVER), io_
    except (OSError, ValueError, RuntimeError) as e:
        if io_ is not None:
            io_.close()
        aside = f"{partial}.damaged-{time.strftime('%Y%m%d-%H%M%S')}"
        os.replace(partial, aside)
        warn(f"warning: {partial} cannot be reopened ({str(e).splitlines()[0][:120]}); "
             f"kept it as {aside} and starting over")
        return None


def last_complete(f: h5py.File, n: int, checksum: Callable[[np.ndarray], int],
                  keys: Sequence[str]) -> int:
    """The number of leading frames whose every ``key`` matches its stored ``crc32/<key>``.

    Only the last frames are checked (a kill can cut the newest frame only); steps back while the
    newest is incomplete. Frames are flushed in order, so the older ones were on disk first.
    """
    while n > 0:
        ok = "timestamps" in f and len(f["timestamps"]) >= n
        for key in keys:
            if not ok:
                break
            crc = f"crc32/{key}"
            try:
                ok = (key in f and crc in f and len(f[key]) >= n and len(f[crc]) >= n
                      and checksum(f[key][n - 1]) == int(f[crc][n - 1]))
            except (OSError, ValueError, RuntimeError, KeyError):
                ok = False
        if ok:
            return n
        n -= 1
    return 0


def leftover(partial: str, resume_how: str = "--resume continues it") -> InputError:
    """The one line for a ``.partial`` found with neither ``--resume`` nor ``--restart``: it is
    never resumed or deleted unasked (``resume_how``: how this command continues it)."""
    return InputError("an earlier run stopped before finishing (interrupted, or by a bad input) "
                      f"and left this file: {resume_how}, --restart starts over", partial)


def refuse(partial: str, diff: Sequence[str]) -> InputError:
    return InputError("cannot resume: the partial was written with other inputs or settings ("
                      + "; ".join(diff[:3]) + (f"; {len(diff) - 3} more" if len(diff) > 3 else "")
                      + "); --restart starts over", partial)


#: The undo journal beside a partial (see :class:`UndoableFile`).
JOURNAL = ".undo"
_MAGIC = b"SDUNDO1\0"
_HEAD = struct.Struct("<8sQ")     # magic, the partial's size at the last commit
_REC = struct.Struct("<QII")      # offset, length, CRC-32 of (offset, length, old bytes)


def _record_crc(off: int, data: bytes) -> int:
    return zlib.crc32(data, zlib.crc32(struct.pack("<QI", off, len(data)))) & 0xFFFFFFFF


def recover_journal(partial: str) -> int:
    """Put a killed writer's partial back as it was after its last complete frame.

    Applies ``<partial>.undo`` (see :class:`UndoableFile`): every complete record's old bytes,
    newest first, then the size of the last commit; a record cut by the kill is ignored (its
    overwrite had not started). Removes the journal. Idempotent: a recovery killed half-way is
    done again. Returns the number of records applied (0 without a journal).
    """
    jpath = partial + JOURNAL
    try:
        with open(jpath, "rb") as j:
            data = j.read()
    except FileNotFoundError:
        return 0
    records: list[tuple[int, bytes]] = []
    size = None
    if len(data) >= _HEAD.size:
        magic, size = _HEAD.unpack_from(data, 0)
        if magic != _MAGIC:
            size = None
    if size is not None:  # no valid header: cut at a commit, the partial is complete as it is
        pos = _HEAD.size
        while pos + _REC.size <= len(data):
            off, n, crc = _REC.unpack_from(data, pos)
            old = data[pos + _REC.size:pos + _REC.size + n]
            if len(old) != n or _record_crc(off, old) != crc:
                break
            records.append((off, old))
            pos += _REC.size + n
        fd = os.open(partial, os.O_RDWR)
        try:
            for off, old in reversed(records):
                os.pwrite(fd, old, off)
            if os.fstat(fd).st_size > size:
                os.ftruncate(fd, size)
            os.fsync(fd)
        finally:
            os.close(fd)
    os.remove(jpath)
    return len(records)


def journal_pending(partial: str) -> bool:
    """``partial`` has writes since its last commit (a killed writer's, or one in progress):
    its metadata may be half-written, so HDF5 must not read it before :func:`recover_journal`."""
    try:
        return os.path.getsize(partial + JOURNAL) > _HEAD.size
    except OSError:
        return False


def remove_journal(partial: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.remove(partial + JOURNAL)


class UndoableFile(io.RawIOBase):
    """The partial file as h5py sees it (driver ``fileobj``): writes since the last
    :meth:`commit` can be undone, in this process and after it was killed.

    HDF5 cannot recover from a failed write (disk full, file-size limit): its flush has already
    rewritten part of the file's metadata, the file no longer opens, and closing it crashes the
    process at exit (measured: ``synth`` under a file-size limit segfaulted). Here a failed write
    is recorded in :attr:`failed` (the writer checks it after every flush) and HDF5 is not told:
    it finishes its flush or close normally while the rest is discarded. Every write over bytes
    that existed at the last commit first keeps the old bytes (only metadata is rewritten: a few
    kB per frame), so :meth:`rollback` restores the file exactly as it was after the last
    complete frame.

    A kill (SIGKILL, OOM) in the middle of a flush leaves the same half-rewritten metadata, and
    HDF5 reading it crashed the resuming process (segfault, "addr overflow": 1 random kill in 84
    at 64x32), finished a file with a frame that failed its checksum, or raised
    (tests/test_undo_journal.py kills before every write of a flush). So the old bytes also go to a journal,
    ``<partial>.undo``, before the write that replaces them (each record a single ``write``:
    offset, length, CRC-32, the bytes), and :func:`recover_journal` applies it before the
    partial is reopened. A commit empties the journal and records the partial's size. The
    journal orders writes against a killed process, not against a power cut (no fsync per
    frame).
    """

    def __init__(self, path: str, create: bool):
        self._j: int | None = None
        self._f = open(path, "w+b" if create else "r+b", buffering=0)
        self._fd = self._f.fileno()
        self._size = os.fstat(self._fd).st_size
        self._undo: list[tuple[int, bytes]] = []
        self.failed: OSError | None = None
        self._jpath = path + JOURNAL
        self._jpos = 0
        try:
            self._j = os.open(self._jpath, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
            self._reset_journal()
        except OSError:
            self.close()
            raise

    def _reset_journal(self) -> None:
        """Empty the journal, then record the committed size (a kill between the two leaves an
        empty journal: nothing to undo, which is right, since the file is committed)."""
        os.ftruncate(self._j, 0)
        os.pwrite(self._j, _HEAD.pack(_MAGIC, self._size), 0)
        self._jpos = _HEAD.size

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        return self._f.readinto(b)

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._f.seek(pos, whence)

    def tell(self) -> int:
        return self._f.tell()

    def _keep(self, off: int, end: int) -> None:
        """Keep the committed bytes in [off, end) before they are overwritten (raises OSError
        when the journal cannot take them: the write must not happen then)."""
        end = min(end, self._size)
        if off < end:
            old = os.pread(self._fd, end - off, off)
            self._undo.append((off, old))
            rec = _REC.pack(off, len(old), _record_crc(off, old)) + old
            if os.pwrite(self._j, rec, self._jpos) != len(rec):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            self._jpos += len(rec)

    def write(self, b) -> int:
        if self.failed is not None:
            return len(b)
        mv = memoryview(b).cast("B")
        off = self._f.tell()
        done = 0
        try:
            self._keep(off, off + len(mv))
            while done < len(mv):
                k = self._f.write(mv[done:])
                if not k:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += k
        except OSError as e:  # kept for the writer; HDF5 is told nothing (see the class doc)
            self.failed = e
        return len(mv)

    def truncate(self, size: int | None = None) -> int:
        size = self._f.tell() if size is None else size
        if self.failed is not None:
            return size
        try:
            self._keep(size, self._size)
            return self._f.truncate(size)
        except OSError as e:
            self.failed = e
            return size

    def flush(self) -> None:
        pass  # unbuffered: every write is with the OS already

    def commit(self) -> None:
        """The file as it is now is complete (called after each frame's flush)."""
        if self.failed is None:
            self._undo.clear()
            self._size = os.fstat(self._fd).st_size
            try:
                self._reset_journal()
            except OSError as e:
                self.failed = e

    def rollback(self) -> None:
        """Put back the bytes of the last commit (after a failed write)."""
        for off, old in reversed(self._undo):
            os.pwrite(self._fd, old, off)
        os.ftruncate(self._fd, self._size)
        self._undo.clear()
        with contextlib.suppress(OSError):
            self._reset_journal()

    def close(self) -> None:
        """Close; the journal goes with it unless writes since the last commit remain."""
        if self._j is not None:
            os.close(self._j)
            self._j = None
            if not self._undo:   # committed or rolled back: nothing to undo
                with contextlib.suppress(FileNotFoundError):
                    os.remove(self._jpath)
        if not self._f.closed:
            self._f.close()
        super().close()
