"""Untrusted files never run code: pickled torch payloads, hostile names in the HTML report."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest
import torch

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.errors import InputError
from staticdepth.geometry import Camera, Mounting, plane_depth_map
from staticdepth.models import load_model
from staticdepth.models.trust import models_trusted, trusted_models

HOSTILE = "<img src=x onerror=alert(1)>"


class _TouchPayload:
    """Unpickling this calls ``pathlib.Path.touch(marker)``: code run by merely loading a file."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.touch, (self.marker,)


def _make_module(marker: str) -> torch.nn.Module:
    pathlib.Path(marker).touch()
    return torch.nn.Conv2d(3, 2, 1)  # two output channels: refused by the first prediction


class _ModulePayload:
    """Unpickling creates the marker and returns a real module (so a trusted load succeeds)."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self):
        return _make_module, (str(self.marker),)


def _seq(path: pathlib.Path, n: int = 5) -> pathlib.Path:
    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    gt = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 80, 40)
    ag = schema.empty_agents(1)
    ag["instance_id"], ag["class_id"], ag["track_id"], ag["foot_u"], ag["foot_v"] = 1, 0, 7, 40, 30
    with SequenceWriter(path, SequenceMeta(name="s", camera=cam, gt_kind="synthetic",
                                           adapt_frames=n - 1, mounting=mnt),  # >= tracking.min_frames
                        streams=("left", "depth")) as w:
        for i in range(n):
            w.append(left=np.full((40, 80, 3), 60 * i, np.uint8), depth=gt, agents=ag)
    return path


def test_pickle_payload_is_refused_without_trust(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    marker = tmp_path / "MARKER"
    torch.save({"weights": torch.zeros(2), "x": _TouchPayload(marker)}, tmp_path / "evil.pt")
    assert not models_trusted()
    with pytest.raises(InputError, match=r"would run code \(it imports .*pathlib.*--trust-model"):
        load_model(f"torch:{tmp_path / 'evil.pt'}")
    assert not marker.exists()
    # the legacy (non-zip) torch format too
    torch.save({"x": _TouchPayload(marker)}, tmp_path / "legacy.pt",
               _use_new_zipfile_serialization=False)
    with pytest.raises(InputError, match=r"legacy.pt: loading this torch file would run code"):
        load_model(f"torch:{tmp_path / 'legacy.pt'}")
    assert not marker.exists()
    # the project's own checkpoint loaders read with weights_only too
    from staticdepth.baseline.train import load_checkpoint
    from staticdepth.models.tiny import load_builtin
    for loader in (load_builtin, load_checkpoint):
        with pytest.raises(InputError, match="would run code"):
            loader(tmp_path / "evil.pt")
    assert not marker.exists()
    with trusted_models():  # what --trust-model does: the payload runs
        with pytest.raises(InputError, match="not a torch module"):
            load_model(f"torch:{tmp_path / 'evil.pt'}")
    assert marker.exists()
    assert not models_trusted()


def test_trust_model_flag_on_the_command_line(tmp_path, capsys):
    seq = _seq(tmp_path / "s.h5")
    marker = tmp_path / "MARKER"
    torch.save(_ModulePayload(marker), tmp_path / "evil.pt")
    argv = ["adapt", str(seq), "--model", f"torch:{tmp_path / 'evil.pt'}", "--detector", "motion",
            "--epochs", "0", "--device", "cpu"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "evil.pt: loading this torch file would run code" in err[0]
    assert "Traceback" not in err[0] and "--trust-model" in err[0]
    assert not marker.exists()
    # with --trust-model the file loads (the payload runs: the marker appears) and the command
    # goes on until the module's two-channel output is refused
    assert main(argv + ["--trust-model"]) == 2
    assert marker.exists()
    assert "one channel" in capsys.readouterr().err
    assert not models_trusted()


def test_a_recipe_cannot_trust_models(tmp_path, capsys):
    import yaml

    marker = tmp_path / "MARKER"
    torch.save(_ModulePayload(marker), tmp_path / "evil.pt")
    seq = str(_seq(tmp_path / "s.h5"))
    model = f"torch:{tmp_path / 'evil.pt'}"
    for args in ({"_": [seq], "model": model, "trust_model": True},
                 {"_": [seq, "--trust-model"], "model": model},
                 {"_": [seq], "model": model, "trust": True}):  # argparse abbreviation
        recipe = tmp_path / "r.yaml"
        recipe.write_text(yaml.safe_dump({"name": "r", "out_dir": str(tmp_path / "out"),
                                          "stages": {"a": {"command": "adapt", "args": args}}}))
        assert main(["run", str(recipe)]) == 2
        err = capsys.readouterr().err
        assert "r.yaml: a recipe cannot pass --trust-model" in err, err
        assert not marker.exists()
    # without the flag in the recipe: refused as on the command line ...
    args = {"_": [seq], "model": model, "detector": "motion", "epochs": 0, "device": "cpu"}
    recipe.write_text(yaml.safe_dump({"name": "r", "out_dir": str(tmp_path / "out"),
                                      "stages": {"a": {"command": "adapt", "args": args}}}))
    assert main(["run", str(recipe)]) == 2
    assert "would run code" in capsys.readouterr().err and not marker.exists()
    # ... and the user's own `run --trust-model` reaches the recipe's stages
    assert main(["run", str(recipe), "--trust-model"]) == 2
    assert "one channel" in capsys.readouterr().err and marker.exists()


def test_report_escapes_names_from_data_files(tmp_path):
    seq = _seq(tmp_path / "s.h5", n=3)
    gt = plane_depth_map(Camera.from_fov(80, 40, 90).K, Mounting.from_pitch_roll(5.0, 45.0).normal,
                         Mounting.from_pitch_roll(5.0, 45.0).height_m, 80, 40)
    # prediction names written by staticdepth are restricted (dataset/predictions.check_name), but
    # a crafted file can carry any name in an in-file (legacy) prediction group
    import h5py

    with h5py.File(seq, "a") as f:
        f.create_dataset(f"pred/{HOSTILE}/depth", data=np.stack([gt * 1.1] * 3).astype(np.float32))
    out = tmp_path / "rep"
    scene = "<script>alert(2)</script>"
    assert main(["report", f"{scene}={seq}", "--out", str(out)]) == 0
    pages = list(out.glob("*.html"))
    assert len(pages) == 1 and pages[0].name == "report__script_alert_2_script_.html"
    page = pages[0].read_text()
    assert HOSTILE not in page and "<script>" not in page
    assert "&lt;img src=x onerror=alert(1)&gt;" in page  # shown, as text
    md = (out / "tables.md").read_text()
    assert HOSTILE not in md and "&lt;img src=x onerror=alert(1)&gt;" in md
