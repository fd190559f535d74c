"""The sequence file: one HDF5 file per sequence (schema in ``staticdepth.dataset.schema``).

This module and its helpers (``writer``: :class:`SequenceWriter`; ``resume``; ``integrity``) alone
talk to h5py. Guarantees:
- a writer builds ``<out>.partial`` and only a finished file is renamed onto ``<out>`` (after the
  ``complete`` attribute is set, flushed and fsynced), so a killed write leaves either the previous
  complete file or nothing at ``<out>``, and the ``.partial`` file is rejected by the reader;
- ``SequenceWriter(..., resume=True)`` continues a ``.partial`` file after the last frame that was
  fully written, also after SIGKILL, and only with the same inputs and settings;
- the reader refuses data from other files (external links, external storage, virtual datasets)
  and ``checksum_errors`` covers every dataset;
- one frame per chunk, so reading frame i decodes frame i only;
- predictions are separate files beside the sequence (:func:`add_prediction`,
  :mod:`staticdepth.dataset.predictions`); legacy in-file ``pred/<name>`` groups are still read.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, Mapping

import h5py
import numpy as np

from staticdepth import __version__
from staticdepth.dataset import schema
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, Mounting, StereoRig, check_camera_height

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
        elif self.camera_height_m is not None:
            object.__setattr__(self, "camera_height_m",
                               check_camera_height(self.camera_height_m, "camera_height_m"))

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
            if not np.isnan(h):
                h = check_camera_height(h, "the camera_height_m attribute", path)
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


def __getattr__(name: str):
    # The writer lives in its own module (it imports this one); ``from staticdepth.dataset.h5
    # import SequenceWriter`` keeps working.
    if name in ("SequenceWriter", "check_replaceable_sequence"):
        from staticdepth.dataset import writer

        return getattr(writer, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
        except InputError:
            self._f.close()
            raise
        except (KeyError, RuntimeError, OSError, ValueError, TypeError, OverflowError) as e:
            # h5py's errors on a damaged header or attribute ("exponent range out of bounds",
            # "integer offset out of bounds"): the file, not a bug
            self._f.close()
            raise InputError(f"corrupt sequence file ({type(e).__name__}: {e})",
                             self.path) from None

    def _check(self) -> None:
        from staticdepth.dataset.integrity import link_problems, size_problem

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
        too_big = size_problem(f["agents"]) if "agents" in f else None
        if too_big:
            raise InputError(too_big, p)
        if self.meta.adapt_frames > n:
            raise InputError(f"adapt_frames {self.meta.adapt_frames} > {n} frames", p)
        if (self.meta.camera.width, self.meta.camera.height) != (w, h):
            raise InputError("camera size differs from the frame size", p)
        for name in (sorted(f["aux"]) if "aux" in f else []):
            if f[f"aux/{name}"].shape != (n, h, w):
                raise InputError(f"aux map {name!r} has shape {f[f'aux/{name}'].shape}", p)
        for name in self._legacy_predictions():
            if f[f"pred/{name}/depth"].shape != (n, h, w):
                raise InputError(f"prediction {name!r} has shape {f[f'pred/{name}/depth'].shape}", p)
        self.n_frames, self.width, self.height = n, w, h
        self._crc: dict[str, np.ndarray | None] = {}

    # -- access ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.n_frames

    def __enter__(self) -> "SequenceReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for side in self.__dict__.pop("_sidecars", {}).values():
            if side is not None:
                side.close()
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
        """``key[i]``, checked against its stored checksum; a corrupt chunk (h5py's OSError) or
        a frame whose bytes changed is an InputError naming file and frame (every command reads
        through here: a damaged frame never reaches evaluation, training or an export)."""
        i = self._index(i)
        try:
            a = self._f[key][i]
        except OSError as e:
            raise InputError(f"{key} frame {i} is unreadable, the file is damaged "
                             f"({str(e).strip() or type(e).__name__}); check it with "
                             "'staticdepth verify'", self.path) from None
        crc = self._checksums(key)
        if crc is not None and i < len(crc) and _frame_checksum(a) != int(crc[i]):
            raise InputError(f"{key} frame {i} does not match its checksum, the file is damaged; "
                             "check it with 'staticdepth verify'", self.path)
        return a

    def _checksums(self, key: str) -> np.ndarray | None:
        """The stored per-frame checksums of ``key`` (read once), None for a file without."""
        if key not in self._crc:
            name = f"crc32/{key}"
            self._crc[key] = self._f[name][:] if name in self._f else None
        return self._crc[key]

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

    # -- predictions: sidecar files <SEQ>.h5.pred/<name>.h5 (dataset/predictions.py) and legacy
    # in-file pred/<name> groups; a sidecar file wins over an in-file group of the same name
    def sequence_id(self) -> str:
        from staticdepth.dataset.predictions import sequence_id

        if getattr(self, "_sid", None) is None:
            self._sid = sequence_id(self._f)
        return self._sid

    def _legacy_predictions(self) -> list[str]:
        if "pred" not in self._f:
            return []
        return sorted(k for k in self._f["pred"] if "depth" in self._f["pred"][k])

    def _sidecar(self, name: str):
        from staticdepth.dataset.predictions import FrameFile, prediction_names, prediction_path

        cache = self.__dict__.setdefault("_sidecars", {})   # name -> open file, or None (none)
        if name in cache:
            return cache[name]
        if name not in prediction_names(self.path):
            if name in self._legacy_predictions():
                cache[name] = None                            # an in-file group: stop looking
            return None
        cache[name] = FrameFile(prediction_path(self.path, name), self.sequence_id(),
                                (self.n_frames, self.height, self.width))
        return cache[name]

    def predictions(self) -> list[str]:
        from staticdepth.dataset.predictions import prediction_names

        return sorted(set(self._legacy_predictions()) | set(prediction_names(self.path)))

    def prediction(self, name: str, i: int) -> np.ndarray:
        side = self._sidecar(name)
        if side is not None:
            return side[self._index(i)]
        key = f"pred/{name}/depth"
        if key not in self._f:
            raise InputError(f"sequence has no prediction {name!r} (has {self.predictions()})",
                             self.path)
        return self._f[key][self._index(i)]

    def prediction_attrs(self, name: str) -> dict[str, Any]:
        side = self._sidecar(name)
        if side is not None:
            return side.attrs
        if f"pred/{name}" not in self._f:
            raise InputError(f"sequence has no prediction {name!r} (has {self.predictions()})",
                             self.path)
        return dict(self._f[f"pred/{name}"].attrs)

    def checksum_errors(self) -> list[str]:
        """Recompute the checksum of every dataset (frames, timestamps, agents, aux maps,
        predictions); a line per mismatch or dataset without one (empty when intact)."""
        from staticdepth.dataset.integrity import checksum_problems

        return checksum_problems(self._f)


def add_prediction(path: str | os.PathLike, name: str, depth_maps: Iterable[np.ndarray],
                   attrs: Mapping[str, Any] | None = None, *, overwrite: bool = True) -> None:
    """Store the prediction ``name`` ((H, W) float32 per frame) of a complete sequence file.

    Written frame by frame into its own file ``<path>.pred/<name>.h5``
    (:mod:`staticdepth.dataset.predictions`); the sequence file itself is never rewritten.
    """
    from staticdepth.dataset.predictions import write_prediction

    path = os.fspath(path)
    if not overwrite:
        with SequenceReader(path) as r:
            if name in r.predictions():
                raise InputError(f"prediction {name!r} already exists", path)
    write_prediction(path, name, depth_maps, attrs)
