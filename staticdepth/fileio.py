"""The one atomic writer, the one image reader and the one output lock.

Every command that writes a file goes through here:

- :func:`atomic_path` yields a temporary path beside the output; only when the ``with`` block ends
  without an exception is the file fsynced and renamed onto the output (``os.replace``), so the
  output is either the previous complete file or the new complete one, never a half-written one.
  The temporary file is removed on any error. Temporaries are named ``<out>.tmp-<pid>-<tag>`` and
  :func:`remove_stale_temporaries` deletes those whose process is gone.
- :func:`atomic_write_text` / :func:`atomic_write_bytes` / :func:`atomic_write_json` for small
  outputs.
- :func:`exclusive_lock` takes an exclusive, non-blocking ``fcntl`` lock on ``<out>.lock`` for the
  whole time a process writes ``out`` (or adds to it); a second writer gets one clear error line.
  The kernel drops the lock when the process dies (also on SIGKILL), so a crash never leaves a
  stale lock behind. A run whose output does not exist at the end (refused, failed,
  interrupted) removes the lock file, while it still holds the lock; every locker checks, once
  it holds a lock, that the file it locked is still the one at ``<out>.lock`` (else it opens
  the path again), so a removal never lets two processes hold "the" lock. Beside an output that
  exists the (empty) lock file stays.
- :func:`read_image` decodes an image file (missing, empty or undecodable: one
  :class:`InputError` naming it) and :func:`read_rgb` gives an 8-bit colour image as RGB; every
  command reads images through these two (the dataset importers, ``stereo``, ``calibrate``,
  ``capture``'s replay, masks).
- :func:`sorted_frames` is the one order of frame files listed from a folder (numbers by value:
  ``2.png`` before ``10.png``).
- :func:`os_error` turns an ``OSError`` into an :class:`InputError` naming the path and the
  problem (disk full, read-only, permission denied, is a folder, ...).
"""
from __future__ import annotations

import contextlib
import errno
import glob
import json
import os
import re
from typing import Any, Iterator

from staticdepth.errors import InputError

_TMP_RE = re.compile(r"\.tmp-(\d+)-[A-Za-z0-9_]*$")

_PROBLEMS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EISDIR: "is a folder, not a file",
    errno.ENOTDIR: "a parent of the path is not a folder",
    errno.ENOENT: "no such file or folder",
    errno.EFBIG: "file too large (file-size limit reached)",
    errno.ENAMETOOLONG: "file name too long",
    errno.EEXIST: "already exists",
}


# the file names the toolkit reads as images and as videos (folders, globs, inputs)
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")
VIDEO_EXTS = (".avi", ".mp4", ".mov", ".mkv", ".webm", ".m4v")

_DIGITS_RE = re.compile(r"(\d+)")
# binary files a user may give where a text or another file is expected: (signature, kind)
FILE_KINDS = ((b"\x89HDF\r\n\x1a\n", "hdf5"), (b"\x89PNG\r\n\x1a\n", "png"),
              (b"\xff\xd8\xff", "jpeg"), (b"PK\x03\x04", "zip"), (b"\x93NUMPY", "npy"))
KIND_NAMES = {"hdf5": "an HDF5 file (a sequence or a prediction?)", "png": "a PNG image",
              "jpeg": "a JPEG image", "zip": "a zip archive (a torch checkpoint?)",
              "npy": "a numpy array (.npy)"}


def file_kind(path: str | os.PathLike) -> str | None:
    """The kind of a binary file by its signature (a key of KIND_NAMES), else None (a text file,
    another binary, a folder or an unreadable path)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return None
    return next((kind for magic, kind in FILE_KINDS if head.startswith(magic)), None)


def not_text(expected: str, path: str | os.PathLike) -> str:
    """The problem of a binary file given where the text file ``expected`` is read: names its
    kind when known ('expected a JSON file, got a PNG image'; was the codec's byte 0x89)."""
    kind = file_kind(path)
    return f"expected {expected}, got {KIND_NAMES[kind] if kind else 'binary data'}"


def frame_order_key(name: str) -> tuple:
    """The sort key of frame files: numbers inside a name compare by value, the rest as text.

    ``1.png, 2.png, 10.png`` keep that order (plain ``sorted`` gives 1, 10, 2); zero-padded names
    (``00000009.png, 00000010.png``, what ``capture`` writes) keep theirs. The key is a total
    order: text and numbers alternate at fixed positions (``re.split`` with a group), so keys
    always compare, and equal values (``7`` and ``007``) fall back to the text of the number."""
    parts = _DIGITS_RE.split(os.fspath(name))
    return tuple((int(p), p) if i % 2 else p for i, p in enumerate(parts))


def sorted_frames(names) -> list:
    """The one frame order: ``names`` (file names or paths) sorted by :func:`frame_order_key`.
    Every listing of frames from a folder or a glob goes through it."""
    return sorted(names, key=frame_order_key)


def os_error(e: OSError, path: str | os.PathLike | None = None) -> InputError:
    """An :class:`InputError` for ``e``: ``<path>: <problem>``."""
    where = path if path is not None else (e.filename or None)
    problem = _PROBLEMS.get(e.errno or -1) or (e.strerror or str(e))
    return InputError(problem, where)


def _fsync_dir(path: str) -> None:
    try:
        fd = os.open(os.path.dirname(os.path.abspath(path)) or ".", os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def fsync_file(path: str | os.PathLike) -> None:
    """fsync a file and its folder (the folder entry matters for a rename to survive a crash)."""
    path = os.fspath(path)
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    _fsync_dir(path)


def temporary_path(path: str | os.PathLike, tag: str = "") -> str:
    """``<path>.tmp-<pid>-<tag>``: beside the output (same file system, so the rename is atomic)."""
    return f"{os.fspath(path)}.tmp-{os.getpid()}-{tag}"


def check_output_parent(path: str | os.PathLike) -> None:
    """Before any work: the folder that is to hold the output ``path`` (a file or a folder)
    exists. The one line for a missing one, naming it, for every output (the atomic writer's
    files, the sequence writers, ``export``, ``publish``; taking the output's lock first said "no
    such file or folder", the atomic writer "its folder does not exist")."""
    parent = os.path.dirname(os.path.abspath(os.fspath(path)))
    if not os.path.isdir(parent):
        raise InputError("output's parent does not exist (create that folder first)"
                         if not os.path.lexists(parent) else
                         "output's parent is not a folder", parent)


def _check_output_path(path: str) -> None:
    if os.path.isdir(path):
        raise InputError("is a folder, not a file (give a file name)", path)
    check_output_parent(path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, tag: str = "", *, fsync: bool = True) -> Iterator[str]:
    """Yield a temporary path; on success it is fsynced and renamed onto ``path``.

    On any exception the temporary file is removed and ``path`` is untouched; an ``OSError`` is
    re-raised as an :class:`InputError` naming ``path``.
    """
    path = os.fspath(path)
    _check_output_path(path)
    tmp = temporary_path(path, tag)
    try:
        yield tmp
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
        if fsync:
            _fsync_dir(path)
    except OSError as e:
        raise os_error(e, path) from e      # __cause__ keeps the errno (capture: disk full)
    finally:
        if os.path.lexists(tmp):
            with contextlib.suppress(OSError):
                os.remove(tmp)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def read_image(path: str | os.PathLike, *, flags: int | None = None):
    """The one image decoder: the file's pixels as OpenCV decodes them with ``flags``
    (``cv2.IMREAD_UNCHANGED`` when None: grey stays grey, 16-bit stays 16-bit, BGR order). A
    missing, unreadable, empty or undecodable file is an :class:`InputError` naming it."""
    import cv2
    import numpy as np

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("file not found", path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        raise os_error(e, path) from None
    if (data[:8].tobytes() == b"\x89PNG\r\n\x1a\n" and data[-8:-4].tobytes() != b"IEND"
            and data.tobytes().rfind(b"IEND", 8) < 0):
        # a cut PNG (its end chunk is last, or followed by appended bytes): said here, before
        # libpng prints a line of its own to stderr
        raise InputError("corrupt or unreadable image (a PNG cut short: no IEND chunk)", path)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED if flags is None else flags) \
        if data.size else None
    if img is None:
        raise InputError("corrupt or unreadable image", path)
    return img


def read_npy(path: str | os.PathLike):
    """The one ``.npy`` reader: the array in the file, never a pickle. A missing, empty,
    truncated, pickled or otherwise unreadable file is an :class:`InputError` naming it."""
    import numpy as np

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("is a folder, not a .npy file" if os.path.isdir(path)
                         else "file not found", path)
    try:
        return np.load(path, allow_pickle=False)
    except OSError as e:
        if e.errno is not None:
            raise os_error(e, path) from None
        raise InputError(f"not a readable .npy file ({e})", path) from None
    except (ValueError, EOFError) as e:
        if "allow_pickle" in str(e):
            raise InputError("not a readable .npy file (it holds pickled Python objects, which "
                             "are never loaded: save a numeric array)", path) from None
        raise InputError(f"not a readable .npy file ({e or 'empty file'})", path) from None


def read_rgb(path: str | os.PathLike):
    """An 8-bit image as RGB (H, W, 3) uint8: grey is repeated to 3 channels, alpha is dropped.

    Anything but 8 bits per channel is refused, not scaled: OpenCV's own conversion divides a
    16-bit image by 256, which leaves 12-bit sensor data (0-4095) at 0-15, too dark to match or
    to detect a chessboard in, without a word."""
    import numpy as np

    img = read_image(path)
    if img.dtype != np.uint8:
        raise InputError(f"expected an 8-bit image, got {img.dtype} (convert it to 8 bits per "
                         "channel first)", path)
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2)
    if img.shape[2] == 4:
        img = img[..., :3]
    elif img.shape[2] == 1:
        return np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[..., ::-1])


def write_image(path: str | os.PathLike, image, *, fsync: bool = True) -> None:
    """The one image writer: encode ``image`` in memory in the format of ``path``'s suffix (PNG
    when there is none) and write it atomically. A 3-channel image is RGB (as everywhere in
    the toolkit; OpenCV's BGR stays inside); 1-channel uint8/uint16 images are written as they
    are. Encoding in memory makes a full disk an ``OSError`` named by :func:`os_error`
    (``cv2.imwrite`` only returns False)."""
    import cv2
    import numpy as np

    path = os.fspath(path)
    ext = os.path.splitext(path)[1] or ".png"
    a = np.asarray(image)
    try:
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(a[..., ::-1] if a.ndim == 3 else a))
    except cv2.error:               # an unknown suffix, or a dtype/shape the format cannot hold
        ok = False
    if not ok:
        raise InputError(f"cannot encode an image as {ext}", path)
    with atomic_path(path, fsync=fsync) as tmp:
        with open(tmp, "wb") as f:
            f.write(buf.tobytes())


def atomic_torch_save(path: str | os.PathLike, obj, tag: str = "") -> None:
    """``torch.save(obj)`` atomically (weights, checkpoints); torch is imported here, not at
    start-up."""
    import torch

    with atomic_path(path, tag) as tmp, open(tmp, "wb") as f:   # open() errors are OSErrors
        torch.save(obj, f)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any, *, indent: int = 2) -> None:
    atomic_write_text(path, json.dumps(obj, indent=indent, sort_keys=False) + "\n")


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(path: str | os.PathLike) -> list[str]:
    """Delete ``<path>.tmp-<pid>-*`` files (or folders) whose process no longer exists."""
    import shutil

    removed = []
    for p in glob.glob(glob.escape(os.fspath(path)) + ".tmp-*"):
        m = _TMP_RE.search(p)
        if not m or _pid_alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            if os.path.isdir(p) and not os.path.islink(p):
                shutil.rmtree(p)
            else:
                os.remove(p)
            removed.append(p)
    return removed


class OutputLocked(InputError):
    """Another process holds the output's lock."""


@contextlib.contextmanager
def exclusive_lock(path: str | os.PathLike, *, what: str = "writing") -> Iterator[None]:
    """Hold an exclusive lock on ``<path>.lock`` for the block; fail at once if another holds it.

    Re-entrant within one process for the same path (a command that locks an output and then
    calls a library function that locks it again does not deadlock itself). When ``path`` does
    not exist at the end, the lock file is removed (see the module doc for why that is safe).
    """
    import fcntl

    path = os.path.abspath(os.fspath(path))
    if path in _HELD:
        _HELD[path] += 1
        try:
            yield
        finally:
            _HELD[path] -= 1
        return
    lock = path + ".lock"
    check_output_parent(path)      # the one line for a missing folder ('no such file or folder')
    fd = _lock_file(lock, path, what)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        _HELD[path] = 1
        try:
            yield
        finally:
            del _HELD[path]
            with contextlib.suppress(OSError):
                if os.path.lexists(path):
                    os.ftruncate(fd, 0)
                else:   # nothing was made: no lock file beside a missing output. Removed while
                    os.unlink(lock)     # held: a waiting locker finds its file gone and retries
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


_HELD: dict[str, int] = {}


def _lock_file(lock: str, path: str, what: str) -> int:
    """Open ``lock`` and take its exclusive lock; the descriptor. Another holder is an
    :class:`OutputLocked`. A lock taken on a file that its holder removed in the meantime (see
    :func:`exclusive_lock`) is no lock: then the path is opened again."""
    import fcntl

    for _ in range(100):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            # the user named the output, not its lock: a missing folder is the output's problem
            raise os_error(e, path if e.errno == errno.ENOENT else lock) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            except OSError:
                holder = "?"
            os.close(fd)
            raise OutputLocked(f"another staticdepth process (pid {holder}) is {what} this file; "
                               "wait for it to finish or stop it", path) from None
        try:
            if os.path.samestat(os.fstat(fd), os.stat(lock)):
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)                    # closing drops the lock on the removed file
    raise OutputLocked(f"its lock file {lock} keeps being replaced; another process is {what} "
                       "this file", path)


def check_writable(path: str | os.PathLike) -> None:
    """Before any heavy work: can a file be written at ``path``? Not a folder, its folder exists,
    and a file can be created there (a probe ``<path>.tmp-<pid>-probe``, removed at once).
    Raises :class:`InputError` naming ``path`` (read-only, permission denied, ...)."""
    path = os.fspath(path)
    _check_output_path(path)
    probe = temporary_path(path, "probe")
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except OSError as e:
        raise os_error(e, path) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.remove(probe)
