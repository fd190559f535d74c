"""Figures and the one-file HTML report of a sequence (``staticdepth report``).

Figures: colourised depth per stage, error maps per stage (the paper's Fig. 6), the ground planes
(predicted, from agents, true) drawn on the image (Fig. 3), and the agents' tracks with foot points.
The HTML embeds every picture as a data URI, so it opens offline in any browser.
"""
from __future__ import annotations

import argparse
import base64
import html
import os
import re
from typing import Any, Mapping, Sequence

import cv2
import numpy as np

from staticdepth.dataset.inspect import colorize_depth
from staticdepth.errors import InputError
from staticdepth.evaluate import default_protocol, evaluate_sequence
from staticdepth.geometry.plane import plane_depth_map
from staticdepth.metrics import apply_protocol, valid_mask
from staticdepth.tables import Table, table1, table2, table3, table_regions, write_tables

PLANE_COLOURS = {"true": (40, 220, 40), "agents": (255, 160, 0), "predicted": (230, 40, 230)}


def error_map(pred: np.ndarray, gt: np.ndarray, vmax: float = 0.5) -> np.ndarray:
    """|pred - gt| / gt coloured from black (0) through red to yellow (>= vmax); no gt = grey."""
    ok = valid_mask(gt)
    rel = np.zeros(gt.shape)
    rel[ok] = np.abs(pred[ok] - gt[ok]) / gt[ok]
    t = (np.clip(rel / vmax, 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(t, cv2.COLORMAP_HOT)[..., ::-1].copy()
    rgb[~ok] = 90
    return rgb


def draw_planes(image: np.ndarray, K: np.ndarray,
                planes: Mapping[str, tuple[np.ndarray, float]],
                depths_m: Sequence[float] = (5, 10, 20, 40)) -> np.ndarray:
    """Iso-depth contours of each ground plane (one colour per plane) over the image."""
    out = image.copy()
    h, w = image.shape[:2]
    for label, (n, d) in planes.items():
        z = plane_depth_map(K, np.asarray(n), float(d), w, h)
        colour = PLANE_COLOURS.get(label, (255, 255, 255))
        for zc in depths_m:
            m = (np.nan_to_num(z, nan=1e9) < zc).astype(np.uint8)
            cnts, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(out, cnts, -1, colour, 1, cv2.LINE_AA)
        cv2.putText(out, label, (5, 15 + 15 * list(planes).index(label)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return out


def draw_tracks(image: np.ndarray, agents: np.ndarray, max_tracks: int = 200) -> np.ndarray:
    """Foot points of every agent row, joined per track."""
    out = image.copy()
    rows = agents[(agents["foot_v"] >= 0) & (agents["track_id"] >= 0)]
    rng = np.random.default_rng(0)
    for tid in np.unique(rows["track_id"])[:max_tracks]:
        r = rows[rows["track_id"] == tid]
        r = r[np.argsort(r["frame"])]
        pts = np.stack([r["foot_u"], r["foot_v"]], 1).astype(np.int32)
        colour = tuple(int(c) for c in rng.integers(60, 255, 3))
        cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, colour, 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), 2, colour, -1)
    return out


def _png_uri(rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode()


def _planes_from_summary(summary: Mapping[str, Any] | None) -> dict[str, tuple[np.ndarray, float]]:
    planes: dict[str, tuple[np.ndarray, float]] = {}
    for label in ("agents", "predicted"):
        p = (summary or {}).get("planes", {}).get(label)
        if p is not None:
            planes[label] = (np.asarray(p["normal"], float), float(p["d"]))
    return planes


def sequence_figures(path: str | os.PathLike, summary: Mapping[str, Any] | None = None,
                     frame: int | None = None) -> list[tuple[str, np.ndarray]]:
    """(caption, RGB image) pairs for one evaluation frame of a sequence."""
    from staticdepth.dataset.h5 import SequenceReader

    figs: list[tuple[str, np.ndarray]] = []
    with SequenceReader(path) as r:
        ev = r.split("eval")
        i = frame if frame is not None else (ev[len(ev) // 2] if len(ev) else 0)
        img = r.left(i)
        gt = r.depth(i) if r.has("depth") else None
        figs.append((f"frame {i}: image", img))
        if gt is not None:
            figs.append(("ground truth depth", colorize_depth(gt)))
        for name in r.predictions():
            pred = r.prediction(name, i).astype(np.float64)
            prot = default_protocol(name)
            if gt is not None and valid_mask(gt).any():
                scaled, s = apply_protocol(pred, gt, prot, valid_mask(gt))
                figs.append((f"{name}: depth ({prot}, scale {s:.3g})", colorize_depth(scaled)))
                figs.append((f"{name}: relative error |pred-gt|/gt (black 0, yellow >= 0.5)",
                             error_map(scaled, gt)))
            else:
                figs.append((f"{name}: depth", colorize_depth(pred)))
        planes = _planes_from_summary(summary)
        if r.meta.mounting is not None:
            planes = {"true": (r.meta.mounting.normal, r.meta.mounting.height_m), **planes}
        if planes:
            # relative planes (predicted) are drawn at the scale of their own d: only their shape
            figs.append(("ground planes: iso-depth lines at 5, 10, 20, 40 m "
                         "(green true, orange from agents, magenta predicted)",
                         draw_planes(img, r.camera.K, planes)))
        agents = r.agents()
        if len(agents):
            figs.append(("agents' tracks and foot points (all frames)", draw_tracks(img, agents)))
    return figs


def write_html(path: str | os.PathLike, title: str, tables: Sequence[Table],
               figures: Sequence[tuple[str, np.ndarray]], notes: Sequence[str] = ()) -> None:
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:"
             "collapse;margin-bottom:1em}td,th{border:1px solid #999;padding:2px 6px;"
             "text-align:right}figure{display:inline-block;margin:4px}img{max-width:560px}")
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             f"</title><style>{style}</style></head><body><h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{html.escape(n)}</p>" for n in notes]
    parts += [t.html() for t in tables]
    parts += [f"<figure><img src='{_png_uri(img)}'><figcaption>{html.escape(c)}</figcaption>"
              f"</figure>" for c, img in figures]
    parts.append("</body></html>")
    from staticdepth.fileio import atomic_write_text
    atomic_write_text(path, "\n".join(parts))


def anchor_row(path: str | os.PathLike, summary: Mapping[str, Any] | None) -> dict[str, float]:
    """Table 2's row: ground-truth anchor depth (median over eval frames of a 5x5 patch at the
    bottom-centre pixel) and the estimates from the adaptation summary."""
    from staticdepth.dataset.h5 import SequenceReader

    with SequenceReader(path) as r:
        h, w = r.height, r.width
        vals = []
        for i in r.split("eval"):
            patch = r.depth(i)[h - 5:h, w // 2 - 2:w // 2 + 3]
            if np.isfinite(patch).any():
                vals.append(float(np.nanmedian(patch)))
    s = summary or {}
    return {"gt_m": float(np.median(vals)) if vals else None,
            "parallel_m": s.get("anchor_depth_parallel_m"), "ours_m": s.get("anchor_depth_m")}


def build_report(sequences: Mapping[str, str], out_dir: str | os.PathLike,
                 summaries: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """Evaluate every sequence, write the tables (text, CSV, Markdown) and one HTML per scene."""
    os.makedirs(out_dir, exist_ok=True)
    summaries = summaries or {}
    evals = {}
    protos = ("median", "metric")
    for scene, seq in sequences.items():
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(seq) as r:
            names = r.predictions()
        if not names:
            raise InputError("no predictions to report (run adapt / baseline first)", seq)
        evals[scene] = evaluate_sequence(seq, names, protocols=protos)["results"]
    anchors = {scene: anchor_row(seq, summaries.get(scene)) for scene, seq in sequences.items()}
    tables = [table1(evals), table2(anchors), table3(evals), table_regions(evals)]
    paths = write_tables(tables, out_dir)
    for scene, seq in sequences.items():
        figs = sequence_figures(seq, summaries.get(scene))
        p = os.path.join(out_dir, f"report_{_file_stem(scene)}.html")
        write_html(p, f"staticdepth report: {scene}", tables, figs,
                   notes=[f"sequence: {seq}"])
        paths.append(p)
    return {"tables": tables, "paths": paths, "evals": evals, "anchors": anchors}


def _file_stem(name: str) -> str:
    """A scene name as a safe file name part (no folders, no markup)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).lstrip(".") or "scene"


def register(sub) -> None:
    p = sub.add_parser("report", help="tables and an HTML report for evaluated sequences",
                       description="Evaluate the stored predictions, print the paper's three "
                                   "tables, write them as CSV/Markdown and an offline HTML report.")
    p.add_argument("sequences", nargs="+", help="SCENE=SEQ.h5 or SEQ.h5 (scene = file stem)")
    p.add_argument("--summary", nargs="*", default=[],
                   help="SCENE=SEQ.adapt.json ... (anchor depths, planes) written by `adapt`")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=_report_cmd)


def _pairs(items: Sequence[str]) -> dict[str, str]:
    out = {}
    for it in items:
        scene, _, path = it.rpartition("=")
        out[scene or os.path.splitext(os.path.basename(path))[0]] = path
    return out


def _report_cmd(args: argparse.Namespace) -> int:
    from staticdepth.geometry.camera import read_json

    seqs = _pairs(args.sequences)
    summaries = {scene: read_json(p) for scene, p in _pairs(args.summary).items()}
    res = build_report(seqs, args.out, summaries)
    for t in res["tables"]:
        print(t.text())
        print()
    for p in res["paths"]:
        print(f"wrote {p}")
    return 0
