"""What every stage shares: the workspace (sequence, prediction store, stage files) and the
agents' per-frame instance maps and rows."""
from __future__ import annotations

import os
from typing import Callable

import numpy as np

from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.predictions import (FrameFile, FrameFileWriter, is_complete,
                                             prediction_path, prediction_writer)

WORK_SUFFIX = ".adapt"     # <SEQ>.h5.adapt/: the stages' own files (instance maps, labels, ...)


class Workspace:
    """One sequence being adapted: its size, camera, splits, identity, and where stages write.

    ``frames[stage]`` counts the frames each stage computed in this run and ``skipped`` lists the
    stages found up to date (the summary reports both).
    """

    def __init__(self, seq_path: str | os.PathLike, log: Callable[[str], None] = print):
        self.seq = os.fspath(seq_path)
        with SequenceReader(self.seq) as r:
            self.n, self.height, self.width = r.n_frames, r.height, r.width
            self.K = r.camera.K
            self.adapt_split = r.split("adapt")
            self.camera_height_m = r.meta.camera_height_m
            self.has_instances = r.has("instances")
            self.identity = r.sequence_id()
        self.dir = self.seq + WORK_SUFFIX
        self.log = log
        self.frames: dict[str, int] = {}
        self.skipped: list[str] = []

    def reader(self) -> SequenceReader:
        return SequenceReader(self.seq)

    def path(self, name: str) -> str:
        return os.path.join(self.dir, name)

    def count(self, stage: str, k: int = 1) -> None:
        self.frames[stage] = self.frames.get(stage, 0) + k

    def skip(self, stage: str, why: str = "up to date") -> None:
        self.skipped.append(stage)
        self.log(f"{stage}: {why}, skipped")

    def frame_writer(self, name: str, *, n: int, shape, dtype, config_hash: str, rows_dtype=None,
                     chunk: int = 1, attrs=None) -> FrameFileWriter:
        return FrameFileWriter(self.path(name), n=n, shape=shape, dtype=dtype,
                               identity=self.identity, config_hash=config_hash,
                               rows_dtype=rows_dtype, chunk=chunk, attrs=attrs)

    def frame_file(self, name: str) -> FrameFile:
        return FrameFile(self.path(name), self.identity)

    def pred_writer(self, name: str, config_hash: str, attrs=None, chunk: int = 1,
                    rewrite: bool = False) -> FrameFileWriter:
        return prediction_writer(self.seq, name, n=self.n, height=self.height, width=self.width,
                                 identity=self.identity, attrs=attrs, config_hash=config_hash,
                                 chunk=chunk, rewrite=rewrite)

    def pred_done(self, name: str, config_hash: str) -> bool:
        return is_complete(prediction_path(self.seq, name), self.identity, config_hash)


class RowIndex:
    """Per-frame lookup of a table of rows with a ``frame`` field (read once: rows are small)."""

    def __init__(self, rows: np.ndarray, n: int):
        order = np.argsort(rows["frame"], kind="stable")
        self.rows = rows[order]
        self.bounds = np.searchsorted(self.rows["frame"], np.arange(n + 1))

    def __call__(self, i: int) -> np.ndarray:
        return self.rows[self.bounds[i]:self.bounds[i + 1]]


class Agents:
    """Instance maps and agent rows per frame: the sequence's own (detector ``gt``) or the agents
    stage's file ``agents.h5``."""

    def __init__(self, ws: Workspace, detector: str):
        self._reader = self._file = None
        if detector == "gt":
            self._reader = ws.reader()
            self.instances = self._reader.instances
            rows = self._reader.agents()
        else:
            self._file = ws.frame_file("agents.h5")
            self.instances = self._file.__getitem__
            rows = self._file._f["rows"][:]
        self.rows = RowIndex(rows, ws.n)

    def close(self) -> None:
        for h in (self._reader, self._file):
            if h is not None:
                h.close()

    def __enter__(self) -> "Agents":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

