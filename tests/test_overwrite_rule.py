"""One overwrite rule for every output: an output that exists already is refused with one line and
exit code 2, and left as it was; with ``--overwrite`` the command replaces it.

Each case builds the smallest real inputs of its command and names the output that is already
there; the same command line then runs twice, without and with ``--overwrite``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from staticdepth.cli import main
from test_agent_plane import camera_K, people_observations, true_normal
from test_cli_ground_align import _align_inputs, write_csv

OLD = b"an earlier run's output\n"


def _ground_plane(d: Path):
    K, w, h = camera_K(600.0)
    obs = people_observations(np.random.default_rng(5), K, w, h, true_normal(30.0), 6.0,
                              n_tracks=20)
    write_csv(d / "obs.csv", obs)
    (d / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 600.0, "cx": K[0, 2],
                                            "cy": K[1, 2]}))
    return (["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
             str(d / "cam.json"), "--bootstrap", "0", "--out", str(d / "plane.json")],
            d / "plane.json", lambda p: "normal" in json.loads(p.read_text()))


def _align(d: Path, output: str):
    _align_inputs(d)
    argv = ["align", "--pred", str(d / "pred.npy"), "--inverse", "--intrinsics",
            str(d / "cam.json"), "--plane", str(d / "plane.json"), "--ground-mask",
            str(d / "mask.png"), "--camera-height", "5", "--out", str(d / "out.npy"),
            "--json", str(d / "info.json")]
    if output == "json":
        return argv, d / "info.json", lambda p: json.loads(p.read_text())["units"] == "m"
    return argv, d / "out.npy", lambda p: np.load(p).shape == np.load(d / "pred.npy").shape


def _report(d: Path):
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
    from staticdepth.geometry import Camera, Mounting, plane_depth_map

    cam, mnt = Camera.from_fov(64, 32, 90), Mounting.from_pitch_roll(5.0, 45.0)
    gt = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 64, 32)
    with SequenceWriter(d / "s.h5", SequenceMeta(name="s", camera=cam, gt_kind="synthetic",
                                                 adapt_frames=1, mounting=mnt),
                        streams=("left", "depth")) as w:
        for _ in range(2):
            w.append(left=np.zeros((32, 64, 3), np.uint8), depth=gt)
    add_prediction(d / "s.h5", "base", [gt * 2] * 2)
    (d / "rep").mkdir()
    return (["report", f"S={d / 's.h5'}", "--out", str(d / "rep")], d / "rep" / "tables.md",
            lambda p: "Table 1" in p.read_text())


def _capture(d: Path):
    argv = ["capture", "--source", "synthetic", "--size", "32x16", "--frames", "1",
            "--summary-json", str(d / "sum.json"), "--numbered", "--out", str(d / "recs")]
    return argv, d / "sum.json", lambda p: json.loads(p.read_text())["frames"] == 1


def _train_builtin(d: Path):
    return (["train-builtin", "--out", str(d / "b.pt"), "--frames", "2", "--epochs", "1",
             "--size", "64x32", "--batch-size", "2", "--device", "cpu"], d / "b.pt",
            lambda p: p.read_bytes()[:2] == b"PK")        # a torch zip archive


def _tiny_model(d: Path) -> str:
    import torch

    from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin

    torch.manual_seed(0)
    save_builtin(d / "tiny.pt", builtin_model(TinyDepthNet(enc_channels=(4, 8, 8, 16, 16),
                                                           dec_channels=(16, 8, 8, 4)),
                                              input_height=32, input_width=64))
    return f"builtin:{d / 'tiny.pt'}"


def _adapt(d: Path):
    from staticdepth.dataset.synth_io import render_to_file

    model = _tiny_model(d)
    render_to_file(d / "c.h5", preset_name="c1", n_frames=40, adapt_frames=40, seed=1,
                   overrides={"width": 64, "height": 32})
    return (["adapt", str(d / "c.h5"), "--model", model, "--detector", "gt",
             "--epochs", "0", "--device", "cpu", "--set", "tracking.min_height_px=3",
             "--set", "plane.bootstrap=0"], d / "c.adapt.json",
            lambda p: "plane" in json.loads(p.read_text()))


def _tiny_model_and_sequence(d: Path):
    from staticdepth.dataset.synth_io import render_to_file

    model = _tiny_model(d)
    render_to_file(d / "s.h5", preset_name="demo", n_frames=10, adapt_frames=8, seed=1,
                   overrides={"width": 160, "height": 80})
    return model, d / "s.h5"


def _locate(d: Path):
    from upright_scene import UprightScene

    scene = UprightScene(n_people=4, seed=4)
    scene.write(str(d / "up.h5"), frames=3)
    (d / "plane.json").write_text(json.dumps({"normal": scene.normal.tolist()}))
    return (["locate", str(d / "up.h5"), "--plane", str(d / "plane.json"), "--camera-height",
             str(scene.height_m), "--out", str(d / "pos.csv")], d / "pos.csv",
            lambda p: p.read_text().startswith("frame,"))


def _export_model(d: Path):
    from staticdepth.dataset.h5 import SequenceReader

    model, seq = _tiny_model_and_sequence(d)
    with SequenceReader(seq) as r:
        m = r.meta.mounting
    (d / "s.adapt.json").write_text(json.dumps({
        "plane": {"normal": m.normal.tolist()}, "camera_height_m": m.height_m,
        "scale": {"ft-align": m.height_m}, "config": {"eps": 1e-6, "detector": "gt"}}))
    return (["export-model", "--model", model, "--summary", str(d / "s.adapt.json"),
             "--sequence", str(seq), "--out", str(d / "m.onnx"), "--check-frames", "1"],
            d / "m.onnx", lambda p: p.stat().st_size > 1000)


def _predict(d: Path):
    model, seq = _tiny_model_and_sequence(d)
    (d / "pred").mkdir()
    return (["predict", "--model", model, "--input", str(seq), "--out", str(d / "pred"),
             "--format", "npy", "--max-frames", "1", "--device", "cpu"],
            d / "pred" / "000000.npy", lambda p: np.load(p).shape == (80, 160))


CASES = {"ground-plane --out": _ground_plane,
         "align --json": lambda d: _align(d, "json"),
         "align --out": lambda d: _align(d, "npy"),
         "report --out": _report,
         "capture --summary-json": _capture,
         "train-builtin --out": _train_builtin,
         "adapt summary": _adapt,
         "locate --out": _locate,
         "export-model --out": _export_model,
         "predict --out (a folder holding files)": _predict}


@pytest.mark.parametrize("case", list(CASES))
def test_existing_output_is_refused_then_replaced_with_overwrite(case, tmp_path, capsys):
    argv, out, is_new = CASES[case](tmp_path)
    out.write_bytes(OLD)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err and "pass --overwrite" in err, err
    assert str(out if out.parent.name != "pred" else out.parent) in err   # predict names its folder
    assert out.read_bytes() == OLD                       # left as it was
    assert main([*argv, "--overwrite"]) == 0
    assert out.read_bytes() != OLD and is_new(out)       # replaced by this run's output
    assert not list(tmp_path.rglob("*.tmp-*"))           # the atomic writer left nothing behind


def _input_cases(d: Path) -> dict:
    argv, _, _ = _align(d, "npy")
    pred = d / "pred.npy"
    np.save(d / "gt.npy", np.load(pred) + 1.0)
    (d / "link.npy").symlink_to(pred)
    swap = lambda opt, path: [path if a == argv[argv.index(opt) + 1] and i == argv.index(opt) + 1
                              else a for i, a in enumerate(argv)]
    return {
        "align --out over --pred": (swap("--out", str(pred)), pred, "--out names this command's "
                                    "input (pred)"),
        "align --json over --plane": (swap("--json", str(d / "plane.json")), d / "plane.json",
                                      "--json names this command's input (plane)"),
        "metrics --json over --pred, through a link": (
            ["metrics", "--pred", str(d / "link.npy"), "--gt", str(d / "gt.npy"), "--json",
             str(pred)], pred, "--json names this command's input (pred)"),
        "align --out and --json one file": (swap("--json", str(d / "out.npy")), d / "out.npy",
                                            "--out and --json name the same file"),
    }


@pytest.mark.parametrize("case", ["align --out over --pred", "align --json over --plane",
                                  "metrics --json over --pred, through a link",
                                  "align --out and --json one file"])
def test_an_output_that_is_an_input_is_refused_even_with_overwrite(case, tmp_path, capsys):
    # `evaluate seq.h5 --json seq.h5 --overwrite` replaced a sequence with JSON: an output that
    # names one of the command's inputs (or another output) is refused before any work
    argv, victim, msg = _input_cases(tmp_path)[case]
    if not victim.exists():
        victim.write_bytes(OLD)
    before = victim.read_bytes()
    capsys.readouterr()
    assert main([*argv, "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and msg in err and str(victim) in err, err
    assert victim.read_bytes() == before


def test_evaluate_refuses_to_write_its_json_over_the_sequence(tmp_path, capsys):
    seq = tmp_path / "s.h5"
    assert main(["synth", "--preset", "c1", "--frames", "3", "--adapt-frames", "1", "--set",
                 "width=96", "--set", "height=48", "--out", str(seq)]) == 0
    before = seq.read_bytes()
    for cmd in (["evaluate", str(seq)], ["inspect", str(seq)]):
        capsys.readouterr()
        assert main([*cmd, "--json", str(seq), "--overwrite"]) == 2
        assert "names this command's input" in capsys.readouterr().err
    assert seq.read_bytes() == before


def test_no_output_replaces_a_sequences_files_even_with_overwrite(tmp_path, capsys):
    """``evaluate SEQ --json SEQ.pred/base.h5 --overwrite`` replaced a stored prediction (an input
    the command reads through the sequence) with JSON, and ``metrics --json other.h5
    --overwrite`` a sequence it does not even read: an output in a sequence input's own folders,
    or over an HDF5 file of a command that writes none, is refused in one line, the file kept.
    A sequence writer still replaces its own kind of file with --overwrite."""
    from staticdepth.dataset.h5 import add_prediction

    seq, other = tmp_path / "s.h5", tmp_path / "o.h5"
    for p in (seq, other):
        assert main(["synth", "--preset", "c1", "--frames", "3", "--adapt-frames", "1", "--set",
                     "width=96", "--set", "height=48", "--out", str(p)]) == 0
    add_prediction(seq, "base", [np.ones((48, 96), np.float32)] * 3)
    base = tmp_path / "s.h5.pred" / "base.h5"
    (tmp_path / "s.h5.adapt").mkdir()
    np.save(tmp_path / "p.npy", np.ones((4, 4), np.float32))
    np.save(tmp_path / "g.npy", np.full((4, 4), 2.0, np.float32))
    inside = "a folder of this command's input (sequence)"
    cases = [(["evaluate", str(seq), "--json", str(base)], base, inside),
             (["evaluate", str(seq), "--json", str(tmp_path / "s.h5.adapt" / "e.json")],
              tmp_path / "s.h5.adapt" / "e.json", inside),
             (["metrics", "--pred", str(tmp_path / "p.npy"), "--gt", str(tmp_path / "g.npy"),
               "--json", str(other)], other, "names an HDF5 file")]
    for argv, victim, msg in cases:
        before = victim.read_bytes() if victim.exists() else None
        capsys.readouterr()
        assert main([*argv, "--overwrite"]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and msg in err and str(victim) in err, err
        assert (victim.read_bytes() if victim.exists() else None) == before
    assert main(["evaluate", str(seq)]) == 0                       # the prediction still reads
    assert main(["synth", "--preset", "c1", "--frames", "2", "--adapt-frames", "1", "--set",
                 "width=64", "--set", "height=32", "--out", str(other), "--overwrite"]) == 0


def test_overwrite_replaces_an_earlier_output_not_an_image(tmp_path, capsys):
    """`train-builtin --out photo.png --overwrite` turned a photo into torch weights, and
    `adapt --summary photo.png --overwrite` into JSON: an existing image (or sequence) under an
    output that writes none is refused in one line, kept as it was."""
    import cv2

    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), np.full((8, 8, 3), 90, np.uint8))
    jpeg = tmp_path / "photo.jpg"
    cv2.imwrite(str(jpeg), np.full((8, 8, 3), 90, np.uint8))
    before = photo.read_bytes(), jpeg.read_bytes()
    for argv, victim in (
            (["train-builtin", "--out", str(photo), "--frames", "2", "--epochs", "1",
              "--size", "64x32"], photo),
            (["adapt", str(tmp_path / "none.h5"), "--summary", str(jpeg)], jpeg)):
        capsys.readouterr()
        assert main([*argv, "--overwrite"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(victim) in err and "image, which this command does " \
            "not write: even with --overwrite it is not replaced" in err, err
    assert (photo.read_bytes(), jpeg.read_bytes()) == before
