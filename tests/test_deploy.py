"""export-model and predict: the exported ONNX graph (image -> metric depth) against the
torch/numpy pipeline it replaces, and the predict command's outputs."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    """A small synthetic sequence, a tiny built-in network and an adapt-style summary holding
    the scene's true plane (the keys export-model reads)."""
    from staticdepth.dataset.synth_io import render_to_file
    from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin

    d = tmp_path_factory.mktemp("deploy")
    seq = d / "s.h5"
    render_to_file(seq, preset_name="demo", n_frames=10, adapt_frames=8, seed=1,
                   overrides={"width": 200, "height": 100})
    torch.manual_seed(0)
    net = TinyDepthNet((8, 8, 16, 16, 32), (16, 8, 8, 8))
    save_builtin(d / "m.pt", builtin_model(net, input_height=64, input_width=128))
    with SequenceReader(seq) as r:
        m = r.meta.mounting
    summary = d / "s.adapt.json"
    summary.write_text(json.dumps({"plane": {"normal": m.normal.tolist()},
                                   "camera_height_m": m.height_m,
                                   "scale": {"ft-align": m.height_m},
                                   "config": {"eps": 1e-6, "detector": "gt", "erode_px": None}}))
    return d, seq, summary


def test_export_matches_pipeline(deployment, capsys):
    from staticdepth.deploy import MetricOnnx, deployment_constants, metric_depth_reference
    from staticdepth.models import load_model

    d, seq, summary = deployment
    out = d / "m.onnx"
    assert main(["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(summary),
                 "--sequence", str(seq), "--out", str(out), "--check-frames", "2"]) == 0
    assert "median relative difference" in capsys.readouterr().out
    # independently of the command's own check: another frame, the reference recomputed here
    model = load_model(f"builtin:{d / 'm.pt'}")
    c = deployment_constants(str(summary), str(seq))
    with SequenceReader(seq) as r:
        img = r.left(7)
    ref = metric_depth_reference(model, img, c)
    got = MetricOnnx(str(out)).predict(img)
    assert got.shape == ref.shape == (100, 200) and got.dtype == np.float32
    rel = np.abs(got - ref) / ref
    assert np.median(rel) <= 0.005, np.median(rel)
    # metric: the ground region's median depth is the agents' plane depth there (alignment)
    from staticdepth.geometry.plane import plane_depth_map

    zp = plane_depth_map(c["K"], c["normal"], c["camera_height_m"], 200, 100)
    G = c["ground"]
    assert abs(np.median(got[G] / zp[G]) - 1) < 0.05


def test_predict_formats(deployment, capsys):
    from staticdepth.deploy import MetricOnnx

    d, seq, summary = deployment
    onnx_path = d / "m.onnx"
    if not onnx_path.exists():
        assert main(["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary",
                     str(summary), "--sequence", str(seq), "--out", str(onnx_path),
                     "--check-frames", "1"]) == 0
    assert main(["predict", "--model", str(onnx_path), "--input", str(seq), "--out",
                 str(d / "npy"), "--format", "npy", "--max-frames", "3"]) == 0
    assert "frames/s" in capsys.readouterr().out
    m = MetricOnnx(str(onnx_path))
    with SequenceReader(seq) as r:
        first = m.predict(r.left(0))
    got = np.load(d / "npy" / "000000.npy")
    assert len(list((d / "npy").glob("*.npy"))) == 3 and np.allclose(got, first)
    with SequenceReader(seq) as r:                   # the raw video's size: resized to the model's
        big = cv2.resize(r.left(0), (400, 200), interpolation=cv2.INTER_NEAREST)
    assert m.predict(big).shape == (100, 200)
    assert np.median(np.abs(m.predict(big) - first) / first) < 0.01
    from staticdepth.errors import InputError

    with pytest.raises(InputError, match="exported model takes"):
        m.predict(np.zeros((100, 100, 3), np.uint8))
    assert main(["predict", "--model", str(onnx_path), "--input", str(seq), "--out",
                 str(d / "png"), "--format", "png16", "--max-frames", "2"]) == 0
    png = cv2.imread(str(d / "png" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and np.allclose(png / 256.0, first, atol=1 / 256)
    assert main(["predict", "--model", str(onnx_path), "--input", str(seq), "--out",
                 str(d / "mp4"), "--format", "mp4", "--max-frames", "4"]) == 0
    assert (d / "mp4" / "depth.mp4").stat().st_size > 1000
    # a model spec with the summary: the numpy pipeline, the same metric depth
    assert main(["predict", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(summary),
                 "--sequence", str(seq), "--input", str(seq), "--out", str(d / "ref"),
                 "--format", "npy", "--max-frames", "1"]) == 0
    ref = np.load(d / "ref" / "000000.npy")
    assert np.median(np.abs(ref - first) / ref) <= 0.005
    # without the summary the depth is relative, and says so
    assert main(["predict", "--model", f"builtin:{d / 'm.pt'}", "--input", str(seq), "--out",
                 str(d / "rel"), "--format", "npy", "--max-frames", "1"]) == 0
    assert "relative" in capsys.readouterr().out


def test_export_bad_inputs(deployment, tmp_path):
    d, seq, summary = deployment
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"config": {}}))
    assert main(["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(bad),
                 "--sequence", str(seq), "--out", str(tmp_path / "x.onnx")]) == 2
    assert main(["export-model", "--model", "onnx:nothing.onnx", "--summary", str(summary),
                 "--sequence", str(seq), "--out", str(tmp_path / "x.onnx")]) == 2
    assert not (tmp_path / "x.onnx").exists()
    assert main(["predict", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(summary),
                 "--input", str(seq), "--out", str(tmp_path / "o")]) == 2   # no --sequence


def test_ground_region_sources(deployment, tmp_path):
    """The ground region: the summary's polygon when it has one, else the feet hull of the
    sequence's agents (adapt's), else a given mask."""
    from staticdepth.deploy import deployment_constants
    from staticdepth.geometry.alignment import ground_mask_from_feet

    d, seq, summary = deployment
    c = deployment_constants(str(summary), str(seq))
    with SequenceReader(seq) as r:
        rows = np.concatenate([r.agents(i) for i in r.split("adapt")])
    feet = np.stack([rows["foot_u"], rows["foot_v"]], 1)
    assert np.array_equal(c["ground"], ground_mask_from_feet(feet[feet[:, 1] >= 0], 200, 100,
                                                             200 / 80.0))
    s = json.loads(summary.read_text())
    s["ground_polygon"] = [[10, 99], [190, 99], [150, 60], [50, 60]]
    poly = tmp_path / "p.json"
    poly.write_text(json.dumps(s))
    c = deployment_constants(str(poly), str(seq))
    assert c["ground"][80, 100] and not c["ground"][40, 100] and "polygon" in c["ground_from"]
    mask = np.zeros((100, 200), np.uint8)
    mask[70:, :] = 255
    cv2.imwrite(str(tmp_path / "g.png"), mask)
    c = deployment_constants(str(summary), str(seq), str(tmp_path / "g.png"))
    assert c["ground"].sum() == 30 * 200
    cv2.imwrite(str(tmp_path / "small.png"), mask[:50])
    from staticdepth.errors import InputError

    with pytest.raises(InputError, match="ground mask"):
        deployment_constants(str(summary), str(seq), str(tmp_path / "small.png"))
