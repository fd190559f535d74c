"""``report`` checks its inputs before it writes: summaries of other sequences, unknown labels,
missing files, and says why a sequence without ground truth gets no tables."""
import json

import numpy as np

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
from staticdepth.geometry import Camera


def _sequence(path, gt: bool = True):
    cam = Camera.from_fov(32, 16, 90)
    depth = np.full((16, 32), 5.0, np.float32)
    streams = ("left", "depth") if gt else ("left",)
    with SequenceWriter(path, SequenceMeta(name=path.stem, camera=cam, adapt_frames=1),
                        streams=streams) as w:
        for i in range(2):
            w.append(left=np.full((16, 32, 3), 60 * i, np.uint8),
                     **({"depth": depth} if gt else {}))
    add_prediction(path, "align-metric", [depth * 1.1] * 2, {"metric": True})
    return path


def _summary(path, sequence):
    path.write_text(json.dumps({"sequence": str(sequence), "anchor_depth_m": 5.0}))
    return path


def test_a_summary_of_another_sequence_is_named_in_one_warning(tmp_path, capsys):
    s = _sequence(tmp_path / "s.h5")
    other = _sequence(tmp_path / "other.h5")
    summ = _summary(tmp_path / "other.adapt.json", other)
    assert main(["report", f"s={s}", "--summary", f"s={summ}", "--out", str(tmp_path / "R")]) == 0
    warnings = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and str(other) in warnings[0] and str(s) in warnings[0], warnings
    # its own summary, or one of a moved folder (same file name, old path gone), passes quietly
    for recorded in (s, tmp_path / "moved" / "s.h5"):
        _summary(summ, recorded)
        assert main(["report", f"s={s}", "--summary", f"s={summ}", "--out",
                     str(tmp_path / "R"), "--overwrite"]) == 0
        assert "warning:" not in capsys.readouterr().out


def test_a_summary_label_of_no_sequence_is_refused_before_any_work(tmp_path, capsys):
    s = _sequence(tmp_path / "s.h5")
    summ = _summary(tmp_path / "s.adapt.json", s)
    out = tmp_path / "R"
    assert main(["report", f"s={s}", "--summary", f"other={summ}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "--summary" in err and "'other'" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_a_missing_sequence_leaves_no_output_folder(tmp_path, capsys):
    out = tmp_path / "R"
    assert main(["report", f"demo={tmp_path / 'nope.h5'}", "--out", str(out)]) == 2
    assert "nope.h5" in capsys.readouterr().err
    assert not out.exists()


def test_no_ground_truth_says_why_there_are_no_tables(tmp_path, capsys):
    s = _sequence(tmp_path / "site.h5", gt=False)
    out = tmp_path / "R"
    assert main(["report", str(s), "--out", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().out.splitlines() if "no tables" in ln]
    assert len(notes) == 1 and "ground truth" in notes[0], notes
    assert sorted(p.name for p in out.iterdir()) == ["report_site.html"]


def test_a_report_folder_holds_one_report(tmp_path, capsys):
    """``report --overwrite`` into a folder left an earlier run's pages of other scenes and, when
    the new run wrote no tables (no ground truth), the earlier run's tables beside its own page.
    Every earlier report file is refused without --overwrite and replaced or removed with it."""
    a, b = _sequence(tmp_path / "a.h5"), _sequence(tmp_path / "b.h5", gt=False)
    out = tmp_path / "R"
    assert main(["report", f"D1={a}", "--out", str(out)]) == 0
    first = sorted(p.name for p in out.iterdir())
    assert first == ["report_D1.html", "tables.md", "tables_1.csv", "tables_2.csv",
                     "tables_3.csv", "tables_4.csv"]
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    assert main(["report", f"S={b}", "--out", str(out)]) == 2          # another scene: refused
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already; pass --overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["report", f"S={b}", "--out", str(out), "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["report_S.html"]
    (out / "notes.txt").write_text("mine")                      # not a report file: kept
    assert main(["report", f"D2={a}", "--out", str(out), "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "report_D2.html", *first[1:]]


def test_a_bare_summary_path_goes_with_its_sequence(tmp_path, capsys):
    """`report site.h5 --summary site.adapt.json` was refused ('no sequence labelled
    'site.adapt''): a bare sequence got its file stem as label, its summary a stem adapt never
    gives. Table 2 now shows the summary's anchor depth."""
    s = _sequence(tmp_path / "site.h5")
    summ = _summary(tmp_path / "site.adapt.json", s)
    assert main(["report", str(s), "--summary", str(summ), "--out", str(tmp_path / "R")]) == 0
    table2 = (tmp_path / "R" / "tables_2.csv").read_text().splitlines()
    assert "5.0" in table2[1] and table2[1].startswith("site,"), table2


def test_a_report_folder_named_with_glob_characters(tmp_path, capsys):
    """The folder's name went into the paths escaped for glob ('R[[]1]/tables.md'), so its
    tables.md was never found: an earlier report's tables were replaced without --overwrite."""
    a = _sequence(tmp_path / "a.h5")
    out = tmp_path / "R[1]{x}"
    assert main(["report", f"D1={a}", "--out", str(out)]) == 0
    before = (out / "tables.md").read_bytes()
    capsys.readouterr()
    assert main(["report", f"D1={a}", "--out", str(out)]) == 2
    assert str(out / "tables.md") in capsys.readouterr().err
    assert (out / "tables.md").read_bytes() == before
