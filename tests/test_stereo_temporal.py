"""Temporal stereo fusion against exact depth, on two renderers with different texture models.

- ``own``: tests/stereo_scene.py (independent ray caster, sinusoidal gratings and painted tiles,
  camera 7 m high, f = 200 px);
- ``synth``: the project's renderer (``SyntheticScene``, fractal texture, 5 m high, f = 160 px).
Both: 320x160, 30 frames at 10 fps, a 27 cm baseline, moving people, and Gaussian sensor noise
(4 DN, independent per view and frame) as a real camera has; the reference is SGBM per frame
with the project's ground-truth settings, run on the same frames.
"""
from __future__ import annotations

import json
from functools import lru_cache

import cv2
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.stereo.match import create_matcher
from staticdepth.stereo.temporal import (TemporalConfig, build_background, fuse_frame,
                                         sample_indices, smooth_planar)
from stereo_scene import FusionScore, Scene, SceneRenderer

N_FRAMES, NOISE_DN = 30, 4.0


def _noisy(img, rng):
    return np.clip(np.round(img + rng.normal(0, NOISE_DN, img.shape)), 0, 255).astype(np.uint8)


@lru_cache(maxsize=None)
def scene_frames(which: str):
    """(f B, frames with left, right, depth, instances)."""
    if which == "own":
        r = SceneRenderer(Scene(noise_dn=NOISE_DN))
        return r.disparity_scale, [r.render(i) for i in range(N_FRAMES)]
    from staticdepth.dataset.synth import SyntheticScene, preset

    sc = SyntheticScene(preset("demo", width=320, height=160, seed=0))
    rng = np.random.default_rng(1)
    frames = []
    for i in range(N_FRAMES):
        f = sc.render(i)
        frames.append({"left": _noisy(f["left"], rng), "right": _noisy(f["right"], rng),
                       "depth": f["depth"], "instances": f["instances"]})
    return sc.config.focal * sc.config.baseline_m, frames


@lru_cache(maxsize=None)
def fusion_scores(which: str):
    fB, frames = scene_frames(which)
    h, w = frames[0]["depth"].shape
    c = TemporalConfig()
    one = create_matcher("sgbm", num_disparities=16, image_size=(w, h))
    up = create_matcher("sgbm", num_disparities=16 * c.plate_scale,
                        image_size=(w * c.plate_scale, h * c.plate_scale))
    match = lambda a, b: one.match(a, b).disparity  # noqa: E731
    picks = sample_indices(len(frames), c.samples)
    model = build_background(((frames[i]["left"], frames[i]["right"]) for i in picks), match,
                             lambda a, b: up.match(a, b).disparity, c)
    score = FusionScore(fB)
    for f in frames:
        d = match(f["left"], f["right"])
        score.add(f, d, fuse_frame(model, f["left"], d))
    return score.t, score.halves()


@pytest.mark.parametrize("which", ["own", "synth"])
def test_fused_background_halves_the_per_frame_error(which):
    t, _ = fusion_scores(which)
    frame, fused = t["frame_bg"], t["fused_bg"]
    info = (which, frame.bad1, fused.bad1, frame.abs_rel, fused.abs_rel, fused.holes)
    assert frame.bad1 > 0.003 and frame.abs_rel > 0.02, info       # the comparison means something
    assert fused.bad1 <= 0.5 * frame.bad1, info
    assert fused.abs_rel <= 0.5 * frame.abs_rel, info
    assert fused.holes <= 0.01, info


@pytest.mark.parametrize("which", ["own", "synth"])
def test_agents_keep_their_own_frame(which):
    t, _ = fusion_scores(which)
    frame, fused = t["frame_agents"], t["fused_agents"]
    info = (which, frame.bad1, fused.bad1, frame.abs_rel, fused.abs_rel, frame.known)
    assert frame.known > 10_000, info                                # people were in view
    # no smearing into the background: as good as per frame (1% slack for a few pixels)
    assert fused.bad1 <= 1.01 * frame.bad1 + 1e-4, info
    assert fused.abs_rel <= 1.01 * frame.abs_rel, info
    assert fused.holes <= frame.holes + 0.002, info


@pytest.mark.parametrize("which", ["own", "synth"])
def test_confidence_is_informative(which):
    _, halves = fusion_scores(which)
    for key in ("bad1", "abs_rel"):
        top, bottom = halves[key]
        assert bottom > 0, (which, halves)
        assert top <= 0.5 * bottom, (which, key, halves)


def test_smooth_planar_recovers_a_plane_and_keeps_an_edge(rng):
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w]
    plane = (3.0 + 0.01 * u + 0.03 * v).astype(np.float32)
    noisy = plane + rng.normal(0, 0.15, plane.shape).astype(np.float32)
    smooth, rms = smooth_planar(noisy, 4, 0.4)
    inner = np.s_[5:-5, 5:-5]
    assert np.std(smooth[inner] - plane[inner]) < 0.3 * np.std(noisy[inner] - plane[inner])
    assert np.nanmedian(rms[inner]) == pytest.approx(0.15, rel=0.2)
    step = np.where(u < 40, 2.0, 8.0).astype(np.float32)          # a depth edge at u = 40
    out, rms = smooth_planar(step, 4, 0.4)
    assert np.array_equal(out[:, 36:44], step[:, 36:44])           # windows across it fit badly
    assert np.isnan(rms[:, 36:44]).all()


def test_background_reads_at_most_its_samples():
    r = SceneRenderer(Scene(width=96, height=48, focal_px=60, n_people=2))
    consumed = []

    def pairs():
        for i in range(100):
            consumed.append(i)
            f = r.render(i % 3)
            yield f["left"], f["right"]

    m = create_matcher("sgbm", num_disparities=16, image_size=(96, 48))
    match = lambda a, b: m.match(a, b).disparity  # noqa: E731
    model = build_background(pairs(), match, None, TemporalConfig(samples=5, disparity_samples=2,
                                                                  plate_scale=1))
    assert len(consumed) <= 6 and model.disparity.shape == (48, 96)
    assert sample_indices(1000, 25) == sorted(set(sample_indices(1000, 25)))
    assert len(sample_indices(1000, 25)) == 25 and sample_indices(3, 25) == [0, 1, 2]


def test_fusion_drops_matches_outside_the_right_image():
    r = SceneRenderer(Scene(width=96, height=48, focal_px=60, n_people=0))
    f = r.render(0)
    m = create_matcher("sgbm", num_disparities=16, image_size=(96, 48))
    match = lambda a, b: m.match(a, b).disparity  # noqa: E731
    model = build_background([(f["left"], f["right"])] * 3, match, None,
                             TemporalConfig(plate_scale=1))
    fused = fuse_frame(model, f["left"], np.full((48, 96), 5.0, np.float32))
    u = np.arange(96)[None, :].repeat(48, 0)
    d = fused.disparity
    assert np.isnan(d[:, :1]).all()                               # u = 0: no match possible
    assert not np.any(np.isfinite(d) & ((u < d) | (d <= 0)))     # all inside the right image
    assert np.isfinite(d[:, 20:]).mean() > 0.95
    assert np.all(fused.confidence[~np.isfinite(fused.disparity)] == 0)


# -- the command -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def synth_seq(tmp_path_factory):
    path = tmp_path_factory.mktemp("tstereo") / "seq.h5"
    assert main(["synth", "--preset", "demo", "--frames", "12", "--adapt-frames", "4",
                 "--set", "width=320", "--set", "height=160", "--out", str(path)]) == 0
    return path


def test_stereo_sequence_temporal_fill_and_evaluate(synth_seq, tmp_path, capsys):
    from staticdepth.dataset.h5 import SequenceReader

    assert main(["stereo", "--sequence", str(synth_seq), "--out-name", "sgbm"]) == 0
    assert main(["stereo", "--sequence", str(synth_seq), "--out-name", "fused", "--temporal",
                 "--fill", "--set", "temporal.samples=8"]) == 0
    out = capsys.readouterr().out
    assert "100.0% of pixels with depth" in out and "reused" not in out
    assert main(["stereo", "--sequence", str(synth_seq), "--out-name", "fused", "--temporal",
                 "--fill", "--set", "temporal.samples=8", "--overwrite"]) == 0
    assert "background model reused" in capsys.readouterr().out
    assert main(["stereo", "--sequence", str(synth_seq), "--out-name", "fused", "--temporal",
                 "--fill", "--set", "temporal.samples=6", "--overwrite"]) == 0   # rebuilt
    assert "reused" not in capsys.readouterr().out
    assert main(["stereo", "--sequence", str(synth_seq), "--out-name", "fused", "--temporal",
                 "--fill", "--set", "temporal.samples=8", "--overwrite"]) == 0
    capsys.readouterr()
    with SequenceReader(synth_seq) as r:
        assert {"sgbm", "sgbm-confidence", "fused", "fused-confidence"} <= set(r.predictions())
        for i in range(len(r)):
            z, c = r.prediction("fused", i), r.prediction("fused-confidence", i)
            assert np.isfinite(z).all() and (z > 0).all()         # --fill: every pixel
            assert ((c >= 0) & (c <= 1)).all()
            gt = r.depth(i)
            inst = r.instances(i)
            rel = np.abs(z - gt) / gt
            assert np.median(rel[inst == 0]) < 0.05
    js = tmp_path / "eval.json"
    assert main(["evaluate", str(synth_seq), "--split", "all", "--json", str(js)]) == 0
    printed = capsys.readouterr().out
    res = json.loads(js.read_text())["results"]
    assert set(res) == {"sgbm", "fused"}                          # confidence is not a depth
    fused = res["fused"]["metric"]                                 # stereo depth is metric
    assert fused["all"]["scale_median"] == 1.0
    bands = [k for k in fused if k.startswith("conf ")]
    assert bands == ["conf q1", "conf q2", "conf q3", "conf q4"]
    assert all(b in printed for b in bands)
    in_bands = sum(fused[b]["pixels"] for b in bands)       # filled pixels have confidence 0
    assert 0.95 * fused["all"]["pixels"] <= in_bands <= fused["all"]["pixels"]
    assert fused["conf q4"]["abs_rel"] < 0.5 * fused["conf q1"]["abs_rel"]
    assert fused["all"]["abs_rel"] < res["sgbm"]["metric"]["all"]["abs_rel"] * 1.2


def test_stereo_sequence_errors(synth_seq, tmp_path, capsys):
    from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter

    cases = [
        (["--out-name", "x-confidence"], "must be non-empty"),
        (["--out-name", "x", "--set", "temporal.samples=4"], "need --temporal"),
        (["--out-name", "x", "--temporal", "--set", "temporal.nonsense=1"], "unknown setting"),
        (["--out-name", "x", "--temporal", "--set", "temporal.samples=0"], "samples must be"),
        (["--out-name", "x", "--left", "a.png"], "drop --left"),
        ([], "go together"),
    ]
    for extra, message in cases:
        assert main(["stereo", "--sequence", str(synth_seq), *extra]) == 2, extra
        assert message in capsys.readouterr().err, extra
    with SequenceReader(synth_seq) as r:
        meta, frame = r.meta, r.frame(0)
    mono = tmp_path / "mono.h5"
    with SequenceWriter(mono, SequenceMeta(name="mono", camera=meta.camera),
                        streams=("left", "depth")) as w:
        w.append(left=frame["left"], depth=frame["depth"])
    assert main(["stereo", "--sequence", str(mono), "--out-name", "x"]) == 2
    assert "no right stream" in capsys.readouterr().err


def test_confidence_masks_split_by_rank():
    from staticdepth.evaluate import confidence_masks

    c = np.array([[0.0, 0.1, 0.2, 0.3], [0.4, 0.5, 0.6, 0.7], [0.8, 0.9, np.nan, 0.05]])
    m = confidence_masks(c)
    assert sorted(m) == ["conf q1", "conf q2", "conf q3", "conf q4"]
    assert sum(x.sum() for x in m.values()) == 10                # 0 and NaN have no confidence
    assert m["conf q4"][2, 1] and m["conf q1"][2, 3] and not any(x[0, 0] for x in m.values())
    assert confidence_masks(np.zeros((2, 2))) == {}


def test_fill_is_fully_dense_on_real_pairs(shared_data):
    """Midd1 used to keep 13% of its pixels at disparity 0 (no depth) after --fill."""
    from staticdepth.geometry.camera import Camera, StereoRig
    from staticdepth.stereo.io import read_rgb
    from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline

    left = read_rgb(shared_data / "middlebury/Midd1/view1.png")
    right = read_rgb(shared_data / "middlebury/Midd1/view5.png")
    gt = cv2.imread(str(shared_data / "middlebury/Midd1/disp1.png"), cv2.IMREAD_UNCHANGED) / 3.0
    h, w = left.shape[:2]
    rig = StereoRig.rectified(Camera.from_intrinsics(1000, 1000, w / 2, h / 2, w, h), 0.1)
    res = StereoPipeline(rig, StereoConfig(num_disparities=80, fill=True)).process(left, right)
    assert (res.disparity > 0).all() and np.isfinite(res.depth).all()
    known = gt > 0
    assert np.mean(np.abs(res.disparity - gt)[known] > 2) < 0.25   # and mostly right
