"""Rig importers (DepthAI JSON, Middlebury calib.txt, KITTI calib_cam_to_cam.txt) and import-rig."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import StereoRig
from staticdepth.stereo.rectify import Rectifier
from staticdepth.stereo.rig_import import (import_rig, parse_size, rig_from_depthai,
                                           rig_from_kitti, rig_from_middlebury)

# -- KITTI (the real calibration file) ----------------------------------------------------------


def kitti_file(shared_data):
    return shared_data / "kitti_raw" / "2011_09_26" / "calib_cam_to_cam.txt"


def test_kitti_colour_and_grey_pairs(shared_data):
    rig = rig_from_kitti(kitti_file(shared_data))
    # numbers copied from the file: P_rect_02, P_rect_03, S_rect_02
    assert rig.is_rectified()
    assert rig.left.size == (1242, 375)
    assert (rig.left.fx, rig.left.fy) == (7.215377e+02, 7.215377e+02)
    assert (rig.left.cx, rig.left.cy) == (6.095593e+02, 1.728540e+02)
    assert rig.baseline_m == pytest.approx((4.485728e+01 + 3.395242e+02) / 7.215377e+02, rel=1e-12)
    assert rig.baseline_m == pytest.approx(0.5327, abs=1e-4)
    grey = rig_from_kitti(kitti_file(shared_data), camera=0)
    assert grey.baseline_m == pytest.approx(3.875744e+02 / 7.215377e+02, rel=1e-12)
    from staticdepth.dataset.kitti import KittiCalib

    calib = KittiCalib.load(kitti_file(shared_data).parent)
    assert rig.baseline_m == pytest.approx(calib.baseline_m)


def test_kitti_cli_and_errors(shared_data, tmp_path, capsys):
    out = tmp_path / "rig.json"
    assert main(["import-rig", "--from", "kitti", str(kitti_file(shared_data)), "--out",
                 str(out)]) == 0
    assert "baseline 0.53273 m" in capsys.readouterr().out
    rig = StereoRig.load(out)
    assert rig.left.fx == 7.215377e+02 and rig.extra["cameras"] == [2, 3]
    assert main(["import-rig", "--from", "kitti", str(kitti_file(shared_data)), "--camera", "1",
                 "--out", str(out)]) == 2
    with pytest.raises(InputError, match="must be 0 or 2"):
        rig_from_kitti(kitti_file(shared_data), camera=1)
    with pytest.raises(InputError, match="not found"):
        rig_from_kitti(tmp_path / "none.txt")
    partial = tmp_path / "calib_cam_to_cam.txt"
    partial.write_text("P_rect_02: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputError, match="P_rect_03") as e:
        rig_from_kitti(partial)
    assert str(partial) in str(e.value)
    partial.write_text("P_rect_02: 700 0 600 0 0 700 170 0 0 0 1 0\n"
                       "P_rect_03: 700 0 600 300 0 700 170 0 0 0 1 0\nS_rect_02: 1242 375\n")
    with pytest.raises(InputError, match="not to the right"):
        rig_from_kitti(partial)
    partial.write_text("P_rect_02: 700 0 600 0 0 700 170 0 0 0 1 0\n"
                       "P_rect_03: 710 0 600 -300 0 700 170 0 0 0 1 0\nS_rect_02: 1242 375\n")
    with pytest.raises(InputError, match="different intrinsics"):
        rig_from_kitti(partial)


# -- Middlebury ---------------------------------------------------------------------------------

CALIB_2014 = """cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]
cam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]
doffs=209.059
baseline=176.252
width=2880
height=1988
ndisp=280
isint=0
vmin=27
vmax=248
dyavg=0
dymax=0
"""


def test_middlebury_calib_and_disparity_offset(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(CALIB_2014)
    rig = rig_from_middlebury(path)
    assert rig.left.size == (2880, 1988)
    assert (rig.left.fx, rig.left.cx, rig.left.cy) == (4161.221, 1445.577, 984.686)
    assert rig.right.cx == 1654.636
    assert rig.baseline_m == pytest.approx(0.176252)
    assert rig.extra["doffs_px"] == 209.059 and rig.extra["ndisp"] == 280
    # a point seen by both raw views: the dataset's convention Z = f B / (d + doffs) ...
    X, Y, Z = 0.3, -0.2, 2.5
    f, B = 4161.221, 0.176252
    u0, u1 = f * X / Z + 1445.577, f * (X - B) / Z + 1654.636
    v = f * Y / Z + 984.686
    assert f * B / ((u0 - u1) + 209.059) == pytest.approx(Z, rel=1e-12)
    # ... and after the toolkit's rectification plain f B / d, in the unchanged left camera
    rect = Rectifier(rig)
    assert rect.camera.fx == f and rect.camera.cx == 1445.577
    assert rect.baseline_m == pytest.approx(B, rel=1e-12)
    l = rect.rectify_points(np.array([[u0, v]]), "left")[0]
    r = rect.rectify_points(np.array([[u1, v]]), "right")[0]
    assert l == pytest.approx([u0, v], abs=1e-6) and r[1] == pytest.approx(v, abs=1e-6)
    assert rect.camera.fx * rect.baseline_m / (l[0] - r[0]) == pytest.approx(Z, rel=1e-9)


def test_middlebury_right_image_shifted_by_doffs(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("cam0=[100 0 30; 0 100 20; 0 0 1]\ncam1=[100 0 35; 0 100 20; 0 0 1]\n"
                    "doffs=5\nbaseline=100\nwidth=64\nheight=48\nndisp=32\n")
    rect = Rectifier(rig_from_middlebury(path))
    rng = np.random.default_rng(0)
    left, right = (rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2))
    L, R = rect.rectify(left, right)
    assert np.array_equal(L, left)
    assert np.array_equal(R[:, :59], right[:, 5:])
    # the same rig at half size: doffs and focal halve, baseline stays
    half = import_rig("middlebury", path, size=(32, 24))
    assert half.extra["doffs_px"] == 2.5 and half.left.fx == 50.0
    assert Rectifier(half).baseline_m == pytest.approx(0.1)


def test_middlebury_errors(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("cam0=[100 0 30; 0 100 20; 0 0 1]\nbaseline=100\nwidth=64\nheight=48\n")
    with pytest.raises(InputError, match=r"missing \['cam1'\]") as e:
        rig_from_middlebury(path)
    assert str(path) in str(e.value)
    path.write_text("cam0=[100 0 30; 0 100 20]\ncam1=[100 0 35; 0 100 20; 0 0 1]\nbaseline=100\n"
                    "width=64\nheight=48\n")
    with pytest.raises(InputError, match="cam0 must be 3x3"):
        rig_from_middlebury(path)
    path.write_text("cam0=[100 0 30; 0 100 20; 0 0 1]\ncam1=[100 0 35; 0 100 20; 0 0 1]\n"
                    "baseline=100\nwidth=64\nheight=48\ndoffs=7\n")
    with pytest.raises(InputError, match="differs from cx1 - cx0"):
        rig_from_middlebury(path)
    path.write_text("cam0=[100 0 30; 0 100 20; 0 0 1]\ncam1=[100 0 35; 0 100 20; 0 0 1]\n"
                    "baseline=ten\nwidth=64\nheight=48\n")
    with pytest.raises(InputError, match="malformed number"):
        rig_from_middlebury(path)
    with pytest.raises(InputError, match="not found"):
        rig_from_middlebury(tmp_path / "none.txt")
    with pytest.raises(InputError, match="KITTI only"):
        import_rig("middlebury", path, camera=2)
    with pytest.raises(InputError, match="unknown rig format"):
        import_rig("zed", path)


# -- DepthAI ------------------------------------------------------------------------------------

SIZE = (1280, 800)
K_L = np.array([[800.5, 0, 640.2], [0, 800.1, 401.3], [0, 0, 1]])
K_R = np.array([[798.7, 0, 636.9], [0, 798.4, 398.8], [0, 0, 1]])
D_L = np.array([-0.02, 0.01, 0.001, -0.0005, 0.0] + [0.0] * 9)
D_R = np.array([-0.015, 0.008, -0.0008, 0.0003, 0.0] + [0.0] * 9)
R_LR = cv2.Rodrigues(np.array([0.004, -0.006, 0.003]))[0]
T_LR_CM = np.array([-7.52, 0.04, 0.11])


def depthai_json(reverse=False, R1=None, R2=None, **drop):
    R1_, R2_, *_ = cv2.stereoRectify(K_L, D_L, K_R, D_R, SIZE, R_LR, (T_LR_CM / 100).reshape(3, 1),
                                     flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    R1 = R1_ if R1 is None else R1
    R2 = R2_ if R2 is None else R2

    def cam(K, D, to, R, T):
        return {"width": SIZE[0], "height": SIZE[1], "intrinsicMatrix": K.tolist(),
                "distortionCoeff": D.tolist(), "cameraType": 0, "specHfovDeg": 71.9,
                "lensPosition": 0,
                "extrinsics": {"rotationMatrix": np.asarray(R).tolist(),
                               "translation": dict(zip("xyz", map(float, T))),
                               "specTranslation": {"x": -7.5, "y": 0.0, "z": 0.0},
                               "toCameraSocket": to}}

    if reverse:   # only the right camera's extrinsics, pointing to the left one
        left = cam(K_L, D_L, -1, np.eye(3), np.zeros(3))
        right = cam(K_R, D_R, 1, R_LR.T, -R_LR.T @ T_LR_CM)
    else:         # left -> right, right -> colour camera
        left = cam(K_L, D_L, 2, R_LR, T_LR_CM)
        right = cam(K_R, D_R, 0, np.eye(3), [3.75, 0, 0])
    rgb = cam(np.array([[1500.0, 0, 960], [0, 1500, 540], [0, 0, 1]]), np.zeros(14), -1,
              np.eye(3), np.zeros(3))
    d = {"boardName": "OAK-D", "version": 7, "cameraData": [[0, rgb], [1, left], [2, right]],
         "stereoRectificationData": {"rectifiedRotationLeft": np.asarray(R1).tolist(),
                                     "rectifiedRotationRight": np.asarray(R2).tolist(),
                                     "leftCameraSocket": 1, "rightCameraSocket": 2}}
    for k in drop:
        d.pop(k)
    return d


def write(tmp_path, d, name="calib.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return p


@pytest.mark.parametrize("reverse", [False, True])
def test_depthai_rig_and_rectification(tmp_path, reverse):
    rig = rig_from_depthai(write(tmp_path, depthai_json(reverse)))
    np.testing.assert_allclose(rig.R, R_LR, atol=1e-12)
    np.testing.assert_allclose(rig.T, T_LR_CM / 100, atol=1e-12)     # cm -> m, not the spec 7.5 cm
    assert rig.baseline_m == pytest.approx(np.linalg.norm(T_LR_CM) / 100)
    assert np.array_equal(rig.left.K, K_L) and np.array_equal(rig.right.dist, D_R)
    assert rig.left.size == SIZE and rig.extra["sockets"] == [1, 2]
    # a point in front of the rig lands on one rectified row, at disparity f B / Z
    rect = Rectifier(rig)
    P = np.array([[0.4, -0.3, 3.0], [-1.0, 0.5, 7.0]])
    uv_l = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K_L, D_L)[0].reshape(-1, 2)
    uv_r = cv2.projectPoints(P, cv2.Rodrigues(R_LR)[0], T_LR_CM / 100, K_R, D_R)[0].reshape(-1, 2)
    l, r = rect.rectify_points(uv_l, "left"), rect.rectify_points(uv_r, "right")
    np.testing.assert_allclose(l[:, 1], r[:, 1], atol=1e-3)
    Z_rect = (np.asarray(rig.rectification["R1"]) @ P.T)[2]
    np.testing.assert_allclose(rect.camera.fx * rect.baseline_m / (l[:, 0] - r[:, 0]), Z_rect,
                               rtol=1e-4)
    assert rect.camera.fx == K_L[0, 0] and rect.baseline_m == pytest.approx(0.07521, abs=1e-4)


def test_depthai_resized_and_cli(tmp_path, capsys):
    path = write(tmp_path, depthai_json())
    out = tmp_path / "rig.json"
    assert main(["import-rig", "--from", "depthai", str(path), "--size", "640x400", "--out",
                 str(out)]) == 0
    assert "640x400" in capsys.readouterr().out
    rig = StereoRig.load(out)
    full = rig_from_depthai(path)
    assert rig.left.fx == pytest.approx(K_L[0, 0] / 2)
    assert rig.left.cx == pytest.approx((K_L[0, 2] + 0.5) / 2 - 0.5)
    rect, rect_full = Rectifier(rig), Rectifier(full)
    assert rect.baseline_m == pytest.approx(rect_full.baseline_m)
    assert rect.camera.fx == pytest.approx(rect_full.camera.fx / 2)
    assert main(["import-rig", "--from", "depthai", str(path), "--size", "640x300", "--out",
                 str(out)]) == 2
    with pytest.raises(InputError, match="WIDTHxHEIGHT"):
        parse_size("640")
    assert parse_size("640x400") == (640, 400)


def test_depthai_errors(tmp_path):
    with pytest.raises(InputError, match="stereoRectificationData") as e:
        rig_from_depthai(write(tmp_path, depthai_json(stereoRectificationData=None)))
    assert "calib.json" in str(e.value)
    d = depthai_json()
    d["stereoRectificationData"]["rightCameraSocket"] = 4
    with pytest.raises(InputError, match="socket 4 is not in cameraData"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["cameraData"][1][1]["extrinsics"]["toCameraSocket"] = -1
    with pytest.raises(InputError, match="no extrinsics chain"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["cameraData"][2][1]["cameraType"] = 1
    with pytest.raises(InputError, match="fisheye"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    del d["cameraData"][1][1]["intrinsicMatrix"]
    with pytest.raises(InputError, match="intrinsicMatrix"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["cameraData"][1][1]["extrinsics"]["translation"] = [1, 2, 3]
    with pytest.raises(InputError, match="x, y, z"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["cameraData"] = {"1": {}}
    with pytest.raises(InputError, match="list of"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["stereoRectificationData"]["leftCameraSocket"] = "CAM_Z"
    with pytest.raises(InputError, match="unknown camera socket"):
        rig_from_depthai(write(tmp_path, d))
    d = depthai_json()
    d["stereoRectificationData"]["leftCameraSocket"] = "LEFT"       # names work too
    assert rig_from_depthai(write(tmp_path, d)).extra["sockets"] == [1, 2]
    rot = cv2.Rodrigues(np.array([0.0, 0.3, 0.0]))[0]               # turns the baseline off x
    with pytest.raises(InputError, match="do not align the baseline"):
        rig_from_depthai(write(tmp_path, depthai_json(R1=rot, R2=rot)))
    with pytest.raises(InputError, match="not found"):
        rig_from_depthai(tmp_path / "none.json")
