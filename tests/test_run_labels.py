"""What ``run`` says of the stages it skips, and its --var errors."""
import numpy as np

from staticdepth.cli import main
from staticdepth.run import load_recipe, run_recipe

RECIPE = """
name: T
out_dir: "{base}/out"
stages:
  first:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", protocol: metric, json: "{out_dir}/a.json"}
    outputs: ["{out_dir}/a.json"]
  second:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", json: "{out_dir}/b.json"}
    outputs: ["{out_dir}/b.json"]
  third:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", json: "{out_dir}/c.json"}
    outputs: ["{out_dir}/c.json"]
"""


def _labels(logs):
    return {line.split("] ", 1)[1].split(":", 1)[0]: line.split(": ", 1)[1] for line in logs}


def test_stages_after_one_run_alone_are_out_of_date_not_up_to_date(tmp_path):
    """--only first after a change to it: second and third are stale (the next dry run runs
    them); third's own recorded hash still chains second's, which once read 'up to date'."""
    gt = np.random.default_rng(0).uniform(1, 30, (2, 8, 8))
    np.save(tmp_path / "gt.npy", gt)
    np.save(tmp_path / "pred.npy", gt * 2)
    rp = tmp_path / "r.yaml"
    rp.write_text(RECIPE)
    assert set(run_recipe(load_recipe(rp, {"base": str(tmp_path)}), log=[].append).values()) \
        == {"ran"}
    logs = []
    assert run_recipe(load_recipe(rp, {"base": str(tmp_path)}), log=logs.append) == \
        dict.fromkeys(("first", "second", "third"), "skipped")
    assert set(_labels(logs).values()) == {"up to date, skipped"}
    rp.write_text(RECIPE.replace("protocol: metric", "protocol: median"))
    r2 = load_recipe(rp, {"base": str(tmp_path)})
    logs = []
    assert run_recipe(r2, only=["first"], log=logs.append)["first"] == "ran"
    labels = _labels(logs)
    assert labels["second"] == labels["third"] == "out of date, not selected, skipped", logs
    dry = []
    assert run_recipe(r2, dry_run=True, log=dry.append) == \
        {"first": "skipped", "second": "dry-run", "third": "dry-run"}


def test_a_var_without_equals_names_var(tmp_path, capsys):
    rp = tmp_path / "r.yaml"
    rp.write_text(RECIPE)
    assert main(["run", str(rp), "--var", "base", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "--var expects key=value" in err and "--set" not in err, err
