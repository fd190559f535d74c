"""Figures and the one-file HTML report of a sequence (``staticdepth report``).

Figures (:mod:`staticdepth.report_figures`, in the pipeline's order): colourised depth per stage
with colour bars in metres, error maps per stage (the paper's Fig. 6), the ground planes
(predicted, from agents, true) drawn on the image (Fig. 3), and the agents' recent tracks. A
sequence without ground truth gets its figures without metrics: its metric predictions in metres
over one shared range, the relative ones over their own range, labelled relative.
The HTML embeds every picture as a data URI, so it opens offline in any browser.
"""
from __future__ import annotations

import argparse
import base64
import html
import os
import re
from typing import Any, Mapping, Sequence

import numpy as np

from staticdepth.errors import InputError
from staticdepth.evaluate import evaluate_sequence, prediction_protocols
from staticdepth.metrics import apply_protocol, valid_mask
from staticdepth.tables import Table, table1, table2, table3, table_regions, write_tables

def error_map(pred: np.ndarray, gt: np.ndarray, vmax: float = 0.5) -> np.ndarray:
    """|pred - gt| / gt coloured from black (0) through red to yellow (>= vmax); no gt, or no
    prediction there (NaN: a hole), = grey."""
    import cv2

    ok = valid_mask(gt) & ~np.isnan(pred)
    rel = np.zeros(gt.shape)
    rel[ok] = np.abs(pred[ok] - gt[ok]) / gt[ok]
    t = (np.clip(rel / vmax, 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(t, cv2.COLORMAP_HOT)[..., ::-1].copy()
    rgb[~ok] = 90
    return rgb


def _png_uri(rgb: np.ndarray) -> str:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode()


def sequence_figures(path: str | os.PathLike, summary: Mapping[str, Any] | None = None,
                     frame: int | None = None) -> list[tuple[str, np.ndarray]]:
    """(caption, RGB panel) pairs for one evaluation frame, in the pipeline's order (see
    :mod:`staticdepth.report_figures`); without ground truth, the predictions alone."""
    from staticdepth import report_figures as rf
    from staticdepth.dataset.h5 import SequenceReader

    figs: list[tuple[str, np.ndarray]] = []
    with SequenceReader(path) as r:
        ev = r.split("eval")
        i = frame if frame is not None else (ev[len(ev) // 2] if len(ev) else 0)
        img = r.left(i)
        gt = r.depth(i) if r.has("depth") else None
        has_gt = gt is not None and valid_mask(gt).any()
        rng = rf.depth_range(gt) if has_gt else None
        figs.append((f"1. input: frame {i}", rf.label(img, f"frame {i}")))
        if has_gt:
            figs.append(("2. ground-truth depth (colours: inverse depth, near = red)",
                         rf.depth_panel(gt, "ground truth", rng)))
        k = len(figs) + 1
        protocol = prediction_protocols(r)[0]
        names = rf.pipeline_sorted(list(protocol))
        metric = {n: protocol[n] == "metric" for n in names}
        if not has_gt:          # one range for the metric panels, as the ground truth's would be
            rng = rf.depth_range(np.concatenate(
                [np.ravel(r.prediction(n, i)) for n in names if metric[n]] or [np.zeros(0)]))
        for name in names:
            pred = r.prediction(name, i).astype(np.float64)
            if has_gt:
                prot = protocol[name]
                scaled, s = apply_protocol(pred, gt, prot, valid_mask(gt))
                figs.append((f"{k}. {name}: depth ({prot} protocol, scale {s:.3g})",
                             rf.depth_panel(scaled, f"{name} ({prot})", rng)))
                figs.append((f"{k}. {name}: relative error |pred - gt| / gt",
                             rf.error_panel(error_map(scaled, gt), f"{name}: relative error")))
            elif metric[name]:
                figs.append((f"{k}. {name}: depth (metric, metres; the metric panels share one "
                             f"colour range; no ground truth)", rf.depth_panel(pred, name, rng)))
            else:
                figs.append((f"{k}. {name}: depth (relative: its own colour range; no ground "
                             f"truth)", rf.depth_panel(pred, name, None)))
            k += 1
        planes = rf.summary_planes(summary)
        agents = r.agents()
        if "predicted" not in planes and "base" in r.predictions() and len(agents) and planes:
            d = next(iter(planes.values()))[1]
            fitted = rf.predicted_plane(r.prediction("base", i), r.camera.K, agents, d,
                                        r.width, r.height)
            if fitted is not None:
                planes["predicted"] = fitted
        if r.meta.mounting is not None:
            planes = {"true": (r.meta.mounting.normal, r.meta.mounting.height_m), **planes}
        if planes:
            drawn = ", ".join(rf.PLANE_CAPTIONS.get(p, p) for p in planes)
            figs.append((f"{k}. ground planes: iso-depth lines in metres ({drawn})",
                         rf.label(rf.draw_planes(img, r.camera.K, planes), "ground planes")))
            k += 1
        if len(agents):
            figs.append((f"{k}. the sequence's own agents (its annotation, not the detector's): "
                         f"foot points over the last 6 frames up to frame {i}, one colour per "
                         "track (newest = dot)",
                         rf.label(rf.draw_tracks(img, agents, i), "agents' tracks")))
    return figs


def write_html(path: str | os.PathLike, title: str, tables: Sequence[Table],
               figures: Sequence[tuple[str, np.ndarray]], notes: Sequence[str] = ()) -> None:
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:"
             "collapse;margin-bottom:1em}td,th{border:1px solid #999;padding:2px 6px;"
             "text-align:right}figure{display:inline-block;vertical-align:top;margin:4px;"
             "max-width:580px}img{max-width:560px}figcaption{font-size:small}")
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
                 summaries: Mapping[str, Mapping[str, Any]] | None = None, warn=print
                 ) -> dict[str, Any]:
    """Evaluate every sequence, write the tables (text, CSV, Markdown) and one HTML per scene.

    ``warn`` receives a sequence's note when some of its predictions store no attribute ``metric``
    (:func:`prediction_protocols`; the note is in its HTML too), a summary written for another
    sequence, and that no tables were written when no sequence has ground truth. Every sequence
    is read before ``out_dir`` is made."""
    summaries = summaries or {}
    check_summaries(sequences, summaries, warn)
    evals, notes_of, protocols = {}, {}, {}
    protos = ("median", "metric")
    for scene, seq in sequences.items():
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(seq) as r:
            protocol, note = prediction_protocols(r)
            protocols[scene] = protocol
            names = list(protocol)
            has_gt = r.has("depth")
        if not names:
            raise InputError("no predictions to report (run adapt / baseline first)", seq)
        if note:
            warn(note)
            notes_of[scene] = [note]
        if has_gt:
            evals[scene] = evaluate_sequence(seq, names, protocols=protos)["results"]
    if not evals:
        warn("note: no tables written: no sequence has ground truth (depth); the HTML pages "
             "show the predictions only")
    os.makedirs(out_dir, exist_ok=True)
    anchors = {scene: anchor_row(seq, summaries.get(scene)) for scene, seq in sequences.items()
               if scene in evals}
    tables = ([table1(evals), table2(anchors), table3(evals),
               table_regions(evals, protocols=protocols)] if evals else [])
    paths = write_tables(tables, out_dir) if tables else []
    from staticdepth.report_figures import metric_definitions

    for scene, seq in sequences.items():
        figs = sequence_figures(seq, summaries.get(scene))
        p = os.path.join(out_dir, f"report_{_file_stem(scene)}.html")
        notes = [f"sequence: {seq}", *notes_of.get(scene, [])]
        notes += (metric_definitions() if scene in evals else
                  ["no ground truth: the predictions are shown without metrics"])
        write_html(p, f"staticdepth report: {scene}", tables if scene in evals else [], figs,
                   notes=notes)
        paths.append(p)
    return {"tables": tables, "paths": paths, "evals": evals, "anchors": anchors}


def check_summaries(sequences: Mapping[str, str], summaries: Mapping[str, Mapping[str, Any]],
                    warn=print) -> None:
    """A summary whose scene is no sequence's is an error; one whose ``"sequence"`` names another
    file than its scene's gets one warning line naming both (Table 2 would show that file's anchor
    depths). Only a warning: a run folder moved or copied as a whole keeps its old paths inside,
    so a recorded path that no longer exists but has the same file name passes. A summary of
    the right sequence whose maps another adapt run has replaced since is an error: its Table 2
    row and planes would be reported beside the other run's maps."""
    from staticdepth.adapt import replaced_since

    unknown = sorted(set(summaries) - set(sequences))
    if unknown:
        raise InputError(f"--summary: no sequence labelled {', '.join(map(repr, unknown))}; the "
                         f"sequences': {', '.join(map(repr, sequences))}")
    for scene, s in summaries.items():
        recorded, seq = (s or {}).get("sequence"), sequences[scene]
        if not isinstance(recorded, str):
            continue
        if os.path.exists(recorded) and os.path.exists(seq):
            same = os.path.samefile(recorded, seq)
        else:
            same = os.path.basename(recorded) == os.path.basename(seq)
        if not same:
            warn(f"warning: the summary for {scene!r} was written for {recorded}, not for {seq}; "
                 "its anchor depths and planes are that sequence's")
        elif (p := replaced_since(s, seq)) is not None:
            raise InputError(f"an adapt run other than the one --summary gives for {scene!r} "
                             "wrote this map since (other settings): give that run's summary, "
                             "or none", p)


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
    from staticdepth.cli import add_overwrite_argument

    add_overwrite_argument(p, "replace the tables and HTML files of an earlier report in --out "
                              "(refused otherwise)")
    p.set_defaults(func=_report_cmd)


def _pairs(items: Sequence[str], summaries: bool = False) -> dict[str, str]:
    """``LABEL=PATH`` items by label; a bare path's label is its file stem (a summary's,
    ``SCENE.adapt.json``, is ``SCENE``, as adapt names it beside ``SCENE.h5``)."""
    out = {}
    for it in items:
        scene, _, path = it.rpartition("=")
        if not scene:
            name = os.path.basename(path)
            scene = (name[:-len(".adapt.json")] if summaries and name.endswith(".adapt.json")
                     else os.path.splitext(name)[0])
        out[scene] = path
    return out


def report_outputs(out_dir: str | os.PathLike) -> list[str]:
    """The report files in ``out_dir`` already: the tables (``tables.md``, ``tables_N.csv``) and
    every scene's HTML (``report_*.html``). A folder holds one report: those of an earlier run
    are refused without ``--overwrite`` and, with it, replaced or removed (a page of a scene no
    longer reported, or tables a run without ground truth does not write, would be read as this
    run's)."""
    import glob

    out_dir = os.fspath(out_dir)
    found = (sorted(glob.glob(os.path.join(glob.escape(out_dir), pattern)))
             for pattern in ("tables_*.csv", "report_*.html"))
    paths = [os.path.join(out_dir, "tables.md"), *(p for group in found for p in group)]
    return [p for p in paths if os.path.lexists(p)]


def _report_cmd(args: argparse.Namespace) -> int:
    from staticdepth.cli import refuse_existing
    from staticdepth.geometry.camera import read_json

    seqs = _pairs(args.sequences)
    earlier = report_outputs(args.out) if os.path.isdir(args.out) else []
    refuse_existing(*earlier, overwrite=args.overwrite)
    summaries = {scene: read_json(p) for scene, p in _pairs(args.summary, True).items()}
    res = build_report(seqs, args.out, summaries)
    for t in res["tables"]:
        print(t.text())
        print()
    for p in res["paths"]:
        print(f"wrote {p}")
    written = {os.path.realpath(p) for p in res["paths"]}
    for p in earlier:
        if os.path.realpath(p) not in written and os.path.lexists(p):
            os.remove(p)
            print(f"removed {p} (an earlier report's)")
    return 0
