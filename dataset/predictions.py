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

The files are :mod:`staticdepth.dataset.framefile` files, the same mechanism the adaptation
stages use for their own per-frame arrays (instance maps, inverse depths, labels).
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import re
from typing import Any, Iterable, Mapping

import h5py
import numpy as np

from staticdepth.dataset.framefile import (PARTIAL, FrameFile, FrameFileWriter,  # noqa: F401
                                           frame_checksum, is_complete)
from staticdepth.errors import InputError
from staticdepth.fileio import exclusive_lock, remove_stale_temporaries

STORE_SUFFIX = ".pred"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")


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
            ds = f["crc32"][name]
            if not isinstance(ds, h5py.Dataset):  # crc32/aux/..., crc32/pred/...: not streams
                continue
            h.update(name.encode())
            h.update(np.asarray(ds[:], dtype="<u4").tobytes())
    return h.hexdigest()[:32]


def sequence_id_of(seq_path: str | os.PathLike) -> str:
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(seq_path) as r:
        return r.sequence_id()


# -- predictions of a sequence ---------------------------------------------------------------------
def prediction_names(seq_path: str | os.PathLike) -> list[str]:
    """Names of the complete sidecar predictions (``.partial`` and lock files are not listed)."""
    folder = store_dir(seq_path)
    if not os.path.isdir(folder):
        return []
    return sorted(os.path.basename(p)[:-3] for p in glob.glob(os.path.join(glob.escape(folder),
                                                                          "*.h5")))


def remove_stale(seq_path: str | os.PathLike) -> list[str]:
    """Delete the sidecar predictions that belong to another sequence than ``seq_path`` now
    holds (a sequence replaced with ``--overwrite``: the reader refuses them and ``verify``
    would fail the new file for them); those of identical content stay. Returns their names."""
    names = prediction_names(seq_path)
    if not names:
        return []
    sid = sequence_id_of(seq_path)
    stale = []
    for name in names:
        path = prediction_path(seq_path, name)
        try:
            with h5py.File(path, "r") as f:
                other = f.attrs.get("sequence_id")
        except OSError:
            continue                      # unreadable: verify names it; never deleted here
        if other is not None and str(other) != sid:
            os.remove(path)
            stale.append(name)
    return stale


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
    from staticdepth.dataset.resume import remove_journal
    from staticdepth.fileio import OutputLocked

    folder = store_dir(seq_path)
    removed: list[str] = []
    for part in glob.glob(os.path.join(glob.escape(folder), "*.h5" + PARTIAL)):
        final = part[:-len(PARTIAL)]
        removed += remove_stale_temporaries(final)
        try:
            with exclusive_lock(final):
                os.remove(part)
                remove_journal(part)
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
                        ok = frame_checksum(ff._ds[i]) == int(crc[i])   # unchecked read
                    except (OSError, ValueError) as e:
                        bad.append(f"{tag}[{i}]: unreadable ({e})")
                        continue
                    if not ok:
                        bad.append(f"{tag}[{i}]: checksum mismatch")
        except InputError as e:
            bad.append(f"{tag}: {e.problem}")
    return bad
