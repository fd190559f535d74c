"""Recipe runner: placeholders, argv building, skipping up-to-date stages, errors."""
import json
from pathlib import Path

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.run import argv_from_args, load_recipe, run_recipe

RECIPE = """
name: T
out_dir: "{base}/out"
vars: {factor: "2"}
stages:
  first:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", protocol: metric, json: "{out_dir}/a.json"}
    outputs: ["{out_dir}/a.json"]
  second:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", json: "{out_dir}/b.json"}
    outputs: ["{out_dir}/b.json"]
"""


def test_argv_from_args():
    argv = argv_from_args("baseline train", {"_": ["s.h5"], "epochs": 3, "fill": True,
                                              "skip": False, "drives": ["a", "b"],
                                              "set": {"lr": 0.1, "tracking": {"min_frames": 2}},
                                              "max_depth": 80})
    assert argv == ["baseline", "train", "s.h5", "--epochs", "3", "--fill", "--drives", "a", "b",
                    "--set", "lr=0.1", "--set", "tracking.min_frames=2", "--max-depth", "80"]


def test_recipe_runs_then_skips_then_reruns_changed_stage(tmp_path):
    gt = np.random.default_rng(0).uniform(1, 30, (2, 8, 8))
    np.save(tmp_path / "gt.npy", gt)
    np.save(tmp_path / "pred.npy", gt * 2)
    rp = tmp_path / "r.yaml"
    rp.write_text(RECIPE)
    logs = []
    r = load_recipe(rp, {"base": str(tmp_path)})
    assert run_recipe(r, log=logs.append) == {"first": "ran", "second": "ran"}
    assert json.loads((tmp_path / "out" / "a.json").read_text())["abs_rel"] == pytest.approx(1.0)
    assert run_recipe(r, log=logs.append) == {"first": "skipped", "second": "skipped"}
    # a change in the first stage's settings reruns it and everything after it
    rp.write_text(RECIPE.replace("protocol: metric", "protocol: median"))
    r2 = load_recipe(rp, {"base": str(tmp_path)})
    assert run_recipe(r2, log=logs.append) == {"first": "ran", "second": "ran"}
    (tmp_path / "out" / "b.json").unlink()  # a missing output reruns its stage
    assert run_recipe(r2, log=logs.append)["second"] == "ran"
    assert main(["run", str(rp), "--var", f"base={tmp_path}", "--dry-run"]) == 0


def test_recipe_errors(tmp_path, capsys):
    rp = tmp_path / "r.yaml"
    rp.write_text("name: T\nstages: {a: {command: metrics, args: {pred: '{nope}'}}}\n")
    with pytest.raises(InputError, match=r"unknown placeholder \{nope\}"):
        load_recipe(rp)
    rp.write_text("name: T\nstagez: {}\n")
    assert main(["run", str(rp)]) == 2
    assert "unknown recipe key(s) ['stagez']" in capsys.readouterr().err
    rp.write_text("name: T\nout_dir: " + str(tmp_path / "o") +
                  "\nstages: {a: {command: metrics, args: {pred: x.npy, gt: y.npy}}}\n")
    assert main(["run", str(rp)]) == 2
    assert "stage 'a' failed" in capsys.readouterr().err


@pytest.mark.parametrize("recipe", sorted((Path(__file__).parents[1] / "recipes").glob("*.yaml")),
                         ids=lambda p: p.stem)
def test_shipped_recipes_parse_against_the_real_cli(recipe):
    """Every stage of every shipped recipe is a valid command line of the real parser."""
    from staticdepth.cli import build_parser

    r = load_recipe(recipe)
    assert r["stages"], recipe
    parser = build_parser()
    for name, st in r["stages"].items():
        argv = argv_from_args(st["command"], st["args"])
        try:
            args = parser.parse_args(argv)
        except SystemExit:
            pytest.fail(f"{recipe.name} stage {name}: invalid command line {argv}")
        assert callable(args.func)
        if st["command"] == "adapt":     # every setting is a valid key of the adaptation's tree
            from staticdepth.adapt import config_from_args

            config_from_args(args)
        if st["command"] == "baseline predict":
            # its output is the prediction it writes, not the sequence (which it never rewrites):
            # the sequence as output made `run` pass --overwrite on a first run and never redo
            # the stage when the prediction was deleted
            from staticdepth.dataset.predictions import prediction_path

            assert st["outputs"] == [prediction_path(st["args"]["_"][0], args.name)], name


CHAIN = """
name: T
out_dir: "{base}/out"
vars: {protocol: metric}
stages:
  first:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", protocol: "{protocol}",
           json: "{out_dir}/a.json"}
    outputs: ["{out_dir}/a.json"]
  second:
    command: metrics
    args: {pred: "{base}/pred.npy", gt: "{base}/gt.npy", protocol: "{protocol}",
           json: "{out_dir}/b.json"}
    outputs: ["{out_dir}/b.json"]
"""


def test_a_stage_reruns_when_the_stage_before_it_was_remade(tmp_path, capsys):
    # `demo --quick`, then `run --only adapt` with the full settings, then a full run: the full
    # run remade the earlier stages but took adapt for up to date (its inputs were the quick ones)
    gt = np.random.default_rng(0).uniform(1, 30, (2, 8, 8))
    np.save(tmp_path / "gt.npy", gt)
    np.save(tmp_path / "pred.npy", gt * 2)
    rp = tmp_path / "r.yaml"
    rp.write_text(CHAIN)
    quick = load_recipe(rp, {"base": str(tmp_path), "protocol": "median"})
    full = load_recipe(rp, {"base": str(tmp_path)})
    log = [].append
    assert run_recipe(quick, log=log) == {"first": "ran", "second": "ran"}
    assert run_recipe(full, only=["second"], log=log) == {"first": "skipped", "second": "ran"}
    assert run_recipe(full, log=log) == {"first": "ran", "second": "ran"}   # was: skipped
    assert run_recipe(full, log=log) == {"first": "skipped", "second": "skipped"}
    # a dry run shows the stages after a changed one as running too
    assert run_recipe(quick, dry_run=True, log=log) == {"first": "dry-run", "second": "dry-run"}


def test_unknown_stages_and_variables_are_refused(tmp_path, capsys):
    rp = tmp_path / "r.yaml"
    rp.write_text(CHAIN)
    base = ["run", str(rp), "--var", f"base={tmp_path}"]
    assert main([*base, "--only", "frist"]) == 2
    assert "--only: no stage(s) ['frist']; the recipe's: first, second" in capsys.readouterr().err
    assert main([*base, "--var", "protocl=median"]) == 2
    err = capsys.readouterr().err
    assert "unknown variable(s) ['protocl']" in err and "protocol" in err and "base" in err


def test_changed_inputs_reruns_and_replaced_outputs_rerun(tmp_path):
    """A stage was up to date as long as its settings were: input data changed in place, a
    stage forced again under --only, or an output another command replaced were not seen."""
    gt = np.random.default_rng(0).uniform(1, 30, (2, 8, 8))
    np.save(tmp_path / "gt.npy", gt)
    np.save(tmp_path / "pred.npy", gt * 2)
    rp = tmp_path / "r.yaml"
    rp.write_text(CHAIN)
    r = load_recipe(rp, {"base": str(tmp_path)})
    log = [].append
    assert run_recipe(r, log=log) == {"first": "ran", "second": "ran"}
    assert run_recipe(r, log=log) == {"first": "skipped", "second": "skipped"}
    np.save(tmp_path / "pred.npy", gt * 3)                    # the data changed in place
    assert run_recipe(r, log=log) == {"first": "ran", "second": "ran"}
    a = json.loads((tmp_path / "out" / "a.json").read_text())["abs_rel"]
    assert a > 1.5                                             # 1.0 before: the new data's
    assert run_recipe(r, only=["first"], force=True, log=log) == {"first": "ran",
                                                                   "second": "skipped"}
    assert run_recipe(r, log=log) == {"first": "skipped", "second": "ran"}   # was: skipped
    (tmp_path / "out" / "b.json").write_text("{}")           # another command replaced it
    assert run_recipe(r, log=log) == {"first": "skipped", "second": "ran"}
    assert run_recipe(r, log=log) == {"first": "skipped", "second": "skipped"}


SYNTH = """
name: S
out_dir: "{base}/out"
vars: {frames: "3"}
stages:
  render:
    command: synth
    args: {preset: c1, frames: "{frames}", adapt_frames: 1, set: {width: 64, height: 32},
           out: "{out_dir}/s.h5"}
    outputs: ["{out_dir}/s.h5"]
  train:
    command: baseline train
    args: {_: ["{out_dir}/s.h5"], checkpoint: "{out_dir}/s.pt"}
    outputs: ["{out_dir}/s.pt"]
"""


def test_an_interrupted_stage_is_continued_not_started_over(tmp_path, monkeypatch):
    """After Ctrl-C, run passed --overwrite to the interrupted stage: `baseline train
    --overwrite` starts over and threw the resumable checkpoint away, and an importer's partial
    file stopped the run ("--resume continues it, --restart starts over"). The same stage with
    the same inputs now gets --resume (or no --overwrite for baseline train); a stage with other
    settings gets --restart. The commands' own behaviour is tested with them; here: their
    command lines."""
    import staticdepth.cli as cli

    rp = tmp_path / "r.yaml"
    rp.write_text(SYNTH)
    calls: list[list[str]] = []
    stop = {"render": False, "train": False}
    real = cli.main

    def fake(argv, recipe=None):
        calls.append(list(argv))
        if argv[0] == "synth":
            if stop["render"]:
                raise KeyboardInterrupt
            return real(argv, recipe=recipe)
        open(argv[argv.index("--checkpoint") + 1], "wb").write(b"a checkpoint")
        if stop["train"]:
            raise KeyboardInterrupt
        return 0

    monkeypatch.setattr(cli, "main", fake)
    r = load_recipe(rp, {"base": str(tmp_path)})
    log = [].append
    assert run_recipe(r, log=log) == {"render": "ran", "train": "ran"}
    assert "--restart" in calls[0] and "--overwrite" not in calls[0]
    assert "--overwrite" not in calls[1]
    stop["train"] = True
    r4 = load_recipe(rp, {"base": str(tmp_path), "frames": "4"})
    with pytest.raises(KeyboardInterrupt):
        run_recipe(r4, log=log)
    assert {"--restart", "--overwrite"} <= set(calls[2])       # other settings: started over
    assert "--overwrite" in calls[3]                            # its input was remade
    stop["train"] = False
    assert run_recipe(r4, log=log) == {"render": "skipped", "train": "ran"}
    assert "--overwrite" not in calls[4]                        # continued, not restarted
    stop["render"] = True
    r5 = load_recipe(rp, {"base": str(tmp_path), "frames": "5"})
    with pytest.raises(KeyboardInterrupt):
        run_recipe(r5, log=log)
    stop["render"] = False
    assert run_recipe(r5, log=log) == {"render": "ran", "train": "ran"}
    assert "--resume" in calls[6] and "--restart" not in calls[6]
    assert "--overwrite" in calls[7]


def test_the_data_folder_is_absolute_and_a_missing_one_is_said(tmp_path, monkeypatch):
    """{data} defaulted to ../shared/data relative to wherever run was started: outside the
    repository the detector path pointed nowhere, said only when the stage ran."""
    rp = tmp_path / "r.yaml"
    rp.write_text("name: T\nstages:\n  a: {command: metrics, args: {pred: '{data}/p.npy'}}\n")
    work = tmp_path / "deep" / "cwd"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    monkeypatch.delenv("STATICDEPTH_DATA", raising=False)
    with pytest.raises(InputError, match=r"\{data\} is .*shared/data \(../shared/data from the "
                                         r"current folder\), which does not exist"):
        load_recipe(rp)
    (tmp_path / "deep" / "shared" / "data").mkdir(parents=True)
    r = load_recipe(rp)
    assert r["stages"]["a"]["args"]["pred"] == str(tmp_path / "deep" / "shared" / "data" / "p.npy")
    assert load_recipe(rp, {"data": "/d"})["stages"]["a"]["args"]["pred"] == "/d/p.npy"


def test_a_name_is_not_taken_for_an_input_folder(tmp_path, monkeypatch):
    """`name: C1` beside a folder C1 in the current folder (the CARLA export itself, often) was
    walked as an input, and any change there reran the stage."""
    from staticdepth.run import _input_paths

    monkeypatch.chdir(tmp_path)
    (tmp_path / "C1").mkdir()
    (tmp_path / "C1" / "x.png").write_bytes(b"x")
    (tmp_path / "a.h5").write_bytes(b"x")
    st = {"args": {"name": "C1", "_": ["a.h5", f"S={tmp_path / 'C1'}"], "model": "builtin",
                   "out": "o.h5"}, "outputs": ["o.h5"]}
    assert _input_paths(st) == ["a.h5", str(tmp_path / "C1")]
