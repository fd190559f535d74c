"""KITTI-style export and the PyTorch dataset, checked against the sequence file they came from."""
import json
import pickle

import cv2
import numpy as np
import pytest
import torch

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.export import export_kitti, kitti_png_from_depth
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.dataset.kitti import KittiCalib, read_depth_png
from staticdepth.dataset.torch_dataset import SequenceDataset
from staticdepth.errors import InputError
from staticdepth.geometry import Camera, Mounting, StereoRig

CAM = Camera.from_intrinsics(50.0, 50.0, 31.5, 15.5, 64, 32)


def make_sequence(path, n=5, adapt=2, seed=0, right=True):
    """A small sequence with known content: random images, depth with holes, instances."""
    rng = np.random.default_rng(seed)
    streams = ("left", "right", "depth", "instances") if right else ("left", "depth")
    meta = SequenceMeta(name=path.stem, camera=CAM, gt_kind="stereo", source="test",
                        adapt_frames=adapt, rig=StereoRig.rectified(CAM, 0.27) if right else None,
                        mounting=Mounting.from_pitch_roll(5.0, 30.0),
                        provenance={"matcher": "sgbm", "stereo_config": {"num_disparities": 64}})
    frames = []
    with SequenceWriter(path, meta, streams) as w:
        for i in range(n):
            depth = rng.uniform(0.5, 80, (32, 64)).astype(np.float32)
            depth[rng.random((32, 64)) < 0.3] = np.nan
            fr = {"left": rng.integers(0, 255, (32, 64, 3), dtype=np.uint8), "depth": depth}
            if right:
                fr["right"] = rng.integers(0, 255, (32, 64, 3), dtype=np.uint8)
                fr["instances"] = rng.integers(0, 4, (32, 64)).astype(np.uint16)
            ag = schema.empty_agents(1)
            w.append(timestamp=100 + 0.1 * i, agents=ag, **fr)
            frames.append(fr)
    return frames


def test_depth_png_encoding():
    d = np.array([[np.nan, 0.0, 1 / 256, 10.0, 255.99, 300.0, 1e-4]], np.float32)
    code, far = kitti_png_from_depth(d)
    assert code.tolist() == [[0, 0, 1, 2560, 65533, 0, 1]] and far == 1


def test_export_cli_round_trip(tmp_path, capsys):
    seq = tmp_path / "S.h5"
    frames = make_sequence(seq)
    out = tmp_path / "kitti"
    assert main(["export", str(seq), "--format", "kitti", "--out", str(out)]) == 0
    assert "exported 5 frames" in capsys.readouterr().out
    names = sorted(p.name for p in (out / "image_02" / "data").iterdir())
    assert names == [f"{i:010d}.png" for i in range(5)]
    for i, fr in enumerate(frames):
        name = f"{i:010d}.png"
        np.testing.assert_array_equal(cv2.imread(str(out / "image_02/data" / name))[..., ::-1],
                                      fr["left"])
        np.testing.assert_array_equal(cv2.imread(str(out / "image_03/data" / name))[..., ::-1],
                                      fr["right"])
        d = read_depth_png(out / "proj_depth/groundtruth/image_02" / name)  # the KITTI reader
        np.testing.assert_array_equal(np.isnan(d), np.isnan(fr["depth"]))
        ok = ~np.isnan(d)
        assert np.max(np.abs(d[ok] - fr["depth"][ok])) <= 0.5 / 256 + 1e-6
        inst = cv2.imread(str(out / "instances" / name), cv2.IMREAD_ANYDEPTH)
        np.testing.assert_array_equal(inst, fr["instances"])
    ts = np.loadtxt(out / "timestamps.txt")
    np.testing.assert_allclose(ts, 100 + 0.1 * np.arange(5))
    assert (out / "splits/adapt.txt").read_text().split() == ["0000000000", "0000000001"]
    assert len((out / "splits/eval.txt").read_text().split()) == 3
    # the calibration file reads back with the KITTI parser: same camera, same baseline
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib/calib_cam_to_cam.txt").write_text((out / "calib_cam_to_cam.txt").read_text())
    (tmp_path / "calib/calib_velo_to_cam.txt").write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    calib = KittiCalib.load(tmp_path / "calib")
    assert calib.camera() == CAM and calib.baseline_m == pytest.approx(0.27)
    info = json.loads((out / "calib.json").read_text())
    assert info["camera_height_m"] == 5.0 and info["adapt_frames"] == 2
    # no overwrite without the flag; nothing left behind
    assert main(["export", str(seq), "--out", str(out)]) == 2
    assert "exists already; pass --overwrite" in capsys.readouterr().err
    export_kitti(seq, out, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()
                  if not p.name.endswith(".lock")) == ["S.h5", "calib", "kitti"]


def test_export_bad_input(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        export_kitti(tmp_path / "none.h5", tmp_path / "out")
    with pytest.raises(InputError, match="parent does not exist"):
        export_kitti(tmp_path / "none.h5", tmp_path / "a" / "b")


def test_torch_dataset_reads_frames_lazily(tmp_path):
    seq = tmp_path / "S.h5"
    frames = make_sequence(seq, n=6, adapt=2)
    ds = SequenceDataset(seq, split="eval", streams=("left", "right", "depth", "instances"))
    assert len(ds) == 4 and ds._reader is None  # nothing opened yet
    item = ds[1]
    assert item["index"] == 3 and item["split"] == "eval"
    np.testing.assert_allclose(item["image"].numpy(),
                               frames[3]["left"].transpose(2, 0, 1) / 255.0, atol=1e-7)
    assert item["depth"].shape == (1, 32, 64)
    np.testing.assert_array_equal(item["depth"][0].numpy(), frames[3]["depth"])
    np.testing.assert_array_equal(item["instances"].numpy(), frames[3]["instances"])
    torch.testing.assert_close(item["K"], torch.tensor(CAM.K, dtype=torch.float32))
    # the pickled dataset (what a DataLoader worker gets) carries no file handle and no frames
    blob = pickle.dumps(ds)
    assert len(blob) < 5000
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=2)
    batches = list(loader)
    assert [b["index"].tolist() for b in batches] == [[2, 3], [4, 5]]
    np.testing.assert_array_equal(batches[1]["depth"][1, 0].numpy(), frames[5]["depth"])
    adapt = SequenceDataset(seq, split="adapt")
    assert [adapt[k]["split"] for k in range(len(adapt))] == ["adapt", "adapt"]
    ds.close()
    with pytest.raises(InputError, match="no stream"):
        SequenceDataset(make_sequence(tmp_path / "L.h5", right=False) and tmp_path / "L.h5",
                        streams=("left", "right"))
    with pytest.raises(InputError, match="unknown split"):
        SequenceDataset(seq, split="train")


def test_inspect_summary_and_thumbnail_sheet(tmp_path, capsys):
    from staticdepth.dataset.inspect import colorize_depth

    seq = tmp_path / "S.h5"
    frames = make_sequence(seq, n=5, adapt=2)
    sheet, js = tmp_path / "sheet.png", tmp_path / "s.json"
    assert main(["inspect", str(seq), "--sheet", str(sheet), "--json", str(js)]) == 0
    text = capsys.readouterr().out
    assert "frames           5" in text and str(sheet) in text
    info = json.loads(js.read_text())
    assert info["frames"] == 5 and info["splits"] == {"adapt": 2, "eval": 3}
    assert info["gt_density"] == pytest.approx(
        np.mean([np.isfinite(f["depth"]).mean() for f in frames]), abs=1e-4)
    assert info["depth_range_m"] == pytest.approx(
        [min(np.nanmin(f["depth"]) for f in frames), max(np.nanmax(f["depth"]) for f in frames)],
        abs=1e-3)
    assert info["baseline_m"] == 0.27 and info["pitch_deg"] == pytest.approx(30.0)
    img = cv2.imread(str(sheet))[..., ::-1]
    assert img.shape == (2 * 120, 5 * 240, 3)     # image over depth, one column per frame
    np.testing.assert_array_equal(
        img[:120, 240:480], cv2.resize(frames[1]["left"], (240, 120), interpolation=cv2.INTER_AREA))
    np.testing.assert_array_equal(
        img[120:, :240], cv2.resize(colorize_depth(frames[0]["depth"]), (240, 120),
                                    interpolation=cv2.INTER_NEAREST))
    assert main(["inspect", str(tmp_path / "none.h5")]) == 2
    assert "none.h5: file not found" in capsys.readouterr().err


def make_far_sequence(path, name="far"):
    """Two frames whose depth reaches beyond the KITTI PNG's 255.996 m at 3 + 2 known pixels."""
    meta = SequenceMeta(name=name, camera=CAM, gt_kind="synthetic", source="test", adapt_frames=1)
    depth = np.full((2, 32, 64), 20.0, np.float32)
    depth[0, 0, :3] = [300.0, 256.0, 1e4]  # beyond: stored as 0
    depth[0, 1, 0] = 255.99  # within: 65533
    depth[1, 5, 5:7] = 4000.0
    depth[1, 6, 6] = np.nan
    with SequenceWriter(path, meta, ("left", "depth")) as w:
        for i in range(2):
            w.append(timestamp=float(i), left=np.zeros((32, 64, 3), np.uint8), depth=depth[i])
    return depth


def test_export_warns_about_depth_beyond_the_png_range(tmp_path, capsys):
    depth = make_far_sequence(tmp_path / "F.h5")
    out = tmp_path / "F_kitti"
    assert main(["export", str(tmp_path / "F.h5"), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"exported 2 frames to {out}",
        f"warning: {out}: 5 depth pixel(s) beyond 255.996 m (the limit of KITTI's uint16 PNG, "
        "depth x 256) are stored as 0 (unknown)"]
    assert json.loads((out / "calib.json").read_text())["depth_beyond_range_px"] == 5
    png = cv2.imread(str(out / "proj_depth/groundtruth/image_02/0000000000.png"),
                     cv2.IMREAD_ANYDEPTH)
    assert png[0, :3].tolist() == [0, 0, 0] and png[1, 0] == 65533 and png[2, 0] == 20 * 256
    assert np.count_nonzero(png == 0) == 3 and np.isfinite(depth[0]).all()
    # a sequence within range: no warning, and the count says 0
    make_sequence(tmp_path / "S.h5")
    assert main(["export", str(tmp_path / "S.h5"), "--out", str(tmp_path / "S_kitti")]) == 0
    assert "warning" not in capsys.readouterr().out
    assert json.loads((tmp_path / "S_kitti/calib.json").read_text())["depth_beyond_range_px"] == 0
