"""The sequence writer: frames appended to ``<out>.partial``, renamed onto ``<out>`` when complete.

Guarantees (see also :mod:`staticdepth.dataset.resume`):
- one writer per output (:func:`staticdepth.fileio.exclusive_lock` for the whole run); stale
  temporaries of dead processes are removed;
- the partial is flushed after every frame and reopens after SIGKILL; ``resume=True`` continues
  after the last complete frame (CRC-checked) only when the inputs and settings are the same;
  a leftover partial is never resumed or deleted unasked (``restart=True`` starts over);
- a failed write (disk full, file-size limit, read-only) rolls the partial back to the last
  complete frame and raises one line; the previous ``<out>`` is untouched;
- ``overwrite`` replaces only a sequence file;
- SIGTERM ends the run like Ctrl-C (the partial is closed for ``--resume``).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import sys
import threading
import time
from typing import Any, Iterable, Mapping, Sequence

import h5py
import numpy as np

from staticdepth.dataset import resume as rs
from staticdepth.dataset import schema
from staticdepth.dataset.h5 import (PARTIAL_SUFFIX, SequenceMeta, _compression, _frame_checksum,
                                    _fsync_path)
from staticdepth.dataset.integrity import ATTRS_CRC, attrs_checksum
from staticdepth.errors import InputError


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


def check_sequence_output(path: str | os.PathLike) -> None:
    """Before any work: the one rule for the ``--out`` of every sequence writer (import-video,
    import-kitti, import-carla, pack, synth): a sequence file's name ends in ``.h5`` (an HDF5
    file named ``x.png`` was written without a word). A file that is there already and is no
    sequence is said to be left untouched first (what ``--overwrite`` onto it says)."""
    path = os.fspath(path)
    if not path.endswith(".h5"):
        if os.path.lexists(path):
            check_replaceable_sequence(path)
        raise InputError("a sequence file's name must end in .h5 (--out)", path)


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
                 warn=print, resume_how: str = "--resume continues it"):
        """``settings``: what else changes the output (beside ``meta``); ``inputs``: one identity
        per input frame (:func:`staticdepth.dataset.resume.task_identity`), ``labels`` their names;
        both are stored and a ``resume`` with others is refused (see :mod:`.resume`).
        ``resume_how``: how this command continues a leftover partial (said when it is found)."""
        from staticdepth.fileio import exclusive_lock, remove_stale_temporaries

        self.path = os.fspath(path)
        self.partial = self.path + PARTIAL_SUFFIX
        self.meta = meta
        self.streams = tuple(streams)
        self.aux = {k: np.dtype(v) for k, v in (aux or {}).items()}  # extra maps: aux/<name>
        schema.check_name(meta.name)        # every writer: import-video, stereo, synth, ...
        unknown = set(self.streams) - set(schema.FRAME_STREAMS)
        if unknown or "left" not in self.streams:
            raise InputError(f"streams must include 'left' and be among {schema.FRAME_STREAMS}, "
                             f"got {self.streams}")
        if os.path.lexists(self.path) and not overwrite:
            raise InputError("exists already; pass --overwrite to replace it", self.path)
        self._warn = warn
        self._replaced = os.path.lexists(self.path)
        if self._replaced:
            check_replaceable_sequence(self.path)
        self._f: h5py.File | None = None
        self._io = None  # the partial's UndoableFile (see resume.py)
        self.n = 0
        self.resumed_from = 0
        self._fingerprint = rs.settings_fingerprint(meta.to_attrs(), self.streams, self.aux,
                                                    settings)
        self._inputs = None if inputs is None else list(inputs)
        self._busy, self._pending = False, None
        self._lock = contextlib.ExitStack()
        self._lock.enter_context(exclusive_lock(self.path, what="writing"))
        try:
            self._install_sigterm()
            remove_stale_temporaries(self.path)
            if os.path.exists(self.partial) and not (resume or restart):
                raise rs.leftover(self.partial, resume_how)
            opened = rs.open_partial(self.partial, warn) if resume and os.path.exists(
                self.partial) else None
            with self._writing():
                if opened is not None:
                    self._f, self._io = opened
                    self._resume(self._f, rs, labels)
                else:
                    self._create()
        except BaseException:
            self._close_file()
            self._restore_sigterm()
            self._lock.close()
            raise

    # -- setup ----------------------------------------------------------------------------------
    def _create(self) -> None:
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
        if stored != self.streams or stored_aux != sorted(self.aux):
            raise InputError(f"cannot resume: the partial file has streams {stored} and aux "
                             f"{stored_aux}, not {self.streams} and {sorted(self.aux)}",
                             self.partial)
        size = (int(f.attrs["width"]), int(f.attrs["height"]))
        if size != (self.meta.camera.width, self.meta.camera.height):
            raise InputError(f"cannot resume: the partial file's frames are {size[0]}x{size[1]}, "
                             f"these are {self.meta.camera.width}x{self.meta.camera.height} "
                             "(another --width or input?); --restart starts over", self.partial)
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
        """SIGTERM ends the run like Ctrl-C (the partial is flushed and closed for ``--resume``).
        A SIGTERM or Ctrl-C that arrives while a frame is being written waits until that frame
        is complete: HDF5 cannot recover from an exception raised inside its own write call."""
        self._old_handlers: dict[int, Any] = {}
        if threading.current_thread() is not threading.main_thread():
            return

        def on_signal(signum, frame):
            if self._busy:
                self._pending = signum
                return
            self._interrupt(signum)

        for sig, default in ((signal.SIGTERM, signal.SIG_DFL),
                             (signal.SIGINT, signal.default_int_handler)):
            if signal.getsignal(sig) is default:
                self._old_handlers[sig] = signal.signal(sig, on_signal)

    def _interrupt(self, signum: int) -> None:
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        print(f"terminated (SIGTERM): {self.partial} keeps {self.n} frames; run again with "
              "--resume to continue", file=sys.stderr, flush=True)
        raise SystemExit(128 + signal.SIGTERM)

    @contextlib.contextmanager
    def _writing(self):
        """A block that HDF5 writes in: signals wait for its end (see :meth:`_install_sigterm`)."""
        self._busy = True
        try:
            yield
        finally:
            self._busy = False
        if self._pending is not None:
            signum, self._pending = self._pending, None
            self._interrupt(signum)

    def _restore_sigterm(self) -> None:
        for sig, handler in getattr(self, "_old_handlers", {}).items():
            signal.signal(sig, handler)
        self._old_handlers = {}

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
            rs.remove_journal(self.partial)
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
            raise InputError(f"frame {self.n}: expected streams {self.streams}, "
                             f"got {sorted(frames)}")
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
        with self._writing():
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
            except (OSError, RuntimeError) as e:  # h5py raises RuntimeError for some
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
            rs.remove_journal(self.partial)
            self.abort()
            raise InputError("no frames were written", self.path)
        if self.meta.adapt_frames > self.n:
            self.abort()
            raise InputError(f"adapt_frames = {self.meta.adapt_frames} exceeds the "
                             f"{self.n} frames written", self.path)
        self._busy = True  # a signal now waits: the run is finishing (see _install_sigterm)
        try:
            for key in ("timestamps", "agents"):  # whole-dataset checksums (verify reads them)
                f[key].attrs["crc32"] = _frame_checksum(f[key][:])
            f.attrs["n_frames"] = self.n
            f.attrs["complete"] = True
            f.attrs[ATTRS_CRC] = attrs_checksum(f.attrs)      # the metadata, for verify
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
            if self._replaced:
                from staticdepth.dataset.predictions import remove_stale

                stale = remove_stale(self.path)
                if stale:
                    self._warn(f"removed the predictions of the sequence this file replaced "
                               f"(another sequence's, unreadable with it): {', '.join(stale)}")
        except (OSError, RuntimeError) as e:
            self.n = max(self.n, 1)
            self._fail(e)
        finally:
            self._busy = False
            self._restore_sigterm()
            self._lock.close()
        return self.path

    def abort(self, exc: BaseException | None = None) -> None:
        """Close without finishing: the ``.partial`` file stays for a later ``resume``. Stopped by
        Ctrl-C or SIGTERM (``exc``, else the exception being handled), it says on stderr what
        was kept and how to go on (the command's own "interrupted" line follows)."""
        exc = exc if exc is not None else sys.exc_info()[1]
        try:
            if self._f is not None:
                with contextlib.suppress(Exception):
                    self._f.flush()
                    self._f.close()  # a clean close: committed, the journal goes
                    self._f = None
                    self._commit()
            self._close_file()
        finally:
            self._restore_sigterm()
            self._lock.close()
        if isinstance(exc, KeyboardInterrupt) and os.path.exists(self.partial):
            print(f"note: {self.partial} keeps the {self.n} frame(s) written; the same command "
                  f"with --resume continues it, --restart starts over", file=sys.stderr)

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
            return
        self.abort(exc)
