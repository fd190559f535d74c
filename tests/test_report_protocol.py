"""The report scores each prediction with the protocol ``evaluate`` gives it.

The report's panels used the name-only protocol (a metric stereo map stored with ``metric = 1``
was median-rescaled, hiding its 30% scale error), scored confidence maps as depth, and said
nothing when a file's predictions store no ``metric`` attribute (an older file, or another tool):
now their protocol comes from the name, said in one note line (stdout and the HTML page).
"""
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
from staticdepth.geometry import Camera, Mounting, plane_depth_map
from staticdepth.report import build_report, sequence_figures


def _sequence(path, attrs: bool):
    """Ground truth on a plane; ``stereo`` is metric and 1.3x too far, ``base`` 2x (relative)."""
    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    gt = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 80, 40)
    with SequenceWriter(path, SequenceMeta(name="s", camera=cam, gt_kind="synthetic",
                                           adapt_frames=2, mounting=mnt),
                        streams=("left", "depth")) as w:
        for i in range(4):
            w.append(left=np.full((40, 80, 3), 60 * i, np.uint8), depth=gt)
    add_prediction(path, "base", [2.0 * gt] * 4, {"metric": 0} if attrs else None)
    add_prediction(path, "stereo", [1.3 * gt] * 4,
                   {"kind": "depth", "metric": 1, "confidence": "stereo-confidence"} if attrs
                   else None)
    add_prediction(path, "ft-align-metric", [1.1 * gt] * 4, {"metric": 1} if attrs else None)
    if attrs:
        add_prediction(path, "stereo-confidence", [np.full((40, 80), 0.5, np.float32)] * 4,
                       {"kind": "confidence", "of": "stereo"})
    return path


def _captions(path):
    """The depth panels' captions, in the pipeline's order."""
    return [c for c, _ in sequence_figures(path) if ": depth (" in c]


def test_stored_attributes_choose_the_protocol_and_confidence_is_not_depth(tmp_path, capsys):
    p = _sequence(tmp_path / "s.h5", attrs=True)
    assert [c.split(". ", 1)[1] for c in _captions(p)] == [
        "base: depth (median protocol, scale 0.5)",
        "ft-align-metric: depth (metric protocol, scale 1)",
        "stereo: depth (metric protocol, scale 1)"]
    res = build_report({"S": str(p)}, tmp_path / "rep")
    assert sorted(res["evals"]["S"]) == ["base", "ft-align-metric", "stereo"]
    assert res["evals"]["S"]["stereo"]["metric"]["all"]["abs_rel"] == pytest.approx(0.3, abs=1e-5)
    assert "note:" not in capsys.readouterr().out


def test_predictions_without_the_attribute_are_named_in_one_note(tmp_path, capsys):
    p = _sequence(tmp_path / "old.h5", attrs=False)
    out = tmp_path / "rep"
    assert main(["report", f"S={p}", "--out", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("note:")]
    note = (f"note: {p}: 3 prediction(s) store no 'metric' attribute; protocol from the name "
            "(metric if it ends in -metric or starts with stereo-baseline, else median): "
            "base median, ft-align-metric metric, stereo median")
    assert notes == [note]
    assert f"<p>{note}</p>" in (out / "report_S.html").read_text().replace("&#x27;", "'")
    assert [c.split(". ", 1)[1] for c in _captions(p)] == [
        "base: depth (median protocol, scale 0.5)",
        "ft-align-metric: depth (metric protocol, scale 1)",
        "stereo: depth (median protocol, scale 0.769)"]


def test_the_regions_table_uses_each_predictions_protocol(tmp_path):
    """The regions table named the protocol from the prediction's name: the stored metric stereo
    map (1.3x too far) was a median row with AbsRel 0.000; now metric, 0.300, as evaluate says."""
    p = _sequence(tmp_path / "s.h5", attrs=True)
    build_report({"S": str(p)}, tmp_path / "rep")
    md = (tmp_path / "rep" / "tables.md").read_text()
    block = md[md.index("Regions:"):]
    rows = {cells[2]: cells[3:6] for cells in (
        [c.strip() for c in ln.split("|")] for ln in block.splitlines()[2:] if ln.startswith("|"))
        if len(cells) > 5 and cells[1] == "S"}
    assert rows["stereo"][0] == "metric" and float(rows["stereo"][1]) == pytest.approx(0.3, 1e-3)
    assert rows["base"][0] == "median" and float(rows["base"][1]) == pytest.approx(0, abs=1e-3)
    assert rows["ft-align-metric"][0] == "metric"
    assert float(rows["ft-align-metric"][1]) == pytest.approx(0.1, 1e-3)


def test_evaluate_says_which_protocols_came_from_names(tmp_path, capsys):
    """evaluate fell back on the names without a word; now the same note line as report's."""
    p = _sequence(tmp_path / "old.h5", attrs=False)
    assert main(["evaluate", str(p)]) == 0
    out = capsys.readouterr().out
    assert (f"note: {p}: 3 prediction(s) store no 'metric' attribute; protocol from the name "
            "(metric if it ends in -metric or starts with stereo-baseline, else median): base "
            "median, ft-align-metric metric, stereo median") in out.splitlines()
    p2 = _sequence(tmp_path / "new.h5", attrs=True)
    assert main(["evaluate", str(p2)]) == 0
    assert "note:" not in capsys.readouterr().out
    assert main(["evaluate", str(p), "--protocol", "metric"]) == 0    # chosen: nothing guessed
    assert "note:" not in capsys.readouterr().out
