"""Kill every long writer (SIGKILL, SIGTERM) at a random frame, resume, and compare the result with
an uninterrupted run: identical datasets, and the resumed run wrote only the missing frames."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import cv2
import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader, SequenceWriter

CLI = "import sys; from staticdepth.cli import main; sys.exit(main(sys.argv[1:]))"
KITTI_DATE, KITTI_DRIVE = "2011_09_26", "2011_09_26_drive_sample"


# -- inputs (built once) -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    from conftest import shared_data_dir
    from staticdepth.dataset.synth import SyntheticScene, preset
    from staticdepth.dataset.synth.carla_export import write_carla_export

    d = tmp_path_factory.mktemp("inputs")
    scene = SyntheticScene(preset("demo", width=192, height=96, seed=1))
    rec = d / "rec"
    for sub in ("left", "right"):
        (rec / sub).mkdir(parents=True)
    for i in range(24):
        fr = scene.render(i)
        cv2.imwrite(str(rec / "left" / f"{i:04d}.png"), fr["left"][..., ::-1])
        cv2.imwrite(str(rec / "right" / f"{i:04d}.png"), fr["right"][..., ::-1])
    scene.rig.save(rec / "rig.json")
    write_carla_export(SyntheticScene(preset("demo", width=160, height=80, seed=2)),
                       d / "carla", n_frames=24)
    kitti = None
    src = shared_data_dir() / "kitti_raw" / KITTI_DATE
    if src.is_dir():  # four "drives", each the real 3-frame sample (symlinked)
        kitti = d / "kitti"
        (kitti / KITTI_DATE).mkdir(parents=True)
        for n in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
            os.symlink(src / n, kitti / KITTI_DATE / n)
        for k in range(4):
            shutil.copytree(src / (KITTI_DRIVE + "_sync"),
                            kitti / KITTI_DATE / f"{KITTI_DATE}_drive_{k:04d}_sync",
                            copy_function=os.symlink)
    return {"rec": rec, "carla": d / "carla", "kitti": kitti}


def writer_args(kind: str, inputs, out) -> tuple[list[str], int]:
    """The command line of writer ``kind`` writing ``out``, and its frame count."""
    if kind == "synth":
        return ["synth", "--frames", "40", "--set", "width=160", "--set", "height=80",
                "--out", str(out)], 40
    if kind == "pack":
        rec = inputs["rec"]
        return ["pack", "--recording", str(rec), "--rig", str(rec / "rig.json"),
                "--adapt-frames", "4", "--set", "num_disparities=32", "--out", str(out)], 24
    if kind == "stereo":
        rec = inputs["rec"]
        return ["stereo", "--recording", str(rec), "--rig", str(rec / "rig.json"), "--name", "s",
                "--max-disparity", "32", "--out", str(out)], 24
    if kind == "import-carla":
        return ["import-carla", str(inputs["carla"]), "--adapt-frames", "3", "--name", "c",
                "--out", str(out)], 24
    if kind == "import-kitti":
        if inputs["kitti"] is None:
            pytest.skip("KITTI sample not found (set STATICDEPTH_DATA)")
        drives = [f"{KITTI_DATE}_drive_{k:04d}" for k in range(4)]
        return ["import-kitti", "--root", str(inputs["kitti"]), "--drives", *drives,
                "--name", "k", "--out", str(out)], 12
    raise ValueError(kind)


# -- helpers --------------------------------------------------------------------------------------
# The partial is read while another process writes it. HDF5 has no reader for a file being
# written (no SWMR here): a read that meets half-written metadata may crash the reading process
# (pytest itself died of a segfault here on a loaded machine), so the reads run in a child
# process: one line in, the partial's frame count out (-1 while it cannot be read); a reader
# that died is started again.
POLL = ("import sys, h5py\n"
        "for _ in sys.stdin:\n"
        "    try:\n"
        "        with h5py.File(sys.argv[1], 'r', locking=False) as f:\n"
        "            n = int(f.attrs['n_written'])\n"
        "    except Exception:\n"
        "        n = -1\n"
        "    print(n, flush=True)\n")


class FrameCounter:
    """The frame count of a partial being written, read in a child process (see POLL)."""

    def __init__(self, partial: str):
        self.partial, self.proc = partial, None

    def __call__(self) -> int:
        if self.proc is None or self.proc.poll() is not None:
            self.close()
            self.proc = subprocess.Popen([sys.executable, "-c", POLL, self.partial],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=subprocess.DEVNULL, text=True)
        try:
            self.proc.stdin.write("\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        except BrokenPipeError:             # the reader died on the previous read
            return -1
        return int(line) if line.strip() else -1        # "": it died on this one

    def close(self) -> None:
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()
            for pipe in (self.proc.stdin, self.proc.stdout):
                try:
                    pipe.close()
                except BrokenPipeError:
                    pass
            self.proc = None


def run_and_kill(args: list[str], partial: str, sig: int, at: int, timeout: float = 300):
    """Run the CLI in a subprocess, wait until the partial holds ``at`` complete frames, send
    ``sig``; (0, stderr) when the writer completed before the signal reached it.

    A count the reader sees may belong to a frame still being flushed (the counter is written
    with the frame's data, in no set order), so ``at`` frames are complete once it reads
    ``at + 1``: the flush of frame ``at`` starts after frame ``at - 1``'s ended. Waiting for
    ``at`` only, a SIGKILL in that flush had the resume keep ``at - 1`` frames, rightly."""
    proc = subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    frames_written = FrameCounter(partial)
    t0 = time.monotonic()
    try:
        while frames_written() < at + 1:
            if proc.poll() is not None:
                if proc.returncode == 0:   # done before we looked (a loaded machine): retried
                    return 0, proc.stderr.read()
                pytest.fail(f"the writer ended before frame {at}: {proc.stderr.read()}")
            if time.monotonic() - t0 > timeout:
                pytest.fail("the writer made no progress")
            time.sleep(0.005)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        frames_written.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


def assert_same_sequence(a, b) -> None:
    """Every dataset and every root attribute equal (except the run's own bookkeeping)."""
    def datasets(f):
        out = {}
        f.visititems(lambda k, v: out.__setitem__(k, v[()]) if isinstance(v, h5py.Dataset)
                     else None)
        return out

    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        da, db = datasets(fa), datasets(fb)
        assert sorted(da) == sorted(db)
        for k in da:
            if da[k].dtype.names:
                assert da[k].tobytes() == db[k].tobytes(), k
            else:
                np.testing.assert_array_equal(da[k], db[k], err_msg=k)
        skip = {"created", "resumed_after", "attrs_crc32"}  # the last covers the first two
        assert {k for k in fa.attrs if k not in skip} == {k for k in fb.attrs if k not in skip}
        for k in fa.attrs:
            if k not in skip:
                assert str(fa.attrs[k]) == str(fb.attrs[k]), k
        for k in ("timestamps", "agents"):
            assert fa[k].attrs["crc32"] == fb[k].attrs["crc32"]


WRITERS = ["synth", "pack", "stereo", "import-carla", "import-kitti"]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
@pytest.mark.parametrize("kind", WRITERS)
def test_killed_writer_resumes_to_the_uninterrupted_result(kind, sig, inputs, tmp_path,
                                                           monkeypatch, capsys):
    ref = tmp_path / "ref.h5"
    out = tmp_path / "out.h5"
    args, n = writer_args(kind, inputs, out)
    at = random.Random(f"{kind}{sig}").randint(1, n // 2)
    for _ in range(5):
        rc, err = run_and_kill(args, str(out) + ".partial", sig, at)
        if rc != 0:
            break
        # the writer finished its few frames (or was in close(), where a signal waits for the
        # end by design) before the signal reached it: a loaded machine; that run is complete
        assert out.exists(), err
        out.unlink()
    else:
        pytest.fail("the writer finished before the signal in 5 runs")
    assert not out.exists() and os.path.exists(str(out) + ".partial")
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
    else:  # SIGTERM: the partial is closed cleanly and the user told how to continue
        assert rc == 128 + signal.SIGTERM, err
        assert "terminated (SIGTERM)" in err and "--resume" in err
    # without --resume the partial is neither resumed nor thrown away
    assert main(args) == 2
    assert "--resume continues it" in capsys.readouterr().err
    assert os.path.exists(str(out) + ".partial")
    appended = []
    real = SequenceWriter.append

    def counting(self, **kw):
        appended.append(self.n)
        return real(self, **kw)

    monkeypatch.setattr(SequenceWriter, "append", counting)
    assert main(args + ["--resume"]) == 0
    text = capsys.readouterr().out
    with h5py.File(out, "r") as f:
        resumed = f.attrs["resumed_after"]
    k = json.loads(resumed)[0]
    assert at <= k < n, (at, k)
    assert appended == list(range(k, n))  # only the missing frames were written
    assert str(k) in text
    monkeypatch.setattr(SequenceWriter, "append", real)
    ref_args, _ = writer_args(kind, inputs, ref)
    assert main(ref_args) == 0
    assert_same_sequence(out, ref)
    assert main(["verify", str(out)]) == 0


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killed_capture_keeps_its_complete_frames_and_packs(sig, tmp_path):
    """``capture`` records a live source, so it is not resumed: a killed recording keeps every
    frame committed before the kill (images exact) and is packed like a finished one."""
    from staticdepth.capture import layout
    from staticdepth.capture.sources.synthetic import SyntheticSource
    from staticdepth.geometry import Camera
    from staticdepth.geometry.camera import StereoRig

    rec = tmp_path / "rec"
    proc = subprocess.Popen([sys.executable, "-c", CLI, "capture", "--source", "synthetic",
                             "--size", "320x200", "--fps", "30", "--frames", "100000",
                             "--out", str(rec)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    at = random.Random(f"capture{sig}").randint(3, 12)
    csv = rec / "seg_0000" / "timestamps.csv"
    t0 = time.monotonic()
    try:
        while not (csv.exists() and csv.read_text().count("\n") > at):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < 120, "capture made no progress"
            time.sleep(0.02)
        proc.send_signal(sig)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    r = layout.read_recording(rec)
    n = len(r.frames)
    assert n >= at and [f.frame for f in r.frames] == list(range(n))
    assert r.status == ("recording" if sig == signal.SIGKILL else "stopped")
    src = SyntheticSource(320, 200)
    for f in r.frames:
        left, right = src.make_pair(f.frame)
        np.testing.assert_array_equal(cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED), left)
        np.testing.assert_array_equal(cv2.imread(str(f.right_path), cv2.IMREAD_UNCHANGED), right)
    cam = Camera.from_fov(320, 200, 70)
    StereoRig.rectified(cam, 0.1).save(tmp_path / "rig.json")
    out = tmp_path / "p.h5"
    assert main(["pack", "--recording", str(rec), "--rig", str(tmp_path / "rig.json"),
                 "--set", "num_disparities=32", "--out", str(out)]) == 0
    with SequenceReader(out) as s:
        assert len(s) == n
    assert main(["verify", str(out)]) == 0
