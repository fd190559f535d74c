"""The tables ``staticdepth locate`` writes: positions and pairwise distances, as CSV or Parquet.

The format follows the path's extension: ``.parquet`` writes Parquet (needs ``pyarrow``, the
optional extra ``staticdepth[parquet]``), ``.csv`` CSV; any other extension is refused. Both hold the same columns in the
same units; CSV rounds (metres to mm, pixels to 0.1 px), Parquet keeps full precision with native
types (an unknown speed is null there, an empty cell in CSV).
"""
from __future__ import annotations

import csv
import io
import os
from typing import Any

import numpy as np

from staticdepth.errors import InputError

POS_COLUMNS = ("frame", "time_s", "track", "class", "score", "u", "v", "X", "Y", "Z", "ground_x",
               "ground_y", "distance_m", "source", "occluded", "rider", "speed_mps")
PAIR_COLUMNS = ("frame", "time_s", "track_a", "track_b", "distance_m", "close")


def is_parquet(path: str | None) -> bool:
    return bool(path) and str(path).lower().endswith(".parquet")


def check_table_path(path: str | None) -> None:
    """Refuse up front a table path that is neither ``.csv`` nor ``.parquet`` (a ``.txt`` or
    ``.json`` got CSV under that name), and a ``.parquet`` one when pyarrow is not installed."""
    if path and os.path.splitext(path)[1].lower() not in (".csv", ".parquet"):
        raise InputError("a table is written as .csv or .parquet: name the file so", path)
    if is_parquet(path):
        try:
            import pyarrow  # noqa: F401  (only whether it imports)
        except ImportError:
            raise InputError("Parquet output needs pyarrow (pip install 'staticdepth[parquet]'); "
                             "or give a .csv path", path) from None


def positions_columns(pos: np.ndarray) -> dict[str, np.ndarray]:
    """POS_DTYPE rows -> {column: array} in :data:`POS_COLUMNS` order (``class`` by name)."""
    from staticdepth.locate import CLASS_NAMES

    cols: dict[str, np.ndarray] = {}
    for c in POS_COLUMNS:
        if c == "class":
            cols[c] = np.array([CLASS_NAMES.get(int(k), "unknown") for k in pos["class_id"]],
                               dtype=object)
        elif c in ("occluded", "rider"):
            cols[c] = pos[c].astype(np.int8)
        else:
            cols[c] = pos[c]
    return cols


def positions_csv(pos: np.ndarray) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(POS_COLUMNS)
    cols = positions_columns(pos)
    for i in range(len(pos)):
        p = {c: cols[c][i] for c in POS_COLUMNS}
        w.writerow([int(p["frame"]), f"{p['time_s']:.3f}", int(p["track"]), p["class"],
                    f"{p['score']:.3f}", f"{p['u']:.1f}", f"{p['v']:.1f}"]
                   + [f"{p[k]:.3f}" for k in ("X", "Y", "Z", "ground_x", "ground_y", "distance_m")]
                   + [p["source"], int(p["occluded"]), int(p["rider"]),
                      "" if not np.isfinite(p["speed_mps"]) else f"{p['speed_mps']:.3f}"])
    return buf.getvalue()


def pairs_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(PAIR_COLUMNS)
    for p in rows:
        w.writerow([p["frame"], f"{p['time_s']:.3f}", p["track_a"], p["track_b"],
                    f"{p['distance_m']:.3f}", p["close"]])
    return buf.getvalue()


def parquet_bytes(columns: dict[str, Any]) -> bytes:
    """One Parquet file of the columns; non-finite floats become nulls."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {}
    for name, values in columns.items():
        v = np.asarray(values)
        if v.dtype.kind == "f":
            arrays[name] = pa.array(v, mask=~np.isfinite(v))
        elif v.dtype.kind in "OU":
            arrays[name] = pa.array([str(x) for x in v], type=pa.string())
        else:
            arrays[name] = pa.array(v)
    sink = pa.BufferOutputStream()
    pq.write_table(pa.table(arrays), sink)
    return sink.getvalue().to_pybytes()


def write_positions(path: str, pos: np.ndarray) -> None:
    from staticdepth.fileio import atomic_write_bytes, atomic_write_text

    check_table_path(path)
    if is_parquet(path):
        atomic_write_bytes(path, parquet_bytes(positions_columns(pos)))
    else:
        atomic_write_text(path, positions_csv(pos))


def write_pairs(path: str, rows: list[dict[str, Any]]) -> None:
    from staticdepth.fileio import atomic_write_bytes, atomic_write_text

    check_table_path(path)
    if is_parquet(path):
        cols = {c: np.array([r[c] for r in rows], dtype=np.float64 if c in ("time_s",
                                                                            "distance_m")
                            else np.int64) for c in PAIR_COLUMNS}
        atomic_write_bytes(path, parquet_bytes(cols))
    else:
        atomic_write_text(path, pairs_csv(rows))
