"""The paper's three tables from evaluation results, as text, CSV and Markdown.

- Table 1: per scene, the stages ``base``, ``ft``, ``align``, ``ft-align`` with median rescaling.
- Table 2: anchor depth per scene: ground truth, the parallel-camera baseline and ours, with the
  errors in metres.
- Table 3: ours with metric scale from the camera height vs the stereo self-supervised baseline.
"""
from __future__ import annotations

import csv
import html
import io
import os
from typing import Any, Mapping, Sequence

TABLE1_STAGES = ("base", "ft", "align", "ft-align")
TABLE1_METRICS = ("silog", "rmse", "abs_rel", "sq_rel")
TABLE3_METHODS = (("ours (metric)", "ft-align-metric", "metric"),
                  ("stereo baseline", "stereo-baseline", "metric"))
LABELS = {"silog": "SiLog", "rmse": "RMSE", "abs_rel": "AbsRel", "sq_rel": "SqRel",
          "rmse_log": "RMSElog", "a1": "d<1.25", "a2": "d<1.25^2", "a3": "d<1.25^3"}


class Table:
    """A small table: a title, a header row and rows of cells (str or float)."""

    def __init__(self, title: str, header: Sequence[str], rows: Sequence[Sequence[Any]]):
        self.title, self.header, self.rows = title, list(header), [list(r) for r in rows]

    @staticmethod
    def _cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4f}" if abs(v) < 100 else f"{v:.2f}"
        return "-" if v is None else str(v)

    def text(self) -> str:
        cells = [self.header] + [[self._cell(v) for v in r] for r in self.rows]
        w = [max(len(r[i]) for r in cells) for i in range(len(self.header))]
        lines = [self.title, "  ".join(h.ljust(w[i]) for i, h in enumerate(self.header))]
        lines.append("  ".join("-" * x for x in w))
        lines += ["  ".join(c.rjust(w[i]) if i else c.ljust(w[i]) for i, c in enumerate(r))
                  for r in cells[1:]]
        return "\n".join(lines)

    def markdown(self) -> str:
        def md(s: str) -> str:  # Markdown viewers render raw HTML: escape it, and the cell bar
            return html.escape(str(s)).replace("|", "\\|")

        lines = [f"**{md(self.title)}**", "", "| " + " | ".join(map(md, self.header)) + " |",
                 "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(md(self._cell(v)) for v in r) + " |" for r in self.rows]
        return "\n".join(lines)

    def csv(self) -> str:
        buf = io.StringIO()
        wr = csv.writer(buf)
        wr.writerow(self.header)
        for r in self.rows:
            wr.writerow(["" if v is None else v for v in r])
        return buf.getvalue()

    def html(self) -> str:
        """The table as HTML; every string is escaped (names come from data files)."""
        esc = html.escape
        head = "".join(f"<th>{esc(str(h))}</th>" for h in self.header)
        body = "".join("<tr>" + "".join(f"<td>{esc(self._cell(v))}</td>" for v in r) + "</tr>"
                       for r in self.rows)
        return f"<h3>{esc(self.title)}</h3><table><tr>{head}</tr>{body}</table>"


def _metric(results: Mapping[str, Any], name: str, protocol: str, key: str,
            region: str = "all") -> float | None:
    try:
        return float(results[name][protocol][region][key])
    except KeyError:
        return None


def table1(evals: Mapping[str, Mapping[str, Any]]) -> Table:
    """``evals``: scene -> ``evaluate_sequence(...)["results"]`` (median protocol)."""
    rows = []
    for scene, res in evals.items():
        for stage in TABLE1_STAGES:
            if stage in res:
                rows.append([scene, stage] + [_metric(res, stage, "median", k)
                                              for k in TABLE1_METRICS])
    return Table("Table 1: adaptation stages (median rescaling, evaluation split)",
                 ["scene", "stage"] + [LABELS[k] for k in TABLE1_METRICS], rows)


def table2(anchors: Mapping[str, Mapping[str, float]]) -> Table:
    """``anchors``: scene -> {gt_m, parallel_m, ours_m} (anchor depth, metres)."""
    rows = []
    for scene, a in anchors.items():
        gt, par, ours = a.get("gt_m"), a.get("parallel_m"), a.get("ours_m")
        err = (lambda x: None if x is None or gt is None else abs(x - gt))
        rows.append([scene, gt, par, err(par), ours, err(ours)])
    return Table("Table 2: anchor depth (bottom-centre pixel), metres",
                 ["scene", "ground truth", "parallel camera", "error", "ours", "error"], rows)


def table3(evals: Mapping[str, Mapping[str, Any]]) -> Table:
    rows = []
    for scene, res in evals.items():
        for label, name, prot in TABLE3_METHODS:
            if name in res:
                rows.append([scene, label] + [_metric(res, name, prot, k) for k in TABLE1_METRICS])
    return Table("Table 3: metric depth without rescaling (evaluation split)",
                 ["scene", "method"] + [LABELS[k] for k in TABLE1_METRICS], rows)


def table_regions(evals: Mapping[str, Mapping[str, Any]], key: str = "abs_rel",
                  protocols: Mapping[str, Mapping[str, str]] | None = None) -> Table:
    """AbsRel (or ``key``) per stage and region: all pixels, agents, ground, distance bands;
    each prediction under ``protocols[scene][name]`` (the protocol ``evaluate`` gives it, from
    its stored attributes), else the one its name implies."""
    regions: list[str] = []
    for res in evals.values():
        for by_prot in res.values():
            for regs in by_prot.values():
                regions += [r for r in regs if r not in regions]
    from staticdepth.evaluate import default_protocol

    rows = []
    for scene, res in evals.items():
        for name in res:
            prot = ((protocols or {}).get(scene) or {}).get(name) or default_protocol(name)
            rows.append([scene, name, prot] + [_metric(res, name, prot, key, r) for r in regions])
    return Table(f"Regions: {LABELS.get(key, key)} by region (evaluation split)",
                 ["scene", "prediction", "protocol"] + regions, rows)


def write_tables(tables: Sequence[Table], out_dir: str | os.PathLike, stem: str = "tables") -> list[str]:
    """Write ``<stem>.md`` (all tables) and ``<stem>_<i>.csv`` per table; returns the paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    md = os.path.join(out_dir, f"{stem}.md")
    _atomic_write(md, "\n\n".join(t.markdown() for t in tables) + "\n")
    paths.append(md)
    for i, t in enumerate(tables, start=1):
        p = os.path.join(out_dir, f"{stem}_{i}.csv")
        _atomic_write(p, t.csv())
        paths.append(p)
    return paths


def _atomic_write(path: str, text: str) -> None:
    from staticdepth.fileio import atomic_write_text
    atomic_write_text(path, text)
