"""`inspect --pred`: predictions of a sequence without ground truth on the sheet."""
from __future__ import annotations

import cv2
import numpy as np

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
from staticdepth.geometry import Camera

CAM = Camera.from_fov(160, 80, 90)


def _no_gt_sequence(path, n=4):
    meta = SequenceMeta(name="site", camera=CAM, gt_kind="none", source="test", adapt_frames=2)
    rng = np.random.default_rng(0)
    with SequenceWriter(path, meta, streams=("left",)) as w:
        for i in range(n):
            w.append(left=rng.integers(0, 255, (80, 160, 3), dtype=np.uint8), timestamp=0.1 * i)
    near_left = np.where(np.arange(160) < 80, 1.0, 10.0).astype(np.float32)
    add_prediction(path, "base", [np.tile(near_left, (80, 1))] * n)


def test_inspect_pred_sheet_without_ground_truth(tmp_path, capsys):
    seq, sheet = tmp_path / "site.h5", tmp_path / "sheet.png"
    _no_gt_sequence(seq)
    assert main(["inspect", str(seq), "--sheet", str(sheet), "--pred", "base",
                 "--frames", "2"]) == 0
    img = cv2.imread(str(sheet))[..., ::-1].astype(int)
    # two columns of 240 px, rows: image, pred base (no ground-truth row)
    assert img.shape == (2 * 120, 2 * 240, 3)
    row = img[120 + 60]                     # middle line of the prediction row, first frame
    near, far = row[20:100].mean(axis=0), row[140:220].mean(axis=0)
    # near = red, far = blue
    assert near[0] > near[2] + 50 and near[0] > far[0] + 50 and far[2] > far[0]
    assert main(["inspect", str(seq), "--sheet", str(sheet), "--pred", "base"]) == 2
    assert "exists already; pass --overwrite" in capsys.readouterr().err
    assert main(["inspect", str(seq), "--sheet", str(sheet), "--pred", "ft", "--overwrite"]) == 2
    assert "no prediction 'ft'" in capsys.readouterr().err


def test_report_without_ground_truth_shows_predictions_without_metrics(tmp_path, capsys):
    seq = tmp_path / "site.h5"
    _no_gt_sequence(seq)
    out = tmp_path / "rep"
    assert main(["report", f"site={seq}", "--out", str(out)]) == 0
    html = (out / "report_site.html").read_text()
    assert "no ground truth: the predictions are shown without metrics" in html
    assert "base: depth (relative: its own colour range; no ground truth)" in html
    assert "Table 1" not in html and not (out / "tables_1.csv").exists()


def test_an_unwritable_sheet_is_refused_before_the_summary(tmp_path, capsys):
    """`inspect seq --sheet nodir/s.png` printed the whole summary, then refused the folder."""
    seq = tmp_path / "site.h5"
    _no_gt_sequence(seq)
    for out in (["--sheet", str(tmp_path / "nodir" / "s.png")],
                ["--json", str(tmp_path / "nodir" / "s.json")]):
        assert main(["inspect", str(seq), *out]) == 2
        got = capsys.readouterr()
        assert got.out == "" and got.err.count("\n") == 1, got
        assert "output's parent does not exist" in got.err
