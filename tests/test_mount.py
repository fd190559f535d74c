"""Mounting from a board rendered on the ground of a synthetic scene; COLMAP camera round trips."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig, normal_from_pitch_roll
from staticdepth.geometry.plane import angle_between_deg
from staticdepth.stereo import mount
from staticdepth.stereo.calibrate import Board
from staticdepth.stereo.colmap import (camera_from_colmap, camera_to_colmap, read_cameras_txt,
                                       write_cameras_txt)

CAM = Camera.from_intrinsics(500.0, 500.0, 399.5, 199.5, 800, 400)


def render_board_on_ground(camera, height_m, pitch_deg, roll_deg, square_m=0.4, cols=9, rows=6,
                           px=60, seed=0):
    """A chessboard texture warped onto the ground plane, centred on the optical axis."""
    n = normal_from_pitch_roll(pitch_deg, roll_deg)
    centre = np.array([0.0, 0.0, 1.0]) * height_m / n[2]
    x = np.cross(n, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    origin = centre - (cols - 1) / 2 * square_m * x - (rows - 1) / 2 * square_m * y
    tex = np.full(((rows + 3) * px, (cols + 3) * px), 255, np.uint8)
    for i in range(cols + 1):
        for j in range(rows + 1):
            if (i + j) % 2 == 0:
                tex[(j + 1) * px:(j + 2) * px, (i + 1) * px:(i + 2) * px] = 0
    s = square_m / px   # texture pixel -> board metres; first inner corner at texture (2px, 2px)
    A = np.array([[s, 0, -2 * px * s], [0, s, -2 * px * s], [0, 0, 1]])
    H = camera.K @ np.column_stack([x, y, origin]) @ A
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur((rng.random((camera.height, camera.width)) * 60 + 100).astype(np.uint8),
                          (5, 5), 0)
    warped = cv2.warpPerspective(tex, H, camera.size, flags=cv2.INTER_LINEAR)
    inside = cv2.warpPerspective(np.ones_like(tex), H, camera.size, flags=cv2.INTER_NEAREST)
    img = np.where(inside > 0, warped, bg)
    return np.repeat(img[..., None], 3, axis=2), n


@pytest.mark.parametrize("height_m, pitch, roll", [(4.0, 30.0, 3.0), (6.0, 45.0, -5.0)])
def test_mount_from_board_on_ground(tmp_path, height_m, pitch, roll):
    img, n_true = render_board_on_ground(CAM, height_m, pitch, roll)
    f = tmp_path / "board.png"
    cv2.imwrite(str(f), img[..., ::-1])
    est = mount.mount_from_board(StereoRig.rectified(CAM, 0.27), [str(f)],
                                 Board("chessboard", 9, 6, 0.4))
    assert est.mounting.height_m == pytest.approx(height_m, rel=0.01)
    assert angle_between_deg(est.mounting.normal, n_true) < 0.5
    assert est.mounting.pitch_deg == pytest.approx(pitch, abs=0.5)
    assert est.mounting.roll_deg == pytest.approx(roll, abs=0.5)
    assert est.crosscheck_deg < 0.5    # pycolmap and OpenCV agree (0 when pycolmap is absent)


def test_opencv_fallback_and_thickness(tmp_path, monkeypatch):
    img, n_true = render_board_on_ground(CAM, 4.0, 30.0, 0.0)
    f = tmp_path / "board.png"
    cv2.imwrite(str(f), img[..., ::-1])
    monkeypatch.setattr(mount, "pycolmap", None)
    est = mount.mount_from_board(StereoRig.rectified(CAM, 0.27), [str(f)],
                                 Board("chessboard", 9, 6, 0.4), thickness_m=0.01)
    assert est.method == "opencv"
    assert est.mounting.height_m == pytest.approx(4.01, rel=0.01)
    assert angle_between_deg(est.mounting.normal, n_true) < 0.5


def test_mount_in_rectified_frame(tmp_path):
    """The mounting is stored in the rectified left frame: n_rect = R1 n_raw."""
    img, n_true = render_board_on_ground(CAM, 4.0, 30.0, 3.0)
    f = tmp_path / "board.png"
    cv2.imwrite(str(f), img[..., ::-1])
    R1 = cv2.Rodrigues(np.array([0.05, -0.02, 0.1]))[0]
    rig = StereoRig(CAM, CAM, np.eye(3), [-0.27, 0, 0], rectification={"R1": R1})
    est = mount.mount_from_board(rig, [str(f)], Board("chessboard", 9, 6, 0.4))
    assert angle_between_deg(est.mounting.normal, R1 @ n_true) < 0.5
    assert est.mounting.height_m == pytest.approx(4.0, rel=0.01)


def test_cli_mount(tmp_path, capsys):
    img, _ = render_board_on_ground(CAM, 5.0, 35.0, 2.0)
    cv2.imwrite(str(tmp_path / "g0.png"), img[..., ::-1])
    rig_path = tmp_path / "rig.json"
    StereoRig.rectified(CAM, 0.27).save(rig_path)
    rc = main(["mount", "--rig", str(rig_path), "--images", str(tmp_path / "g*.png"),
               "--board", "9x6", "--square", "0.4", "--out", str(rig_path)])
    assert rc == 0
    m = StereoRig.load(rig_path).mounting
    assert m.height_m == pytest.approx(5.0, rel=0.01) and m.pitch_deg == pytest.approx(35, abs=0.5)
    cv2.imwrite(str(tmp_path / "g1.png"), np.full((400, 800, 3), 90, np.uint8))
    cv2.imwrite(str(tmp_path / "g0.png"), np.full((400, 800, 3), 90, np.uint8))
    rc = main(["mount", "--rig", str(rig_path), "--images", str(tmp_path / "g*.png"),
               "--board", "9x6", "--square", "0.4", "--out", str(rig_path)])
    assert rc == 2 and "not found in any" in capsys.readouterr().err
    cv2.imwrite(str(tmp_path / "g0.png"), np.full((100, 100, 3), 90, np.uint8))
    with pytest.raises(InputError, match="100x100"):
        mount.mount_from_board(StereoRig.rectified(CAM, 0.27), [str(tmp_path / "g0.png")],
                               Board("chessboard", 9, 6, 0.4))


def test_colmap_round_trip_and_pixel_centres(tmp_path):
    cam = Camera.from_intrinsics(500, 510, 320.0, 240.0, 640, 480, [0.1, -0.02, 0.001, 0.002, 0])
    model, params = camera_to_colmap(cam)
    assert model == "OPENCV" and params[2:4] == [320.5, 240.5]
    write_cameras_txt(tmp_path / "cameras.txt", {1: cam, 2: CAM})
    cams = read_cameras_txt(tmp_path / "cameras.txt")
    assert cams[1] == cam and cams[2] == CAM
    assert camera_to_colmap(CAM)[0] == "PINHOLE"
    simple = camera_from_colmap("SIMPLE_RADIAL", 640, 480, [500, 320.5, 240.5, 0.1])
    assert (simple.fx, simple.cx, simple.cy, simple.dist[0]) == (500, 320.0, 240.0, 0.1)


@pytest.mark.parametrize("dist, model_name", [
    ([0.1, -0.02, 0.001, 0.002, 0], "OPENCV"),
    ([-0.28, 0.05, 0.001, -0.0001, 0.1], "FULL_OPENCV"),                   # calibrate's k3
    ([-0.28, 0.05, 0.001, -0.0001, 0.1, 0.02, -0.01, 0.005], "FULL_OPENCV")])  # rational model
def test_colmap_agrees_with_pycolmap(dist, model_name):
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap not installed")
    cam = Camera.from_intrinsics(500, 510, 320.0, 240.0, 640, 480, dist)
    model, params = camera_to_colmap(cam)
    assert model == model_name
    pc = pycolmap.Camera(model=model, width=640, height=480, params=params)
    P = np.array([[0.3, -0.2, 2.0], [-0.5, 0.4, 3.0]])
    uv_colmap = np.asarray(pc.img_from_cam(P))
    uv_cv = cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)
    assert np.allclose(uv_colmap - 0.5, uv_cv, atol=1e-6)


def test_colmap_bad_input(tmp_path):
    p = tmp_path / "cameras.txt"
    p.write_text("1 FISHEYE 640 480 1 2 3\n")
    with pytest.raises(InputError, match="unsupported COLMAP camera model"):
        read_cameras_txt(p)
    p.write_text("1 PINHOLE 640 480 1 2 3\n")
    with pytest.raises(InputError, match="needs 4 parameters"):
        read_cameras_txt(p)
    p.write_text("# nothing\n")
    with pytest.raises(InputError, match="no cameras"):
        read_cameras_txt(p)
    p.write_text("x PINHOLE\n")
    with pytest.raises(InputError, match="line 1"):
        read_cameras_txt(p)
    with pytest.raises(InputError, match="not found"):
        read_cameras_txt(tmp_path / "missing.txt")
    with pytest.raises(InputError, match="thin-prism"):
        camera_to_colmap(Camera.from_intrinsics(1, 1, 0, 0, 2, 2, [0] * 8 + [0.1, 0, 0, 0]))
