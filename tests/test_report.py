"""Tables and the HTML report on a sequence with known predictions."""
import json
import re

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
from staticdepth.geometry import Camera, Mounting, plane_depth_map
from staticdepth.tables import table2


@pytest.fixture
def seq(tmp_path):
    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    gt = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 80, 40)
    p = tmp_path / "scene.h5"
    ag = schema.empty_agents(1)
    ag["instance_id"], ag["class_id"], ag["track_id"], ag["foot_u"], ag["foot_v"] = 1, 0, 7, 40, 30
    with SequenceWriter(p, SequenceMeta(name="s", camera=cam, gt_kind="synthetic", adapt_frames=2,
                                        mounting=mnt), streams=("left", "depth")) as w:
        for i in range(4):
            w.append(left=np.full((40, 80, 3), 60 * i, np.uint8), depth=gt, agents=ag)
    for name, f in (("base", 2.0), ("ft", 3.0), ("align", 1.0), ("ft-align", 1.0),
                    ("ft-align-metric", 1.1), ("stereo-baseline", 0.95)):
        pred = gt * f
        if name == "base":
            pred = pred * np.linspace(0.8, 1.2, 80)[None, :]  # a tilt median scaling cannot fix
        add_prediction(p, name, [pred] * 4)
    return p, gt


def test_report_writes_three_tables_and_offline_html(seq, tmp_path, capsys):
    p, gt = seq
    summary = tmp_path / "sum.json"
    summary.write_text(json.dumps({"anchor_depth_m": 5.5, "anchor_depth_parallel_m": 10.0,
                                   "planes": {"agents": {"normal": [0, 0.7071, 0.7071], "d": 5.0}}}))
    out = tmp_path / "rep"
    assert main(["report", f"S1={p}", "--summary", f"S1={summary}", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Table 1" in text and "Table 2" in text and "Table 3" in text
    t1 = (out / "tables_1.csv").read_text().splitlines()
    assert t1[0] == "scene,stage,SiLog,RMSE,AbsRel,SqRel"
    rows = {r.split(",")[1]: [float(x) for x in r.split(",")[2:]] for r in t1[1:]}
    assert rows["align"][2] == pytest.approx(0, abs=1e-6) and rows["base"][2] > 0.02
    t3 = (out / "tables_3.csv").read_text().splitlines()
    assert any(r.startswith("S1,ours (metric)") and abs(float(r.split(",")[4]) - 0.1) < 1e-5
               for r in t3)
    assert any(r.startswith("S1,stereo baseline") and abs(float(r.split(",")[4]) - 0.05) < 1e-5
               for r in t3)
    t2 = (out / "tables_2.csv").read_text().splitlines()[1].split(",")
    gt_anchor = float(np.median(gt[35:40, 38:43]))
    assert float(t2[1]) == pytest.approx(gt_anchor, rel=1e-5)
    assert float(t2[5]) == pytest.approx(abs(5.5 - gt_anchor), rel=1e-5)
    regions = (out / "tables_4.csv").read_text().splitlines()
    assert regions[0].startswith("scene,prediction,protocol,all,")
    assert "0-10m" in regions[0]
    align = next(r for r in regions if r.startswith("S1,align,median"))
    assert float(align.split(",")[3]) == pytest.approx(0, abs=1e-6)
    html = (out / "report_S1.html").read_text()
    assert html.count("<img src='data:image/png;base64,") >= 10
    assert not re.search(r"src=['\"]http", html)  # viewable offline
    assert (out / "tables.md").read_text().count("| S1 |") >= 6


def test_report_without_predictions_is_an_error(tmp_path, capsys):
    cam = Camera.from_fov(80, 40, 90)
    p = tmp_path / "s.h5"
    with SequenceWriter(p, SequenceMeta(name="s", camera=cam), streams=("left", "depth")) as w:
        w.append(left=np.zeros((40, 80, 3), np.uint8), depth=np.ones((40, 80), np.float32))
    assert main(["report", str(p), "--out", str(tmp_path / "r")]) == 2
    assert "no predictions" in capsys.readouterr().err


def test_table2_errors_in_metres():
    t = table2({"C1": {"gt_m": 10.0, "parallel_m": 7.0, "ours_m": 10.5}})
    assert t.rows[0] == ["C1", 10.0, 7.0, 3.0, 10.5, 0.5]
    assert "C1" in t.text() and t.csv().splitlines()[1] == "C1,10.0,7.0,3.0,10.5,0.5"


def test_report_without_ground_truth_labels_what_it_draws(tmp_path):
    """A camera without ground truth (import-video, adapt): the metric panels read in metres over
    one shared range (they each had their own, labelled "relative"), the relative ones keep their
    own range and that label, and the planes' caption names only the planes drawn (it named a
    green true plane the sequence does not have)."""
    from staticdepth import report_figures as rf
    from staticdepth.report import sequence_figures

    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    depth = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 80, 40)
    depth = np.where(np.isfinite(depth), depth, 60.0).astype(np.float32)
    ag = schema.empty_agents(1)
    ag["instance_id"], ag["class_id"], ag["track_id"], ag["foot_u"], ag["foot_v"] = 1, 0, 7, 40, 30
    p = tmp_path / "site.h5"
    with SequenceWriter(p, SequenceMeta(name="site", camera=cam, adapt_frames=2),
                        streams=("left",)) as w:
        for i in range(4):
            w.append(left=np.full((40, 80, 3), 60 * i, np.uint8), agents=ag)
    preds = {"base": 1.0 / depth, "align": depth / 5.0, "align-metric": depth,
             "ft-align-metric": 2.0 * depth}
    for name, pred in preds.items():
        add_prediction(p, name, [pred] * 4, {"metric": name.endswith("-metric")})
    figs = dict((c.split(". ", 1)[1].split(":")[0], (c, img))
                for c, img in sequence_figures(p, {"planes": {"agents": {
                    "normal": mnt.normal.tolist(), "d": mnt.height_m}}}))
    shared = rf.depth_range(np.concatenate([depth.ravel(), 2.0 * depth.ravel()]))
    for name in ("align-metric", "ft-align-metric"):
        caption, img = figs[name]
        assert "metric, metres" in caption
        np.testing.assert_array_equal(img, rf.depth_panel(preds[name], name, shared))
    assert np.any(figs["align-metric"][1] != figs["ft-align-metric"][1])  # 2x farther: colours
    for name in ("base", "align"):
        caption, img = figs[name]
        assert "relative" in caption
        np.testing.assert_array_equal(img, rf.depth_panel(preds[name], name, None))
    caption = figs["ground planes"][0]
    assert "orange from the agents" in caption and "green" not in caption, caption
