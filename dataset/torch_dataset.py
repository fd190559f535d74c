"""A sequence file as a PyTorch ``Dataset`` that reads one frame at a time.

The HDF5 file is opened lazily in each process that reads (DataLoader workers included), never
loaded whole and never pickled: the dataset object carries only the path, the frame indices and
the camera.
"""
from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError


class SequenceDataset(Dataset):
    """Frames of one split of a sequence file.

    ``ds[k]`` is a dict for the k-th frame of the split:
    ``image`` (3, H, W) float32 in [0, 1] (the left view), ``right`` (3, H, W) when asked for,
    ``depth`` (1, H, W) float32 metres with NaN = unknown, ``instances`` (H, W) int64 when asked
    for, ``K`` (3, 3) float32, ``index`` (frame number in the file), ``split`` ("adapt"/"eval").
    """

    def __init__(self, path: str | os.PathLike, split: str = "all",
                 streams: Sequence[str] = ("left", "depth")):
        self.path = os.fspath(path)
        with SequenceReader(self.path) as r:
            self.indices = list(r.split(split))
            missing = [s for s in streams if not r.has(s)]
            if missing:
                raise InputError(f"sequence has no stream(s) {missing} (has {r.streams()})",
                                 self.path)
            self.camera = r.camera
            self.adapt_frames = r.meta.adapt_frames
            self.camera_height_m = r.meta.camera_height_m
        self.split = split
        self.streams = tuple(streams)
        self._K = torch.tensor(np.array(self.camera.K), dtype=torch.float32)
        self._reader: SequenceReader | None = None
        self._pid: int | None = None

    def _open(self) -> SequenceReader:
        if self._reader is None or self._pid != os.getpid():
            self._reader = SequenceReader(self.path)
            self._pid = os.getpid()
        return self._reader

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, k: int) -> dict[str, Any]:
        i = self.indices[k]
        r = self._open()
        out: dict[str, Any] = {"index": i, "split": "adapt" if i < self.adapt_frames else "eval",
                               "K": self._K.clone()}
        for s in self.streams:
            a = r.read(s, i)
            if s in ("left", "right"):
                t = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1))).float() / 255.0
                out["image" if s == "left" else "right"] = t
            elif s == "depth":
                out["depth"] = torch.from_numpy(np.asarray(a, np.float32))[None]
            else:
                out[s] = torch.from_numpy(a.astype(np.int64))
        return out

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_reader"] = None  # each worker opens its own handle
        state["_pid"] = None
        return state

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
