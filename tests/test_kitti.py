"""KITTI raw import on the real calibration and scans in ../shared/data/kitti_raw."""
import os
import shutil

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.kitti import (KittiCalib, depth_from_lidar, drive_tasks, import_kitti,
                                       load_frame, pose_difference, read_calib_file,
                                       read_depth_png, read_timestamps, read_velodyne)
from staticdepth.errors import InputError

DATE = "2011_09_26"
DRIVE = "2011_09_26_drive_sample"


@pytest.fixture(scope="module")
def kitti_root(request):
    from conftest import shared_data_dir

    d = shared_data_dir() / "kitti_raw"
    if not (d / DATE).is_dir():
        pytest.skip(f"KITTI sample not found at {d} (set STATICDEPTH_DATA)")
    return d


def _copy_tree(src_root, dst_root, drives=(DRIVE,)):
    """A writable copy of the sample (symlinked files), the drive possibly under other names."""
    src = os.path.join(src_root, DATE)
    dst = os.path.join(dst_root, DATE)
    os.makedirs(dst)
    for n in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        os.symlink(os.path.join(src, n), os.path.join(dst, n))
    for name in drives:
        shutil.copytree(os.path.join(src, DRIVE + "_sync"), os.path.join(dst, name + "_sync"),
                        copy_function=os.symlink)
    return dst_root


def _independent_depth(scan, calib_cam, calib_velo, w, h):
    """Point by point: velo -> cam0 -> rectified cam0 -> image 2, the nearest per pixel."""
    R = calib_velo["R"].reshape(3, 3)
    T = calib_velo["T"]
    R0 = calib_cam["R_rect_00"].reshape(3, 3)
    P2 = calib_cam["P_rect_02"].reshape(3, 4)
    best = {}
    for x, y, z, _ in scan:
        if not x > 0:
            continue
        c0 = R @ np.array([x, y, z], np.float64) + T
        r0 = R0 @ c0
        pu = P2[0, 0] * r0[0] + P2[0, 1] * r0[1] + P2[0, 2] * r0[2] + P2[0, 3]
        pv = P2[1, 0] * r0[0] + P2[1, 1] * r0[1] + P2[1, 2] * r0[2] + P2[1, 3]
        pz = P2[2, 0] * r0[0] + P2[2, 1] * r0[1] + P2[2, 2] * r0[2] + P2[2, 3]
        if pz <= 0:
            continue
        u, v = int(np.round(pu / pz)) - 1, int(np.round(pv / pz)) - 1
        if 0 <= u < w and 0 <= v < h and pz < best.get((v, u), np.inf):
            best[(v, u)] = pz
    out = np.full((h, w), np.nan, np.float32)
    for (v, u), z in best.items():
        out[v, u] = z
    return out


def test_calibration_record_matches_the_files(kitti_root):
    calib = KittiCalib.load(kitti_root / DATE)
    cam = calib.camera()
    assert (cam.width, cam.height) == (1242, 375)
    assert cam.fx == pytest.approx(721.5377) and cam.cx == pytest.approx(609.5593)
    assert cam.cy == pytest.approx(172.854)
    # KITTI's colour cameras are about 0.54 m apart: (44.85728 + 339.5242) / 721.5377
    assert calib.baseline_m == pytest.approx((44.85728 + 339.5242) / 721.5377, rel=1e-6)
    with pytest.raises(ValueError):
        calib.P_rect_02[0, 0] = 1.0  # frozen record


def test_projection_agrees_with_an_independent_loop(kitti_root):
    d = kitti_root / DATE
    scan = read_velodyne(d / f"{DRIVE}_sync" / "velodyne_points" / "data" / "0000000000.bin")
    calib = KittiCalib.load(d)
    depth = depth_from_lidar(scan, calib.img2_from_velo, 1242, 375)
    ref = _independent_depth(scan, read_calib_file(d / "calib_cam_to_cam.txt"),
                             read_calib_file(d / "calib_velo_to_cam.txt"), 1242, 375)
    np.testing.assert_array_equal(np.isfinite(depth), np.isfinite(ref))
    np.testing.assert_allclose(depth[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=1e-5)
    ok = np.isfinite(depth)
    assert 10_000 < ok.sum() < 30_000  # a 64-beam scan covers a few percent of the image
    # Every depth lies within the scan's range: positive and no farther than the farthest point.
    rng = np.linalg.norm(scan[:, :3], axis=1)
    assert depth[ok].min() > 0 and depth[ok].max() <= rng.max() + 0.5
    # A level 64-beam LiDAR (+2 to -25 degrees) sees mostly below the horizon row (c_y = 172.9).
    rows = np.nonzero(ok)[0]
    assert np.mean(rows > 172.9) > 0.6 and rows.max() >= 370


def test_a_point_lands_where_expected(kitti_root):
    calib = KittiCalib.load(kitti_root / DATE)
    P = calib.img2_from_velo
    # Solve for the velodyne point that projects to pixel position (501, 201) at depth 12 m.
    A = np.vstack([P[:, :3]])
    target = np.array([501.0 * 12, 201.0 * 12, 12.0]) - P[:, 3]
    X = np.linalg.solve(A, target)
    near = np.r_[X, 0.0][None]
    far = np.r_[X * 2, 0.0][None]  # a farther point on roughly the same ray must lose
    depth = depth_from_lidar(np.vstack([far, near]), P, 1242, 375)
    assert depth[200, 500] == pytest.approx(12.0, rel=1e-6)  # KITTI: u, v = round(.) - 1
    assert np.count_nonzero(np.isfinite(depth)) <= 2
    behind = np.r_[-X[0], X[1], X[2], 0.0][None]  # x_velo < 0: dropped
    assert not np.isfinite(depth_from_lidar(behind, P, 1242, 375)).any()


def test_timestamps_parse_to_seconds(kitti_root):
    ts = read_timestamps(kitti_root / DATE / f"{DRIVE}_sync" / "image_02" / "timestamps.txt")
    assert len(ts) == 3
    np.testing.assert_allclose(np.diff(ts), [0.103123456, 0.103138304], atol=1e-6)


def test_import_two_drives_cli(kitti_root, tmp_path, capsys):
    root = _copy_tree(kitti_root, tmp_path / "raw", drives=("2011_09_26_drive_0001",
                                                           "2011_09_26_drive_0002"))
    out = tmp_path / "K.h5"
    rc = main(["import-kitti", "--root", str(root), "--drives", "2011_09_26_drive_0001",
               "2011_09_26_drive_0002", "--name", "K0", "--adapt-frames", "4", "--out", str(out)])
    assert rc == 0
    assert "wrote 6 frames" in capsys.readouterr().out
    with SequenceReader(out) as r:
        assert len(r) == 6 and r.meta.name == "K0" and r.meta.gt_kind == "lidar"
        assert r.meta.camera_height_m == 1.65 and r.camera.fx == pytest.approx(721.5377)
        assert r.split("adapt") == range(4)
        t = drive_tasks(root, "2011_09_26_drive_0002")[0][1]
        np.testing.assert_array_equal(r.depth(4), load_frame(t).arrays["depth"])
        np.testing.assert_array_equal(r.left(4), cv2.imread(t.image)[..., ::-1])
        ts = r.timestamps()
        assert ts[3] == pytest.approx(ts[0])  # the second drive is the same recording here
        prov = r.meta.provenance
        assert prov["pose_check"][0]["same_pose"] and prov["pose_check"][0]["mean_abs_diff"] < 1e-6


def test_pose_check_warns_with_the_measured_shift(kitti_root, tmp_path):
    root = _copy_tree(kitti_root, tmp_path / "raw", drives=("2011_09_26_drive_0001",
                                                           "2011_09_26_drive_0002"))
    data = root / DATE / "2011_09_26_drive_0002_sync" / "image_02" / "data"
    for p in sorted(data.iterdir()):
        img = cv2.imread(str(p))
        p.unlink()
        cv2.imwrite(str(p), np.roll(img, 8, axis=1))  # the camera "moved" 8 px
    warnings = []
    rep = import_kitti(root, ["2011_09_26_drive_0001", "2011_09_26_drive_0002"],
                       tmp_path / "K.h5", warn=warnings.append)
    assert rep.frames == 6 and len(warnings) == 1 and "may not share one camera pose" in warnings[0]
    with SequenceReader(tmp_path / "K.h5") as r:
        chk = r.meta.provenance["pose_check"][0]
    assert not chk["same_pose"] and abs(chk["shift_px"][0]) == pytest.approx(8, abs=0.5)


def test_depth_completion_maps_replace_the_projection(kitti_root, tmp_path):
    root = _copy_tree(kitti_root, tmp_path / "raw")
    gt = tmp_path / "depth" / "train" / f"{DRIVE}_sync" / "proj_depth" / "groundtruth" / "image_02"
    gt.mkdir(parents=True)
    m = np.zeros((375, 1242), np.uint16)
    m[300, 600] = 256 * 7 + 128  # 7.5 m
    cv2.imwrite(str(gt / "0000000001.png"), m)  # frames 0 and 2 have no map (as at drive ends)
    np.testing.assert_array_equal(np.isfinite(read_depth_png(gt / "0000000001.png")), m > 0)
    out = tmp_path / "K.h5"
    assert main(["import-kitti", "--root", str(root), "--drives", DRIVE, "--depth-maps",
                 str(tmp_path / "depth"), "--out", str(out)]) == 0
    with SequenceReader(out) as r:
        assert r.depth(1)[300, 600] == 7.5 and np.count_nonzero(np.isfinite(r.depth(1))) == 1
        assert not np.isfinite(r.depth(0)).any()
    with pytest.raises(InputError, match="no depth-completion maps"):
        import_kitti(root, [DRIVE], tmp_path / "x.h5", depth_maps=str(tmp_path / "raw"))


def test_bad_input_is_named(kitti_root, tmp_path, capsys):
    root = _copy_tree(kitti_root, tmp_path / "raw")
    drive = root / DATE / f"{DRIVE}_sync"
    out = tmp_path / "K.h5"
    # missing drive
    with pytest.raises(InputError, match="drive folder not found"):
        import_kitti(root, ["2011_09_26_drive_0099"], out)
    # truncated scan: error naming the file; with --skip-bad a listed, counted skip
    scan = drive / "velodyne_points" / "data" / "0000000001.bin"
    raw = scan.read_bytes()
    scan.unlink()
    scan.write_bytes(raw[:1001])
    with pytest.raises(InputError, match="truncated scan") as e:
        import_kitti(root, [DRIVE], out)
    assert e.value.path == str(scan)
    assert not out.exists()
    rc = main(["import-kitti", "--root", str(root), "--drives", DRIVE, "--out", str(out),
               "--skip-bad", "--resume"])
    text = capsys.readouterr().out
    assert rc == 0 and "wrote 2 frames" in text and "skipped 1 bad frame" in text
    assert "0000000001" in text
    with SequenceReader(out) as r:
        assert len(r) == 2 and r.meta.provenance["skipped"][0]["frame"].endswith("0000000001")
    # corrupt PNG
    img = drive / "image_02" / "data" / "0000000002.png"
    img.unlink()
    img.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    assert main(["import-kitti", "--root", str(root), "--drives", DRIVE, "--out", str(out),
                 "--overwrite"]) == 2
    assert "0000000002.png: corrupt or unreadable image" in capsys.readouterr().err
    # mismatched frame counts between streams
    img.unlink()
    with pytest.raises(InputError, match="mismatched frame counts"):
        import_kitti(root, [DRIVE], out, overwrite=True)
    # --right without image_03
    with pytest.raises(InputError, match="folder not found") as e:
        import_kitti(root, [DRIVE], out, right=True)
    assert e.value.path.endswith("image_03/data")
    # a drive without scans
    shutil.rmtree(drive / "velodyne_points" / "data")
    (drive / "velodyne_points" / "data").mkdir()
    with pytest.raises(InputError, match="no LiDAR scans"):
        import_kitti(root, [DRIVE], out, overwrite=True)


def test_missing_calibration_and_bad_timestamps(kitti_root, tmp_path):
    root = _copy_tree(kitti_root, tmp_path / "raw")
    ts = root / DATE / f"{DRIVE}_sync" / "image_02" / "timestamps.txt"
    ts.unlink()
    ts.write_text("2011-09-26 13:02:25.9\nyesterday\n2011-09-26 13:02:26.1\n")
    with pytest.raises(InputError, match="line 2: not a timestamp") as e:
        import_kitti(root, [DRIVE], tmp_path / "K.h5")
    assert e.value.path == str(ts)
    (root / DATE / "calib_velo_to_cam.txt").unlink()
    with pytest.raises(InputError, match="calibration file not found") as e:
        import_kitti(root, [DRIVE], tmp_path / "K.h5")
    assert e.value.path.endswith("calib_velo_to_cam.txt")
    (root / DATE / "calib_velo_to_cam.txt").write_text("R: 1 0 0\n")
    with pytest.raises(InputError, match="'R' has 3 values"):
        KittiCalib.load(root / DATE)


def test_right_view_and_rig(kitti_root, tmp_path):
    root = _copy_tree(kitti_root, tmp_path / "raw")
    drive = root / DATE / f"{DRIVE}_sync"
    shutil.copytree(drive / "image_02", drive / "image_03", copy_function=os.symlink)
    out = tmp_path / "K.h5"
    rep = import_kitti(root, [DRIVE], out, right=True, adapt_frames=1)
    assert rep.frames == 3
    with SequenceReader(out) as r:
        assert r.streams() == ["left", "right", "depth"]
        assert r.meta.rig.baseline_m == pytest.approx(0.5327, abs=1e-4)
        assert r.meta.rig.is_rectified()


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_skip_bad_passes_over_unreadable_sample_images(kitti_root, tmp_path, capsys):
    """The pose check's sample images (and the image that gives the size) were read outside the
    skip-bad handling: a truncated PNG stopped ``--skip-bad`` before anything was written."""
    drives = ("2011_09_26_drive_0001", "2011_09_26_drive_0002")
    root = _copy_tree(kitti_root, tmp_path / "raw", drives=drives)
    bad = [root / DATE / f"{drives[0]}_sync" / "image_02" / "data" / "0000000000.png",
           root / DATE / f"{drives[1]}_sync" / "image_02" / "data" / "0000000001.png"]
    for p in bad:
        raw = p.read_bytes()
        p.unlink()
        p.write_bytes(raw[:5000])  # head -c 5000: a truncated PNG
    out = tmp_path / "K.h5"
    argv = ["import-kitti", "--root", str(root), "--drives", *drives, "--out", str(out)]
    assert main(argv) == 2
    assert _one_error_line(capsys).endswith(
        f"{bad[0]}: corrupt or unreadable image (a PNG cut short: no IEND chunk)")
    assert not out.exists() and not os.path.exists(f"{out}.partial")
    assert main(argv + ["--skip-bad"]) == 0
    text = capsys.readouterr().out
    assert "wrote 4 frames" in text and "skipped 2 bad frame(s)" in text
    with SequenceReader(out) as r:
        assert len(r) == 4 and r.width == 1242 and r.height == 375
        assert [s["frame"] for s in r.meta.provenance["skipped"]] == [
            f"{drives[0]}_sync/0000000000", f"{drives[1]}_sync/0000000001"]
        good = root / DATE / f"{drives[0]}_sync" / "image_02" / "data" / "0000000001.png"
        np.testing.assert_array_equal(r.left(0), cv2.imread(str(good))[..., ::-1])
        chk = r.meta.provenance["pose_check"][0]
    # the pose check compared the readable frames: 1, 2 of the first drive with 0, 2 of the second
    src = kitti_root / DATE / f"{DRIVE}_sync" / "image_02" / "data"
    img = [cv2.imread(str(src / f"{i:010d}.png"))[..., ::-1] for i in range(3)]
    ref = pose_difference([img[1], img[2]], [img[0], img[2]])
    assert chk["same_pose"] and chk["mean_abs_diff"] == pytest.approx(ref["mean_abs_diff"])
    assert ref["mean_abs_diff"] > 1.0  # other samples would give another value


def test_duplicate_drives_are_refused(kitti_root, tmp_path, capsys):
    out = tmp_path / "dup.h5"
    for second in (DRIVE, DRIVE + "_sync"):
        assert main(["import-kitti", "--root", str(kitti_root), "--drives", DRIVE, second,
                     "--out", str(out)]) == 2
        assert _one_error_line(capsys).endswith(
            f"{kitti_root}: drive {DRIVE} is listed twice in --drives (its frames would be "
            "imported twice)")
        assert not out.exists() and not os.path.exists(f"{out}.partial")


def test_a_drive_name_without_a_date_names_the_root(kitti_root, tmp_path, capsys):
    assert main(["import-kitti", "--root", str(kitti_root), "--drives", "foo",
                 "--out", str(tmp_path / "f.h5")]) == 2
    line = _one_error_line(capsys)
    assert f"{kitti_root}: drive 'foo' does not start with its recording date" in line
    assert "foo_sync/foo_sync" not in line
    with pytest.raises(InputError, match="drive folder not found") as e:
        import_kitti(kitti_root, ["2011_09_26_drive_0099"], tmp_path / "f.h5")
    assert e.value.path == str(kitti_root / DATE / "2011_09_26_drive_0099_sync")


def test_adapt_frames_beyond_the_input_is_refused_before_writing(kitti_root, tmp_path, capsys):
    out = tmp_path / "x.h5"
    argv = ["import-kitti", "--root", str(kitti_root), "--drives", DRIVE, "--out", str(out)]
    assert main(argv + ["--adapt-frames", "5"]) == 2
    assert _one_error_line(capsys).endswith(
        "--adapt-frames must be within 1..3 (the input's frames), got 5")
    assert sorted(os.listdir(tmp_path)) == []  # no partial, nothing to resume or restart
    assert main(argv + ["--adapt-frames", "3"]) == 0
    with SequenceReader(out) as r:
        assert r.split("adapt") == range(3) and len(r.split("eval")) == 0


def test_default_name_is_the_outputs_stem(kitti_root, tmp_path):
    assert main(["import-kitti", "--root", str(kitti_root), "--drives", DRIVE,
                 "--out", str(tmp_path / "t1.h5")]) == 0
    with SequenceReader(tmp_path / "t1.h5") as r:
        assert r.meta.name == "t1"
        assert r.meta.provenance["drives"] == [DRIVE]


def _long_drive(kitti_root, root, n):
    """A drive of ``n`` frames (the sample's 3 in turn, symlinked) with ``n`` timestamps."""
    src = kitti_root / DATE / f"{DRIVE}_sync"
    d = root / DATE / f"{DRIVE}_sync"
    os.makedirs(root / DATE)
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        os.symlink(kitti_root / DATE / name, root / DATE / name)
    for sub, ext in (("image_02", ".png"), ("velodyne_points", ".bin")):
        (d / sub / "data").mkdir(parents=True)
        for i in range(n):
            os.symlink(src / sub / "data" / f"{i % 3:010d}{ext}",
                       d / sub / "data" / f"{i:010d}{ext}")
    (d / "image_02" / "timestamps.txt").write_text(
        "".join(f"2011-09-26 13:02:{20 + 0.1 * i:012.9f}\n" for i in range(n)))
    return d


def test_a_depth_map_missing_mid_drive_is_a_bad_frame_and_drive_ends_are_counted(
        kitti_root, tmp_path, capsys):
    """Frames without a map became all-NaN depth silently, mid-drive too. The official maps leave
    out a drive's first and last 5 frames: those stay unknown, counted and listed; a map missing
    elsewhere is refused naming it, or skipped and listed with --skip-bad."""
    root = tmp_path / "raw"
    _long_drive(kitti_root, root, 13)
    gt = tmp_path / "depth" / "val" / f"{DRIVE}_sync" / "proj_depth" / "groundtruth" / "image_02"
    gt.mkdir(parents=True)
    for i in (5, 7):  # frames 5..7 have maps in the official layout; 6's is missing
        m = np.zeros((375, 1242), np.uint16)
        m[200, 100 + i] = 256 * i + 64  # i + 0.25 m
        cv2.imwrite(str(gt / f"{i:010d}.png"), m)
    out = tmp_path / "K.h5"
    argv = ["import-kitti", "--root", str(root), "--drives", DRIVE, "--depth-maps",
            str(tmp_path / "depth"), "--out", str(out)]
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert err == [f"staticdepth import-kitti: error: {gt / '0000000006.png'}: depth-completion "
                   "map not found (the official maps leave out only the first and last 5 frames "
                   "of a drive)"]
    note = ("note: 10 of 13 frames have no depth-completion map (the official maps leave out the "
            "first and last 5 frames of each drive): their depth is unknown (NaN); listed as "
            "frames_without_depth_map")
    assert note in captured.out
    assert not out.exists() and os.path.exists(f"{out}.partial")  # frames 0-5 kept to resume
    assert main(argv + ["--skip-bad", "--resume"]) == 0
    text = capsys.readouterr().out
    assert note in text and "wrote 12 frames" in text and "(resumed after frame 6)" in text
    assert f"skipped {DRIVE}_sync/0000000006: {gt / '0000000006.png'}: depth-completion" in text
    with SequenceReader(out) as r:
        assert len(r) == 12
        prov = r.meta.provenance
        assert [s["frame"] for s in prov["skipped"]] == [f"{DRIVE}_sync/0000000006"]
        assert prov["frames_without_depth_map"] == {
            "count": 10, "frames": [f"{DRIVE}_sync/{i:010d}" for i in (0, 1, 2, 3, 4, 8, 9, 10,
                                                                          11, 12)]}
        for k, i in ((5, 5), (6, 7)):  # written frames 5 and 6 are drive frames 5 and 7
            d = r.depth(k)
            assert d[200, 100 + i] == i + 0.25 and np.count_nonzero(np.isfinite(d)) == 1
        for k in (0, 4, 7, 11):
            assert not np.isfinite(r.depth(k)).any()


def test_skip_bad_skips_a_frame_whose_scan_is_missing(kitti_root, tmp_path, capsys):
    """A missing .bin gave "mismatched frame counts" even with --skip-bad (a truncated one was
    skipped): now it is a bad frame like any other, named, or skipped and listed."""
    root = _copy_tree(kitti_root, tmp_path / "raw")
    scan = root / DATE / f"{DRIVE}_sync" / "velodyne_points" / "data" / "0000000001.bin"
    scan.unlink()
    out = tmp_path / "K.h5"
    argv = ["import-kitti", "--root", str(root), "--drives", DRIVE, "--out", str(out)]
    assert main(argv) == 2
    assert _one_error_line(capsys) == f"staticdepth import-kitti: error: {scan}: file not found"
    assert not out.exists()
    # the rerun does not call the stopped run interrupted, and says how to pass the bad frame
    assert main(argv) == 2
    assert _one_error_line(capsys).endswith(
        f"{out}.partial: an earlier run stopped before finishing (interrupted, or by a bad input) "
        "and left this file: --resume continues it (add --skip-bad to pass a bad frame that "
        "stopped it), --restart starts over")
    assert main(argv + ["--skip-bad", "--resume"]) == 0
    text = capsys.readouterr().out
    assert "wrote 2 frames" in text and "skipped 1 bad frame(s):" in text
    assert f"skipped {DRIVE}_sync/0000000001: {scan}: file not found" in text
    with SequenceReader(out) as r:
        assert len(r) == 2
        assert [s["frame"] for s in r.meta.provenance["skipped"]] == [f"{DRIVE}_sync/0000000001"]
        t = drive_tasks(kitti_root, DRIVE)[0][2]
        np.testing.assert_array_equal(r.depth(1), load_frame(t).arrays["depth"])
