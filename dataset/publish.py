"""Release folders: sequence files, their KITTI-style export, a dataset card and a SHA-256 manifest.

Layout: ``sequences/<name>.h5``, ``kitti/<name>/...`` (see :mod:`staticdepth.dataset.export`),
``README.md`` (the dataset card), ``dataset_card.json`` (the same facts, machine-readable) and
``MANIFEST.sha256`` (``sha256sum`` format: ``<hex>  <relative path>``, every other file listed
but lock files, ``<path>.lock`` beside ``<path>``, which the writers leave and a release needs not).
:func:`verify_release` (used by ``staticdepth verify DIR``) re-hashes every file, reports files that
are missing or not listed, and re-checks every sequence's frame checksums. Names in the Markdown
card are one line each and escaped (HTML, table bars), as in the Markdown reports.
"""
from __future__ import annotations

import hashlib
import html
import json
import os
import shutil
import time
from typing import Any, Sequence

import numpy as np

from staticdepth import __version__
from staticdepth.dataset.export import beyond_range_note, export_kitti, replace_dir
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError
from staticdepth.progress import progress
from staticdepth.tables import Table

MANIFEST = "MANIFEST.sha256"
CARD_JSON = "dataset_card.json"
CARD_MD = "README.md"


def sha256_file(path: str | os.PathLike, block: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def _is_lock(root: str, rel: str) -> bool:
    """``rel`` is a lock file (``fileio.exclusive_lock``'s ``<path>.lock`` beside ``<path>``)."""
    return rel.endswith(".lock") and os.path.lexists(os.path.join(root, rel[:-len(".lock")]))


def _files(root: str, locks: bool = False) -> list[str]:
    """Every file under ``root`` (lock files only with ``locks``), as sorted relative paths."""
    out = []
    for d, _, names in os.walk(root):
        out += [os.path.relpath(os.path.join(d, n), root).replace(os.sep, "/") for n in names]
    return sorted(rel for rel in out if locks or not _is_lock(root, rel))


def sequence_card(reader: SequenceReader) -> dict[str, Any]:
    """Card entry for one sequence: camera, rig, height, splits, ground truth, its statistics."""
    m = reader.meta
    dens, lo, hi, meds = [], np.inf, -np.inf, []
    if reader.has("depth"):
        for i in range(len(reader)):
            d = reader.depth(i)
            ok = np.isfinite(d) & (d > 0)
            dens.append(float(ok.mean()))
            if ok.any():
                v = d[ok]
                lo, hi = min(lo, float(v.min())), max(hi, float(v.max()))
                meds.append(float(np.median(v)))
    prov = dict(m.provenance)
    stereo = {k: prov[k] for k in ("matcher", "stereo_config", "model") if k in prov}
    return {
        "name": m.name, "frames": len(reader), "width": reader.width, "height": reader.height,
        "streams": reader.streams(),
        "splits": {"adapt": [0, m.adapt_frames], "eval": [m.adapt_frames, len(reader)]},
        "camera": {k: v for k, v in m.camera.to_dict().items() if k in ("fx", "fy", "cx", "cy")},
        "rig": None if m.rig is None else {"baseline_m": m.rig.baseline_m},
        "camera_height_m": m.camera_height_m,
        "mounting": None if m.mounting is None else {"pitch_deg": m.mounting.pitch_deg,
                                                     "roll_deg": m.mounting.roll_deg},
        "ground_truth": {"kind": m.gt_kind, "source": m.source,
                         "method": prov.get("ground_truth", m.gt_kind), **stereo},
        "statistics": None if not dens else {
            "density_mean": float(np.mean(dens)), "density_min": float(np.min(dens)),
            "depth_min_m": lo if np.isfinite(lo) else None,
            "depth_max_m": hi if np.isfinite(hi) else None,
            "depth_median_of_frame_medians_m": float(np.median(meds)) if meds else None},
        "skipped_input_frames": len(prov.get("skipped", [])),
        "toolkit_version": str(reader.attrs.get("toolkit_version", "")),
    }


def _one_line(text: Any) -> str:
    """Text from a data file as one line (line breaks and runs of white space become a space)."""
    return " ".join(str(text).split())


def _md_text(text: Any) -> str:
    """One line of Markdown text outside a table: HTML escaped (Markdown viewers render it)."""
    return html.escape(_one_line(text))


def card_markdown(card: dict[str, Any]) -> str:
    rows = []
    for s in card["sequences"]:
        st = s["statistics"] or {}
        rng = (f"{st['depth_min_m']:.2f} - {st['depth_max_m']:.2f}"
               if st.get("depth_min_m") is not None else "-")
        rows.append([
            _one_line(s["name"]), str(s["frames"]), f"{s['width']}x{s['height']}",
            f"{s['splits']['adapt'][1]} / {s['frames'] - s['splits']['adapt'][1]}",
            str(s["camera_height_m"]) if s["camera_height_m"] is not None else "-",
            "-" if s["rig"] is None else str(round(s["rig"]["baseline_m"], 4)),
            _one_line(s["ground_truth"]["kind"]),
            "-" if not st else format(st["density_mean"], ".3f"), rng])
    # the Markdown reports' table: cells escaped (HTML, the cell bar)
    table = Table("Summary", ["sequence", "frames", "size", "adapt / eval", "camera height (m)",
                              "baseline (m)", "ground truth", "density", "depth range (m)"], rows)
    lines = [f"# {_md_text(card['title'])}", "", f"Released {card['created']} with staticdepth "
             f"{card['toolkit_version']}.", "", f"**Licence:** {_md_text(card['licence'])}", "",
             table.markdown()]
    lines += ["", "Splits: the first N frames of each sequence are the adaptation split, the rest "
              "the evaluation split. Depth is in metres; in the KITTI-style export it is stored "
              "as uint16 PNG = depth x 256, 0 = unknown."]
    for s in card["sequences"]:
        if s.get("export_depth_beyond_range_px"):
            lines += ["", f"In the export of {_md_text(s['name'])}, "
                          f"{beyond_range_note(s['export_depth_beyond_range_px'])}."]
    lines += ["", "## Sequences", ""]
    for s in card["sequences"]:
        lines += [f"### {_md_text(s['name'])}", "", "```json", json.dumps(s, indent=2), "```",
                  ""]
    lines += ["## Files", "",
              "- `sequences/*.h5`: sequence files (read with `staticdepth inspect`)",
              "- `sequences/*.h5.pred/*.h5`: predictions stored beside each sequence",
              "- `kitti/<name>/`: KITTI-style export", f"- `{MANIFEST}`: SHA-256 of every file; "
              "check with `staticdepth verify <this folder>`", "", "## Citation", "",
              card["citation"] or "(none given)", ""]
    return "\n".join(lines)


def publish(files: Sequence[str | os.PathLike], out: str | os.PathLike, *,
            title: str | None = None, licence: str = "unspecified", citation: str | None = None,
            export: bool = True, overwrite: bool = False) -> dict[str, Any]:
    """Build the release folder ``out`` (atomically: beside it, then renamed)."""
    from staticdepth.dataset.export import check_replaceable
    from staticdepth.fileio import check_output_parent, exclusive_lock

    out = os.fspath(out)
    check_output_parent(out)
    check_replaceable(out, overwrite, is_release, "a staticdepth release folder")
    if not files:
        raise InputError("publish needs at least one sequence file")
    stems = [os.path.splitext(os.path.basename(os.fspath(f)))[0] for f in files]
    for i, stem in enumerate(stems):
        if stem in stems[:i]:
            first = os.fspath(files[stems.index(stem)])
            if os.path.realpath(first) == os.path.realpath(os.fspath(files[i])):
                raise InputError("is given twice (each sequence once)", files[i])
            raise InputError(f"two input files share the name {stem!r}: {first} and "
                             f"{os.fspath(files[i])} (a release names its sequences by file "
                             "name: rename one)")
    with exclusive_lock(out, what="writing"):
        return _publish(files, stems, out, title, licence, citation, export, overwrite)


def is_release(path: str) -> bool:
    """A release folder written by :func:`publish` (manifest and dataset card present)."""
    try:
        with open(os.path.join(path, CARD_JSON)) as f:
            card = json.load(f)
        return os.path.isfile(os.path.join(path, MANIFEST)) and "sequences" in card
    except (OSError, ValueError):
        return False


def _publish(files, stems, out, title, licence, citation, export, overwrite) -> dict[str, Any]:
    from staticdepth.fileio import os_error, remove_stale_temporaries, temporary_path

    remove_stale_temporaries(out)
    tmp = temporary_path(out, "publish")
    try:
        os.makedirs(os.path.join(tmp, "sequences"))
        cards, preds_listed = [], []
        for f, stem in zip(files, stems):
            with SequenceReader(f) as r:
                problems = r.checksum_errors()
                if problems:
                    raise InputError(f"sequence fails verification: {problems[0]}", f)
                cards.append(sequence_card(r))
            shutil.copyfile(f, os.path.join(tmp, "sequences", stem + ".h5"))
            preds_listed += [f"sequences/{stem}.h5.pred/{n}.h5"
                             for n in _copy_predictions(f, os.path.join(tmp, "sequences",
                                                                        stem + ".h5"))]
            if export:
                os.makedirs(os.path.join(tmp, "kitti"), exist_ok=True)
                info = export_kitti(os.path.join(tmp, "sequences", stem + ".h5"),
                                    os.path.join(tmp, "kitti", stem))
                cards[-1]["export_depth_beyond_range_px"] = info["depth_beyond_range_px"]
        for rel in sorted(set(_files(tmp, locks=True)) - set(_files(tmp))):
            os.remove(os.path.join(tmp, rel))  # the export's lock files: not part of a release
        card = {"title": title or "staticdepth release: " + ", ".join(c["name"] for c in cards),
                "created": time.strftime("%Y-%m-%d"), "licence": licence, "citation": citation,
                "toolkit_version": __version__, "sequences": cards,
                "files": {"sequences": [f"sequences/{s}.h5" for s in stems],
                          "kitti": [f"kitti/{s}" for s in stems] if export else [],
                          "predictions": preds_listed}}
        with open(os.path.join(tmp, CARD_JSON), "w") as fh:
            json.dump(card, fh, indent=2)
        with open(os.path.join(tmp, CARD_MD), "w") as fh:
            fh.write(card_markdown(card))
        listed = _files(tmp)
        with open(os.path.join(tmp, MANIFEST), "w") as fh:
            for rel in progress(listed, total=len(listed), desc="sha256", unit="file"):
                fh.write(f"{sha256_file(os.path.join(tmp, rel))}  {rel}\n")
        replace_dir(tmp, out, overwrite, is_release, "a staticdepth release folder")
    except OSError as e:
        raise os_error(e, out) from None
    finally:
        if os.path.exists(tmp):
            shutil.rmtree(tmp)
    return {"path": out, "sequences": [c["name"] for c in cards], "files": len(listed) + 1,
            "depth_beyond_range_px": {f"kitti/{stem}": c["export_depth_beyond_range_px"]
                                      for stem, c in zip(stems, cards)
                                      if c.get("export_depth_beyond_range_px")}}


def _copy_predictions(seq: str | os.PathLike, dst_seq: str) -> list[str]:
    """Copy the sequence's sidecar predictions (``<seq>.pred/*.h5``) beside its copy; verified
    first (identity and every frame's checksum)."""
    from staticdepth.dataset.predictions import (prediction_names, prediction_path,
                                                 verify_predictions)

    names = prediction_names(seq)
    problems = verify_predictions(seq)
    if problems:
        raise InputError(f"prediction fails verification: {problems[0]}", seq)
    for n in names:
        os.makedirs(os.path.dirname(prediction_path(dst_seq, n)), exist_ok=True)
        shutil.copyfile(prediction_path(seq, n), prediction_path(dst_seq, n))
    return names


def verify_release(folder: str | os.PathLike) -> list[str]:
    """Problems with a release folder (empty when intact): manifest, hashes, card, sequences."""
    folder = os.fspath(folder)
    mpath = os.path.join(folder, MANIFEST)
    if not os.path.isfile(mpath):
        return [f"no {MANIFEST} (not a release folder)"]
    problems: list[str] = []
    listed: dict[str, str] = {}
    with open(mpath) as f:
        for k, line in enumerate(f, 1):
            digest, sep, rel = line.rstrip("\n").partition("  ")
            if not sep or len(digest) != 64 or not rel:
                problems.append(f"{MANIFEST} line {k}: malformed")
                continue
            listed[rel] = digest
    listed = {rel: d for rel, d in listed.items() if not _is_lock(folder, rel)}
    present = set(_files(folder)) - {MANIFEST}
    for rel in sorted(set(listed) - present):
        problems.append(f"{rel}: listed in the manifest but missing")
    for rel in sorted(present - set(listed)):
        problems.append(f"{rel}: not in the manifest")
    for rel in progress(sorted(set(listed) & present), desc="sha256", unit="file"):
        if sha256_file(os.path.join(folder, rel)) != listed[rel]:
            problems.append(f"{rel}: SHA-256 mismatch")
    try:
        with open(os.path.join(folder, CARD_JSON)) as f:
            card = json.load(f)
        for rel in card["files"]["sequences"]:
            if not os.path.isfile(os.path.join(folder, rel)):
                problems.append(f"{CARD_JSON}: lists {rel}, which is missing")
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as e:
        problems.append(f"{CARD_JSON}: unreadable ({e})")
    for rel in sorted(r for r in present if r.startswith("sequences/") and r.endswith(".h5")
                      and r.count("/") == 1):     # not sequences/<name>.h5.pred/<pred>.h5
        try:
            with SequenceReader(os.path.join(folder, rel)) as r:
                problems += [f"{rel}: {p}" for p in r.checksum_errors()]
            from staticdepth.dataset.predictions import verify_predictions

            problems += [f"{rel}: {p}" for p in verify_predictions(os.path.join(folder, rel))]
        except InputError as e:
            problems.append(f"{rel}: {e.problem}")
    return problems
