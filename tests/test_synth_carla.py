"""CARLA-format export of a synthetic sequence: encodings checked against CARLA's formulas."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from staticdepth.dataset.synth import SyntheticScene, preset
from staticdepth.dataset.synth.carla_export import (carla_depth_from_meters,
                                                    meters_from_carla_depth, write_carla_export)
from staticdepth.dataset.synth.layout import TAG
from staticdepth.errors import InputError


def test_depth_encoding_matches_carla_formula():
    depth = np.array([[0.0, 1.0, 12.3456], [999.9, np.nan, np.inf]])
    rgb = carla_depth_from_meters(depth)
    r, g, b = (rgb[..., k].astype(float) for k in range(3))
    carla = (r + g * 256 + b * 65536) / (256 ** 3 - 1) * 1000   # CARLA's documented decoding
    np.testing.assert_allclose(carla[0], depth[0], atol=1000 / (256 ** 3 - 1))
    np.testing.assert_allclose(carla[1], [999.9, 1000, 1000], atol=1e-4)
    np.testing.assert_allclose(meters_from_carla_depth(rgb), carla, rtol=1e-6)
    assert tuple(rgb[0, 1]) == (round(1 / 1000 * (256 ** 3 - 1)) & 255,
                                (round(1 / 1000 * (256 ** 3 - 1)) >> 8) & 255, 0)


def test_export_round_trip(tmp_path):
    scene = SyntheticScene(preset("demo", seed=5, width=200, height=100))
    out = write_carla_export(scene, tmp_path / "carla", n_frames=2, start=40)
    meta = json.loads((out / "sensor.json").read_text())
    assert (meta["image_size_x"], meta["image_size_y"], meta["n_frames"]) == (200, 100, 2)
    assert meta["fov"] == pytest.approx(90.0)
    assert meta["transform"]["location"]["z"] == pytest.approx(5.0)
    assert meta["transform"]["rotation"]["pitch"] == pytest.approx(-25.0)   # looks down
    assert meta["baseline_m"] == pytest.approx(0.27)
    fr = scene.render(41)
    bgr = cv2.imread(str(out / "rgb" / "000041.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(bgr[..., ::-1], fr["left"])
    right = cv2.imread(str(out / "right" / "000041.png"))[..., ::-1]
    np.testing.assert_array_equal(right, fr["right"])
    d = cv2.imread(str(out / "depth" / "000041.png"))
    depth = (d[..., 2] + 256.0 * d[..., 1] + 65536.0 * d[..., 0]) / (256 ** 3 - 1) * 1000
    gt = np.nan_to_num(fr["depth"], nan=1000.0)
    np.testing.assert_allclose(depth, gt, atol=1e-4, rtol=1e-6)
    inst = cv2.imread(str(out / "instance" / "000041.png"))
    tags, ids = inst[..., 2], inst[..., 1].astype(int) + 256 * inst[..., 0].astype(int)
    np.testing.assert_array_equal(ids, fr["instances"])
    np.testing.assert_array_equal(tags, fr["semantic"])
    assert TAG["road"] in tags and TAG["sky"] not in tags[ids > 0]
    assert set(np.unique(tags[ids > 0])) <= {12, 13, 14, 15, 16, 18, 19, 21}


def test_export_errors(tmp_path):
    scene = SyntheticScene(preset("demo", width=64, height=32))
    write_carla_export(scene, tmp_path / "a", n_frames=1)
    with pytest.raises(InputError, match="not empty"):
        write_carla_export(scene, tmp_path / "a", n_frames=1)
    with pytest.raises(InputError, match="n_frames"):
        write_carla_export(scene, tmp_path / "b", n_frames=0)
    with pytest.raises(InputError, match="camera= and mounting="):
        write_carla_export([scene.render(0)], tmp_path / "c")
    fr = dict(scene.render(0))
    del fr["semantic"]
    with pytest.raises(InputError, match="semantic"):
        write_carla_export([fr], tmp_path / "d", camera=scene.camera, mounting=scene.mounting)
    # frame dicts with camera and mounting are accepted; fov follows the focal length
    out = write_carla_export([scene.render(0)], tmp_path / "e", camera=scene.camera,
                             mounting=scene.mounting, right=False)
    meta = json.loads((out / "sensor.json").read_text())
    assert meta["fov"] == pytest.approx(math.degrees(2 * math.atan(32 / scene.camera.fx)))
    assert not (out / "right").exists()
