"""``stereo --sequence`` follows the project's output rules, and bad options are refused by name.

- an existing prediction NAME (or NAME-confidence) is replaced only with ``--overwrite``;
- a run stopped before finishing leaves ``NAME.h5.partial``; Ctrl-C says so and how to go on;
  a rerun without ``--resume``/``--restart`` refuses it (never deleted unasked), ``--resume``
  continues it with the same settings only, ``--restart`` starts over;
- ``--out-name`` is a prediction name, ``--max-disparity`` is positive (0 is no "auto"),
  ``calibrate --square`` is a finite positive number.
"""
from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.framefile import FrameFileWriter
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.stereo import sequence as stereo_sequence_module


@pytest.fixture
def seq(tmp_path):
    from staticdepth.dataset.synth_io import render_to_file

    path = tmp_path / "s.h5"
    render_to_file(path, preset_name="c1", n_frames=4, adapt_frames=1,
                   overrides={"width": 96, "height": 48})
    return path


def _stereo(seq, *extra):
    return main(["stereo", "--sequence", str(seq), *extra])


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err.strip()
    assert err.startswith("staticdepth stereo: error:") and "\n" not in err, err
    for w in words:
        assert w in err, err
    return err


def _depth(seq, name):
    with SequenceReader(seq) as r:
        return np.stack([r.prediction(name, i) for i in range(len(r))])


def test_existing_prediction_is_replaced_only_with_overwrite(seq, capsys):
    assert _stereo(seq, "--out-name", "sgbm") == 0
    first = _depth(seq, "sgbm")
    capsys.readouterr()
    pred = f"{seq}.pred/sgbm.h5"
    assert _stereo(seq, "--out-name", "sgbm", "--fill", "--max-disparity", "32") == 2
    _one_line_error(capsys, pred, "exists already; pass --overwrite to replace it")
    np.testing.assert_array_equal(_depth(seq, "sgbm"), first)       # untouched
    # another command's prediction (adapt's 'base'): the same rule
    assert _stereo(seq, "--out-name", "base") == 0
    capsys.readouterr()
    assert _stereo(seq, "--out-name", "base", "--fill") == 2
    _one_line_error(capsys, f"{seq}.pred/base.h5", "--overwrite")
    # a leftover NAME-confidence alone is refused too
    assert _stereo(seq, "--out-name", "sgbm-x") == 0
    os.remove(f"{seq}.pred/sgbm-x.h5")
    capsys.readouterr()
    assert _stereo(seq, "--out-name", "sgbm-x") == 2
    _one_line_error(capsys, f"{seq}.pred/sgbm-x-confidence.h5", "--overwrite")
    assert _stereo(seq, "--out-name", "sgbm", "--fill", "--max-disparity", "32",
                   "--overwrite") == 0
    assert np.isfinite(_depth(seq, "sgbm")).all()                 # --fill: replaced


def _interrupt_after(monkeypatch, frames: int) -> None:
    """Ctrl-C while the frame after ``frames`` is matched."""
    real = stereo_sequence_module.frame_confidence
    calls = [0]

    def stop(*a):
        calls[0] += 1
        if calls[0] > frames:
            raise KeyboardInterrupt
        return real(*a)

    monkeypatch.setattr(stereo_sequence_module, "frame_confidence", stop)


def _depth_writes(monkeypatch) -> list[int]:
    """The frame indices written into ``NAME.h5`` (not the confidence) from now on."""
    written: list[int] = []
    real = FrameFileWriter.write

    def write(self, i, frame, rows=None):
        if not self.path.endswith("-confidence.h5"):
            written.append(i)
        return real(self, i, frame, rows)

    monkeypatch.setattr(FrameFileWriter, "write", write)
    return written


def test_interrupted_run_keeps_its_partial_until_resume_or_restart(seq, capsys, monkeypatch):
    partial = f"{seq}.pred/sg3.h5.partial"
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        assert _stereo(seq, "--out-name", "sg3") == 130
    err = capsys.readouterr().err
    assert f"note: {partial} keeps the frames written" in err and "--resume" in err, err
    assert "interrupted" in err
    with h5py.File(partial, "r") as f:
        assert len(f["crc32"]) == 2
    # other settings, neither flag: refused, the partial untouched
    assert _stereo(seq, "--out-name", "sg3", "--fill") == 2
    _one_line_error(capsys, partial, "--resume continues it, --restart starts over")
    assert _stereo(seq, "--out-name", "sg3") == 2                 # same settings: the same
    _one_line_error(capsys, partial, "--resume")
    with h5py.File(partial, "r") as f:
        assert len(f["crc32"]) == 2
    # --resume with other settings: refused (it would mix two settings' frames)
    assert _stereo(seq, "--out-name", "sg3", "--fill", "--resume") == 2
    _one_line_error(capsys, partial, "cannot resume", "--restart")
    assert _stereo(seq, "--out-name", "sg3", "--resume", "--restart") == 2
    _one_line_error(capsys, "not both")
    # --resume with the same settings writes only the frames that were missing
    written = _depth_writes(monkeypatch)
    assert _stereo(seq, "--out-name", "sg3", "--resume") == 0
    assert written == [2, 3]
    assert _stereo(seq, "--out-name", "whole") == 0
    np.testing.assert_array_equal(_depth(seq, "sg3"), _depth(seq, "whole"))


def test_restart_deletes_the_partial_and_starts_over(seq, capsys, monkeypatch):
    partial = f"{seq}.pred/sg3.h5.partial"
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        assert _stereo(seq, "--out-name", "sg3") == 130
    written = _depth_writes(monkeypatch)
    assert _stereo(seq, "--out-name", "sg3", "--fill", "--restart") == 0
    assert written == [0, 1, 2, 3]
    assert not os.path.exists(partial)
    assert np.isfinite(_depth(seq, "sg3")).all()                  # the --fill run's


@pytest.mark.parametrize("name", ["../evil", "a/b", ".hidden", "x.h5", "x-confidence"])
def test_out_name_is_checked_before_any_work(seq, capsys, name):
    assert _stereo(seq, "--out-name", name) == 2
    err = _one_line_error(capsys, "--out-name", repr(name))
    assert ".tmp" not in err and str(seq) not in err, err           # no temporary file named
    assert not (seq.parent / "s.h5.pred").exists()


@pytest.mark.parametrize("value", ["0", "-1"])
def test_max_disparity_must_be_positive(seq, tmp_path, capsys, value):
    assert _stereo(seq, "--out-name", "x", "--max-disparity", value) == 2
    _one_line_error(capsys, f"--max-disparity must be positive, got {value}")
    assert not (tmp_path / "s.h5.pred" / "x.h5").exists()
    img = str(tmp_path / "a.png")
    assert main(["stereo", "--rectified", "--left", img, "--right", img, "--max-disparity", value,
                 "--disparity-out", str(tmp_path / "d.npy")]) == 2
    _one_line_error(capsys, f"--max-disparity must be positive, got {value}")


def _board_pairs(shared_data) -> tuple[str, str]:
    d = shared_data / "opencv" / "stereo_calib"
    return str(d / "left0[1-3].jpg"), str(d / "right0[1-3].jpg")


@pytest.mark.parametrize("square", ["inf", "-inf", "nan", "0"])
def test_calibrate_square_must_be_finite_and_positive(shared_data, tmp_path, capsys, square):
    """inf gave RuntimeWarnings and an OpenCV assertion on real board images."""
    left, right = _board_pairs(shared_data)
    assert main(["calibrate", "--board", "9x6", f"--square={square}", "--left", left,
                 "--right", right, "--min-pairs", "2", "--out", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("staticdepth calibrate: error:") and "\n" not in err, err
    assert "square size must be a finite positive number" in err, err


@pytest.mark.parametrize("marker", ["inf", "nan", "-0.01", "0.04", "0.05"])
def test_charuco_marker_must_be_below_the_square(shared_data, tmp_path, capsys, marker):
    """OpenCV's CharucoBoard raised a SystemError (a traceback) for these."""
    left, right = _board_pairs(shared_data)
    assert main(["calibrate", "--pattern", "charuco", "--board", "5x7", "--square", "0.04",
                 f"--marker={marker}", "--left", left, "--right", right, "--min-pairs", "2",
                 "--out", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("staticdepth calibrate: error:") and "\n" not in err, err
    assert "marker size must be 0 (0.75 of the square) or a finite number below" in err, err
