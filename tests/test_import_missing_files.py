"""A frame's file missing from one stream is a bad frame, not "mismatched frame counts".

import-kitti --right (a right image missing from image_03) and import-carla (a depth, instance or
right image missing) name the file in one error line (exit 2), or with --skip-bad skip the frame
and list it in the file's provenance, as import-kitti already did for a missing LiDAR scan. A file
without the frame's main image (left / rgb) still belongs to no frame and is refused.
"""
import json
import os
import shutil

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.carla import import_carla, write_carla_frame
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.kitti import import_kitti
from staticdepth.errors import InputError

DATE = "2011_09_26"
DRIVE = "2011_09_26_drive_sample"
W, H = 32, 16


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.fixture
def kitti_stereo(shared_data, tmp_path):
    """A symlinked copy of the KITTI sample whose image_03 repeats image_02 (3 frames)."""
    src = shared_data / "kitti_raw" / DATE
    if not src.is_dir():
        pytest.skip(f"KITTI sample not found at {src}")
    root = tmp_path / "raw"
    (root / DATE).mkdir(parents=True)
    for n in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        os.symlink(src / n, root / DATE / n)
    drive = root / DATE / f"{DRIVE}_sync"
    shutil.copytree(src / f"{DRIVE}_sync", drive, copy_function=os.symlink)
    shutil.copytree(drive / "image_02", drive / "image_03", copy_function=os.symlink)
    return root, drive


def test_kitti_right_image_missing_is_a_bad_frame(kitti_stereo, tmp_path, capsys):
    root, drive = kitti_stereo
    missing = drive / "image_03" / "data" / "0000000001.png"
    missing.unlink()
    out = tmp_path / "K.h5"
    argv = ["import-kitti", "--root", str(root), "--drives", DRIVE, "--right", "--out", str(out)]
    assert main(argv) == 2
    assert _error_line(capsys) == f"staticdepth import-kitti: error: {missing}: file not found"
    assert not out.exists()
    assert main(argv + ["--skip-bad", "--resume"]) == 0
    text = capsys.readouterr().out
    assert "wrote 2 frames" in text and "skipped 1 bad frame(s):" in text
    assert f"skipped {DRIVE}_sync/0000000001: {missing}: file not found" in text
    with SequenceReader(out) as r:
        assert len(r) == 2 and r.streams() == ["left", "right", "depth"]
        prov = r.meta.provenance
        assert prov["skipped"] == [{"frame": f"{DRIVE}_sync/0000000001",
                                    "error": f"{missing}: file not found"}]
        assert prov["frames_in_input"] == 3
        third = cv2.imread(str(drive / "image_02" / "data" / "0000000002.png"))[..., ::-1]
        np.testing.assert_array_equal(r.right(1), third)  # frames 0 and 2 kept


def test_kitti_right_images_that_belong_to_no_frame_are_refused(kitti_stereo, tmp_path):
    root, drive = kitti_stereo
    right = drive / "image_03" / "data"
    os.symlink(right / "0000000000.png", right / "0000000007.png")
    with pytest.raises(InputError, match=r"mismatched frame counts: .*image_03/data has 1 right "
                                         r"image\(s\) without a left image \(e.g. '0000000007'\)"):
        import_kitti(root, [DRIVE], tmp_path / "x.h5", right=True)
    shutil.rmtree(right)
    right.mkdir()
    with pytest.raises(InputError, match=r"drive has no right images \(image_03/data/\*.png\)"):
        import_kitti(root, [DRIVE], tmp_path / "x.h5", right=True)


def _carla_export(folder, n=4):
    """``n`` frames of a CARLA export with a right view: frame i's depth is i + 2 m everywhere."""
    rng = np.random.default_rng(0)
    tags = np.full((H, W), 1, np.uint8)           # road
    ids = np.zeros((H, W), np.uint16)
    for i in range(n):
        rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        depth = np.full((H, W), i + 2.0, np.float32)
        write_carla_frame(folder, i, rgb, depth, tags, ids, right=rgb[:, ::-1])
    (folder / "sensor.json").write_text(json.dumps({
        "image_size_x": W, "image_size_y": H, "fov": 90, "sensor_tick": 0.05, "baseline_m": 0.5,
        "transform": {"location": {"z": 2.0}, "rotation": {"pitch": -10.0}}}))
    return folder


@pytest.mark.parametrize("sub", ["depth", "instance", "right"])
def test_carla_file_missing_is_a_bad_frame(sub, tmp_path, capsys):
    src = _carla_export(tmp_path / "C")
    missing = src / sub / "000001.png"
    missing.unlink()
    out = tmp_path / "C.h5"
    assert main(["import-carla", str(src), "--out", str(out)]) == 2
    assert _error_line(capsys) == f"staticdepth import-carla: error: {missing}: file not found"
    assert not out.exists()
    assert main(["import-carla", str(src), "--out", str(out), "--skip-bad", "--resume"]) == 0
    text = capsys.readouterr().out
    assert "wrote 3 frames" in text and f"skipped 000001: {missing}: file not found" in text
    with SequenceReader(out) as r:
        assert len(r) == 3
        assert r.meta.provenance["skipped"] == [{"frame": "000001",
                                                 "error": f"{missing}: file not found"}]
        assert r.meta.provenance["frames_in_input"] == 4
        np.testing.assert_allclose(r.timestamps(), [0.0, 0.1, 0.15])  # frames 0, 2, 3
        assert [float(r.depth(k)[0, 0]) for k in range(3)] == pytest.approx([2.0, 4.0, 5.0],
                                                                             abs=1e-3)


def test_carla_files_that_belong_to_no_frame_are_refused(tmp_path):
    src = _carla_export(tmp_path / "C", n=2)
    shutil.copy(src / "depth" / "000000.png", src / "depth" / "000005.png")
    with pytest.raises(InputError, match=r"mismatched frame counts: depth/ has 1 image\(s\) "
                                         r"without an rgb image \(e.g. '000005'\)"):
        import_carla(src, tmp_path / "x.h5")
    (src / "depth" / "000005.png").unlink()
    shutil.rmtree(src / "instance")
    (src / "instance").mkdir()
    with pytest.raises(InputError, match=r"no frames in instance/"):
        import_carla(src, tmp_path / "x.h5")
