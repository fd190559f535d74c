"""Bounds checked before any work: ``synth``'s frames, image size and disk space, ``ground-plane
--bootstrap``; and the help texts of ``adapt`` and ``ground-plane`` that say what a default is."""
from __future__ import annotations

import os
import shutil

import pytest

from staticdepth import cli
from staticdepth.cli import main
from staticdepth.dataset import synth
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth import SceneConfig, preset
from staticdepth.dataset import synth_io
from staticdepth.errors import InputError
from conftest import disk_usage_with_free


@pytest.fixture
def no_rendering(monkeypatch):
    """A refusal must come before the scene is built (the old code rendered for ever, or ran
    out of memory in the scene's ray grid)."""
    def refuse(*a, **k):
        raise AssertionError("the scene was built: the check came too late")
    monkeypatch.setattr(synth, "SyntheticScene", refuse)


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("staticdepth synth: error: "), err
    for w in words:
        assert w in err, err
    return err


def test_synth_refuses_frames_beyond_the_bound(tmp_path, capsys, no_rendering):
    out = tmp_path / "z.h5"
    assert main(["synth", "--preset", "c1", "--frames", "1000000000000", "--out", str(out)]) == 2
    _one_line_error(capsys, "--frames must be in 1..1,000,000, got 1000000000000")
    assert main(["synth", "--preset", "c1", "--frames", "0", "--out", str(out)]) == 2
    _one_line_error(capsys, "--frames must be in 1..1,000,000, got 0")
    assert os.listdir(tmp_path) == []


def test_synth_refuses_an_output_that_cannot_fit(tmp_path, capsys, monkeypatch, no_rendering):
    out = tmp_path / "z.h5"
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(2**30))     # 1 GiB free
    assert main(["synth", "--preset", "c1", "--frames", "100000", "--out", str(out)]) == 2
    err = _one_line_error(capsys, "not enough free disk space for 100000 frames of 800x400",
                          "1.00 GiB free", "--frames", str(tmp_path))
    need = 100000 * 800 * 400 * synth_io.RAW_BYTES_PER_PIXEL * synth_io.MIN_COMPRESSED_FRACTION
    assert f"at least {need / 2**30:.2f} GiB" in err
    assert os.listdir(tmp_path) == []       # no file, no .partial, no lock


@pytest.mark.parametrize("name, overrides", [
    ("demo", {}),
    # the least content a scene can have: no agents, props or buildings, the coarsest texture
    ("c1", {"n_agents": 0, "n_props": 0, "n_buildings": 0, "texture_m": 1.0, "width": 400,
            "height": 200})])
def test_the_disk_estimate_is_below_the_real_file(tmp_path, monkeypatch, name, overrides):
    """The estimate refuses only what surely does not fit: a real output is larger, and one
    byte less free than the estimate refuses, exactly the estimate renders."""
    cfg = preset(name, **overrides)
    n = 3
    need = int(n * cfg.width * cfg.height * synth_io.RAW_BYTES_PER_PIXEL
               * synth_io.MIN_COMPRESSED_FRACTION)
    out = tmp_path / "s.h5"
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(need - 1))
    with pytest.raises(InputError, match="not enough free disk space"):
        synth_io.render_to_file(out, preset_name=name, n_frames=n, overrides=overrides)
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(need))
    synth_io.render_to_file(out, preset_name=name, n_frames=n, overrides=overrides)
    with SequenceReader(out) as r:
        assert len(r) == n
    assert os.path.getsize(out) > need


def test_synth_refuses_an_image_size_beyond_the_bound(tmp_path, capsys, no_rendering):
    out = tmp_path / "z.h5"
    assert main(["synth", "--preset", "c1", "--frames", "3", "--set", "width=100000",
                 "--set", "height=100000", "--out", str(out)]) == 2
    _one_line_error(capsys, "scene config: width must be at most 8192, got 100000")
    with pytest.raises(InputError, match="height must be at most 8192, got 8193"):
        SceneConfig(height=8193)
    with pytest.raises(InputError, match=r"width x height must be at most 16,777,216 pixels"):
        SceneConfig(width=8192, height=4096)
    assert SceneConfig(width=8192, height=2048).width == 8192      # the bounds themselves pass
    assert os.listdir(tmp_path) == []


def test_ground_plane_bootstrap_has_an_upper_bound(tmp_path, capsys):
    """Refused from the options alone, before the files are read (they do not exist here)."""
    out = tmp_path / "plane.json"
    assert main(["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
                 str(tmp_path / "cam.json"), "--bootstrap", "1000000000000",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--bootstrap must be a finite number within 0..10000, got 1000000000000" in err
    assert not out.exists()
    # adapt's plane.bootstrap: the same range, from the same rule
    from staticdepth.adaptation.config import build_config
    from staticdepth.errors import InputError

    with pytest.raises(InputError, match=r"plane.bootstrap must be a finite number within "
                                         r"0..10000, got 20000"):
        build_config({"plane.bootstrap": 20000})


def _option_help(command: str, dest: str) -> str:
    parser = cli.build_parser([command])
    sub = next(a for a in parser._actions if a.dest == "command")
    return next(a.help for a in sub.choices[command]._actions if a.dest == dest)


def test_help_says_where_the_camera_height_comes_from():
    """The camera height's default is the agents' per-class height distributions (adaptation/
    scale.py with_camera_height, agent_plane_gate.with_camera_height_from_agents), not a 1.7 m
    agent prior: adapt's --camera-height and ground-plane's --agent-height said so."""
    adapt = _option_help("adapt", "camera_height")
    assert "1.7" not in adapt and "per-class height distributions" in adapt
    assert "scale.agent_height_m" in adapt
    agent = _option_help("ground-plane", "agent_height")
    assert "people 1.7" not in agent and "per-class height distributions" in agent


def test_a_resumed_partial_counts_as_written(tmp_path, monkeypatch):
    """--resume needs only what the .partial file does not hold yet."""
    out = tmp_path / "s.h5"
    need = int(10 * 64 * 32 * synth_io.RAW_BYTES_PER_PIXEL * synth_io.MIN_COMPRESSED_FRACTION)
    (tmp_path / "s.h5.partial").write_bytes(b"\0" * 1000)
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(need - 1000))
    synth_io.check_disk_space(out, 10, 64, 32, resume=True)
    with pytest.raises(InputError, match="not enough free disk space for 10 frames of 64x32"):
        synth_io.check_disk_space(out, 10, 64, 32)
