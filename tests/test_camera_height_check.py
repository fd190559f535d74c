"""One camera-height check (``geometry.camera.check_camera_height``): every command and function
that takes a camera height refuses 0, -1, NaN, inf and the absurd finite 5000 m and 1e12 m (were
accepted and gave nonsense downstream) in one line naming its option or key, the value and the
range (0, 1000], and takes a valid height (5.4 m) as before."""
from __future__ import annotations

import json

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Mounting, normal_from_pitch_roll

from test_agent_plane import camera_K, people_observations, true_normal
from test_carla import _export
from test_cli_ground_align import _align_inputs, write_csv
from test_kitti import kitti_root  # noqa: F401  (a fixture)
from test_pack import plain_recording  # noqa: F401  (a fixture)
from upright_scene import UprightScene

BAD = ["0", "-1", "nan", "inf", "5000", "1e12"]
RANGE = "must be a height in metres in (0, 1000], got"
OK = 5.4


def _said(what: str, value: str) -> str:
    return f"{what} {RANGE} {float(value)}"


def _one_line(capsys) -> str:
    """The command's one error line, without its ``staticdepth CMD: error:`` prefix."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("staticdepth ") and ": error: " in err[0], err
    return err[0].split(": error: ", 1)[1]


# -- the function ----------------------------------------------------------------------------------
@pytest.mark.parametrize("value", BAD)
def test_check_refuses_in_one_line_naming_the_key_value_and_range(value):
    from staticdepth.geometry.camera import check_camera_height

    with pytest.raises(InputError) as e:
        check_camera_height(float(value), "--camera-height")
    assert str(e.value) == _said("--camera-height", value)
    with pytest.raises(InputError) as e:
        check_camera_height(float(value), "camera_height_m", "plane.json")
    assert str(e.value) == f"plane.json: {_said('camera_height_m', value)}"
    assert e.value.path == "plane.json"


def test_check_takes_valid_heights_as_floats():
    from staticdepth.geometry.camera import MAX_CAMERA_HEIGHT_M, check_camera_height

    assert MAX_CAMERA_HEIGHT_M == 1000.0
    for v in (OK, 1000, 1e-3, np.float32(2.5), "5.4"):
        h = check_camera_height(v)
        assert type(h) is float and h == pytest.approx(float(v))
    for v in (True, None, "five", [5.0], 1000.001):
        with pytest.raises(InputError, match=r"^camera height must be a height in metres"):
            check_camera_height(v)


# -- the commands ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def observations(tmp_path_factory):
    d = tmp_path_factory.mktemp("gp")
    K, w, h = camera_K(600.0)
    obs = people_observations(np.random.default_rng(5), K, w, h, true_normal(33.0, 2.0), OK,
                              n_tracks=30)
    write_csv(d / "obs.csv", obs)
    (d / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 600.0, "cx": K[0, 2],
                                            "cy": K[1, 2], "width": w, "height": h}))
    return d


def _ground_plane(d, out, height):
    return main(["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
                 str(d / "cam.json"), "--model", "paper", "--bootstrap", "0",
                 "--camera-height", height, "--out", str(out)])


@pytest.mark.parametrize("value", BAD)
def test_ground_plane_refuses(observations, tmp_path, capsys, value):
    assert _ground_plane(observations, tmp_path / "p.json", value) == 2
    assert _one_line(capsys) == _said("--camera-height", value)
    assert not (tmp_path / "p.json").exists()


def test_ground_plane_takes_a_valid_height(observations, tmp_path, capsys):
    assert _ground_plane(observations, tmp_path / "p.json", str(OK)) == 0
    assert "camera height 5.400 m (given)" in capsys.readouterr().out
    assert json.loads((tmp_path / "p.json").read_text())["camera_height_m"] == OK


def _align(tmp_path, *height):
    return main(["align", "--pred", str(tmp_path / "pred.npy"), "--inverse", "--intrinsics",
                 str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
                 "--ground-mask", str(tmp_path / "mask.png"), *height,
                 "--out", str(tmp_path / "out.npy")])


@pytest.mark.parametrize("value", BAD)
def test_align_refuses_the_option_and_the_planes_key(tmp_path, capsys, value):
    _, n, _, _ = _align_inputs(tmp_path)
    assert _align(tmp_path, "--camera-height", value) == 2
    assert _one_line(capsys) == _said("--camera-height", value)
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"normal": n.tolist(), "horizon": [0, 1, 0],
                                 "camera_height_m": float(value)}))
    assert _align(tmp_path) == 2
    assert _one_line(capsys) == f"{plane}: {_said('camera_height_m', value)}"
    assert not (tmp_path / "out.npy").exists()


def test_align_takes_a_valid_height(tmp_path, capsys):
    _align_inputs(tmp_path)
    assert _align(tmp_path, "--camera-height", str(OK)) == 0
    assert np.all(np.isfinite(np.load(tmp_path / "out.npy")))


@pytest.fixture(scope="module")
def upright(tmp_path_factory):
    d = tmp_path_factory.mktemp("loc")
    scene = UprightScene(n_people=3, seed=5)
    scene.write(str(d / "up.h5"), frames=2)
    (d / "plane.json").write_text(json.dumps({"normal": scene.normal.tolist()}))
    return d, scene


def _locate(d, out, *extra):
    return main(["locate", str(d / "up.h5"), "--out", str(out), *extra])


@pytest.mark.parametrize("value", BAD)
def test_locate_refuses_the_option_the_planes_and_the_summarys_key(upright, tmp_path, capsys,
                                                                    value):
    d, scene = upright
    out = tmp_path / "pos.csv"
    assert _locate(d, out, "--plane", str(d / "plane.json"), "--camera-height", value) == 2
    assert _one_line(capsys) == _said("--camera-height", value)
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"normal": scene.normal.tolist(), "camera_height_m": float(value)}))
    assert _locate(d, out, "--plane", str(plane)) == 2
    assert _one_line(capsys) == f"{plane}: {_said('camera_height_m', value)}"
    summary = tmp_path / "s.adapt.json"
    summary.write_text(json.dumps({"plane": {"normal": scene.normal.tolist()},
                                   "camera_height_m": float(value)}))
    if float(value) != 0:        # 0 reads as "no camera height" there (its own line)
        assert _locate(d, out, "--summary", str(summary), "--detector", "gt") == 2
        assert _one_line(capsys) == f"{summary}: {_said('camera_height_m', value)}"
    assert not out.exists()


def test_locate_takes_a_valid_height(upright, tmp_path):
    d, scene = upright
    assert _locate(d, tmp_path / "pos.csv", "--plane", str(d / "plane.json"),
                   "--camera-height", str(scene.height_m)) == 0
    assert (tmp_path / "pos.csv").stat().st_size > 0


def _pack(rec, out, height):
    return main(["pack", "--recording", str(rec), "--rig", str(rec / "rig.json"),
                 "--camera-height", height, "--out", str(out), "--set", "num_disparities=32"])


@pytest.mark.parametrize("value", BAD)
def test_pack_refuses(plain_recording, tmp_path, capsys, value):  # noqa: F811
    from staticdepth.dataset.pack import pack_recording

    rec = plain_recording[0]
    assert _pack(rec, tmp_path / "R.h5", value) == 2
    assert _one_line(capsys) == _said("--camera-height", value)
    with pytest.raises(InputError, match="^--camera-height must be a height in metres"):
        pack_recording(rec, rec / "rig.json", tmp_path / "R.h5", camera_height_m=float(value))
    assert not (tmp_path / "R.h5").exists()


def test_pack_takes_a_valid_height(plain_recording, tmp_path):  # noqa: F811
    from staticdepth.dataset.h5 import SequenceReader

    assert _pack(plain_recording[0], tmp_path / "R.h5", str(OK)) == 0
    with SequenceReader(tmp_path / "R.h5") as r:
        assert r.meta.camera_height_m == OK


@pytest.mark.parametrize("value", BAD)
def test_import_kitti_refuses_before_reading(tmp_path, capsys, value):
    assert main(["import-kitti", "--root", str(tmp_path / "none"), "--drives", "2011_09_26_x",
                 "--camera-height", value, "--out", str(tmp_path / "K.h5")]) == 2
    assert _one_line(capsys) == _said("--camera-height", value)


def test_import_kitti_takes_a_valid_height(kitti_root, tmp_path):  # noqa: F811
    from staticdepth.dataset.h5 import SequenceReader

    assert main(["import-kitti", "--root", str(kitti_root), "--drives",
                 "2011_09_26_drive_sample", "--camera-height", str(OK),
                 "--out", str(tmp_path / "K.h5")]) == 0
    with SequenceReader(tmp_path / "K.h5") as r:
        assert r.meta.camera_height_m == OK


@pytest.mark.parametrize("value", BAD + ["5.4"])
def test_import_carla_checks_the_sensors_height(tmp_path, capsys, value):
    src = _export(tmp_path / "C", n=2)
    meta = json.loads((src / "sensor.json").read_text())
    meta["transform"]["location"]["z"] = float(value)
    (src / "sensor.json").write_text(json.dumps(meta))
    rc = main(["import-carla", str(src), "--out", str(tmp_path / "C.h5")])
    if value == "5.4":
        from staticdepth.dataset.h5 import SequenceReader

        assert rc == 0
        with SequenceReader(tmp_path / "C.h5") as r:
            assert r.meta.mounting.height_m == OK
        return
    assert rc == 2
    assert _one_line(capsys) == (f"{src / 'sensor.json'}: "
                                 f"{_said('the camera height transform.location.z', value)}")


def _adapt(*extra):
    return main(["adapt", "x.h5", "--print-config", *extra])


@pytest.mark.parametrize("value", BAD)
def test_adapt_refuses_the_option_the_setting_and_the_recipes_key(tmp_path, capsys, value):
    """The flag by its name, the setting it sets (``--set``, a recipe) by its key (NaN: the
    settings' own line, which names the setting, comes first)."""
    assert _adapt("--camera-height", value) == 2
    assert _one_line(capsys) == _said("--camera-height", value)
    said = _said("scale.camera_height_m", value)
    if value == "nan":
        said = "setting 'scale.camera_height_m': NaN is no value (give a number, or none where"
    assert _adapt("--set", f"scale.camera_height_m={value}") == 2
    assert _one_line(capsys).startswith(said)
    recipe = tmp_path / "r.yaml"
    recipe.write_text(f"camera_height_m: {float(value)}\nstages: {{adapt: {{}}}}\n".replace(
        "nan", ".nan").replace("inf", ".inf"))
    assert _adapt("--recipe", str(recipe)) == 2
    # (the settings' NaN line does not name the recipe: not this check's)
    assert _one_line(capsys).startswith(said if value == "nan" else f"{recipe}: {said}")


def test_adapt_takes_a_valid_height(capsys):
    assert _adapt("--camera-height", str(OK)) == 0
    assert "camera_height_m: 5.4" in capsys.readouterr().out


# -- the library's other entry points --------------------------------------------------------------
@pytest.mark.parametrize("value", [float(v) for v in BAD])
def test_library_entry_points_refuse(value):
    from staticdepth.adaptation.config import ScaleConfig
    from staticdepth.dataset.h5 import SequenceMeta
    from staticdepth.geometry import Camera
    from staticdepth.geometry.agent_plane import AgentPlane, AgentPlaneConfig
    from staticdepth.geometry.ground_frame import GroundFrame, ground_points
    from staticdepth.geometry.scale import anchor_depth, anchor_depth_parallel

    K, w, h = camera_K(600.0)
    n = true_normal(30.0)
    said = r"must be a height in metres in \(0, 1000\], got "
    cases = [
        (lambda: Mounting(value, n), "^mounting height_m " + said),
        (lambda: Mounting.from_dict({"height_m": value, "normal": n.tolist()}, "rig.json"),
         "^rig.json: mounting height_m " + said),
        (lambda: AgentPlaneConfig(known_height_m=value), "^plane.known_height_m " + said),
        (lambda: GroundFrame.from_plane(n, value), "^the camera height " + said),
        (lambda: ground_points(K, n, value, [w / 2], [h - 1]), "^the camera height " + said),
        (lambda: anchor_depth(K, n, value, w / 2, h - 1), "^camera height " + said),
        (lambda: anchor_depth_parallel(K, value, h - 1), "^camera height " + said),
        (lambda: ScaleConfig(camera_height_m=value), "^scale.camera_height_m " + said),
        (lambda: SequenceMeta("s", Camera.from_fov(w, h, 60.0), camera_height_m=value),
         "^camera_height_m " + said),
    ]
    plane = AgentPlane.from_dict({"normal": n.tolist(), "horizon": [0, 1, 0]})
    cases += [(lambda: plane.with_camera_height(value, "given"),
               r"^the camera height \(given\) " + said),
              (lambda: AgentPlane.from_dict({"normal": n.tolist(), "horizon": [0, 1, 0],
                                             "camera_height_m": value}, "p.json"),
               "^p.json: camera_height_m " + said)]
    for call, msg in cases:
        with pytest.raises(InputError, match=msg):
            call()


def test_library_entry_points_take_a_valid_height():
    from staticdepth.adaptation.config import ScaleConfig
    from staticdepth.geometry.agent_plane import AgentPlane, AgentPlaneConfig
    from staticdepth.geometry.ground_frame import GroundFrame
    from staticdepth.geometry.scale import anchor_depth_parallel

    K, _, h = camera_K(600.0)
    n = normal_from_pitch_roll(30.0, 0.0)
    assert Mounting(OK, n).height_m == OK
    assert Mounting.from_dict({"height_m": OK, "pitch_deg": 30.0}).height_m == OK
    assert AgentPlaneConfig(known_height_m=OK).known_height_m == OK
    assert GroundFrame.from_plane(n, OK).camera_height_m == OK
    assert anchor_depth_parallel(K, OK, h - 1) == pytest.approx(K[1, 1] * OK / (h - 1 - K[1, 2]))
    assert ScaleConfig(camera_height_m=OK).camera_height_m == OK
    plane = AgentPlane.from_dict({"normal": n.tolist(), "horizon": [0, 1, 0],
                                  "camera_height_m": OK})
    assert plane.camera_height_m == OK
    assert plane.with_camera_height(OK, "given").camera_height_m == OK


def test_a_sequence_files_camera_height_attribute_is_checked(tmp_path):
    from staticdepth.dataset.h5 import SequenceMeta
    from staticdepth.geometry import Camera

    meta = SequenceMeta("s", Camera.from_fov(64, 32, 60.0), camera_height_m=OK)
    attrs = meta.to_attrs()
    assert SequenceMeta.from_attrs(attrs, "s.h5").camera_height_m == OK
    attrs["camera_height_m"] = 5000.0
    with pytest.raises(InputError) as e:
        SequenceMeta.from_attrs(attrs, "s.h5")
    assert str(e.value) == f"s.h5: {_said('the camera_height_m attribute', '5000')}"
