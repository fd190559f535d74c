"""Sequence file: round trip, crash safety, resume, verification of bad files."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset import schema
from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter, add_prediction
from staticdepth.errors import InputError
from staticdepth.geometry import Camera, Mounting, StereoRig

CAM = Camera.from_fov(64, 32, 90)


def _meta(adapt=2, **kw):
    return SequenceMeta(name="t", camera=CAM, gt_kind="synthetic", source="test",
                        adapt_frames=adapt, rig=StereoRig.rectified(CAM, 0.27),
                        mounting=Mounting.from_pitch_roll(5.0, 30.0), **kw)


def _frame(i, rng):
    depth = rng.uniform(1, 50, (32, 64)).astype(np.float32)
    depth[0, :i + 1] = np.nan
    return dict(left=rng.integers(0, 255, (32, 64, 3), dtype=np.uint8),
                right=rng.integers(0, 255, (32, 64, 3), dtype=np.uint8), depth=depth,
                instances=rng.integers(0, 5, (32, 64)).astype(np.uint16))


def _write(path, n=5, rng=None, **kw):
    rng = rng or np.random.default_rng(0)
    frames = [_frame(i, rng) for i in range(n)]
    with SequenceWriter(path, _meta(), streams=("left", "right", "depth", "instances"), **kw) as w:
        for i, fr in enumerate(frames):
            ag = schema.empty_agents(2)
            ag["instance_id"] = [1, 2]
            ag["class_id"] = [0, 2]
            ag["track_id"] = [10 + i, 20]
            w.append(timestamp=0.1 * i, agents=ag, **fr)
    return frames


def test_round_trip_with_attributes(tmp_path):
    p = tmp_path / "s.h5"
    frames = _write(p)
    with SequenceReader(p) as r:
        assert len(r) == 5 and r.streams() == ["left", "right", "depth", "instances"]
        for i in (4, 0, 2):  # random access
            fr = r.frame(i)
            for k in ("left", "right", "depth", "instances"):
                np.testing.assert_array_equal(fr[k], frames[i][k])
            assert fr["timestamp"] == pytest.approx(0.1 * i)
            assert list(fr["agents"]["track_id"]) == [10 + i, 20]
        assert r.split("adapt") == range(0, 2) and r.split("eval") == range(2, 5)
        assert r.meta.camera == CAM
        assert r.meta.rig.baseline_m == pytest.approx(0.27)
        assert r.meta.camera_height_m == 5.0
        assert r.meta.mounting.pitch_deg == pytest.approx(30.0)
        assert r.checksum_errors() == []
    with h5py.File(p) as f:  # one frame per chunk: reading frame i decodes frame i only
        assert f["left"].chunks == (1, 32, 64, 3) and f["depth"].chunks == (1, 32, 64)
    assert not os.path.exists(str(p) + ".partial")


def test_existing_output_is_not_overwritten_without_flag(tmp_path):
    p = tmp_path / "s.h5"
    _write(p)
    with pytest.raises(InputError, match="exists already; pass --overwrite"):
        _write(p)
    _write(p, n=3, overwrite=True)
    with SequenceReader(p) as r:
        assert len(r) == 3


def test_exception_keeps_previous_file_and_resume_finishes(tmp_path):
    p = tmp_path / "s.h5"
    _write(p, n=3)
    rng = np.random.default_rng(1)
    frames = [_frame(i, rng) for i in range(6)]
    with pytest.raises(RuntimeError):
        with SequenceWriter(p, _meta(), streams=("left", "right", "depth", "instances"),
                            overwrite=True) as w:
            for fr in frames[:4]:
                w.append(**fr)
            raise RuntimeError("killed")
    with SequenceReader(p) as r:  # the previous complete file is intact
        assert len(r) == 3
    with pytest.raises(InputError, match="incomplete"):
        SequenceReader(str(p) + ".partial")
    with SequenceWriter(p, _meta(), streams=("left", "right", "depth", "instances"),
                        overwrite=True, resume=True) as w:
        assert len(w) == 4
        for fr in frames[4:]:
            w.append(**fr)
    with SequenceReader(p) as r:
        assert len(r) == 6
        np.testing.assert_array_equal(r.left(5), frames[5]["left"])
        np.testing.assert_array_equal(r.depth(1), frames[1]["depth"])


KILL_SCRIPT = textwrap.dedent("""
    import sys, time, numpy as np
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
    from staticdepth.geometry import Camera
    cam = Camera.from_fov(320, 160, 90)
    meta = SequenceMeta(name="k", camera=cam, gt_kind="synthetic")
    w = SequenceWriter(sys.argv[1], meta, streams=("left", "depth"), overwrite=True)
    rng = np.random.default_rng(0)
    for i in range(100000):
        w.append(left=rng.integers(0, 255, (160, 320, 3), dtype=np.uint8),
                 depth=rng.uniform(1, 9, (160, 320)).astype(np.float32))
        if i == 3:
            print("writing", flush=True)
""")


def test_kill_during_write_leaves_previous_complete_file(tmp_path):
    p = tmp_path / "s.h5"
    _write(p, n=3)
    before = open(p, "rb").read()
    proc = subprocess.Popen([sys.executable, "-c", KILL_SCRIPT, str(p)], stdout=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b"writing"
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert open(p, "rb").read() == before  # untouched
    with SequenceReader(p) as r:
        assert len(r) == 3
    assert main(["inspect", str(p) + ".partial"]) == 2  # the partial file is rejected


def _corrupt(tmp_path, how):
    p = tmp_path / "s.h5"
    _write(p)
    if how == "truncated":
        data = open(p, "rb").read()
        open(p, "wb").write(data[: len(data) // 2])
    else:
        with h5py.File(p, "a") as f:
            if how == "missing_attr":
                del f.attrs["camera"]
            elif how == "wrong_shape":
                del f["depth"]
                f.create_dataset("depth", data=np.zeros((5, 31, 64), np.float32))
            elif how == "not_complete":
                f.attrs["complete"] = False
            elif how == "bad_format":
                f.attrs["format"] = "something/else"
            elif how == "bitflip":
                a = f["left"][1]
                a[0, 0, 0] ^= 1
                f["left"][1] = a
    return p


@pytest.mark.parametrize("how, match", [
    ("truncated", "not a readable HDF5 file"),
    ("missing_attr", "missing attribute 'camera'"),
    ("wrong_shape", "'depth' has shape"),
    ("not_complete", "incomplete sequence"),
    ("bad_format", "not a staticdepth sequence"),
])
def test_bad_files_give_clear_errors(tmp_path, capsys, how, match):
    p = _corrupt(tmp_path, how)
    with pytest.raises(InputError, match=match):
        SequenceReader(p)
    assert main(["inspect", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(p) in err[0]


def test_verify_detects_checksum_mismatch(tmp_path, capsys):
    p = _corrupt(tmp_path, "bitflip")
    assert main(["verify", str(p)]) == 2
    assert "left[1]: checksum mismatch" in capsys.readouterr().out
    good = tmp_path / "g.h5"
    _write(good)
    assert main(["verify", str(good)]) == 0


def test_add_prediction_and_its_checks(tmp_path):
    p = tmp_path / "s.h5"
    _write(p)
    maps = [np.full((32, 64), i, np.float32) for i in range(5)]
    add_prediction(p, "base", maps, attrs={"model": "x", "params": {"a": 1}})
    with SequenceReader(p) as r:
        assert r.predictions() == ["base"]
        np.testing.assert_array_equal(r.prediction("base", 3), maps[3])
        assert r.prediction_attrs("base")["model"] == "x"
        assert r.checksum_errors() == []
    with pytest.raises(InputError, match="has 4 frames, the sequence 5"):
        add_prediction(p, "short", maps[:4])
    with pytest.raises(InputError, match="shape"):
        add_prediction(p, "bad", [np.zeros((3, 3))] * 5)
    with SequenceReader(p) as r:  # failed additions left the file as it was
        assert r.predictions() == ["base"]
    assert [f for f in os.listdir(tmp_path) if "tmp" in f] == []


def test_writer_rejects_bad_frames(tmp_path):
    w = SequenceWriter(tmp_path / "s.h5", _meta(adapt=0), streams=("left", "depth"))
    with pytest.raises(InputError, match="shape"):
        w.append(left=np.zeros((10, 10, 3), np.uint8), depth=np.zeros((32, 64), np.float32))
    with pytest.raises(InputError, match="expected streams"):
        w.append(left=np.zeros((32, 64, 3), np.uint8))
    w.abort()
    with pytest.raises(InputError, match="adapt_frames"):
        SequenceMeta(name="t", camera=CAM, adapt_frames=-1)
    with pytest.raises(InputError, match="gt_kind"):
        SequenceMeta(name="t", camera=CAM, gt_kind="magic")


def test_aux_maps_and_attributes_round_trip_and_resume(tmp_path):
    p = tmp_path / "a.h5"
    masks = [np.random.default_rng(i).random((32, 64)) > 0.5 for i in range(4)]
    w = SequenceWriter(p, _meta(adapt=1), streams=("left",), aux={"ground": bool})
    w.append(left=np.zeros((32, 64, 3), np.uint8), aux={"ground": masks[0]})
    w.append(left=np.zeros((32, 64, 3), np.uint8), aux={"ground": masks[1]})
    w.set_attr("skipped", "[1]")
    with pytest.raises(InputError, match="expected aux maps"):
        w.append(left=np.zeros((32, 64, 3), np.uint8))
    w.abort()
    with pytest.raises(InputError, match="cannot resume"):
        SequenceWriter(p, _meta(adapt=1), streams=("left",), resume=True)
    with SequenceWriter(p, _meta(adapt=1), streams=("left",), aux={"ground": bool},
                        resume=True) as w:
        assert len(w) == 2 and w.get_attr("skipped") == "[1]"
        for m in masks[2:]:
            w.append(left=np.zeros((32, 64, 3), np.uint8), aux={"ground": m})
    with SequenceReader(p) as r:
        assert r.aux_names() == ["ground"]
        for i, m in enumerate(masks):
            np.testing.assert_array_equal(r.aux("ground", i), m)
        with pytest.raises(InputError, match="no aux map 'sky'"):
            r.aux("sky", 0)
