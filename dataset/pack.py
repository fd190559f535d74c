"""Pack frames into a sequence file: the writing loop every importer shares; stereo recordings.

Every importer (KITTI, CARLA, stereo recordings) turns its input into a list of *tasks* (one per
frame, picklable) and a pure *loader* ``load(task) -> LoadedFrame``. :func:`write_frames` runs the
loader over the tasks through an executor (serial, processes or Ray; results come back in frame
order) and appends them with one :class:`~staticdepth.dataset.h5.SequenceWriter`, so the output
does not depend on the executor. It

- resumes a killed run: frames already in ``<out>.partial`` are neither loaded nor written again;
- turns a bad frame into an :class:`InputError` naming the file, or with ``skip_bad`` into a
  listed, counted skip stored in the file's provenance (never a silently shorter sequence);
- stores extra per-frame boolean/integer maps under ``aux/<name>`` (e.g. CARLA's ground mask).

The stereo-recording packer (``staticdepth pack``) is :func:`pack_recording`: the per-frame work
(rectify, match, triangulate) is :class:`StereoLoader`, a pure function of (frame paths, rig,
stereo settings), so ``--workers N`` and ``--executor ray`` give the same file as a serial run.
Recordings are read in the ``staticdepth.capture`` layout (``manifest.json``, ``seg_NNNN/``) or the
plain layout ``DIR/left/*.png``, ``DIR/right/*.png`` (matched by name) with an optional
``DIR/timestamps.csv`` (one row per frame in frame order, the timestamp in seconds last).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.errors import InputError
# the toolkit's one image reader; the importers import it from here too
from staticdepth.fileio import read_image, read_rgb, sorted_frames  # noqa: F401
from staticdepth.progress import progress


def read_left_right(left_path: str | os.PathLike, right_path: str | os.PathLike | None,
                    size: tuple[int, int], size_source: str) -> dict[str, np.ndarray]:
    """``{"left": rgb[, "right": rgb]}``; the left image must be ``size`` = (W, H) (which
    ``size_source`` states, for the error) and the right image the left's size."""
    left = read_rgb(left_path)
    w, h = size
    if (left.shape[1], left.shape[0]) != (w, h):
        raise InputError(f"image is {left.shape[1]}x{left.shape[0]}, {size_source} {w}x{h}",
                         left_path)
    arrays = {"left": left}
    if right_path is not None:
        r = read_rgb(right_path)
        if r.shape != left.shape:
            raise InputError(f"right image is {r.shape[1]}x{r.shape[0]}, left is {w}x{h}",
                             right_path)
        arrays["right"] = r
    return arrays


def list_frames(folder: str | os.PathLike, ext: str = ".png") -> list[str]:
    """File names (not paths) with extension ``ext`` in ``folder`` (which must exist), in frame
    order (:func:`~staticdepth.fileio.sorted_frames`: ``2.png`` before ``10.png``)."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise InputError("folder not found", folder)
    return sorted_frames(n for n in os.listdir(folder) if n.lower().endswith(ext))


def no_frames_error(folder: str | os.PathLike, ext: str = ".png") -> InputError:
    """The error for a stream folder without ``ext`` frames, saying what it holds instead
    (``holds no .png files (it holds 4 .jpg files)``), not the output's "no frames to write"."""
    from collections import Counter

    folder = os.fspath(folder)
    kinds = Counter(os.path.splitext(n)[1].lower() or "extensionless" for n in os.listdir(folder))
    held = ", ".join(f"{k} {e}" for e, k in kinds.most_common(3)) + (
        ", ..." if len(kinds) > 3 else "")
    return InputError(f"holds no {ext} files ({f'it holds {held} files' if kinds else 'empty'})",
                      folder)


def match_streams(streams: Mapping[str, Sequence[str]], where: str) -> list[str]:
    """Frame stems present in every stream; an :class:`InputError` when the streams disagree.

    ``streams`` maps a stream's folder to its file names; the error names the folder and the first
    missing frame so that a user can find it.
    """
    stems = {k: [os.path.splitext(n)[0] for n in v] for k, v in streams.items()}
    common = sorted_frames(set.intersection(*(set(s) for s in stems.values())))
    for k, s in stems.items():
        if len(s) != len(common):
            extra = sorted_frames(set(s) - set(common))
            raise InputError(f"mismatched frame counts: {k} has {len(s)} frames, the frames common "
                             f"to all streams are {len(common)} (e.g. {extra[0]!r} has no partner)",
                             where)
    return common


def name_from_output(out: str | os.PathLike) -> str:
    """A sequence's name when none is given: the output file's stem (``out/K1.h5`` -> ``K1``)."""
    return os.path.splitext(os.path.basename(os.fspath(out)))[0]


# -- the writing loop ---------------------------------------------------------------------------
@dataclass
class LoadedFrame:
    """One frame ready for the writer: arrays per stream, timestamp, agents, auxiliary maps."""

    arrays: dict[str, np.ndarray]
    timestamp: float | None = None
    agents: np.ndarray | None = None
    aux: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class AuxStream:
    """An extra per-frame map stored as ``aux/<name>`` (N, H, W) beside the schema's streams."""

    name: str
    dtype: Any = np.bool_


@dataclass
class WriteReport:
    path: str
    frames: int
    skipped: list[dict[str, str]]
    resumed_from: int


def _load_or_error(load: Callable[[Any], LoadedFrame], task: Any) -> LoadedFrame | InputError:
    try:
        return load(task)
    except InputError as e:
        return e


@dataclass(frozen=True)
class _Bound:
    """``load`` wrapped so that bad input comes back as a value (picklable for process pools)."""

    load: Callable[[Any], LoadedFrame]

    def __call__(self, task: Any) -> LoadedFrame | InputError:
        return _load_or_error(self.load, task)


def write_frames(out: str | os.PathLike, meta: SequenceMeta, streams: Sequence[str],
                 tasks: Sequence[Any], load: Callable[[Any], LoadedFrame], *,
                 labels: Sequence[str] | None = None, skip_bad: bool = False,
                 resume: bool = False, overwrite: bool = False, aux: Sequence[AuxStream] = (),
                 executor=None, desc: str = "pack", restart: bool = False,
                 settings: Mapping[str, Any] | None = None) -> WriteReport:
    """Load every task's frame and write the sequence ``out`` atomically; see the module doc.

    ``labels[i]`` names task i in skip lists and errors (default: its index). ``executor`` maps
    the loader over tasks in order (default: serial, in this process). Every task's identity
    (its fields and its files' size and mtime) and ``settings`` are stored, so that ``resume``
    with other inputs is refused (``restart`` starts over).
    """
    from staticdepth.dataset.executors import SerialExecutor
    from staticdepth.dataset.resume import callable_identity, task_identity

    labels = [str(i) for i in range(len(tasks))] if labels is None else list(labels)
    if len(labels) != len(tasks):
        raise ValueError("labels and tasks differ in length")
    if not tasks:
        raise InputError("no frames to write", out)
    if meta.adapt_frames > len(tasks):  # before writing; the writer checks the frames written
        raise InputError(f"--adapt-frames must be within 1..{len(tasks)} (the input's frames), "
                         f"got {meta.adapt_frames}")
    executor = executor or SerialExecutor()
    w = SequenceWriter(out, meta, streams, resume=resume, overwrite=overwrite,
                       aux={a.name: a.dtype for a in aux}, restart=restart,
                       settings={"loader": callable_identity(load), **dict(settings or {})},
                       inputs=[task_identity(t) for t in tasks], labels=labels,
                       resume_how="--resume continues it (add --skip-bad to pass a bad frame "
                                  "that stopped it)")
    try:
        skipped: list[dict[str, str]] = json.loads(w.get_attr("skipped", "[]")) if len(w) else []
        done_skips = {s["frame"] for s in skipped}
        resumed_from = len(w)
        # Tasks already accounted for: the first len(w) good ones and the skips among them.
        start, good = 0, 0
        while start < len(tasks) and good < len(w):
            if labels[start] not in done_skips:
                good += 1
            start += 1
        todo = [t for t in range(start, len(tasks)) if labels[t] not in done_skips]
        results = executor.map(_Bound(load), [tasks[t] for t in todo])
        for t, res in progress(zip(todo, results), total=len(todo), desc=desc, unit="frame"):
            if isinstance(res, InputError):
                if not skip_bad:
                    raise res
                skipped.append({"frame": labels[t], "error": str(res)})
                w.set_attr("skipped", json.dumps(skipped))
                continue
            missing = [a.name for a in aux if a.name not in res.aux]
            if missing:
                raise ValueError(f"loader gave no aux map(s) {missing}")
            w.append(timestamp=res.timestamp, agents=res.agents,
                     aux={a.name: res.aux[a.name] for a in aux}, **res.arrays)
        prov = json.loads(w.get_attr("provenance", "{}"))
        prov["skipped"] = skipped
        prov["frames_in_input"] = len(tasks)
        w.set_attr("provenance", json.dumps(prov, default=str))
    except BaseException:
        w.abort()
        raise
    path = w.close()
    return WriteReport(path, len(w), skipped, resumed_from)


def format_report(rep: WriteReport) -> str:
    """One line for the CLI, plus one line per skipped frame."""
    lines = [f"wrote {rep.frames} frames to {rep.path}"
             + (f" (resumed after frame {rep.resumed_from})" if rep.resumed_from else "")
             + (f"; skipped {len(rep.skipped)} bad frame(s):" if rep.skipped else "")]
    lines += [f"  skipped {s['frame']}: {s['error']}" for s in rep.skipped]
    return "\n".join(lines)


# -- stereo recordings ----------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoTask:
    left: str
    right: str
    timestamp: float | None


def recording_tasks(folder: str | os.PathLike) -> tuple[list[StereoTask], list[str], Any]:
    """Tasks, labels and the own rig (or None) of a capture-layout or plain recording."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise InputError("recording folder not found", folder)
    if os.path.exists(os.path.join(folder, "manifest.json")):
        from staticdepth.capture.layout import read_recording

        rec = read_recording(folder)
        tasks = [StereoTask(os.fspath(f.left_path), os.fspath(f.right_path), f.timestamp_s)
                 for f in rec.frames]
        return tasks, [f"{f.frame:08d}" for f in rec.frames], rec.rig
    names = {os.path.join(folder, s): list_frames(os.path.join(folder, s))
             for s in ("left", "right")}
    for sub, found in names.items():
        if not found:
            raise no_frames_error(sub)
    stems = match_streams(names, folder)
    ts: list[float | None] = [None] * len(stems)
    csv_path = os.path.join(folder, "timestamps.csv")
    if os.path.exists(csv_path):
        with open(csv_path) as f:
            rows = [ln.strip() for ln in f if ln.strip()]
        last = rows[0].split(",")[-1].strip() if rows else ""
        if rows and not last.replace(".", "", 1).replace("-", "", 1).isdigit():
            rows = rows[1:]  # header
        if len(rows) != len(stems):
            raise InputError(f"{len(rows)} timestamps for {len(stems)} frames", csv_path)
        try:
            ts = [float(r.split(",")[-1]) for r in rows]
        except ValueError as e:
            raise InputError(f"malformed timestamp ({e})", csv_path) from None
    tasks = [StereoTask(os.path.join(folder, "left", s + ".png"),
                        os.path.join(folder, "right", s + ".png"), t) for s, t in zip(stems, ts)]
    return tasks, stems, None


_PIPELINES: dict[str, Any] = {}  # per process: built once, reused for every frame


@dataclass(frozen=True)
class StereoLoader:
    """Load a pair and run the stereo pipeline: a pure function of (task, rig, stereo settings)."""

    rig_json: str
    config_json: str
    store_right: bool = True

    def pipeline(self):
        from staticdepth.geometry.camera import StereoRig
        from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline

        key = self.rig_json + self.config_json
        if key not in _PIPELINES:
            _PIPELINES.clear()
            _PIPELINES[key] = StereoPipeline(StereoRig.from_dict(json.loads(self.rig_json)),
                                             StereoConfig.from_dict(json.loads(self.config_json)))
        return _PIPELINES[key]

    def __call__(self, task: StereoTask) -> LoadedFrame:
        pipe = self.pipeline()
        left, right = read_rgb(task.left), read_rgb(task.right)
        pipe.check_frame(left, right, task.left)
        res = pipe.process(left, right)
        arrays = {"left": res.left_rect, "depth": res.depth}
        if self.store_right:
            arrays["right"] = res.right_rect
        return LoadedFrame(arrays=arrays, timestamp=task.timestamp)


def _rectified_mounting(rig, camera_height_m: float | None):
    """The rig's mounting with ``camera_height_m`` when given (else None without a mounting).

    ``staticdepth mount`` stores the ground normal in the rectified left camera's frame already
    (the frame of the packed images and depth maps), so it is used as it is.
    """
    from staticdepth.geometry.camera import Mounting

    m = rig.mounting
    if m is None:
        return None
    return Mounting(camera_height_m or m.height_m, m.normal, m.source)


def check_rig_rectifies(pipe, tasks: Sequence[StereoTask], rig_name: str, skip_bad: bool) -> None:
    """Before any work, as ``stereo`` does: the rig must rectify the first readable pair (rows of
    matched features agree) and the views must not look swapped (most matched features of
    negative disparity, ``stereo``'s warning), else its depth would be garbage."""
    from staticdepth.stereo.diagnose import swapped_views
    from staticdepth.stereo.rectify import check_rectified

    for t in tasks[:10]:
        try:
            left, right = read_rgb(t.left), read_rgb(t.right)
            pipe.check_frame(left, right, t.left)
        except InputError:
            if skip_bad:
                continue
            raise
        rl, rr = pipe.rectifier.rectify(left, right)
        check = check_rectified(rl, rr, source=f"{rig_name} (after rectifying {t.left})")
        swapped = swapped_views(check)
        if swapped:
            raise InputError(f"{swapped}; exchange the recording's left and right images, or "
                             "pass --skip-rectification-check", t.left)
        return


def pack_recording(recording: str | os.PathLike, rig_path: str | os.PathLike | None,
                   out: str | os.PathLike, *, camera_height_m: float | None = None,
                   adapt_frames: int = 0, matcher: str = "sgbm", model: str | None = None,
                   overrides: Mapping[str, Any] | None = None, store_right: bool = True,
                   name: str | None = None, skip_bad: bool = False, resume: bool = False,
                   overwrite: bool = False, executor=None, restart: bool = False,
                   check_rectification: bool = True) -> WriteReport:
    """Stereo depth for every pair of a recording, written as one sequence file (see module doc).

    Stored images are the rectified pair, the camera is the rectified left camera, and depth is
    NaN where the stereo consistency check failed or beyond ``max_depth_m``. The first pair is
    checked first (:func:`check_rig_rectifies`) unless ``check_rectification`` is False.
    """
    from staticdepth.geometry.camera import StereoRig, check_camera_height
    from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline

    if camera_height_m is not None:     # before any work
        camera_height_m = check_camera_height(camera_height_m, "--camera-height")
    tasks, labels, rec_rig = recording_tasks(recording)
    if rig_path is not None:
        rig = StereoRig.load(rig_path)
    elif rec_rig is not None:
        rig = rec_rig
    else:
        raise InputError("the recording has no rig: pass --rig rig.json", recording)
    from staticdepth.config import split_options

    fields, options = split_options(StereoConfig, dict(overrides or {}))
    values: dict[str, Any] = {"matcher": matcher, **fields}
    if model is not None:
        options["model"] = model
    if options:
        values["options"] = options
    config = StereoConfig.from_dict(values, source="--set")
    pipe = StereoPipeline(rig, config)  # validates the settings once, before any work
    if check_rectification:
        check_rig_rectifies(pipe, tasks, os.fspath(rig_path) if rig_path else
                            f"{os.fspath(recording)} (its rig)", skip_bad)
    tasks = [StereoTask(t.left, t.right, float(i) if t.timestamp is None else t.timestamp)
             for i, t in enumerate(tasks)]
    mounting = _rectified_mounting(rig, camera_height_m)
    meta = SequenceMeta(
        name=name or os.path.basename(os.path.normpath(os.fspath(recording))), camera=pipe.camera,
        gt_kind="stereo", source=f"stereo recording: {os.fspath(recording)}",
        adapt_frames=adapt_frames, rig=StereoRig.rectified(pipe.camera, pipe.baseline_m),
        mounting=mounting, camera_height_m=camera_height_m if mounting is None else None,
        provenance={"ground_truth": f"stereo ({config.matcher})", "matcher": config.matcher,
                    "stereo_config": config.to_dict(), "pipeline": pipe.provenance(),
                    "input_rig": rig.to_dict(), "recording": os.fspath(recording)})
    loader = StereoLoader(json.dumps(rig.to_dict()), json.dumps(config.to_dict(), default=str),
                          store_right)
    streams = ("left", "right", "depth") if store_right else ("left", "depth")
    return write_frames(out, meta, streams, tasks, loader, labels=labels, skip_bad=skip_bad,
                        resume=resume, overwrite=overwrite, executor=executor, desc="pack",
                        restart=restart)
