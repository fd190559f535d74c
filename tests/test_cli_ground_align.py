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
    # foot and height only (no top column): the std carries the people-as-boxes inflation
    # (agent_plane_boot.BOX_INFLATION), 0.72 deg with 30 tracks, at the gate's 0.71
    obs = people_observations(np.random.default_rng(5), K, w, h, n, 6.0, n_tracks=45)
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
    # both heights: the agent height does not set the camera height, said in one warning
    rc = main(["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
               str(d / "cam.json"), "--model", "paper", "--camera-height", "6",
               "--agent-height", "1.7", "--bootstrap", "0", "--out", str(d / "both.json")])
    out = capsys.readouterr().out
    assert rc == 0 and "camera height 6.000 m (given)" in out
    assert "warning: --camera-height is given: --agent-height does not set the camera" in out


@pytest.mark.parametrize("text,msg", [
    ("frame,track,foot_u,foot_v\n1,1,2,3\n", "missing column(s) height_px"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,x,4\n", "line 2: column 'foot_v' is not a number"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,3,4\n2,1,5,6,7\n", "2 usable observation(s)"),
    ("frame,track,foot_u,foot_v,height_px\n1,1,2,3\n", "line 2: 4 fields"),
    ("", "empty file"),
    ("frame,track,foot_u,foot_v,height_px,image_width\n1,1,2,3,4,800\n",
     "has one of the columns image_width and image_height without the other"),
    ("frame,track,foot_u,foot_v,height_px,image_width,image_height\n1,1,2,3,4,800,400\n"
     "2,1,5,6,7,800,400\n3,2,5,9,9,640,320\n", "rows of 2 image sizes (640x320, 800x400)"),
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
    assert rc == 2 and "collinear (12 observations of 3 track(s))" in capsys.readouterr().err


def test_ground_plane_one_parked_vehicle_says_so(tmp_path, capsys):
    """--classes vehicles on a video whose one vehicle is parked: "collinear" did not say that one
    track stood still; the line now counts the observations and tracks of the classes selected."""
    rows = "".join(f"{i},7,2,{400 + 0.2 * (i % 2)},{300 + 0.1 * (i % 3)},40\n" for i in range(9))
    people = "".join(f"{i},{1 + i // 5},0,{100 + 13 * i},{250 + 7 * (i % 5)},60\n"
                     for i in range(15))
    (tmp_path / "obs.csv").write_text("frame,track,class_id,foot_u,foot_v,height_px\n" + rows
                                      + people)
    (tmp_path / "cam.json").write_text('{"fx": 500, "fy": 500, "cx": 400, "cy": 200}')
    rc = main(["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
               str(tmp_path / "cam.json"), "--classes", "vehicles", "--out",
               str(tmp_path / "p.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert "(9 observations of 1 track(s) of the classes selected)" in err
    assert not (tmp_path / "p.json").exists()


def test_observations_refuses_an_image_in_one_line(tmp_path, capsys):
    """Was "not a readable HDF5 file" for a JPEG."""
    cv2.imwrite(str(tmp_path / "a.jpg"), np.zeros((32, 32, 3), np.uint8))
    rc = main(["observations", str(tmp_path / "a.jpg"), "--out", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert "a.jpg: an image: observations reads a sequence file (.h5) or a video" in err
    assert not (tmp_path / "o.csv").exists()


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
              "--camera-height must be a height in metres in (0, 1000], got -1.0")]
    for extra, msg in cases:
        rc = main(base + extra)
        err = capsys.readouterr().err
        assert rc == 2 and msg in err, (extra, err)
    assert not (tmp_path / "o.npy").exists()


def _align(tmp_path, *extra):
    return main(["align", "--pred", str(tmp_path / "pred.npy"), "--inverse", "--intrinsics",
                 str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
                 "--camera-height", "5", "--out", str(tmp_path / "out.npy"), "--overwrite", *extra])


def test_align_with_a_ground_polygon_text_json_or_txt(tmp_path):
    K, n, depth, ground = _align_inputs(tmp_path)
    # a quadrilateral inside the ground region (rows 55-79 see the ground everywhere)
    verts = [(10.5, 55.5), (150.5, 55.5), (155.5, 79.4), (5.5, 79.4)]
    assert ground[56:80, 6:155].all()
    (tmp_path / "poly.json").write_text(json.dumps({"vertices": verts}))
    (tmp_path / "poly.txt").write_text("".join(f"{u} {v}\n" for u, v in verts))
    text = " ".join(f"{u},{v}" for u, v in verts)
    for arg in (text, str(tmp_path / "poly.json"), str(tmp_path / "poly.txt")):
        assert _align(tmp_path, "--ground-polygon", arg) == 0
        out = np.load(tmp_path / "out.npy")
        assert np.mean(np.abs(out - depth)[ground] / depth[ground]) < 0.01, arg


def test_align_agent_mask_leaves_the_fit_and_is_aligned(tmp_path):
    K, n, depth, ground = _align_inputs(tmp_path)
    # a fake "agent" over part of the ground whose prediction is garbage: removed from the fit
    pred = dpt_failure(depth)
    agent = np.zeros_like(ground)
    agent[60:75, 20:60] = True
    pred[agent] = 5.0
    np.save(tmp_path / "pred.npy", pred)
    cv2.imwrite(str(tmp_path / "agents.png"), agent.astype(np.uint8) * 255)
    assert _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--agent-mask",
                  str(tmp_path / "agents.png"), "--near-plane", "0.01", "--json",
                  str(tmp_path / "info.json"), "--mode", "eq2") == 0
    out = np.load(tmp_path / "out.npy")
    g = ground & ~agent
    assert np.mean(np.abs(out - depth)[g] / depth[g]) < 0.01
    # always aligned, even with --near-plane (it lies far off the predicted plane): not merely
    # rescaled by the fallback ratio like the pixels off the plane
    ratio = json.loads((tmp_path / "info.json").read_text())["frames"][0]["fallback_ratio"]
    assert np.isfinite(out[agent]).all()
    assert np.all(np.abs(out[agent] / (0.2 * ratio) - 1) > 0.05)
    # (the garbage on 11% of the ground leaves R^2 0.13: under align.min_ground_r2 the output
    # would be the plane alone; the bar at 0 shows what Eq. 2's fit does with it)
    assert _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--mode", "eq2",
                  "--set", "align.min_ground_r2=0") == 0
    worse = np.load(tmp_path / "out.npy")
    assert np.mean(np.abs(worse - depth)[g] / depth[g]) > 0.02       # the fit saw the garbage


def _sequence(tmp_path, depth, K, n_frames=2):
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
    from staticdepth.geometry.camera import Camera

    h, w = depth.shape
    cam = Camera.from_intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h)
    path = tmp_path / "seq.h5"
    _, _, _, ground, _ = scene()
    with SequenceWriter(path, SequenceMeta("t", cam), streams=("left",),
                        aux={"ground": np.uint8}) as wr:
        for _ in range(n_frames):
            wr.append(left=np.zeros((h, w, 3), np.uint8), aux={"ground": ground.astype(np.uint8)})
    base = [depth_from_inverse_np(dpt_failure(depth, 3.0 - i, 0.05 + 0.02 * i))
            for i in range(n_frames)]
    add_prediction(path, "base", base)
    return path


def depth_from_inverse_np(D):
    return (1.0 / D).astype(np.float32)


def test_align_sequence_mode_with_ground_truth_semantics(tmp_path, capsys):
    from staticdepth.dataset.h5 import SequenceReader

    K, n, depth, ground = _align_inputs(tmp_path)
    seq = _sequence(tmp_path, depth, K)
    rc = main(["align", "--sequence", str(seq), "--pred-name", "base", "--plane",
               str(tmp_path / "plane.json"), "--ground-aux", "ground", "--camera-height", "5",
               "--json", str(tmp_path / "info.json")])
    assert rc == 0, capsys.readouterr().err
    with SequenceReader(seq) as r:
        assert set(r.predictions()) == {"base", "base-align"}
        for i in range(len(r)):
            out = r.prediction("base-align", i)
            assert np.mean(np.abs(out - depth)[ground] / depth[ground]) < 0.01
    assert len(json.loads((tmp_path / "info.json").read_text())["frames"]) == 2
    # errors: missing prediction, missing aux map, --ground-aux without a sequence, --out
    base = ["align", "--plane", str(tmp_path / "plane.json")]
    cases = [(["--sequence", str(seq), "--pred-name", "nope", "--ground-aux", "ground"],
              "no prediction 'nope'"),
             (["--sequence", str(seq), "--ground-aux", "road"], "no aux map 'road'"),
             (["--sequence", str(seq), "--ground-aux", "ground", "--out", "x.npy"], "--out-name"),
             (["--sequence", str(seq), "--ground-aux", "ground", "--out-name", "base"],
              "overwrite"),
             (["--pred", str(tmp_path / "pred.npy"), "--ground-aux", "ground"],
              "needs --sequence"),
             (["--pred", str(tmp_path / "pred.npy"), "--ground-mask", str(tmp_path / "mask.png")],
              "needs --intrinsics and --out")]
    for extra, msg in cases:
        rc = main(base + extra)
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, (extra, err)


def test_align_polygon_and_agent_mask_errors(tmp_path, capsys):
    _align_inputs(tmp_path)
    (tmp_path / "bad.json").write_text('{"vertices": [[1, 2, 3]]}')
    cv2.imwrite(str(tmp_path / "agents_small.png"), np.full((10, 10), 255, np.uint8))
    cv2.imwrite(str(tmp_path / "agents_all.png"), np.full((80, 160), 255, np.uint8))
    cases = [(["--ground-polygon", "1,2 3,4"], "at least 3"),
             (["--ground-polygon", "1,2 3,x 5,6"], "list of u,v pairs"),
             (["--ground-polygon", str(tmp_path / "bad.json")], "list of u,v pairs"),
             (["--ground-polygon", "500,500 600,500 600,600"], "covers no pixel"),
             (["--ground-mask", str(tmp_path / "mask.png"), "--agent-mask",
               str(tmp_path / "agents_small.png")], "differs from the agent mask's (10, 10)"),
             (["--ground-mask", str(tmp_path / "mask.png"), "--agent-mask",
               str(tmp_path / "agents_all.png")], "empty once the agents' pixels are removed")]
    for extra, msg in cases:
        rc = _align(tmp_path, *extra)
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, (extra, err)
    assert not (tmp_path / "out.npy").exists()


def test_ground_plane_command_reads_top_columns(tmp_path):
    """With the top column (masks) the fit is tighter than with rows only (boxes)."""
    K, w, h = camera_K(600.0)
    n = true_normal(25.0, -3.0)
    obs = people_observations(np.random.default_rng(25), K, w, h, n, 7.5)
    (tmp_path / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 600.0, "cx": K[0, 2],
                                                   "cy": K[1, 2]}))
    errs = []
    for cols in (("frame", "track", "foot_u", "foot_v", "height_px"),
                 ("frame", "track", "foot_u", "foot_v", "height_px", "top_u")):
        write_csv(tmp_path / "obs.csv", obs, cols)
        rc = main(["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
                   str(tmp_path / "cam.json"), "--bootstrap", "0", "--column-weight", "1",
                   "--out", str(tmp_path / "p.json"), "--overwrite"])
        assert rc == 0
        errs.append(angle_between_deg(json.loads((tmp_path / "p.json").read_text())["normal"], n))
    print(f"rows only {errs[0]:.2f} deg, rows + columns {errs[1]:.2f} deg")
    assert errs[1] < 0.5 and errs[1] < errs[0]


def test_ground_plane_gate_refuses_then_accepts(tmp_path, capsys):
    """Four short tracks: the normal's uncertainty is over the limit, so the command exits 2 with
    one line saying how many tracks it needs and writes nothing; --accept-uncertain writes the
    plane with its gate; --classes vehicles on people only is a clear error."""
    K, w, h = camera_K(600.0)
    obs = people_observations(np.random.default_rng(2), K, w, h, true_normal(30.0), 6.0,
                              n_tracks=4, frames=(4, 5), noise_px=2.0)
    cols = ("frame", "track", "class_id", "foot_u", "foot_v", "height_px", "top_u")
    write_csv(tmp_path / "obs.csv", obs, cols)
    (tmp_path / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 600.0, "cx": K[0, 2],
                                                   "cy": K[1, 2]}))
    args = ["ground-plane", "--observations", str(tmp_path / "obs.csv"), "--intrinsics",
            str(tmp_path / "cam.json"), "--bootstrap", "8", "--max-normal-std", "0.05",
            "--out", str(tmp_path / "p.json")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ground plane too uncertain" in err and "need" in err
    assert not (tmp_path / "p.json").exists()
    assert main(args + ["--accept-uncertain"]) == 0
    p = json.loads((tmp_path / "p.json").read_text())
    assert p["gate"]["ok"] is False and p["gate"]["tracks_needed"] > p["gate"]["tracks"]
    assert p["extents"]["people"] and p["camera_height_m"] > 0
    assert "warning: ground plane too uncertain" in capsys.readouterr().out
    assert main(args + ["--classes", "vehicles", "--overwrite"]) == 2
    assert "no observation of the classes selected" in capsys.readouterr().err


def test_align_command_modes_are_adapts(tmp_path, capsys):
    """``--mode`` (default the config's align.mode, upright) aligns as adapt's align stage: the
    same maps as align_depth with adapt's settings; on a wall the network puts 50% too far,
    only upright re-anchors it at its contact, fully with ``align.max_pull=2`` (truth: the
    rendered scene)."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse

    K, n, depth, ground = _align_inputs(tmp_path)
    wall = ~ground & (depth < 100)
    pred = dpt_failure(depth)
    pred[wall] /= 1.5                                  # inverse depth: the wall 1.5x too far
    np.save(tmp_path / "pred.npy", pred)
    conf = build_config({}).align
    assert conf.mode == "upright"
    err = {}
    for mode in ("upright", "ground", "eq2", None):
        extra = () if mode is None else ("--mode", mode)
        assert _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--json",
                      str(tmp_path / "info.json"), *extra) == 0
        out = np.load(tmp_path / "out.npy")
        info = json.loads((tmp_path / "info.json").read_text())["frames"][0]
        assert info["mode"] == (mode or "upright")
        m = mode or conf.mode
        ref = align_depth(depth_from_inverse(pred), K, n, 5.0, ground, mode=m,
                          snap_rel=conf.snap_rel, **upright_options(conf)).depth
        np.testing.assert_allclose(out, ref, rtol=1e-6)
        err[mode] = float(np.mean(np.abs(out - depth)[wall] / depth[wall]))
        assert np.mean(np.abs(out - depth)[ground] / depth[ground]) < 0.01, mode
    # the default refuses pulls beyond 1.1x its ground-mode depth (align.max_pull): partly fixed
    assert err[None] == err["upright"] < 0.5 * min(err["ground"], err["eq2"])
    assert err["ground"] > 0.3 and err["eq2"] > 0.3
    assert _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--set",
                  "align.max_pull=2") == 0
    loose = np.load(tmp_path / "out.npy")
    assert float(np.mean(np.abs(loose - depth)[wall] / depth[wall])) < 0.07
    # an align.* setting reaches the alignment: a huge jump_rel joins the wall to the sky
    assert _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--set",
                  "align.jump_rel=50") == 0
    assert not np.allclose(np.load(tmp_path / "out.npy")[wall], depth[wall], rtol=0.07)
    for extra, msg in ((("--mode", "plane"), "align.mode must be one of"),
                       (("--set", "jump_rel=0.1"), "align.KEY=VALUE"),
                       (("--set", "align.jump_rel=0"), "jump_rel must be > 0"),
                       (("--near-plane", "0.1"), "needs --mode eq2")):
        rc = _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), *extra)
        e = capsys.readouterr().err
        assert rc == 2 and msg in e and len(e.strip().splitlines()) == 1, (extra, e)


def test_align_command_fits_the_camera_to_a_resized_map(tmp_path, capsys):
    """A camera JSON of the image at half the map's size (a network's map at another resolution,
    a sequence imported with --width) is scaled to the map as import-video scales it: the
    metric output is the closed-form scene's depth, as with the map's own intrinsics; a size
    that is not a uniform resize is one line naming the camera file and the map, nothing
    written. Before, the half-size intrinsics were used as they were (every ray wrong)."""
    K, n, depth, ground = _align_inputs(tmp_path)
    h, w = depth.shape
    half = {"fx": K[0, 0] / 2, "fy": K[1, 1] / 2, "cx": (K[0, 2] + 0.5) / 2 - 0.5,
            "cy": (K[1, 2] + 0.5) / 2 - 0.5, "width": w // 2, "height": h // 2}
    (tmp_path / "cam.json").write_text(json.dumps(half))
    rc = _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), "--json",
                str(tmp_path / "info.json"))
    assert rc == 0
    out = np.load(tmp_path / "out.npy")
    assert np.mean(np.abs(out - depth)[ground] / depth[ground]) < 0.01
    info = json.loads((tmp_path / "info.json").read_text())
    assert info["anchor_depth_m"] == pytest.approx(depth[-1, w // 2], rel=1e-3)
    (tmp_path / "out.npy").unlink()
    (tmp_path / "cam.json").write_text(json.dumps({**half, "width": int(w * 0.6)}))
    capsys.readouterr()
    rc = _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"))
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert str(tmp_path / "cam.json") in err and "pred.npy" in err and "uniform resize" in err
    assert not (tmp_path / "out.npy").exists()


def test_ground_plane_refuses_observations_of_another_resolution(fitted, tmp_path, capsys):
    """Observations read from a video's full frames against the camera of a sequence imported
    at half the width: one line naming both files, nothing written (the fit ran before and
    gave a plane with every ray wrong)."""
    d = fitted[0]
    cam = json.loads((d / "cam.json").read_text())
    half = {k: (cam[k] + 0.5) / 2 - 0.5 if k in ("cx", "cy") else cam[k] / 2 for k in cam}
    half["width"], half["height"] = cam["width"] // 2, cam["height"] // 2
    (tmp_path / "half.json").write_text(json.dumps(half))
    rc = main(["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
               str(tmp_path / "half.json"), "--out", str(tmp_path / "p.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert str(d / "obs.csv") in err and str(tmp_path / "half.json") in err
    assert "different resolutions" in err and not (tmp_path / "p.json").exists()


def test_ground_plane_fits_the_intrinsics_to_the_observations_size(fitted, tmp_path, capsys):
    """A CSV that says its images' size (``observations`` writes it) takes the camera of a
    sequence imported at half the width as the same camera scaled (the plane of the full-size
    camera comes back), and refuses in one line a camera whose image is not a uniform resize of
    the observations' images: a 10% mismatch lies within the 20% margin the size-less check
    allows."""
    d, n, _ = fitted
    cam = json.loads((d / "cam.json").read_text())
    w, h = cam["width"], cam["height"]
    lines = (d / "obs.csv").read_text().splitlines()
    sized = tmp_path / "obs.csv"
    sized.write_text("\n".join([lines[0] + ",image_width,image_height"]
                               + [ln + f",{w},{h}" for ln in lines[1:]]) + "\n")
    half = {k: (cam[k] + 0.5) / 2 - 0.5 if k in ("cx", "cy") else cam[k] / 2 for k in cam}
    half["width"], half["height"] = w // 2, h // 2
    (tmp_path / "half.json").write_text(json.dumps(half))
    args = ["ground-plane", "--observations", str(sized), "--agent-height", "1.7",
            "--bootstrap", "5", "--intrinsics"]
    assert main(args + [str(tmp_path / "half.json"), "--out", str(tmp_path / "p.json")]) == 0
    full = json.loads((d / "plane.json").read_text())
    got = json.loads((tmp_path / "p.json").read_text())
    assert angle_between_deg(got["normal"], full["normal"]) < 1e-3
    assert got["camera_height_m"] == pytest.approx(full["camera_height_m"], rel=1e-4)
    (tmp_path / "squat.json").write_text(json.dumps({**cam, "height": int(h * 0.9)}))
    capsys.readouterr()
    rc = main(args + [str(tmp_path / "squat.json"), "--out", str(tmp_path / "q.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert str(tmp_path / "squat.json") in err and str(sized) in err
    assert "not a uniform resize" in err and not (tmp_path / "q.json").exists()


def test_ground_plane_shows_the_bootstraps_progress(fitted, monkeypatch, capsys):
    # the resamples are most of a fit's time: on a terminal they get a bar (off when not one)
    from staticdepth import progress

    d, n, _ = fitted
    args = ["ground-plane", "--observations", str(d / "obs.csv"), "--intrinsics",
            str(d / "cam.json"), "--agent-height", "1.7", "--bootstrap", "3", "--accept-uncertain"]
    assert main(args + ["--out", str(d / "quiet.json")]) == 0
    assert "ground plane (bootstrap)" not in capsys.readouterr().err
    monkeypatch.setattr(progress, "progress_enabled", lambda: True)
    assert main(args + ["--out", str(d / "bar.json")]) == 0
    err = capsys.readouterr().err
    assert "ground plane (bootstrap)" in err and "/3 [" in err
    quiet, bar = (json.loads((d / f).read_text()) for f in ("quiet.json", "bar.json"))
    assert bar["normal"] == quiet["normal"] and bar["uncertainty"] == quiet["uncertainty"]


def test_align_fits_a_camera_sized_mask_to_a_resized_map(tmp_path, capsys):
    """A network's map at half the camera's resolution, with the camera's own JSON and a ground
    mask drawn on the camera's image: the camera was scaled to the map, the mask was refused
    ("prediction shape (40, 80) differs from the ground mask's (80, 160)"). Now the mask is
    resized as the camera is, and the metric output is the closed-form scene's depth."""
    K, n, depth, ground = _align_inputs(tmp_path)
    h, w = depth.shape
    half = cv2.resize(depth, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    np.save(tmp_path / "half.npy", dpt_failure(half))
    rc = main(["align", "--pred", str(tmp_path / "half.npy"), "--inverse", "--intrinsics",
               str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
               "--ground-mask", str(tmp_path / "mask.png"), "--camera-height", "5",
               "--out", str(tmp_path / "out.npy")])
    assert rc == 0, capsys.readouterr().err
    out = np.load(tmp_path / "out.npy")
    g = cv2.resize(ground.astype(np.uint8), (w // 2, h // 2),
                   interpolation=cv2.INTER_NEAREST) > 0
    g &= cv2.erode(g.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0   # away from its edge
    assert out.shape == (h // 2, w // 2)
    assert np.median(np.abs(out - half)[g] / half[g]) < 0.01


@pytest.mark.parametrize("extra,msg", [
    (["--near-plane", "-3", "--mode", "eq2"], "--near-plane must be a positive number, got -3"),
    (["--near-plane", "nan", "--mode", "eq2"], "--near-plane must be a positive number"),
    (["--out", "OUT/aligned.txt"], "aligned.txt: one map is written as a .npy file"),
])
def test_align_option_checks(tmp_path, capsys, extra, msg):
    """--near-plane -3 was "no ground pixel can be aligned"; --out aligned.txt was written as
    NumPy data under a .txt name."""
    _align_inputs(tmp_path)
    extra = [e.replace("OUT", str(tmp_path)) for e in extra]
    rc = _align(tmp_path, "--ground-mask", str(tmp_path / "mask.png"), *extra)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and msg in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out.npy").exists() and not (tmp_path / "aligned.txt").exists()


def test_align_folder_of_maps_refuses_an_npy_name(tmp_path, capsys):
    """--pred FOLDER --out x.npy made a folder named x.npy."""
    _align_inputs(tmp_path)
    (tmp_path / "preds").mkdir()
    np.save(tmp_path / "preds" / "000.npy", np.load(tmp_path / "pred.npy"))
    rc = main(["align", "--pred", str(tmp_path / "preds"), "--inverse", "--intrinsics",
               str(tmp_path / "cam.json"), "--plane", str(tmp_path / "plane.json"),
               "--ground-mask", str(tmp_path / "mask.png"), "--out", str(tmp_path / "x.npy")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "x.npy: a folder of maps is aligned into a folder" in err
    assert not (tmp_path / "x.npy").exists()
