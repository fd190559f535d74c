"""The demo end to end on its quick settings: every stage runs and the outputs are consistent."""
import csv
import json

import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.demo import DEMO_RECIPE


def test_demo_recipe_is_the_shipped_recipe(tmp_path):
    from conftest import REPO

    assert (REPO / "recipes" / "demo.yaml").read_text() == open(DEMO_RECIPE).read()


def test_quick_demo_runs_every_stage_and_writes_the_tables(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for t in ("Table 1", "Table 2", "Table 3"):
        assert t in text
    with SequenceReader(out / "demo.h5") as r:
        assert set(r.predictions()) == {"base", "ft", "align", "ft-align", "align-metric",
                                        "ft-align-metric", "stereo-baseline"}
        assert len(r) == 30 and len(r.split("adapt")) == 20
    summary = json.loads((out / "demo.adapt.json").read_text())
    with open(out / "report" / "tables_2.csv") as f:
        row = list(csv.DictReader(f))[0]
    gt = float(row["ground truth"])
    assert float(row["ours"]) == pytest.approx(summary["anchor_depth_m"])
    # the tilted camera: the parallel-camera baseline is far off, the agents' plane is not
    assert abs(float(row["ours"]) - gt) < 0.1 * gt < abs(float(row["parallel camera"]) - gt)
    assert (out / "report" / "report_demo.html").stat().st_size > 10_000
    assert (out / "demo_depth.png").exists()
    # a second run finds every stage up to date
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    assert capsys.readouterr().out.count("up to date, skipped") == 6
