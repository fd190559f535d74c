"""The sequence file's schema: one HDF5 file per sequence (see ``staticdepth.dataset.h5``).

Layout (N frames of H x W):
- ``left``       (N, H, W, 3) uint8 RGB, one frame per chunk, compressed
- ``right``      (N, H, W, 3) uint8 RGB (optional)
- ``depth``      (N, H, W)    float32 metres, NaN = unknown (optional)
- ``instances``  (N, H, W)    uint16 instance id map, 0 = background (optional)
- ``agents``     (M,) table of AGENT_DTYPE rows: which instance of which frame is which agent
- ``timestamps`` (N,) float64 seconds
- ``aux/<name>``  (N, H, W) extra per-frame maps (e.g. CARLA's ground mask)
- ``crc32/<dataset>`` (N,) uint32 checksums of each frame's raw bytes of every per-frame dataset
  (streams, ``aux/<name>``, legacy ``pred/<name>/depth``); ``timestamps`` and ``agents`` carry a
  ``crc32`` attribute over all their bytes; ``verify`` checks them all
  (``staticdepth.dataset.integrity``)
- ``fingerprint/inputs`` one digest per input frame, and the root attribute ``fingerprint``:
  what ``--resume`` must find unchanged (``staticdepth.dataset.resume``)
- ``pred/<name>/depth`` (N, H, W) float32 predictions of older files; predictions are now files
  beside the sequence, ``<SEQ>.h5.pred/<name>.h5`` (:mod:`staticdepth.dataset.predictions`)
Root attributes: see REQUIRED_ATTRS; JSON-valued ones are stored as strings.
"""
from __future__ import annotations

import numpy as np

FORMAT = "staticdepth.sequence/1"

FRAME_STREAMS = ("left", "right", "depth", "instances")
STREAM_DTYPES = {"left": np.uint8, "right": np.uint8, "depth": np.float32, "instances": np.uint16}
GT_KINDS = ("stereo", "lidar", "synthetic", "none")

# COCO class ids (0-based, as YOLOX and most detectors emit them) of the agents the method uses.
COCO = {"person": 0, "bicycle": 1, "car": 2, "motorcycle": 3, "bus": 5, "truck": 7,
        "backpack": 24, "umbrella": 25, "handbag": 26, "suitcase": 28}
AGENT_CLASSES = frozenset(COCO[k] for k in ("person", "bicycle", "car", "motorcycle", "bus", "truck"))
ACCESSORY_CLASSES = frozenset(COCO[k] for k in ("backpack", "umbrella", "handbag", "suitcase"))
VEHICLE_CLASSES = frozenset(COCO[k] for k in ("car", "bus", "truck"))
RIDEABLE_CLASSES = frozenset(COCO[k] for k in ("bicycle", "motorcycle"))

# One row per agent instance per frame. Ground-truth fields (3-D points, height) are NaN when
# unknown (detections); pixel fields are measured on the instance mask (-1 when unknown).
AGENT_DTYPE = np.dtype([
    ("frame", np.int32),          # frame index
    ("instance_id", np.uint16),   # value in that frame's ``instances`` map
    ("class_id", np.int16),       # COCO class id
    ("track_id", np.int32),       # same physical agent across frames (-1 = unknown)
    ("foot_u", np.float32),       # bottom-centre of the mask: column (px)
    ("foot_v", np.float32),       # lowest mask row (px)
    ("top_v", np.float32),        # highest mask row (px)
    ("top_u", np.float32),        # median column of the highest mask row (px; NaN = unknown)
    ("score", np.float32),        # detector confidence (1 for ground truth)
    ("foot_x", np.float32), ("foot_y", np.float32), ("foot_z", np.float32),  # true foot (axis
    # bottom, on the ground), camera frame, metres
    ("head_x", np.float32), ("head_y", np.float32), ("head_z", np.float32),  # true top of axis
    ("height_m", np.float32),     # true height of the agent
    ("radius_m", np.float32),     # true body radius (upright cylinder model)
])

REQUIRED_ATTRS = ("format", "name", "camera", "gt_kind", "source", "adapt_frames", "n_frames",
                  "width", "height", "complete", "toolkit_version")
OPTIONAL_ATTRS = ("rig", "mounting", "camera_height_m", "provenance", "created")


def empty_agents(n: int = 0) -> np.ndarray:
    a = np.zeros(n, dtype=AGENT_DTYPE)
    for f in ("top_u", "foot_x", "foot_y", "foot_z", "head_x", "head_y", "head_z", "height_m",
              "radius_m"):
        a[f] = np.nan
    a["track_id"] = -1
    a["foot_u"] = a["foot_v"] = a["top_v"] = -1
    a["score"] = 1.0
    return a


def check_name(name: str | None) -> None:
    """Before any work: a sequence name is one line of printable text (the reports and the
    dataset card print it; a line break in it broke their tables)."""
    from staticdepth.errors import InputError

    if name is not None and not str(name).isprintable():
        raise InputError(f"--name must be one line of printable text, got {name!r}")


#: what leaving ``--adapt-frames`` out means for the importers with ground truth
ADAPT_NONE = "none: every frame is for evaluation"


def check_adapt_frames(value: int | None, left_out: str) -> None:
    """Before any work: the one ``--adapt-frames`` rule of every importer (import-video,
    import-kitti, import-carla, pack): left out (None), or N >= 1 first frames. 0 is refused in
    the same words everywhere; ``left_out`` says what leaving the option out means."""
    from staticdepth.errors import InputError

    if value is not None and value < 1:
        raise InputError(f"--adapt-frames must be >= 1 (the first frames, which adapt learns "
                         f"from; leave it out for {left_out}), got {value}")
