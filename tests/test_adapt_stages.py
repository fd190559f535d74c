"""The adaptation as streamed, resumable stages: bounded memory on 1600 frames, SIGKILL and
resume, config-hash reruns of late stages only, dotted settings, fail-fast checks."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest
import torch

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.models.tiny import TinyDepthNet, builtin_model, save_builtin
from conftest import disk_usage_with_free

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

SMALL = dict(enc_channels=(4, 8, 8, 16, 16), dec_channels=(16, 8, 8, 4))
OUTPUTS = ("base", "ft", "align", "ft-align", "align-metric", "ft-align-metric")
FAST = ["--detector", "gt", "--device", "cpu", "--set", "tracking.min_height_px=3",
        "--set", "plane.bootstrap=0"]
# One torch thread: on a shared 2-core machine two threads per process are much slower.
RUN = ("import resource, sys, torch; torch.set_num_threads(1)\n"
       "from staticdepth.cli import main\n"
       "rc = main(sys.argv[1:])\n"
       "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
       "sys.exit(rc)\n")


def _adapt_cmd(seq, model, *extra):
    return [sys.executable, "-c", RUN, "adapt", str(seq), "--model", f"builtin:{model}",
            *FAST, *extra]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.pt"
    save_builtin(path, builtin_model(TinyDepthNet(**SMALL), input_height=64, input_width=128))
    return str(path)


@pytest.fixture(scope="module")
def tiny32(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny32.pt"
    save_builtin(path, builtin_model(TinyDepthNet(**SMALL), input_height=32, input_width=64))
    return str(path)


@pytest.fixture(scope="module")
def clip32(tmp_path_factory):
    """60 rendered frames at 64x32 (c1), all of them the adaptation split."""
    path = tmp_path_factory.mktemp("clip") / "clip32.h5"
    render_to_file(path, preset_name="c1", n_frames=60, adapt_frames=60, seed=1,
                   overrides={"width": 64, "height": 32})
    return str(path)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """40 rendered frames at 128x64 (c1), 24 of them the adaptation split."""
    path = tmp_path_factory.mktemp("clip") / "clip.h5"
    render_to_file(path, preset_name="c1", n_frames=40, adapt_frames=24, seed=1,
                   overrides={"width": 128, "height": 64})
    return str(path)


def _long_sequence(clip, path, n):
    """``n`` frames cycling through the clip's (its adaptation split comes first)."""
    with SequenceReader(clip) as r:
        frames = [r.frame(i) for i in range(len(r))]
        meta = r.meta
    with SequenceWriter(path, meta, streams=("left", "instances")) as w:
        for i in range(n):
            f = frames[i % len(frames)]
            w.append(left=f["left"], instances=f["instances"], agents=f["agents"],
                     timestamp=float(i))
    return str(path)


def _summary(seq):
    return json.load(open(str(seq).replace(".h5", ".adapt.json")))


def _predictions(seq):
    with SequenceReader(seq) as r:
        return {name: np.stack([r.prediction(name, i) for i in range(len(r))])
                for name in OUTPUTS}


def test_peak_memory_does_not_grow_with_the_number_of_frames(tmp_path, clip32, tiny32):
    peaks = {}
    for n in (100, 1600):
        seq = _long_sequence(clip32, tmp_path / f"long{n}.h5", n)
        out = subprocess.run(_adapt_cmd(seq, tiny32, "--epochs", "1", "--set",
                                        "tracking.min_height_px=2"), capture_output=True,
                             text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        peaks[n] = int(out.stdout.split("PEAK_RSS_KB")[1].split()[0]) / 1024
        assert _summary(seq)["stage_frames"]["base"] == n
        with SequenceReader(seq) as r:
            assert set(r.predictions()) == set(OUTPUTS)
            assert np.isfinite(r.prediction("ft-align-metric", n - 1)).mean() > 0.5
    print(f"\npeak RSS: 100 frames {peaks[100]:.0f} MiB, 1600 frames {peaks[1600]:.0f} MiB")
    # 16x the frames: the whole stack of 1600 images, depths and instance maps alone would add
    # 1600 x 64 x 32 x (3 + 4 x 8 + 2) bytes = 116 MiB
    assert peaks[1600] <= 1.15 * peaks[100] + 20


def _complete(path):
    if not os.path.exists(path):
        return False
    try:
        with h5py.File(path, "r") as f:
            return bool(f.attrs["complete"])
    except OSError:
        return False


def _kill_when(cmd, ready, rng, max_delay):
    """Start ``cmd``, SIGKILL it at a random moment after ``ready()`` holds (or when it ends)."""
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t_end = time.time() + 300
    while not ready() and p.poll() is None and time.time() < t_end:
        time.sleep(0.01)
    time.sleep(rng.uniform(0, max_delay))
    p.send_signal(signal.SIGKILL)
    p.wait()


def test_killed_adapt_resumes_to_the_same_predictions_redoing_no_stage(tmp_path, clip, tiny):
    ref, seq = tmp_path / "ref.h5", tmp_path / "killed.h5"
    shutil.copy(clip, ref)
    shutil.copy(clip, seq)
    extra = ["--epochs", "2", "--set", "finetune.lr=1e-3"]
    out = subprocess.run(_adapt_cmd(ref, tiny, *extra), capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    rng = random.Random(os.getpid())
    pred, work = f"{seq}.pred", f"{seq}.adapt"
    # killed while predicting the base frames, then after the labels exist
    _kill_when(_adapt_cmd(seq, tiny, *extra), lambda: os.path.exists(f"{pred}/base.h5.partial"),
               rng, 0.3)
    _kill_when(_adapt_cmd(seq, tiny, *extra), lambda: _complete(f"{work}/labels.h5"), rng, 1.0)
    done = {"base": _complete(f"{pred}/base.h5"),
            "pseudo_labels": _complete(f"{work}/labels.h5"),
            "ft": _complete(f"{pred}/ft.h5"), "align": _complete(f"{pred}/ft-align.h5"),
            "scale": _complete(f"{pred}/ft-align-metric.h5")}
    assert done["base"] and done["pseudo_labels"]
    with SequenceReader(seq) as r:          # the sequence itself is never touched
        assert r.checksum_errors() == []
    out = subprocess.run(_adapt_cmd(seq, tiny, *extra), capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    s = _summary(seq)
    for stage, complete in done.items():
        if complete:
            assert stage in s["skipped_stages"] and s["stage_frames"][stage] == 0, stage
    a, b = _predictions(ref), _predictions(seq)
    for name in OUTPUTS:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert [r["loss"] for r in s["finetune"]] == [r["loss"] for r in _summary(ref)["finetune"]]
    assert not [f for f in os.listdir(pred) if ".partial" in f or ".tmp-" in f]


def test_a_late_setting_reruns_only_the_stages_after_it(tmp_path, clip, tiny, one_thread,
                                                        monkeypatch):
    from staticdepth.adapt import adapt
    from staticdepth.adaptation import checks
    from staticdepth.adaptation.config import build_config

    probes = []                         # the network's probe runs only while base is to make
    probe = checks.probe_model
    monkeypatch.setattr(checks, "probe_model", lambda *a: probes.append(probe(*a)))

    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    # align.mode ground: the default upright puts the anchor pixel on the plane, where the
    # anchor scale equals the plane's and could not tell which one was applied
    # (the untrained network does not see the ground: align.min_ground_r2 0 aligns it anyway)
    base = {"model": f"builtin:{tiny}", "detector.name": "gt", "finetune.epochs": 1,
            "tracking.min_height_px": 3, "plane.bootstrap": 0, "align.mode": "ground",
            "align.min_ground_r2": 0.0}
    lines: list[str] = []
    s1 = adapt(seq, build_config(base), log=lines.append)
    assert s1["skipped_stages"] == ["agents"]                 # gt: the sequence's own
    # a first run said 'agents: up to date, skipped' of a stage it never ran
    assert ("agents: the sequence's own instance maps are the agents (detector gt), skipped"
            in lines) and not any("up to date" in ln for ln in lines), lines
    # plane.bootstrap 0 with enough tracks: said as such, not as 'fewer than 3 inlier tracks'
    assert any("its uncertainty was not measured (plane.bootstrap=0)" in ln for ln in lines)
    assert ("warning: metric depth unverified: the ground plane's uncertainty was not measured "
            "(plane.bootstrap=0)") in lines and not any("fewer than 3" in ln for ln in lines)
    first = _predictions(seq)
    s2 = adapt(seq, build_config({**base, "scale.metric_scale": "anchor"}), log=lambda m: None)
    assert set(s2["skipped_stages"]) == {"base", "agents", "pseudo_labels", "finetune", "ft",
                                         "ground_plane", "align"}
    assert s2["stage_frames"]["scale"] == 40 and s2["stage_frames"]["base"] == 0
    assert probes == [True, False]
    now = _predictions(seq)
    for name in ("base", "ft", "align", "ft-align"):
        np.testing.assert_array_equal(now[name], first[name])
    k = s2["anchor_scale"]["ft-align"]
    assert s2["scale"]["ft-align"] == k != pytest.approx(s1["scale"]["ft-align"])
    np.testing.assert_allclose(now["ft-align-metric"], first["ft-align"] * np.float32(k),
                               rtol=1e-6)
    s3 = adapt(seq, build_config({**base, "scale.metric_scale": "anchor", "align.erode_px": 3}),
               log=lambda m: None)
    # the default (aligned) pseudo labels are the alignment: they, the fine-tuning and ft follow it
    assert set(s3["skipped_stages"]) == {"base", "agents", "ground_plane"}
    assert s3["stage_frames"]["align"] == 40 and s3["stage_frames"]["pseudo_labels"] == 24


def test_an_interrupted_run_leaves_no_saved_model_and_resumes(tmp_path, clip, tiny, one_thread,
                                                              monkeypatch, capsys):
    # --save-model was written right after fine-tuning: a run interrupted in align left the
    # file, and its resume was refused ("exists already; pass --overwrite")
    from staticdepth.adaptation import align
    from staticdepth.models.tiny import load_builtin

    seq, model = str(tmp_path / "s.h5"), tmp_path / "ft.pt"
    shutil.copy(clip, seq)
    argv = ["adapt", seq, "--model", f"builtin:{tiny}", *FAST, "--epochs", "1",
            "--set", "align.min_ground_r2=0", "--save-model", str(model)]

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(align, "run", interrupted)
        assert main(argv) == 130
    assert not model.exists() and not os.path.exists(tmp_path / "s.adapt.json")
    capsys.readouterr()
    assert main(argv) == 0, capsys.readouterr().err
    s = _summary(seq)
    assert {"finetune", "ft", "base"} <= set(s["skipped_stages"])     # resumed, not redone
    tuned, first = load_builtin(str(model)), load_builtin(tiny)
    moved = [not torch.equal(a, b) for a, b in zip(tuned.net.state_dict().values(),
                                                    first.net.state_dict().values())]
    assert any(moved)                          # the fine-tuned weights, not the initial ones


def test_the_plane_gate_is_kept_in_the_summary_and_said_on_every_run(tmp_path, clip, tiny,
                                                                     one_thread, capsys):
    # the gate's warning was printed only by the ground_plane stage: a rerun that skipped the
    # stage, and the summary, said nothing of a plane too uncertain for alignment
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    argv = ["adapt", seq, "--model", f"builtin:{tiny}", *FAST, "--set", "plane.bootstrap=5",
            "--epochs", "1", "--set", "align.min_ground_r2=0"]
    for run in range(2):
        capsys.readouterr()
        assert main(argv + (["--overwrite"] if run else [])) == 0
        out = capsys.readouterr().out
        gate = _summary(seq)["plane_gate"]
        assert gate["ok"] is False and gate["normal_std_deg"] > gate["max_normal_std_deg"]
        assert f"warning: {gate['message']}; adapt went on with it" in out
        # not "refused" while going on with it
        assert gate["message"].startswith("ground plane too uncertain: ")
    assert "ground_plane" in _summary(seq)["skipped_stages"]


def test_dotted_settings_and_fail_fast(tmp_path, clip, tiny, capsys):
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    cases = [(["--set", "min_height_px=8"], "did you mean 'tracking.min_height_px'?"),
             (["--set", "tracking.min_heigt_px=8"], "did you mean 'tracking.min_height_px'?"),
             (["--set", "detector_model=x.onnx"], "did you mean 'detector.model'?"),
             (["--epochs", "-1"], "finetune.epochs must be a finite number >= 0, got -1"),
             (["--camera-height", "0"], "--camera-height must be a height in metres in "
                                         "(0, 1000], got 0.0"),
             (["--camera-height", "-2"], "--camera-height must be a height in metres in "
                                          "(0, 1000], got -2.0"),
             (["--camera-height", "5000"], "--camera-height must be a height in metres in "
                                            "(0, 1000], got 5000.0"),
             (["--camera-height", "nan"], "--camera-height must be a height in metres in "
                                           "(0, 1000], got nan"),
             (["--set", "finetune.layers=neck"], "has no layer group 'neck'"),
             (["--detector", "yolox"], "weights were not found"),
             (["--set", "detector.name=yolo"], "unknown detector 'yolo'"),
             (["--summary", str(tmp_path / "no" / "s.json")], "folder of the summary"),
             (["--set", "tracking.min_score=1.5"],
              "tracking.min_score must be a finite number within 0..1, got 1.5"),
             (["--set", "tracking.min_height_px=64"], "not below the image height (64 px)"),
             (["--set", "tracking.min_frames=25"], "the adaptation split's 24 frames")]
    for argv, message in cases:
        rc = main(["adapt", seq, "--model", f"builtin:{tiny}", "--device", "cpu", *argv])
        err = capsys.readouterr().err
        assert rc == 2 and message in err and err.count("\n") == 1, (argv, err)
    assert not os.path.exists(seq + ".pred")          # nothing was predicted
    assert main(["adapt", "--print-config", "--set", "tracking.min_height_px=8"]) == 0
    assert "  min_height_px: 8.0\n" in capsys.readouterr().out


def _tree_bytes(*folders):
    return sum(os.path.getsize(os.path.join(d, f)) for folder in folders
               for d, _, fs in os.walk(folder) for f in fs)


def test_disk_space_is_checked_before_any_prediction(tmp_path, clip, tiny, capsys, monkeypatch,
                                                     one_thread):
    from staticdepth.adaptation import checks
    from staticdepth.adaptation.common import Workspace
    from staticdepth.adaptation.config import build_config, model_identity, stage_hashes
    from staticdepth.models import load_model

    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    settings = {"model": f"builtin:{tiny}", "detector.name": "gt", "finetune.epochs": 1,
                "tracking.min_height_px": 3, "plane.bootstrap": 0}

    def need(extra=None):
        conf = build_config({**settings, **(extra or {})})
        model = load_model(conf.model)
        return checks.output_bytes(conf, Workspace(seq, log=lambda m: None),
                                   stage_hashes(conf, model_identity(conf.model)), model), model

    (total, maps), model = need()
    # 40 frames x (6 predictions + the base inverse depth) + 24 labels, float32 at 128x64, and
    # the checkpoint: the weights and Adam's two moments
    assert maps == 40 * 7 + 24
    raw = maps * 128 * 64 * 4 + 3 * 4 * sum(p.numel() for p in model.net.parameters())
    assert raw <= total <= raw + maps * 4 + 9 * 2**20
    argv = ["adapt", seq, "--model", f"builtin:{tiny}", *FAST, "--epochs", "1"]
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(total - 1))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "not enough free disk space" in err and f"{maps} maps of 128x64" in err
    assert err.count("\n") == 1 and str(tmp_path) in err
    assert not os.path.exists(seq + ".pred") and not os.path.exists(seq + ".adapt")
    monkeypatch.setattr(shutil, "disk_usage", disk_usage_with_free(total))
    assert main(argv) == 0
    capsys.readouterr()
    # the estimate bounds what was written (the maps are compressed), and nothing is left to do
    assert _tree_bytes(seq + ".pred", seq + ".adapt") <= total
    assert need()[0] == (0, 0)
    # a late setting: only the two metric maps are written again
    assert need({"scale.metric_scale": "anchor"})[0][1] == 2 * 40


def test_frames_left_counts_what_a_writer_would_still_write(tmp_path):
    from staticdepth.dataset.framefile import FrameFileWriter, frames_left

    path = str(tmp_path / "f.h5")
    assert frames_left(path, "seq", "h1", 10) == 10                 # nothing yet
    w = FrameFileWriter(path, n=10, shape=(4, 5), dtype=np.float32, identity="seq",
                        config_hash="h1", chunk=1)
    with pytest.raises(RuntimeError):          # stopped after 3 frames: the partial file stays
        with w:
            for i in range(3):
                w.write(i, np.full((4, 5), i, np.float32))
            raise RuntimeError("stop")
    assert frames_left(path, "seq", "h1", 10) == 7                  # resumed after 3 frames
    assert frames_left(path, "seq", "h2", 10) == 10                 # other settings: again
    assert frames_left(path, "other", "h1", 10) == 10               # another sequence
    with FrameFileWriter(path, n=10, shape=(4, 5), dtype=np.float32, identity="seq",
                         config_hash="h1") as w:
        assert w.start == 3
        for i in range(w.start, 10):
            w.write(i, np.full((4, 5), i, np.float32))
    assert frames_left(path, "seq", "h1", 10) == 0
    assert frames_left(path, "seq", "h2", 10) == 10                 # replaced only when done


def _unwritable_folder(tmp_path):
    """A folder where this process cannot create a file: a 0o500 folder, or for root (whom
    permissions do not stop) /sys when it refuses a file."""
    if os.geteuid() != 0:
        os.mkdir(tmp_path / "locked", 0o500)
        return str(tmp_path / "locked")
    try:
        os.close(os.open("/sys/staticdepth-probe", os.O_WRONLY | os.O_CREAT | os.O_EXCL))
        os.remove("/sys/staticdepth-probe")
    except OSError:
        return "/sys"
    pytest.skip("running as root and /sys accepts files: no folder to test an unwritable output")


def test_unwritable_outputs_fail_before_any_prediction(tmp_path, clip, tiny, capsys):
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    locked = _unwritable_folder(tmp_path)
    argv = ["adapt", seq, "--model", f"builtin:{tiny}", *FAST]
    for extra, what in ((["--summary", os.path.join(locked, "s.json")], "summary"),
                        (["--save-model", os.path.join(locked, "m.pt")], "saved model")):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err
        assert f"cannot write the {what} there" in err and err.count("\n") == 1, err
    assert not os.path.exists(seq + ".pred") and not os.path.exists(seq + ".adapt")


def test_a_network_without_layer_groups_trains_all_parameters():
    from staticdepth.adaptation.finetune import trainable_layers
    from staticdepth.errors import InputError
    from staticdepth.models import TorchDepthModel

    net = torch.nn.Conv2d(3, 1, 3, padding=1)
    assert trainable_layers(TorchDepthModel(net), "decoder") == "all"
    with pytest.raises(InputError, match="no layer group 'decoder'"):
        trainable_layers(TorchDepthModel(net, layer_groups={"head": ["weight"]}), "decoder")


def test_readme_config_tree_is_the_generated_one():
    from staticdepth.adaptation.config import AdaptConfig
    from staticdepth.config import format_config

    readme = open(os.path.join(os.path.dirname(__file__), "..", "README.md")).read()
    start = readme.index("<!-- adapt --print-config -->")
    block = readme[start:].split("```text\n", 1)[1].split("```", 1)[0]
    assert block == format_config(AdaptConfig()) + "\n"
