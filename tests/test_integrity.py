"""Data integrity: resume with other inputs, one writer per output, --overwrite of foreign outputs,
full disk / file-size limit / read-only folder, verify of every dataset, links out of the file,
pack's rectification check, workers that die with their parent, stale temporaries."""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time

import cv2
import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader

CLI = "import sys; from staticdepth.cli import main; sys.exit(main(sys.argv[1:]))"


def synth_args(out, frames=30, *extra):
    return ["synth", "--frames", str(frames), "--set", "width=160", "--set", "height=80",
            "--out", str(out), *extra]


def frames_written(partial) -> int:
    try:
        with h5py.File(partial, "r", locking=False) as f:
            return int(f.attrs["n_written"])
    except Exception:
        return -1


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from test_pack import render_recording

    d = tmp_path_factory.mktemp("rec")
    render_recording(d, 6, 192, 96)
    return d


def pack_args(rec, out, *extra):
    return ["pack", "--recording", str(rec), "--rig", str(rec / "rig.json"), "--set",
            "num_disparities=32", "--out", str(out), *extra]


# -- resume with other inputs or settings ------------------------------------------------------
def _interrupted_pack(rec, out, monkeypatch):
    """A pack run stopped (Ctrl-C) after frame 3: <out>.partial holds 3 frames."""
    from staticdepth.dataset import h5 as h5mod

    real = h5mod.SequenceWriter.append

    def stop_at_three(self, **kw):
        if self.n == 3:
            raise KeyboardInterrupt
        return real(self, **kw)

    monkeypatch.setattr(h5mod.SequenceWriter, "append", stop_at_three)
    assert main(pack_args(rec, out)) == 130
    monkeypatch.setattr(h5mod.SequenceWriter, "append", real)
    assert frames_written(str(out) + ".partial") == 3


def test_resume_with_other_inputs_or_settings_is_refused(recording, tmp_path, monkeypatch,
                                                         capsys):
    out = tmp_path / "p.h5"
    _interrupted_pack(recording, out, monkeypatch)
    partial = str(out) + ".partial"
    before = open(partial, "rb").read()
    # another recording (same frame names and sizes, other images): the mirrored scene, its
    # mirrored right view as the left (mirrored views alone would look swapped to pack)
    other = tmp_path / "other"
    for sub, src in (("left", "right"), ("right", "left")):
        (other / sub).mkdir(parents=True)
        for p in sorted((recording / src).iterdir()):
            img = cv2.imread(str(p))
            cv2.imwrite(str(other / sub / p.name), np.ascontiguousarray(img[:, ::-1]))
    (other / "rig.json").write_text((recording / "rig.json").read_text())
    capsys.readouterr()
    assert main(pack_args(other, out, "--resume")) == 2
    line = one_error_line(capsys)
    assert "cannot resume" in line and "provenance.recording" in line and "--restart" in line
    # the same recording with another setting
    assert main(pack_args(recording, out, "--resume", "--adapt-frames", "2")) == 2
    line = one_error_line(capsys)
    assert "adapt_frames: 0 in the partial, 2 now" in line
    # an input frame already packed was replaced
    img = recording / "left" / "0001.png"
    saved = img.read_bytes()
    stat = os.stat(img)
    try:
        img.write_bytes(saved)
        os.utime(img, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
        assert main(pack_args(recording, out, "--resume")) == 2
        assert "input frame 0001 changed" in one_error_line(capsys)
    finally:
        os.utime(img, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert open(partial, "rb").read() == before  # refusals leave the partial untouched
    # the same inputs and settings resume; --restart starts over
    assert main(pack_args(recording, out, "--resume")) == 0
    assert "resumed after frame 3" in capsys.readouterr().out
    assert main(pack_args(other, tmp_path / "q.h5")) == 0
    with SequenceReader(out) as a, SequenceReader(tmp_path / "q.h5") as b:
        assert not np.array_equal(a.left(0), b.left(0))


def test_synth_resume_with_other_settings_is_refused(tmp_path, capsys):
    out = tmp_path / "s.h5"
    proc = subprocess.Popen([sys.executable, "-c", CLI, *synth_args(out, 200)])
    while frames_written(str(out) + ".partial") < 2:
        assert proc.poll() is None
        time.sleep(0.01)
    proc.kill()
    proc.wait()
    assert main(synth_args(out, 200, "--resume", "--seed", "3")) == 2
    line = one_error_line(capsys)
    assert "cannot resume" in line and "seed: 0 in the partial, 3 now" in line
    assert main(synth_args(out, 20, "--resume")) == 2
    assert "frames: 200 in the partial, 20 now" in one_error_line(capsys)
    assert main(synth_args(out, 20, "--restart")) == 0
    with SequenceReader(out) as r:
        assert len(r) == 20 and "resumed_after" not in r.attrs


# -- one writer per output -------------------------------------------------------------------------
def test_second_writer_is_refused_and_the_first_finishes_intact(tmp_path, capsys):
    out = tmp_path / "s.h5"
    proc = subprocess.Popen([sys.executable, "-c", CLI, *synth_args(out, 60)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while frames_written(str(out) + ".partial") < 2:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        for extra in ([], ["--resume"], ["--restart"], ["--overwrite"]):
            assert main(synth_args(out, 60, *extra)) == 2
            line = one_error_line(capsys)
            assert f"pid {proc.pid}" in line and "is writing this file" in line
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert main(["verify", str(out)]) == 0
    assert main(synth_args(tmp_path / "ref.h5", 60)) == 0
    with SequenceReader(out) as a, SequenceReader(tmp_path / "ref.h5") as b:
        assert len(a) == 60
        for i in (0, 30, 59):
            np.testing.assert_array_equal(a.left(i), b.left(i))


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    from staticdepth.dataset.export import export_kitti

    seq = tmp_path / "s.h5"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    junk = tmp_path / f"s.h5.tmp-{dead.pid}-x"
    junk.write_bytes(b"0" * 1000)
    assert main(synth_args(seq, 3)) == 0
    assert not junk.exists()
    stale_dir = tmp_path / f"kitti.tmp-{dead.pid}-export"
    stale_dir.mkdir()
    (stale_dir / "a.png").write_bytes(b"x")
    mine = tmp_path / f"kitti.tmp-{os.getpid()}-other"  # a live process's: kept
    mine.mkdir()
    export_kitti(seq, tmp_path / "kitti")
    assert not stale_dir.exists() and mine.exists()


# -- --overwrite replaces only our own kind ------------------------------------------------------
def _tree(path):
    out = {}
    for d, _, names in os.walk(path):
        for n in names:
            out[os.path.relpath(os.path.join(d, n), path)] = open(os.path.join(d, n), "rb").read()
    return out


def test_overwrite_refuses_foreign_folders_and_files(tmp_path, capsys):
    seq = tmp_path / "s.h5"
    assert main(synth_args(seq, 3)) == 0
    foreign = tmp_path / "photos"
    (foreign / "2020").mkdir(parents=True)
    (foreign / "2020" / "me.jpg").write_bytes(b"precious")
    notes = tmp_path / "notes.txt"
    notes.write_text("precious")
    before = _tree(foreign)
    capsys.readouterr()
    for cmd in (["export", str(seq)], ["publish", str(seq)]):
        for target in (foreign, notes):
            assert main(cmd + ["--out", str(target), "--overwrite"]) == 2
            line = one_error_line(capsys)
            assert "left untouched" in line and str(target) in line
    assert _tree(foreign) == before and notes.read_text() == "precious"
    # a sequence output onto a file that is not a sequence
    assert main(synth_args(notes, 3, "--overwrite")) == 2
    assert "is not a readable HDF5 file" in one_error_line(capsys)
    assert main(synth_args(foreign, 3, "--overwrite")) == 2
    capsys.readouterr()
    assert notes.read_text() == "precious" and _tree(foreign) == before
    # our own outputs are replaced, only once the new one is complete
    assert main(["export", str(seq), "--out", str(tmp_path / "k")]) == 0
    assert main(["export", str(seq), "--out", str(tmp_path / "k"), "--overwrite"]) == 0
    assert main(["publish", str(seq), "--out", str(tmp_path / "rel")]) == 0
    assert main(["publish", str(seq), "--out", str(tmp_path / "rel"), "--overwrite"]) == 0
    assert main(["verify", str(tmp_path / "rel")]) == 0
    assert main(synth_args(seq, 4, "--overwrite")) == 0
    with SequenceReader(seq) as r:
        assert len(r) == 4


# -- full disk, file-size limit, read-only folder -------------------------------------------------
def _limited(limit_bytes):
    def pre():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return pre


def test_file_size_limit_one_line_previous_output_intact_then_resume(tmp_path, capsys):
    out = tmp_path / "s.h5"
    assert main(synth_args(out, 2)) == 0
    before = out.read_bytes()
    r = subprocess.run([sys.executable, "-c", CLI, *synth_args(out, 30, "--overwrite")],
                       preexec_fn=_limited(1_000_000), capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "file too large" in err[0] and "--resume" in err[0], err
    assert out.read_bytes() == before  # the previous output is intact
    k = frames_written(str(out) + ".partial")
    assert 0 < k < 30
    assert os.path.getsize(str(out) + ".partial") <= 1_000_000
    # after making room the resumed run equals an uninterrupted one
    assert main(synth_args(out, 30, "--overwrite", "--resume")) == 0
    assert f"resuming after frame {k}" in capsys.readouterr().out
    assert main(synth_args(tmp_path / "ref.h5", 30)) == 0
    with SequenceReader(out) as a, SequenceReader(tmp_path / "ref.h5") as b:
        for i in range(30):
            for s in ("left", "right", "depth", "instances"):
                np.testing.assert_array_equal(a.read(s, i), b.read(s, i))
        np.testing.assert_array_equal(a.timestamps(), b.timestamps())
    assert main(["verify", str(out)]) == 0


def test_file_size_limit_before_the_first_frame_leaves_nothing(tmp_path):
    out = tmp_path / "s.h5"
    r = subprocess.run([sys.executable, "-c", CLI, *synth_args(out, 30)],
                       preexec_fn=_limited(20_000), capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "file too large" in err[0] and "nothing was kept" in err[0], err
    assert not os.path.exists(str(out) + ".partial") and not out.exists()


# -- verify covers every dataset; links out of the file are refused --------------------------------
@pytest.mark.parametrize("dataset", ["timestamps", "agents", "aux/ground", "pred/base/depth",
                                     "left", "instances"])
def test_verify_detects_tampering_of_every_dataset(tmp_path, capsys, dataset):
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter, add_prediction
    from staticdepth.dataset import schema
    from staticdepth.geometry import Camera

    p = tmp_path / "s.h5"
    cam = Camera.from_fov(32, 16, 90)
    rng = np.random.default_rng(0)
    with SequenceWriter(p, SequenceMeta("t", cam), streams=("left", "depth", "instances"),
                        aux={"ground": bool}) as w:
        for i in range(3):
            ag = schema.empty_agents(2)
            ag["instance_id"] = [1, 2]
            w.append(left=rng.integers(0, 255, (16, 32, 3), dtype=np.uint8),
                     depth=rng.uniform(1, 9, (16, 32)).astype(np.float32),
                     instances=rng.integers(0, 3, (16, 32)).astype(np.uint16),
                     aux={"ground": rng.random((16, 32)) > 0.5}, agents=ag, timestamp=0.1 * i)
    add_prediction(p, "base", [np.full((16, 32), i + 1.0, np.float32) for i in range(3)])
    assert main(["verify", str(p)]) == 0
    # predictions live in their own file beside the sequence (dataset/predictions.py)
    target, key = ((f"{p}.pred/base.h5", "depth") if dataset == "pred/base/depth"
                   else (p, dataset))
    with h5py.File(target, "a") as f:
        ds = f[key]
        a = ds[()]
        if dataset == "agents":
            a["instance_id"][1] += 1
        elif a.dtype == bool:
            a[1, 0, 0] = ~a[1, 0, 0]
        elif a.dtype.kind == "f":
            a.flat[1] += 0.5
        else:
            a.flat[1] ^= 1
        ds[...] = a
    capsys.readouterr()
    assert main(["verify", str(p)]) == 2
    out = capsys.readouterr().out
    named = "pred/base" if dataset == "pred/base/depth" else dataset
    assert named in out and "checksum mismatch" in out


@pytest.mark.parametrize("what", ["depth", "left", "prediction"])
def test_commands_refuse_a_frame_that_does_not_match_its_checksum(tmp_path, capsys, what):
    # only verify and publish checked: evaluate, export and inspect --sheet used damaged
    # frames that still decoded (bytes changed inside a chunk)
    from staticdepth.dataset.h5 import add_prediction

    p = tmp_path / "s.h5"
    assert main(synth_args(p, 3)) == 0
    with SequenceReader(p) as r:
        n, shape = len(r), (r.height, r.width)
    add_prediction(p, "base", [np.full(shape, i + 1.0, np.float32) for i in range(n)])
    target, key = ((f"{p}.pred/base.h5", "depth") if what == "prediction" else (p, what))
    with h5py.File(target, "a") as f:
        a = f[key][n - 1]
        a.flat[5] = a.flat[5] + (0.5 if a.dtype.kind == "f" else 1)
        f[key][n - 1] = a
    runs = {"depth": [["evaluate", str(p)]], "prediction": [["evaluate", str(p)]],
            "left": [["export", str(p), "--out", str(tmp_path / "x")],
                     ["inspect", str(p), "--sheet", str(tmp_path / "s.png")]]}[what]
    for argv in runs:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"frame {n - 1} does not match its checksum" in err, err
    assert not (tmp_path / "x").exists() and not (tmp_path / "s.png").exists()


def test_legacy_dataset_without_checksum_is_not_covered(tmp_path, capsys):
    p = tmp_path / "s.h5"
    assert main(synth_args(p, 2)) == 0
    with h5py.File(p, "a") as f:
        del f["timestamps"].attrs["crc32"]
    capsys.readouterr()
    assert main(["verify", str(p)]) == 2
    assert "timestamps: not covered by a checksum" in capsys.readouterr().out


@pytest.mark.parametrize("attr,value", [("camera", None), ("camera_height_m", 9.9),
                                        ("name", "renamed")])
def test_verify_detects_changed_metadata(tmp_path, capsys, attr, value):
    # the camera, the split and the rest of the file's attributes have a checksum of their own
    p = tmp_path / "s.h5"
    assert main(synth_args(p, 3)) == 0
    with h5py.File(p, "a") as f:
        if value is None:                          # one digit of K, as a flipped byte would
            cam = json.loads(f.attrs[attr])
            cam["fx"] = cam["fx"] + 90.0
            f.attrs[attr] = json.dumps(cam)
        else:
            f.attrs[attr] = value
    capsys.readouterr()
    assert main(["verify", str(p)]) == 2
    assert "file attributes: checksum mismatch" in capsys.readouterr().out
    with h5py.File(p, "a") as f:                     # a file of an older version
        del f.attrs["attrs_crc32"]
    assert main(["verify", str(p)]) == 2
    assert "file attributes: not covered by a checksum" in capsys.readouterr().out


def test_damaged_headers_give_one_line_never_a_traceback(tmp_path, capsys):
    # single bytes flipped in the file's first 20 kB (its headers and attributes): h5py's
    # KeyError / RuntimeError there were tracebacks (10 of 60 flips); now exit 2 and one line,
    # or 0 where the byte was unused (the checksums then match)
    p = tmp_path / "s.h5"
    assert main(synth_args(p, 3)) == 0
    data = p.read_bytes()
    rng = np.random.default_rng(0)
    bad = tmp_path / "f.h5"
    codes = []
    for off in rng.integers(0, min(20_000, len(data)), 40):
        b = bytearray(data)
        b[int(off)] ^= 0x5A
        bad.write_bytes(bytes(b))
        for cmd in (["verify", str(bad)], ["inspect", str(bad)]):
            capsys.readouterr()
            rc = main(cmd)
            err = capsys.readouterr().err
            assert rc in (0, 2) and err.count("\n") <= 1, (int(off), cmd[0], err)
            codes.append(rc)
    assert codes.count(2) >= 10                # most flips hit something verify notices


def test_a_header_claiming_a_billion_agents_is_refused_unread(tmp_path, capsys):
    # a corrupted shape made verify allocate 90 GiB for the agents table
    p = tmp_path / "s.h5"
    assert main(synth_args(p, 2)) == 0
    with h5py.File(p, "a") as f:
        f["agents"].resize((1_500_000_000,))
    capsys.readouterr()
    assert main(["verify", str(p)]) == 2
    out = capsys.readouterr().out
    assert "agents: shape (1500000000,) claims" in out and "corrupt header" in out
    assert main(["inspect", str(p)]) == 2
    assert "corrupt header" in capsys.readouterr().err


@pytest.mark.parametrize("how", ["external_link", "external_storage", "virtual", "soft_link"])
def test_data_from_another_file_is_refused(tmp_path, capsys, how):
    p, other = tmp_path / "s.h5", tmp_path / "other.h5"
    assert main(synth_args(p, 2)) == 0
    assert main(synth_args(other, 2, "--seed", "5")) == 0
    with h5py.File(p, "a") as f:
        shape, dtype = f["left"].shape, f["left"].dtype
        del f["left"]
        if how == "external_link":
            f["left"] = h5py.ExternalLink(str(other), "/left")
        elif how == "soft_link":  # a soft link to an external link
            f["elsewhere"] = h5py.ExternalLink(str(other), "/left")
            f["left"] = h5py.SoftLink("/elsewhere")
        elif how == "external_storage":
            raw = tmp_path / "raw.bin"
            with SequenceReader(other) as r:
                raw.write_bytes(np.stack([r.left(i) for i in range(2)]).tobytes())
            f.create_dataset("left", shape=shape, dtype=dtype,
                             external=[(str(raw), 0, h5py.h5f.UNLIMITED)])
        else:
            layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
            layout[:] = h5py.VirtualSource(str(other), "left", shape=shape)
            f.create_virtual_dataset("left", layout)
    capsys.readouterr()
    assert main(["verify", str(p)]) == 2
    assert "refused" in capsys.readouterr().out
    assert main(["export", str(p), "--out", str(tmp_path / "k")]) == 2
    assert "refused" in one_error_line(capsys)
    assert not (tmp_path / "k").exists()


# -- pack checks rectification like stereo ------------------------------------------------------
def test_pack_refuses_a_rig_that_does_not_rectify(tmp_path, capsys):
    from staticdepth.dataset.synth import SyntheticScene, preset

    rec = tmp_path / "rec"
    scene = SyntheticScene(preset("demo", width=320, height=160, seed=1))
    for sub in ("left", "right"):
        (rec / sub).mkdir(parents=True)
    for i in range(2):
        fr = scene.render(i)
        cv2.imwrite(str(rec / "left" / f"{i:04d}.png"), fr["left"][..., ::-1])
        cv2.imwrite(str(rec / "right" / f"{i:04d}.png"), fr["right"][..., ::-1])
    rig = scene.rig.to_dict()
    rig["right"]["cy"] += 8.0  # a calibration 8 px off vertically: rows no longer agree
    rig["right"]["K"][1][2] += 8.0
    (rec / "rig.json").write_text(json.dumps(rig))
    assert main(pack_args(rec, tmp_path / "p.h5")) == 2
    assert "not rectified" in one_error_line(capsys)
    assert not os.path.exists(tmp_path / "p.h5.partial")
    scene.rig.save(rec / "rig.json")  # the true rig packs
    assert main(pack_args(rec, tmp_path / "p.h5")) == 0


# -- workers die with their parent ---------------------------------------------------------------
def _children(pid):
    kids = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        kids.append(int(d))
            except (OSError, IndexError, ValueError):
                pass
    return kids


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pack_workers_die_with_their_parent(recording, tmp_path):
    out = tmp_path / "p.h5"
    proc = subprocess.Popen([sys.executable, "-c", CLI,
                             *pack_args(recording, out, "--workers", "2")])
    try:
        t0 = time.monotonic()
        while len(_children(proc.pid)) < 2 and time.monotonic() - t0 < 120:
            assert proc.poll() is None
            time.sleep(0.05)
        kids = _children(proc.pid)
        assert len(kids) >= 2
    finally:
        proc.kill()
        proc.wait()
    t0 = time.monotonic()
    alive = kids
    while alive and time.monotonic() - t0 < 10:
        time.sleep(0.1)
        alive = [k for k in alive if os.path.exists(f"/proc/{k}")
                 and open(f"/proc/{k}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"]
    assert alive == [], "worker processes outlived their parent"


def test_disparity_out_keeps_the_previous_file_when_the_write_fails(tmp_path):
    from staticdepth.dataset.synth import SyntheticScene, preset

    fr = SyntheticScene(preset("demo", width=320, height=160, seed=1)).render(0)
    for side in ("left", "right"):
        cv2.imwrite(str(tmp_path / f"{side}.png"), fr[side][..., ::-1])
    out = tmp_path / "d.npy"
    out.write_bytes(b"the previous disparity")
    args = ["stereo", "--rectified", "--left", str(tmp_path / "left.png"), "--right",
            str(tmp_path / "right.png"), "--max-disparity", "32", "--disparity-out", str(out),
            "--overwrite"]
    r = subprocess.run([sys.executable, "-c", CLI, *args], preexec_fn=_limited(50_000),
                       capture_output=True, text=True)  # the new map (200 kB) does not fit
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "file too large" in err[0], err
    assert out.read_bytes() == b"the previous disparity"
    assert sorted(os.listdir(tmp_path)) == ["d.npy", "left.png", "right.png"]
    assert main(args) == 0
    assert np.load(out).shape == (160, 320)


@pytest.fixture
def interpreter_signal_handlers():
    """The handlers a Python program starts with, whatever the test runner inherited: a command
    started in the background by a shell without job control starts with SIGINT ignored, and
    the writer rightly leaves an ignored signal ignored."""
    old = {s: signal.signal(s, h) for s, h in ((signal.SIGTERM, signal.SIG_DFL),
                                               (signal.SIGINT, signal.default_int_handler))}
    yield
    for s, h in old.items():
        signal.signal(s, h)


@pytest.mark.parametrize("sig, exc", [(signal.SIGTERM, SystemExit), (signal.SIGINT,
                                                                      KeyboardInterrupt)])
@pytest.mark.usefixtures("interpreter_signal_handlers")
def test_a_signal_inside_an_hdf5_write_waits_for_the_frame(tmp_path, monkeypatch, sig, exc):
    """SIGTERM / Ctrl-C arriving inside HDF5's write call (our file object) must not break the
    file: it takes effect once the frame is complete, and the partial resumes."""
    from staticdepth.dataset import resume as rs
    from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
    from staticdepth.geometry import Camera

    p = tmp_path / "s.h5"
    cam = Camera.from_fov(64, 32, 90)
    frames = [np.full((32, 64, 3), i, np.uint8) for i in range(4)]
    real_write = rs.UndoableFile.write
    state = {"armed": False, "sent": 0}

    def write(self, b):
        if state["armed"] and not state["sent"]:
            state["sent"] = 1
            os.kill(os.getpid(), sig)  # the handler runs here, inside HDF5's flush
        return real_write(self, b)

    monkeypatch.setattr(rs.UndoableFile, "write", write)
    with pytest.raises(exc):
        with SequenceWriter(p, SequenceMeta("t", cam), streams=("left",)) as w:
            w.append(left=frames[0])
            state["armed"] = True
            w.append(left=frames[1])
            pytest.fail("the signal was lost")
    assert state["sent"] and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    monkeypatch.setattr(rs.UndoableFile, "write", real_write)
    with SequenceWriter(p, SequenceMeta("t", cam), streams=("left",), resume=True) as w:
        assert len(w) == 2  # the frame being written when the signal came was completed
        for fr in frames[2:]:
            w.append(left=fr)
    with SequenceReader(p) as r:
        assert r.checksum_errors() == []
        for i in range(4):
            np.testing.assert_array_equal(r.left(i), frames[i])


DISK_SCRIPT = r"""
import json, os, subprocess, sys
d, cli = sys.argv[1], sys.argv[2:]
def run(*args):
    r = subprocess.run([sys.executable, "-c", CLI, *args], capture_output=True, text=True)
    return {"rc": r.returncode, "err": r.stderr.strip().splitlines(), "out": r.stdout}
def synth(out, frames, *extra):
    return run("synth", "--frames", str(frames), "--set", "width=160", "--set", "height=80",
               "--out", out, *extra)
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1500k", "tmpfs", d], check=True)
out = os.path.join(d, "s.h5")
res = {"first": synth(out, 2)}
res["export"] = run("export", out, "--out", os.path.join(d, "k"))
def tree(p):
    return {os.path.join(a, n): open(os.path.join(a, n), "rb").read()
            for a, _, ns in os.walk(p) for n in ns}
before, export_before = open(out, "rb").read(), tree(os.path.join(d, "k"))
res["full"] = synth(out, 40, "--overwrite")
res["intact"] = open(out, "rb").read() == before
fd = os.open(os.path.join(d, "fill"), os.O_WRONLY | os.O_CREAT)  # what the failed frame freed
try:
    while True:
        os.write(fd, bytes(4096))
except OSError:
    os.close(fd)
res["export_full"] = run("export", out, "--out", os.path.join(d, "k"), "--overwrite")
res["export_intact"] = tree(os.path.join(d, "k")) == export_before
res["files"] = sorted(os.listdir(d))
os.remove(os.path.join(d, "fill"))
subprocess.run(["mount", "-o", "remount,size=16m", d], check=True)  # make room
res["resumed"] = synth(out, 40, "--overwrite", "--resume")
res["verify"] = run("verify", out)
subprocess.run(["mount", "-o", "remount,ro", d], check=True)
res["readonly"] = synth(os.path.join(d, "t.h5"), 3)
print(json.dumps(res))
""".replace("CLI", repr(CLI))


def test_full_disk_and_read_only_file_system(tmp_path):
    """A real full disk (a 1.5 MB tmpfs) and a real read-only file system, in a private mount
    namespace (needs root or user namespaces; skipped with the reason otherwise)."""
    import shutil as sh

    if sh.which("unshare") is None or subprocess.run(
            ["unshare", "-m", "mount", "-t", "tmpfs", "tmpfs", str(tmp_path)],
            capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs in a private mount namespace here")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    r = subprocess.run(["unshare", "-m", sys.executable, "-c", DISK_SCRIPT, str(mnt)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["first"]["rc"] == 0
    full = res["full"]
    assert full["rc"] == 2 and len(full["err"]) == 1, full
    assert "no space left on the device" in full["err"][0] and "--resume" in full["err"][0]
    assert res["intact"] and "s.h5.partial" in res["files"]
    assert res["export"]["rc"] == 0
    ex = res["export_full"]  # the disk is still full: the previous export stays as it was
    assert ex["rc"] == 2 and len(ex["err"]) == 1 and res["export_intact"], ex
    assert not [f for f in res["files"] if ".tmp-" in f or f.endswith(".undo")]
    assert res["resumed"]["rc"] == 0 and "resuming after frame" in res["resumed"]["out"]
    assert res["verify"]["rc"] == 0
    ro = res["readonly"]
    assert ro["rc"] == 2 and len(ro["err"]) == 1 and "read-only file system" in ro["err"][0], ro
