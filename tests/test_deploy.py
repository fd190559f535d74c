"""export-model and predict: the exported ONNX graph (image -> metric depth) against the
torch/numpy pipeline it replaces, and the predict command's outputs.

The network is a trained one: ``train-builtin`` with a tiny seed-fixed run (48 street frames,
4 epochs at 128x64; kept in pytest's cache folder between runs, like the acceptance test's),
fine-tuned by a real ``adapt --save-model`` run for the ground-mode checks."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from conftest import trained_builtin

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")
TRAIN = ["--frames", "48", "--epochs", "4", "--size", "128x64", "--seed", "0"]


@pytest.fixture(scope="module")
def trained_weights(request, tmp_path_factory):
    return trained_builtin(request, tmp_path_factory, TRAIN)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory, trained_weights):
    """A small synthetic sequence, the trained built-in network and an adapt-style summary
    holding the scene's true plane (the keys export-model reads; no align.mode: eq2)."""
    from staticdepth.dataset.synth_io import render_to_file

    d = tmp_path_factory.mktemp("deploy")
    seq = d / "s.h5"
    render_to_file(seq, preset_name="demo", n_frames=10, adapt_frames=8, seed=1,
                   overrides={"width": 200, "height": 100})
    shutil.copy(trained_weights, d / "m.pt")
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


@pytest.fixture(scope="module")
def adapted_camera(tmp_path_factory, trained_weights):
    """A real ``adapt`` run on a high, tilted camera (c1 at 256x128, ground-truth agents, one
    epoch, ``align.agents_at_contact=false``), its fine-tuned network saved."""
    from staticdepth.dataset.synth_io import render_to_file

    d = tmp_path_factory.mktemp("adapted")
    seq = d / "c1.h5"
    render_to_file(seq, preset_name="c1", n_frames=30, adapt_frames=24, seed=1,
                   overrides={"width": 256, "height": 128})
    assert main(["adapt", str(seq), "--model", f"builtin:{trained_weights}", "--detector", "gt",
                 "--epochs", "1", "--seed", "0", "--device", "cpu", "--save-model",
                 str(d / "ft.pt"), "--set", "tracking.min_height_px=8",
                 "--set", "align.agents_at_contact=false"]) == 0
    return d, seq, d / "c1.adapt.json"


@pytest.mark.parametrize("mode", ["ground", "eq2", "upright"])
def test_export_of_an_adapted_camera(adapted_camera, mode, capsys):
    """The exported graph bakes the summary's align.mode and reproduces the numpy pipeline on
    frames whose fit (s, t or the predicted plane) differs; adapt's own output differs from it
    only by the agents' pixels adapt removes from the ground mask (a detector's output, not an
    image's)."""
    from staticdepth.deploy import MetricOnnx, deployment_constants, metric_depth_reference
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse
    from staticdepth.metrics import evaluate
    from staticdepth.models import load_model

    d, seq, summary = adapted_camera
    s = json.loads(summary.read_text())
    assert s["config"]["align"]["mode"] == "upright"           # adapt's default
    s["config"]["align"]["mode"] = mode
    summ = d / f"{mode}.adapt.json"
    summ.write_text(json.dumps(s))
    out = d / f"{mode}.onnx"
    assert main(["export-model", "--model", f"builtin:{d / 'ft.pt'}", "--summary", str(summ),
                 "--sequence", str(seq), "--out", str(out), "--check-frames", "1"]) == 0
    assert f"align.mode {mode}" in capsys.readouterr().out
    onnx = MetricOnnx(str(out))
    assert onnx.metadata["staticdepth.align_mode"] == mode
    assert ("jump_rel=0.08" in onnx.metadata.get("staticdepth.upright", "")) == (mode == "upright")
    assert onnx.metadata["staticdepth.agents_at_contact"].startswith("not applied")
    # adapt's default colour foot, on the adaptation frames' median image, in the upright graph
    assert onnx.metadata["staticdepth.colour_foot"].startswith(
        "applied" if mode == "upright" else "not applied")
    model = load_model(f"builtin:{d / 'ft.pt'}")
    c = deployment_constants(str(summ), str(seq))
    assert (c["image"] is not None) == (mode == "upright")
    fits, rel, err_onnx, err_adapt, vs_adapt = set(), [], [], [], []
    with SequenceReader(seq) as r:
        for i in r.split("eval"):
            img, gt = r.left(i), r.depth(i)
            got, ref = onnx.predict(img), metric_depth_reference(model, img, c)
            rel.append(np.median(np.abs(got - ref) / ref))
            Z = depth_from_inverse(model.predict(img), c["eps"])
            a = align_depth(Z, c["K"], c["normal"], 1.0, c["ground"], mode=mode, image=c["image"],
                            **c["upright"])
            fits.add(tuple(np.round(a.plane_normal, 5)))
            err_onnx.append(evaluate(got, gt, "metric")["abs_rel"])
            if mode == "upright":                   # adapt's own output
                stored = r.prediction("ft-align-metric", i)
                m = r.instances(i) > 0
                mine = align_depth(Z, c["K"], c["normal"], 1.0, c["ground"], agent_mask=m,
                                   mode=mode, snap_rel=c["snap_rel"], image=c["image"],
                                   **c["upright"]).depth * np.float32(c["scale"])
                assert np.median(np.abs(mine - stored) / stored) < 1e-5
                err_adapt.append(evaluate(stored, gt, "metric")["abs_rel"])
                vs_adapt.append(np.median(np.abs(got - stored) / stored))
    assert max(rel) <= 0.005, rel
    assert len(fits) == len(rel) >= 5                   # every frame had its own fit
    print(f"\n{mode}: ONNX vs numpy pipeline median rel {np.median(rel):.2e}; AbsRel ONNX "
          f"{np.mean(err_onnx):.4f}" + (f", adapt's ft-align-metric {np.mean(err_adapt):.4f} "
                                        f"(ONNX vs it: median rel {min(vs_adapt):.3f}-"
                                        f"{max(vs_adapt):.3f} per frame)" if err_adapt else ""))
    if err_adapt:
        assert abs(np.mean(err_onnx) - np.mean(err_adapt)) < 0.02


def test_export_applies_the_colour_foot_as_adapt_did(adapted_camera, tmp_path):
    """The summary's align.colour_foot decides: on (adapt's default), the graph stands the
    structures the rule moves on their colour foot, as numpy does on adapt's median image; off,
    or an older summary without the setting, the graph is the one without the rule (and says
    so), as adapt ran it."""
    from staticdepth.adaptation.align import static_image
    from staticdepth.deploy import MetricOnnx, deployment_constants, metric_depth_reference
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse
    from staticdepth.models import load_model

    d, seq, summary = adapted_camera
    s = json.loads(summary.read_text())
    assert s["config"]["align"]["colour_foot"] is True                 # adapt's default
    older = json.loads(summary.read_text())
    del older["config"]["align"]["colour_foot"]
    (tmp_path / "old.adapt.json").write_text(json.dumps(older))
    model = load_model(f"builtin:{d / 'ft.pt'}")
    c = deployment_constants(str(summary), str(seq))
    c_old = deployment_constants(str(tmp_path / "old.adapt.json"), str(seq))
    with SequenceReader(seq) as r:
        assert np.array_equal(c["image"], static_image(r, r.split("adapt")))
        frames = [r.left(i) for i in r.split("eval")[:3]]
    assert c_old["image"] is None and c_old["upright"] == c["upright"]
    moved = 0
    for img in frames:
        Z = depth_from_inverse(model.predict(img), c["eps"])
        on, off = (align_depth(Z, c["K"], c["normal"], 1.0, c["ground"], mode="upright",
                               image=im, **c["upright"]).depth for im in (c["image"], None))
        moved += int((on != off).sum())
        np.testing.assert_array_equal(metric_depth_reference(model, img, c),
                                      on * np.float32(c["scale"]))
        np.testing.assert_array_equal(metric_depth_reference(model, img, c_old),
                                      off * np.float32(c["scale"]))
    assert moved > 20                                   # the rule moves pixels on this camera
    for summ, ref_c, meta in ((summary, c, "applied"), (tmp_path / "old.adapt.json", c_old,
                                                        "not applied")):
        out = tmp_path / f"{meta[:3]}.onnx"
        assert main(["export-model", "--model", f"builtin:{d / 'ft.pt'}", "--summary",
                     str(summ), "--sequence", str(seq), "--out", str(out),
                     "--check-frames", "1"]) == 0
        onnx = MetricOnnx(str(out))
        assert onnx.metadata["staticdepth.colour_foot"].startswith(meta)
        for img in frames:
            ref = metric_depth_reference(model, img, ref_c)
            assert np.abs(onnx.predict(img) - ref).max() <= 1e-4 * ref.max()


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
    # the numpy pipeline (a model SPEC with the summary) takes the raw video's size too
    from staticdepth.deploy_predict import make_predictor

    fn, kind, _ = make_predictor(f"builtin:{d / 'm.pt'}", str(summary), str(seq),
                                 log=lambda s: None, device="cpu")
    assert kind == "metric" and fn(big).shape == (100, 200)
    assert np.median(np.abs(fn(big) - first) / first) <= 0.005
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



def test_predict_mp4_interrupted_leaves_nothing(deployment, tmp_path, monkeypatch):
    """Ctrl-C while the MP4 is being written (after 2 frames) leaves no temporary beside it: the
    writer wrote ``<tmp>.mp4`` where atomic_path removes ``<tmp>``, and the next run into the
    folder was refused (it held files); now nothing is left (the folder this run made, left
    empty, is removed too) and the next run writes."""
    import staticdepth.deploy_predict as dp

    d, seq, summary = deployment
    frames = dp._frames

    def interrupted(*args, **kwargs):
        for k, img in enumerate(frames(*args, **kwargs)):
            if k == 2:
                raise KeyboardInterrupt
            yield img

    monkeypatch.setattr(dp, "_frames", interrupted)
    spec = f"builtin:{d / 'm.pt'}"
    with pytest.raises(KeyboardInterrupt):
        dp.predict(spec, str(seq), str(tmp_path / "o"), "mp4", log=lambda s: None,
                   device="cpu")
    assert not (tmp_path / "o").exists()
    monkeypatch.setattr(dp, "_frames", frames)
    assert main(["predict", "--model", spec, "--input", str(seq), "--out", str(tmp_path / "o"),
                 "--format", "mp4", "--max-frames", "2", "--device", "cpu"]) == 0
    assert [p.name for p in (tmp_path / "o").iterdir()] == ["depth.mp4"]


def test_export_bad_inputs(deployment, tmp_path):
    d, seq, summary = deployment
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"config": {}}))
    assert main(["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(bad),
                 "--sequence", str(seq), "--out", str(tmp_path / "x.onnx")]) == 2
    assert main(["export-model", "--model", "onnx:nothing.onnx", "--summary", str(summary),
                 "--sequence", str(seq), "--out", str(tmp_path / "x.onnx")]) == 2
    assert not (tmp_path / "x.onnx").exists()
    assert main(["export-model", "--model", f"builtin:{d / 'm.pt'}", "--summary", str(summary),
                 "--sequence", str(seq), "--out", str(tmp_path / "x.txt")]) == 2   # not .onnx
    assert not (tmp_path / "x.txt").exists()
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
