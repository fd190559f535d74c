"""export-model, predict and locate refuse what would give a wrong or a half-written result: an
adapt summary written for another sequence (its plane and scale are another scene's), options out
of range, an output folder that does not exist, a damaged sequence; and a failed run leaves no
file or folder behind.

The scenes are tiny (tests/upright_scene.py, 320x160, 3 frames) and the network an untrained
built-in one (the checks are about inputs and files, not depth)."""
from __future__ import annotations

import json
import shutil

import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.errors import InputError

from upright_scene import UprightScene

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def write_summary(path, seq, scene: UprightScene, **extra) -> None:
    """An adapt-style summary of ``seq`` (the keys export-model, predict and locate read), with
    what adapt records of the sequence: its path, size and frame count (``extra`` overrides)."""
    with SequenceReader(seq) as r:
        rec = {"sequence": str(seq), "size": [r.width, r.height], "frames": r.n_frames}
    rec.update(extra)
    path.write_text(json.dumps({
        **rec, "plane": {"normal": scene.normal.tolist()}, "camera_height_m": scene.height_m,
        "scale": {"ft-align": scene.height_m},
        "ground_polygon": [[0, scene.height - 1], [scene.width - 1, scene.height - 1],
                           [scene.width - 1, scene.height // 2], [0, scene.height // 2]],
        "config": {"eps": 1e-6, "detector": "gt"}}))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """Two scenes (``a``: 3 frames at 320x160; ``b``: 4 frames, another camera), each with its
    own summary, and an untrained built-in network."""
    from staticdepth.models.tiny import builtin_model, save_builtin

    d = tmp_path_factory.mktemp("site")
    scenes = {"a": UprightScene(n_people=3, seed=1),
              "b": UprightScene(n_people=3, seed=2, height_m=7.0, pitch_deg=40)}
    for name, frames in (("a", 3), ("b", 4)):
        scenes[name].write(str(d / f"{name}.h5"), frames=frames)
        write_summary(d / f"{name}.adapt.json", d / f"{name}.h5", scenes[name])
    save_builtin(d / "m.pt", builtin_model(input_height=64, input_width=128))
    return d, scenes


def refused(capsys, argv: list[str], *words: str) -> str:
    """Run ``argv``: exit 2 with one error line holding ``words``; returns the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(w in err[0] for w in words), err
    return err[0]


# -- an adapt summary written for another sequence ------------------------------------------------
def test_summary_of_another_sequence_is_refused_by_every_command(site, tmp_path, capsys):
    """Was: export-model, predict and locate took b's plane and scale for a's camera, exit 0."""
    d, _ = site
    other, seq = str(d / "b.adapt.json"), str(d / "a.h5")
    model = f"builtin:{d / 'm.pt'}"
    words = (other, "written for", str(d / "b.h5"), seq)
    refused(capsys, ["export-model", "--model", model, "--summary", other, "--sequence", seq,
                     "--out", str(tmp_path / "e.onnx"), "--check-frames", "1"], *words)
    refused(capsys, ["predict", "--model", model, "--summary", other, "--sequence", seq,
                     "--input", seq, "--out", str(tmp_path / "p"), "--device", "cpu"], *words)
    refused(capsys, ["locate", seq, "--summary", other, "--out", str(tmp_path / "l.csv")], *words)
    assert list(tmp_path.iterdir()) == []
    # its own summary is taken by all three
    own = str(d / "a.adapt.json")
    assert main(["locate", seq, "--summary", own, "--out", str(tmp_path / "l.csv")]) == 0
    assert main(["predict", "--model", model, "--summary", own, "--sequence", seq, "--input",
                 seq, "--out", str(tmp_path / "p"), "--format", "npy", "--device", "cpu"]) == 0
    assert main(["export-model", "--model", model, "--summary", own, "--sequence", seq,
                 "--out", str(tmp_path / "e.onnx"), "--check-frames", "1"]) == 0


@pytest.mark.parametrize("change, why", [
    ({"size": [640, 160]}, "640x160, this one is 320x160"),
    ({"frames": 30}, "30 frames, this one has 3"),
    ({"sequence_id": "0" * 32}, "another sequence identity"),
    ({"sequence": "b.h5"}, r"\(another file\)"),              # b.h5 exists: another file
    ({"sequence": "gone/other.h5"}, r"\(another file name\)")])   # missing, another name
def test_what_proves_another_sequence(site, tmp_path, monkeypatch, change, why):
    from staticdepth.locate import check_summary_of

    d, scenes = site
    monkeypatch.chdir(d)
    write_summary(tmp_path / "s.json", d / "a.h5", scenes["a"], **change)
    with SequenceReader(d / "a.h5") as r, pytest.raises(InputError, match=why) as e:
        check_summary_of(json.loads((tmp_path / "s.json").read_text()), "s.json", r)
    assert str(e.value).startswith("s.json: ") and str(d / "a.h5") in str(e.value)


def test_a_moved_or_copied_run_folder_keeps_its_summary(site, tmp_path):
    """A run folder moved as a whole (the recorded path gone, the same file name) or copied (the
    recorded file there, another file with the same identity) passes, as does a summary that
    records nothing of its sequence (written by hand); the same file under another path too."""
    from staticdepth.locate import check_summary_of

    d, _ = site
    with SequenceReader(d / "a.h5") as r:
        ok = [{"sequence": str(tmp_path / "old" / "a.h5"), "size": [320, 160], "frames": 3},
              {"sequence": str(d / "a.h5")}, {"sequence": f"{d}/../{d.name}/a.h5"}, {}]
        for s in ok:
            check_summary_of(s, "s.json", r)
    shutil.copytree(d, tmp_path / "copy")          # the copy's summary names the original
    moved = tmp_path / "copy"
    with SequenceReader(moved / "a.h5") as r:
        check_summary_of(json.loads((moved / "a.adapt.json").read_text()), "s.json", r)
        with pytest.raises(InputError, match="written for"):
            check_summary_of(json.loads((moved / "b.adapt.json").read_text()), "s.json", r)
    out = tmp_path / "l.csv"
    assert main(["locate", str(moved / "a.h5"), "--out", str(out)]) == 0   # SEQ.adapt.json
    assert out.stat().st_size > 0


# -- export-model: options first, and nothing left at --out --------------------------------------
@pytest.mark.parametrize("extra, msg", [
    (["--check-frames", "0"], "--check-frames must be at least 1"),
    (["--check-frames", "-1"], "--check-frames must be at least 1"),
    (["--opset", "5"], "--opset must be from 12 to"),
    (["--opset", "99"], "--opset must be from 12 to"),
    (["--out", "nodir/e.onnx"], "nodir: output's parent does not exist")])
def test_export_refuses_options_before_any_work(site, tmp_path, capsys, monkeypatch, extra, msg):
    """Was: --check-frames 0 a traceback after the export, leaving a complete .onnx that the
    rerun called 'exists already'; -1 and --opset 5/99 tracebacks; a missing folder refused
    after the detector had run. Now one line, exit 2, before the model is even loaded."""
    import staticdepth.models as models

    d, _ = site
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(models, "load_model", lambda *a, **k: pytest.fail("work started"))
    refused(capsys, ["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary",
                     str(d / "a.adapt.json"), "--sequence", str(d / "a.h5"), "--out", "e.onnx",
                     *extra], msg)
    assert list(tmp_path.iterdir()) == []


def test_failed_export_check_leaves_no_file(site, tmp_path, capsys, monkeypatch):
    """The file is checked as a temporary and renamed onto --out only after the check: a failure
    there leaves neither the output nor a temporary, so the rerun is not 'exists already'."""
    import staticdepth.deploy as deploy

    d, _ = site
    check = deploy.check_export

    def failing(*a, **k):
        raise InputError("the check failed")

    monkeypatch.setattr(deploy, "check_export", failing)
    argv = ["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary",
            str(d / "a.adapt.json"), "--sequence", str(d / "a.h5"), "--out",
            str(tmp_path / "e.onnx"), "--check-frames", "1"]
    refused(capsys, argv, "the check failed")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(deploy, "check_export", check)
    assert main(argv) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["e.onnx"]


# -- locate: the sequence before its summary -------------------------------------------------------
def test_locate_says_a_truncated_sequence_is_damaged(site, tmp_path, capsys):
    """Was: 'ktr.adapt.json: no adapt summary' for a truncated ktr.h5 without a summary."""
    d, _ = site
    data = (d / "a.h5").read_bytes()
    (tmp_path / "t.h5").write_bytes(data[:len(data) // 2])
    line = refused(capsys, ["locate", str(tmp_path / "t.h5"), "--out", str(tmp_path / "t.csv")],
                   str(tmp_path / "t.h5"))
    assert "adapt summary" not in line and "HDF5" in line
    assert not (tmp_path / "t.csv").exists()


# -- predict: no empty output folder after a failure -----------------------------------------------
def test_failed_predict_leaves_no_folder(site, tmp_path, capsys):
    """Was: a missing input, a frame of another aspect (metric pipeline) or a bad URL left an
    empty --out folder (and its new parents). A folder that was there stays."""
    d, _ = site
    model = f"builtin:{d / 'm.pt'}"
    refused(capsys, ["predict", "--model", model, "--input", str(tmp_path / "none.mp4"),
                     "--out", str(tmp_path / "o" / "d1"), "--device", "cpu"], "none.mp4")
    with SequenceReader(d / "a.h5") as r:               # a frame the camera cannot take
        import cv2

        cv2.imwrite(str(tmp_path / "sq.png"), r.left(0)[:, :160])
    (tmp_path / "frames").mkdir()
    shutil.move(tmp_path / "sq.png", tmp_path / "frames" / "000000.png")
    refused(capsys, ["predict", "--model", model, "--summary", str(d / "a.adapt.json"),
                     "--sequence", str(d / "a.h5"), "--input", str(tmp_path / "frames"),
                     "--out", str(tmp_path / "d2"), "--device", "cpu"], "exported model takes")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames"]
    (tmp_path / "kept").mkdir()
    refused(capsys, ["predict", "--model", model, "--input", str(tmp_path / "none.mp4"),
                     "--out", str(tmp_path / "kept"), "--device", "cpu"], "none.mp4")
    assert (tmp_path / "kept").is_dir()


def test_export_an_opset_cannot_hold_is_one_line(site, tmp_path, capsys, monkeypatch):
    """An opset in range that the graph's operators do not exist in (the exporter's error): one
    line naming the opset and --out, nothing written."""
    import torch

    d, _ = site

    def unsupported(*a, **k):
        raise torch.onnx.errors.OnnxExporterError("Exporting the operator 'aten::x' to ONNX opset "
                                                  "version 12 is not supported.\nmore")

    monkeypatch.setattr(torch.onnx, "export", unsupported)
    out = tmp_path / "e.onnx"
    refused(capsys, ["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary",
                     str(d / "a.adapt.json"), "--sequence", str(d / "a.h5"), "--out", str(out),
                     "--opset", "12"], f"{out}: --opset 12: the graph cannot be exported",
            "'aten::x'")
    assert list(tmp_path.iterdir()) == []


def test_predict_into_a_file_is_refused(site, tmp_path, capsys):
    d, _ = site
    (tmp_path / "o").write_text("mine")
    refused(capsys, ["predict", "--model", f"builtin:{d / 'm.pt'}", "--input", str(d / "a.h5"),
                     "--out", str(tmp_path / "o"), "--device", "cpu"],
            f"{tmp_path / 'o'}: is a file, not a folder")
    assert (tmp_path / "o").read_text() == "mine"
