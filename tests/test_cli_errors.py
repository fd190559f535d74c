"""The CLI's one error path: input and environment errors are one line (exit 2), bugs keep their
traceback; onnxruntime sessions log errors only."""
from __future__ import annotations

import errno

import cv2
import numpy as np
import pytest

import staticdepth.evaluate
from staticdepth.cli import main

ARGV = ["metrics", "--pred", "p.npy", "--gt", "g.npy"]


def _raising(exc):
    def cmd(args):
        raise exc
    return cmd


@pytest.mark.parametrize("exc, line", [
    (OSError(errno.ENOSPC, "No space left on device", "/data/out.h5"),
     "/data/out.h5: no space left on the device"),
    (OSError(errno.EROFS, "Read-only file system", "/data/out.h5"),
     "/data/out.h5: read-only file system"),
    # os.replace(tmp, out) onto a folder: the folder is the output, not the temporary
    (OSError(errno.EISDIR, "Is a directory", "/data/out.h5.partial", None, "/data/out.h5"),
     "/data/out.h5: is a folder, not a file"),
    # h5py puts the path only in its message
    (OSError(errno.EACCES, "Unable to synchronously create file (unable to open file: "
                           "name = '/ro/x.h5', errno = 13, error message = 'Permission denied')"),
     "/ro/x.h5: permission denied"),
    (cv2.error("OpenCV(5.0.0) resize.cpp:4220: error: (-215:Assertion failed) inv_scale_x > 0"),
     "OpenCV could not process an input"),
    (UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"),
     "not valid text/JSON (UnicodeDecodeError"),
])
def test_input_and_environment_errors_are_one_line(monkeypatch, capsys, exc, line):
    monkeypatch.setattr(staticdepth.evaluate, "_metrics_cmd", _raising(exc))
    assert main(ARGV) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("staticdepth metrics: error: ")
    assert line in err and "Traceback" not in err


def test_a_closed_pipe_is_no_error_line(monkeypatch, capsys):
    # `staticdepth inspect seq.h5 --sheet s.png | head -2` printed "error: Broken pipe"
    monkeypatch.setattr(staticdepth.evaluate, "_metrics_cmd", _raising(BrokenPipeError(
        errno.EPIPE, "Broken pipe")))
    assert main(ARGV) == 141                    # as a process SIGPIPE stopped: 128 + 13
    assert capsys.readouterr().err == ""


def test_a_missing_output_folder_names_the_output_not_its_lock(tmp_path):
    from staticdepth.errors import InputError
    from staticdepth.fileio import exclusive_lock

    out = tmp_path / "nodir" / "x.h5"
    with pytest.raises(InputError) as e, exclusive_lock(out):
        pass
    assert str(e.value) == (f"{tmp_path / 'nodir'}: output's parent does not exist (create that "
                            "folder first)")


@pytest.mark.parametrize("exc", [TypeError("bad operand"), IndexError("list index"),
                                 AssertionError("invariant"), ZeroDivisionError()])
def test_bugs_keep_their_traceback(monkeypatch, exc):
    monkeypatch.setattr(staticdepth.evaluate, "_metrics_cmd", _raising(exc))
    with pytest.raises(type(exc)):
        main(ARGV)


def test_onnx_sessions_log_errors_only(tmp_path):
    import torch

    from staticdepth.errors import InputError
    from staticdepth.onnx_session import ERRORS_ONLY, onnx_session

    path = tmp_path / "m.onnx"
    torch.onnx.export(torch.nn.Conv2d(3, 1, 1), (torch.zeros(1, 3, 8, 8),), str(path),
                      dynamo=False, opset_version=17)
    s = onnx_session(path, threads=1)
    assert ERRORS_ONLY == 3 and s.get_session_options().log_severity_level == 3
    assert s.get_session_options().intra_op_num_threads == 1
    out = s.run(None, {s.get_inputs()[0].name: np.ones((1, 3, 8, 8), np.float32)})[0]
    assert out.shape == (1, 1, 8, 8)
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(InputError, match="junk.onnx: onnxruntime cannot load the ONNX model"):
        onnx_session(tmp_path / "junk.onnx")


def test_a_usage_error_is_one_line_and_a_recipe_names_its_stage(tmp_path, capsys):
    """argparse printed the command's whole usage block (7 lines for adapt) above its error,
    and inside `run`/`demo` its SystemExit passed the runner's line naming the stage by."""
    from staticdepth.cli import main

    assert main(["adapt", "x.h5", "--epochs", "nan"]) == 2
    err = capsys.readouterr().err
    assert err == ("staticdepth adapt: error: argument --epochs: invalid int value: 'nan' "
                   "(see staticdepth adapt --help)\n")
    assert main(["nosuch"]) == 2 and capsys.readouterr().err.count("\n") == 1
    assert main(["adapt", "--help"]) == 0
    assert "usage: staticdepth adapt" in capsys.readouterr().out
    rp = tmp_path / "r.yaml"
    rp.write_text("name: T\nout_dir: " + str(tmp_path / "o") + "\nstages:\n  fit:\n"
                  "    command: adapt\n    args: {_: [x.h5], epochs: nan}\n")
    assert main(["run", str(rp)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "invalid int value: 'nan'" in err[0], err
    assert "stage 'fit' failed (exit 2): staticdepth adapt x.h5 --epochs nan" in err[1]


def test_a_camera_that_does_not_open_is_one_line(tmp_path):
    """OpenCV printed its own warnings ('[ WARN:0@0.07] global cap_v4l.cpp:915 open ... can't
    open camera by index', one per backend tried) above our error line."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OPENCV_LOG_LEVEL"}
    out = subprocess.run([sys.executable, "-c", "import sys; from staticdepth.cli import main; "
                          "sys.exit(main())", "capture", "--source", "uvc",
                          "--device", "98,99", "--out", str(tmp_path / "rec")],
                         capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 2
    assert out.stderr.splitlines() == [
        "staticdepth capture: error: camera 98 does not open (is it connected, and not in use "
        "by another program?)"], out.stderr
