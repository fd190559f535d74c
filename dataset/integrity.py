"""What ``verify`` checks in a sequence file (and what the reader refuses): links and checksums.

Checksum convention (every writer follows it):

- a per-frame dataset ``D`` (frames along axis 0: ``left``, ``depth``, ``aux/ground``,
  ``pred/<name>/depth``, a prediction file's ``depth``) has ``crc32/D``: one CRC-32 per frame;
- any other dataset (``timestamps``, ``agents``) has an attribute ``crc32`` over all its bytes;
- the file's own attributes (camera, rig, split, provenance, ...) have ``attrs_crc32``, the
  CRC-32 of every other root attribute (:func:`attrs_checksum`), set when the writer finishes.

:func:`checksum_problems` recomputes them all and names every dataset without one ("not covered
by a checksum": a file of an older version), so nothing passes unchecked.

Links: a sequence file must be self-contained. External links, datasets whose data lives in
external files, virtual datasets with sources in other files, and soft links that do not resolve
to an object of this file are refused (:func:`link_problems`), by ``verify`` and by
``SequenceReader`` (so that ``export`` never copies another file's images).
"""
from __future__ import annotations

import zlib

import h5py
import numpy as np

#: Bookkeeping datasets that are not data (the checksums themselves, the resume fingerprint).
BOOKKEEPING = ("crc32/", "fingerprint/")


def checksum(a: np.ndarray) -> int:
    """CRC-32 of an array's bytes (C order)."""
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).data) & 0xFFFFFFFF


def link_problems(f: h5py.File) -> list[str]:
    """Every link or dataset of ``f`` that points outside it (empty when self-contained)."""
    problems: list[str] = []

    def visit(name: str, link) -> None:
        if isinstance(link, h5py.ExternalLink):
            problems.append(f"{name}: external link to {link.filename}:{link.path} (refused: a "
                            "sequence file must hold its own data)")
        elif isinstance(link, h5py.SoftLink):
            target = f.get(link.path, getlink=True)
            if not isinstance(target, h5py.HardLink):
                problems.append(f"{name}: soft link to {link.path}, which is not an object of "
                                "this file (refused)")
        else:
            obj = f.get(name)
            if isinstance(obj, h5py.Dataset):
                if obj.external:
                    problems.append(f"{name}: its data is stored in external file(s) "
                                    f"{sorted({e[0] for e in obj.external})} (refused)")
                if obj.is_virtual:
                    files = sorted({m.file_name for m in obj.virtual_sources()} - {"."})
                    if files:
                        problems.append(f"{name}: virtual dataset reading {files} (refused)")

    _visit_links(f, "", visit)
    return problems


def _visit_links(group: h5py.Group, prefix: str, visit, depth: int = 0) -> None:
    """Every link under ``group`` (``Group.visititems_links`` needs h5py 3.11; we allow 3.8)."""
    for name in group:
        link = group.get(name, getlink=True)
        visit(prefix + name, link)
        if isinstance(link, h5py.HardLink) and depth < 32:
            obj = group.get(name)
            if isinstance(obj, h5py.Group):
                _visit_links(obj, f"{prefix}{name}/", visit, depth + 1)


def _datasets(f: h5py.File) -> list[str]:
    names: list[str] = []
    f.visititems(lambda k, v: names.append(k) if isinstance(v, h5py.Dataset) else None)
    return sorted(n for n in names if not n.startswith(BOOKKEEPING))


#: The root attribute holding :func:`attrs_checksum`.
ATTRS_CRC = "attrs_crc32"
#: A dataset read whole may claim at most this many times its stored bytes (gzip's ceiling is
#: about 1030:1): a header corrupted into a billion rows is refused before it is allocated.
MAX_EXPANSION = 2000


def attrs_checksum(attrs) -> int:
    """CRC-32 over the root attributes but :data:`ATTRS_CRC`, in key order, as h5py reads them
    back (strings as UTF-8, numbers and arrays as their dtype, shape and bytes)."""
    crc = 0
    for k in sorted(attrs):
        if k == ATTRS_CRC:
            continue
        v = attrs[k]
        if isinstance(v, bytes):
            data = b"b" + v
        elif isinstance(v, str):
            data = b"s" + v.encode("utf-8", "surrogatepass")
        else:
            a = np.asarray(v)
            data = (repr(a.tolist()).encode() if a.dtype.kind == "O"
                    else f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
        crc = zlib.crc32(k.encode() + b"\0" + data + b"\0", crc)
    return crc & 0xFFFFFFFF


def attrs_problem(f: h5py.File) -> str | None:
    """The line for root attributes that differ from their checksum, or that have none."""
    if ATTRS_CRC not in f.attrs:
        return ("file attributes: not covered by a checksum (written by an older version; not "
                "verified)")
    if int(f.attrs[ATTRS_CRC]) != attrs_checksum(f.attrs):
        return "file attributes: checksum mismatch (the camera, split or other metadata changed)"
    return None


def size_problem(ds: h5py.Dataset) -> str | None:
    """A dataset whose shape claims far more bytes than the file stores for it (a corrupted
    header), before anything reads it whole."""
    stored = ds.id.get_storage_size()
    if ds.nbytes > max(1 << 20, MAX_EXPANSION * stored):
        return (f"{ds.name.lstrip('/')}: shape {ds.shape} claims {ds.nbytes} bytes but the file "
                f"stores {stored} (corrupt header)")
    return None


def checksum_problems(f: h5py.File, limit: int = 100) -> list[str]:
    """Recompute the root attributes' and every dataset's stored checksums; a line per mismatch
    or uncovered part."""
    attrs = attrs_problem(f)
    bad: list[str] = [attrs] if attrs else []
    for name in _datasets(f):
        ds = f[name]
        crc_key = f"crc32/{name}"
        try:
            if crc_key in f:
                stored = f[crc_key][:]
                if len(stored) != len(ds):
                    bad.append(f"{name}: {len(stored)} checksums for {len(ds)} frames")
                    continue
                for i in range(len(ds)):
                    try:
                        a = ds[i]
                    except (OSError, ValueError) as e:
                        bad.append(f"{name}[{i}]: unreadable ({e})")
                        continue
                    if checksum(a) != int(stored[i]):
                        bad.append(f"{name}[{i}]: checksum mismatch")
            elif "crc32" in ds.attrs:
                too_big = size_problem(ds)
                if too_big:
                    bad.append(too_big)
                elif checksum(ds[()]) != int(ds.attrs["crc32"]):
                    bad.append(f"{name}: checksum mismatch")
            else:
                bad.append(f"{name}: not covered by a checksum (written by an older version; "
                           "not verified)")
        except (OSError, ValueError, KeyError, RuntimeError, TypeError) as e:
            bad.append(f"{name}: unreadable ({e})")
        if len(bad) >= limit:
            break
    return bad
