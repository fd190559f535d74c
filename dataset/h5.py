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

import json
import os
import shutil
import time
import zlib
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, Mapping

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
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).data) & 0xFFFFFFFF


class SequenceWriter:
    """Append frames to a new sequence file; finish atomically.

    >>> with SequenceWriter("seq.h5", meta, streams=("left", "depth")) as w:
    ...     w.append(left=rgb, depth=depth, timestamp=t)

    Leaving the ``with`` block through an exception keeps ``seq.h5.partial`` for ``resume=True``
    and does not touch ``seq.h5``.
    """

    def __init__(self, path: str | os.PathLike, meta: SequenceMeta,
                 streams: Iterable[str] = ("left", "depth"), *, resume: bool = False,
                 overwrite: bool = False, aux: Mapping[str, Any] | None = None):
        self.path = os.fspath(path)
        self.partial = self.path + PARTIAL_SUFFIX
        self.meta = meta
        self.streams = tuple(streams)
        self.aux = {k: np.dtype(v) for k, v in (aux or {}).items()}  # extra maps: aux/<name>
        unknown = set(self.streams) - set(schema.FRAME_STREAMS)
        if unknown or "left" not in self.streams:
            raise InputError(f"streams must include 'left' and be among {schema.FRAME_STREAMS}, "
                             f"got {self.streams}")
        if os.path.exists(self.path) and not overwrite:
            raise InputError("output exists (use --overwrite to replace it)", self.path)
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise InputError("output folder does not exist", parent)
        self._f: h5py.File | None = None
        self.n = 0
        if resume and os.path.exists(self.partial):
            self._open_resume()
        else:
            self._create()

    # -- setup ----------------------------------------------------------------------------------
    def _create(self) -> None:
        f = h5py.File(self.partial, "w", libver="latest")
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
        self._f = f

    def _open_resume(self) -> None:
        try:
            f = h5py.File(self.partial, "a")
            n = int(f.attrs["n_written"])
            stored = tuple(json.loads(f.attrs["streams"]))
            stored_aux = json.loads(f.attrs.get("aux", "[]"))
        except (OSError, KeyError, ValueError):
            # The partial file itself was damaged by the interruption: start it again.
            os.remove(self.partial)
            self._create()
            return
        if (stored != self.streams or stored_aux != sorted(self.aux)
                or int(f.attrs["width"]) != self.meta.camera.width):
            f.close()
            raise InputError(f"cannot resume: the partial file has streams {stored} and aux "
                             f"{stored_aux}, not {self.streams} and {sorted(self.aux)}",
                             self.partial)
        for name in self.streams:
            f[name].resize(n, axis=0)
            f[f"crc32/{name}"].resize(n, axis=0)
        for name in self.aux:
            f[f"aux/{name}"].resize(n, axis=0)
        f["timestamps"].resize(n, axis=0)
        agents = f["agents"]
        keep = int(np.count_nonzero(agents["frame"][:] < n)) if len(agents) else 0
        agents.resize(keep, axis=0)
        self._f = f
        self.n = n

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
        for name in self.streams:
            a = np.asarray(frames[name])
            ds = f[name]
            if a.shape != ds.shape[1:]:
                raise InputError(f"frame {i}: {name} has shape {a.shape}, expected {ds.shape[1:]}")
            a = a.astype(ds.dtype, copy=False)
            ds.resize(i + 1, axis=0)
            ds[i] = a
            crc = f[f"crc32/{name}"]
            crc.resize(i + 1, axis=0)
            crc[i] = _frame_checksum(a)
        for name in self.aux:
            a = np.asarray(aux[name])
            ds = f[f"aux/{name}"]
            if a.shape != ds.shape[1:]:
                raise InputError(f"frame {i}: aux {name} has shape {a.shape}, "
                                 f"expected {ds.shape[1:]}")
            ds.resize(i + 1, axis=0)
            ds[i] = a.astype(ds.dtype, copy=False)
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
        self.n = i + 1
        f.attrs["n_written"] = self.n
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
            f.close()
            self._f = None
            os.remove(self.partial)
            raise InputError("no frames were written", self.path)
        if self.meta.adapt_frames > self.n:
            f.close()
            self._f = None
            raise InputError(f"adapt_frames = {self.meta.adapt_frames} exceeds the "
                             f"{self.n} frames written", self.path)
        f.attrs["n_frames"] = self.n
        f.attrs["complete"] = True
        f.flush()
        f.close()
        self._f = None
        _fsync_path(self.partial)
        os.replace(self.partial, self.path)
        _fsync_path(self.path)
        return self.path

    def abort(self) -> None:
        """Close without finishing: the ``.partial`` file stays for a later ``resume``."""
        if self._f is not None:
            self._f.flush()
            self._f.close()
            self._f = None

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
        f, p = self._f, self.path
        if f.attrs.get("format") != schema.FORMAT:
            raise InputError(f"not a staticdepth sequence (format attribute "
                             f"{f.attrs.get('format')!r})", p)
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

    def _read_frame(self, key: str, i: int) -> np.ndarray:
        """``key[i]``; a corrupt chunk (h5py's OSError) is an InputError naming file and frame."""
        i = self._index(i)
        try:
            return self._f[key][i]
        except OSError as e:
            raise InputError(f"{key} frame {i} is unreadable, the file is damaged "
                             f"({str(e).strip() or type(e).__name__}); check it with "
                             "'staticdepth verify'", self.path) from None

    def read(self, stream: str, i: int) -> np.ndarray:
        if stream not in self._f:
            raise InputError(f"sequence has no {stream!r} stream", self.path)
        return self._read_frame(stream, i)

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
        return self._read_frame(key, i)

    def timestamps(self) -> np.ndarray:
        return self._f["timestamps"][:]

    def agents(self, i: int | None = None) -> np.ndarray:
        """Agent rows of frame ``i`` (all frames when None)."""
        rows = self._f["agents"][:] if "agents" in self._f else schema.empty_agents(0)
        return rows if i is None else rows[rows["frame"] == self._index(i)]

    def frame(self, i: int) -> dict[str, Any]:
        i = self._index(i)
        out: dict[str, Any] = {s: self._read_frame(s, i) for s in self.streams()}
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
        """Recompute every frame's CRC-32; return a line per mismatch (empty when intact)."""
        bad = []
        for name in self.streams():
            key = f"crc32/{name}"
            if key not in self._f:
                bad.append(f"{name}: no checksums stored")
                continue
            stored = self._f[key][:]
            if len(stored) != self.n_frames:
                bad.append(f"{name}: {len(stored)} checksums for {self.n_frames} frames")
                continue
            ds = self._f[name]
            for i in range(self.n_frames):
                try:
                    a = ds[i]
                except (OSError, ValueError) as e:
                    bad.append(f"{name}[{i}]: unreadable ({e})")
                    continue
                if _frame_checksum(a) != int(stored[i]):
                    bad.append(f"{name}[{i}]: checksum mismatch")
        return bad


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
            for a, v in (attrs or {}).items():
                g.attrs[a] = v if isinstance(v, (int, float, str, np.number)) else json.dumps(v)
        _fsync_path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
