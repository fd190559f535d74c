"""Evaluation commands on synthetic inputs with known answers."""
import json

import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
from staticdepth.evaluate import evaluate_sequence, region_masks
from staticdepth.geometry import Camera, Mounting, plane_depth_map


def test_metrics_command_on_npy(tmp_path, rng, capsys):
    gt = rng.uniform(1, 35, (3, 20, 30))  # 2 x gt stays under the 80 m clamp
    gt[:, 0, :] = 0  # unknown
    np.save(tmp_path / "gt.npy", gt)
    np.save(tmp_path / "pred.npy", 2.0 * gt + 0.0)
    out = tmp_path / "m.json"
    assert main(["metrics", "--pred", str(tmp_path / "pred.npy"), "--gt", str(tmp_path / "gt.npy"),
                 "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["abs_rel"] == pytest.approx(0, abs=1e-12) and len(res["per_image"]) == 3
    assert res["per_image"][0]["n"] == 19 * 30
    assert main(["metrics", "--protocol", "metric", "--pred", str(tmp_path / "pred.npy"),
                 "--gt", str(tmp_path / "gt.npy"), "--json", str(out)]) == 2   # exists already
    assert main(["metrics", "--protocol", "metric", "--pred", str(tmp_path / "pred.npy"),
                 "--gt", str(tmp_path / "gt.npy"), "--json", str(out), "--overwrite"]) == 0
    assert json.loads(out.read_text())["abs_rel"] == pytest.approx(1.0)
    # folders of .npy in matching order
    (tmp_path / "P").mkdir(), (tmp_path / "G").mkdir()
    for i in range(3):
        np.save(tmp_path / "P" / f"{i:03d}.npy", gt[i] * 1.1)
        np.save(tmp_path / "G" / f"{i:03d}.npy", gt[i])
    assert main(["metrics", "--protocol", "metric", "--pred", str(tmp_path / "P"), "--gt",
                 str(tmp_path / "G"), "--json", str(out), "--overwrite"]) == 0
    assert json.loads(out.read_text())["abs_rel"] == pytest.approx(0.1)


def test_metrics_command_bad_input(tmp_path, capsys):
    np.save(tmp_path / "a.npy", np.ones((2, 4, 4)))
    np.save(tmp_path / "b.npy", np.ones((3, 4, 4)))
    (tmp_path / "c.npy").write_bytes(b"garbage")
    assert main(["metrics", "--pred", str(tmp_path / "a.npy"), "--gt", str(tmp_path / "b.npy")]) == 2
    assert "2 predictions" in capsys.readouterr().err
    assert main(["metrics", "--pred", str(tmp_path / "c.npy"), "--gt", str(tmp_path / "b.npy")]) == 2
    assert "c.npy: not a readable .npy file" in capsys.readouterr().err


def _sequence_with_ground(tmp_path):
    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    ground = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 80, 40)
    p = tmp_path / "s.h5"
    meta = SequenceMeta(name="g", camera=cam, gt_kind="synthetic", adapt_frames=1, mounting=mnt)
    inst = np.zeros((40, 80), np.uint16)
    inst[20:30, 10:20] = 3
    ag = schema.empty_agents(1)
    ag["instance_id"], ag["class_id"] = 3, 0
    with SequenceWriter(p, meta, streams=("left", "depth", "instances")) as w:
        for i in range(3):
            w.append(left=np.zeros((40, 80, 3), np.uint8), depth=ground, instances=inst, agents=ag)
    return p, ground, inst


def test_evaluate_sequence_regions_and_protocols(tmp_path):
    p, ground, inst = _sequence_with_ground(tmp_path)
    pred = ground * 3.0
    pred_agents_wrong = pred.copy()
    pred_agents_wrong[inst == 3] *= 1.5
    add_prediction(p, "rel", [pred] * 3)
    add_prediction(p, "bad-agents", [pred_agents_wrong] * 3)
    add_prediction(p, "x-metric", [ground * 1.2] * 3)
    res = evaluate_sequence(p)["results"]
    assert res["rel"]["median"]["all"]["abs_rel"] == pytest.approx(0, abs=1e-6)
    assert res["rel"]["median"]["all"]["n_images"] == 2  # eval split
    assert res["x-metric"]["metric"]["all"]["abs_rel"] == pytest.approx(0.2)
    # one median scale for the whole image; agents are then 1.5x off relative to the rest
    ok = np.isfinite(ground)
    s = np.median(ground[ok]) / np.median(pred_agents_wrong[ok])
    agents = res["bad-agents"]["median"]["agents"]["abs_rel"]
    assert agents == pytest.approx(abs(1 - 4.5 * s), rel=1e-5)
    assert res["bad-agents"]["median"]["ground"]["abs_rel"] == pytest.approx(abs(1 - 3 * s), rel=1e-5)
    assert agents > 0.4


def test_region_masks_ground_matches_plane(tmp_path):
    _, ground, inst = _sequence_with_ground(tmp_path)
    cam = Camera.from_fov(80, 40, 90)
    mnt = Mounting.from_pitch_roll(5.0, 45.0)
    ag = schema.empty_agents(1)
    ag["instance_id"], ag["class_id"] = 3, 0
    m = region_masks(ground, inst, ag, cam.K, (mnt.normal, mnt.height_m), 80)
    assert m["ground"].sum() == (np.isfinite(ground) & (inst == 0)).sum()
    assert m["agents"].sum() == 100


def test_evaluate_counts_the_pixels_a_prediction_leaves_out(tmp_path, capsys):
    # a map with holes (a stereo prediction) is evaluated where it has depth, and says how much
    # of the valid ground truth it left out: the count was nowhere before
    p, ground, _ = _sequence_with_ground(tmp_path)
    holes = ground * 2.0
    holes[25:, :] = np.nan
    add_prediction(p, "holes", [holes] * 3)
    add_prediction(p, "full", [ground * 2.0] * 3)
    valid = np.isfinite(ground) & (ground > 1e-3) & (ground < 80)
    want = int((valid & np.isnan(holes)).sum())
    assert want > 0
    res = evaluate_sequence(p)
    assert res["missing"]["holes"]["pixels"] == 2 * want          # the 2 eval frames
    assert res["missing"]["holes"]["share"] == pytest.approx(want / valid.sum())
    assert res["missing"]["full"]["pixels"] == 0
    assert res["results"]["holes"]["median"]["all"]["pixels"] == 2 * int(valid.sum()) - 2 * want
    assert main(["evaluate", str(p)]) == 0
    out = capsys.readouterr().out
    assert f"warning: holes has no depth (NaN) at {2 * want} pixels" in out
    assert "warning: full" not in out


@pytest.mark.parametrize("cap", ["0", "-3", "nan"])
def test_a_depth_cap_that_leaves_nothing_is_refused(tmp_path, capsys, cap):
    p, ground, _ = _sequence_with_ground(tmp_path)
    add_prediction(p, "rel", [ground] * 3)
    np.save(tmp_path / "g.npy", ground)
    for argv in (["evaluate", str(p)], ["metrics", "--pred", str(tmp_path / "g.npy"), "--gt",
                                        str(tmp_path / "g.npy")]):
        capsys.readouterr()
        assert main([*argv, f"--max-depth={cap}"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--max-depth must be a finite depth above" in err


def test_evaluate_without_ground_truth_in_the_split_is_an_error(tmp_path, capsys):
    cam = Camera.from_fov(80, 40, 90)
    p = tmp_path / "s.h5"
    with SequenceWriter(p, SequenceMeta(name="k", camera=cam, gt_kind="lidar", adapt_frames=1),
                        streams=("left", "depth")) as w:
        for i in range(3):          # LiDAR on the adaptation frame only
            d = np.full((40, 80), 10.0 if i == 0 else np.nan, np.float32)
            w.append(left=np.zeros((40, 80, 3), np.uint8), depth=d)
    add_prediction(p, "base", [np.full((40, 80), 5.0, np.float32)] * 3)
    assert main(["evaluate", str(p)]) == 2
    err = capsys.readouterr().err
    assert "no frame of split 'eval' (2 frames) has ground truth between 0.001 and 80 m" in err
    assert main(["evaluate", str(p), "--split", "adapt"]) == 0
    assert "(1 frames)" in capsys.readouterr().out


def test_a_frame_or_region_without_depth_is_left_out_and_a_prediction_without_any_named(
        tmp_path, capsys):
    """A prediction NaN over one whole frame (a stereo matcher that failed on it) stopped
    evaluate and report with 'no valid ground-truth pixel to evaluate' / 'median scaling: no
    valid pixel', naming neither the prediction nor the file. Now that frame's pixels count as
    missing; a prediction with no depth anywhere is one line naming its file."""
    from staticdepth.report import error_map

    p, ground, _ = _sequence_with_ground(tmp_path)
    gone = np.full_like(ground, np.nan)
    add_prediction(p, "gap", [ground * 2.0, gone, ground * 2.0])       # eval frames: 1, 2
    res = evaluate_sequence(p)
    valid = int((np.isfinite(ground) & (ground > 1e-3) & (ground < 80)).sum())
    assert res["missing"]["gap"]["pixels"] == valid
    assert res["results"]["gap"]["median"]["all"]["pixels"] == valid
    assert res["results"]["gap"]["median"]["all"]["abs_rel"] < 1e-6
    add_prediction(p, "none", [gone] * 3)
    capsys.readouterr()
    for argv in (["evaluate", str(p)], ["report", str(p), "--out", str(tmp_path / "r")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(tmp_path / "s.h5.pred" / "none.h5") in err, err
        assert "no depth (NaN) at any of the" in err
    with np.errstate(all="raise"):                    # was: invalid value encountered in cast
        rgb = error_map(gone, ground)
    assert (rgb == 90).all()                          # a hole is grey, as missing ground truth
