"""``staticdepth ground-plane`` and ``staticdepth align`` end to end, in process."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.geometry.plane import angle_between_deg
from test_agent_plane import camera_K, people_observations, true_normal
from test_alignment import dpt_failure, scene


def write_csv(path, obs, cols=("frame", "track", "foot_u", "foot_v", "height_px")):
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for r in obs:
            f.write(",".join(f"{r[c]:.3f}" for c in cols) + "\n")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("gp")
    K, w, h = camera_K(600.0)
    n = true_normal(33.0, 2.0)
    obs = people_observations(np.random.default_rng(5), K, w, h, n, 6.0, n_tracks=30)
    write_csv(d / "obs.csv", obs)
    (d / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 600.0, "cx": K[0, 2],
                                            "cy": K[1, 2], "width": w, "height": h}))
    rc = main(["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
               str(d / "cam.json"), "--agent-height", "1.7", "--bootstrap", "5",
               "--out", str(d / "plane.json")])
    return d, n, rc


def test_ground_plane_command(fitted, capsys):
    d, n, rc = fitted
    assert rc == 0
    p = json.loads((d / "plane.json").read_text())
    assert angle_between_deg(p["normal"], n) < 1.0
    assert abs(p["camera_height_m"] / 6.0 - 1) < 0.05
    for key in ("horizon", "d_over_agent_height", "inliers", "uncertainty"):
        assert key in p
    assert p["uncertainty"]["normal_std_deg"] > 0
    rc = main(["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
               str(d / "cam.json"), "--model", "paper", "--camera-height", "6",
               "--bootstrap", "0", "--out", str(d / "paper.json")])
    assert rc == 0 and "camera height 6.000 m (given)" in capsys.readouterr().out


@pytest.mark.parametrize("text,msg", [
    ("frame,track,foot_u,foot_v\n1,1,2,3\n", "missing column(s) height_px"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,x,4\n", "line 2: column 'foot_v' is not a number"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,3,4\n2,1,5,6,7\n", "2 usable observation(s)"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,3\n", "line 2: 4 fields"),
    ("", "empty file"),
])
def test_ground_plane_bad_csv(tmp_path, capsys, text, msg):
    (tmp_path / "obs.csv").write_text(text)
    (tmp_path / "cam.json").write_text('{"fx": 500, "fy": 500, "cx": 400, "cy": 200}')
    rc = main(["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
               str(tmp_path / "cam.json"), "--out", str(tmp_path / "p.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert str(tmp_path / "obs.csv") in err and msg in err
    assert not (tmp_path / "p.json").exists()


def test_ground_plane_collinear_feet_is_a_clear_error(tmp_path, capsys):
    rows = "".join(f"{i},{i // 4},{100 + 10 * i},{300 + 2 * i},60\n" for i in range(12))
    (tmp_path / "obs.csv").write_text("frame,track,foot_u,foot_v,height_px\n" + rows)
    (tmp_path / "cam.json").write_text('{"fx": 500, "fy": 500, "cx": 400, "cy": 200}')
    rc = main(["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
               str(tmp_path / "cam.json"), "--out", str(tmp_path / "p.json")])
    assert rc == 2 and "collinear" in capsys.readouterr().err


def _align_inputs(tmp_path, pitch=30.0, height=5.0):
    K, n, depth, ground, wall = scene(pitch, height)
    cam = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": depth.shape[1],
           "height": depth.shape[0]}
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    (tmp_path / "plane.json").write_text(json.dumps({"normal": n.tolist(), "horizon": [0, 1, 0]}))
    cv2.imwrite(str(tmp_path / "mask.png"), ground.astype(np.uint8) * 255)
    np.save(tmp_path / "pred.npy", dpt_failure(depth))
    return K, n, depth, ground


def test_align_command_metric_output(tmp_path, capsys):
    K, n, depth, ground = _align_inputs(tmp_path)
    rc = main(["align", "--pred", str(tmp_path / "pred.npy"), "--inverse", "--intrinsics",
               str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
               "--ground-mask", str(tmp_path / "mask.png"), "--camera-height", "5",
               "--out", str(tmp_path / "out.npy"), "--json", str(tmp_path / "info.json")])
    assert rc == 0
    out = np.load(tmp_path / "out.npy")
    assert out.dtype == np.float32 and np.all(np.isfinite(out))
    assert np.mean(np.abs(out - depth)[ground] / depth[ground]) < 0.01
    info = json.loads((tmp_path / "info.json").read_text())
    assert info["units"] == "m"
    assert info["anchor_depth_m"] == pytest.approx(depth[-1, depth.shape[1] // 2], rel=1e-3)
    assert info["anchor_depth_parallel_m"] > 1.3 * info["anchor_depth_m"]
    assert info["scale"] > 0


def test_align_command_folder_relative_output(tmp_path):
    K, n, depth, ground = _align_inputs(tmp_path)
    (tmp_path / "preds").mkdir()
    for i, (s, t) in enumerate([(3.0, 0.08), (2.0, 0.02)]):
        np.save(tmp_path / "preds" / f"{i:03d}.npy", dpt_failure(depth, s, t))
    rc = main(["align", "--pred", str(tmp_path / "preds"), "--inverse", "--intrinsics",
               str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
               "--ground-mask", str(tmp_path / "mask.png"), "--out", str(tmp_path / "out")])
    assert rc == 0
    for i in range(2):
        out = np.load(tmp_path / "out" / f"{i:03d}.npy")     # relative: units of the height
        assert np.mean(np.abs(out * 5.0 - depth)[ground] / depth[ground]) < 0.01


def test_align_command_errors(tmp_path, capsys):
    _align_inputs(tmp_path)
    base = ["align", "--pred", str(tmp_path / "pred.npy"), "--intrinsics",
            str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
            "--out", str(tmp_path / "o.npy")]
    cv2.imwrite(str(tmp_path / "small.png"), np.full((10, 10), 255, np.uint8))
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros((80, 160), np.uint8))
    (tmp_path / "bad.json").write_text('{"horizon": [0, 1, 0]}')
    cases = [(["--ground-mask", str(tmp_path / "small.png")], "differs from the ground mask"),
             (["--ground-mask", str(tmp_path / "empty.png")], "the ground mask is empty"),
             (["--ground-mask", str(tmp_path / "nope.png")], "file not found"),
             (["--ground-mask", str(tmp_path / "mask.png"), "--plane", str(tmp_path / "bad.json")],
              "missing the key 'normal'"),
             (["--ground-mask", str(tmp_path / "mask.png"), "--camera-height", "-1"],
              "camera height must be positive")]
    for extra, msg in cases:
        rc = main(base + extra)
        err = capsys.readouterr().err
        assert rc == 2 and msg in err, (extra, err)
    assert not (tmp_path / "o.npy").exists()
