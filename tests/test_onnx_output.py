"""An ONNX file whose output is not one depth map (a detector's (1, N, 85) boxes) is refused,
from the file's fixed shapes before anything is written, or on the first image when the file's
output shape is dynamic."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.models import load_model

pytest.importorskip("onnx", reason="onnx (test extra) is needed to export")
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


class Boxes(torch.nn.Module):
    """YOLOX's output layout: (1, anchors, 4 box + 1 object + 80 class scores)."""

    def __init__(self):
        super().__init__()
        self.head = torch.nn.Conv2d(3, 85, 1, stride=4)

    def forward(self, x):
        return self.head(x).flatten(2).transpose(1, 2)


def _export(path, dynamic: bool) -> str:
    axes = {"x": {2: "h", 3: "w"}, "y": {1: "n"}} if dynamic else None
    torch.onnx.export(Boxes().eval(), (torch.zeros(1, 3, 64, 64),), str(path),
                      input_names=["x"], output_names=["y"], dynamic_axes=axes, dynamo=False,
                      opset_version=17)
    return str(path)


def test_detector_onnx_refused_by_predict(tmp_path, capsys):
    """Was: predict wrote 2 PNGs of the (256, 85) boxes resized to the frame, exit 0."""
    path = _export(tmp_path / "boxes.onnx", dynamic=False)
    with pytest.raises(InputError, match=r"output \(1, 256, 85\) is not one depth map"):
        load_model(f"onnx:{path}")
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    import cv2

    for i in range(2):
        cv2.imwrite(str(frames / f"{i:03d}.png"), rng.integers(0, 255, (48, 80, 3), np.uint8))
    out = tmp_path / "pc2"
    assert main(["predict", "--model", path, "--input", str(frames), "--out", str(out),
                 "--max-frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and path in err[0] and "not a depth model" in err[0], err
    assert not out.exists()


def test_dynamic_detector_onnx_refused_on_the_first_image(tmp_path):
    path = _export(tmp_path / "dyn.onnx", dynamic=True)
    m = load_model(f"onnx:{path}")                     # the file does not say: h, w, n dynamic
    with pytest.raises(InputError, match=r"output \(1, 9216, 85\) is not one depth map for the "
                                         r"384 x 384 input"):          # the default resize
        m.predict(np.zeros((96, 96, 3), np.uint8))
