"""Ctrl-C with ``--workers N``: the workers stay quiet (no ``KeyboardInterrupt`` tracebacks), the
parent prints its one ``interrupted`` line and the partial resumes to the uninterrupted result.

Ctrl-C sends SIGINT to the terminal's whole process group; here the command runs in its own
session and the signal goes to that group. The child starts with SIGINT at its default action
(a test runner started in the background may ignore SIGINT, and children inherit that)."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest

from test_crash_resume import CLI, FrameCounter, assert_same_sequence

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="reads worker processes from /proc")

# Idle workers: the window's results are in, the parent sleeps, the workers wait for work.
IDLE = ("import sys, time\n"
        "from staticdepth.dataset.executors import ProcessExecutor\n"
        "ex = ProcessExecutor(2)\n"
        "try:\n"
        "    it = ex.map(abs, range(-50, 0))\n"
        "    next(it)\n"
        "    print('ready', flush=True)\n"
        "    time.sleep(60)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', file=sys.stderr)\n"
        "    sys.exit(130)\n"
        "finally:\n"
        "    ex.close()\n")
# Starting workers: the signal comes while they start (import, unpickle the initializer).
STARTING = IDLE.replace("    next(it)\n    print('ready', flush=True)\n",
                        "    print('ready', flush=True)\n    next(it)\n")


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _popen(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_default_sigint)


def _workers(pid: int) -> list[int]:
    """Process ids of ``pid``'s spawned pool workers (not the resource tracker)."""
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{d}/cmdline", "rb") as f:
                cmd = f.read()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmd:
            out.append(int(d))
    return out


def _interrupt(proc: subprocess.Popen) -> tuple[int, str]:
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does: the whole process group
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


@pytest.mark.parametrize("script", [IDLE, STARTING], ids=["idle-workers", "starting-workers"])
def test_ctrl_c_leaves_the_workers_quiet(script):
    proc = _popen([sys.executable, "-c", script])
    assert proc.stdout.readline().strip() == "ready"
    t0 = time.monotonic()
    while len(_workers(proc.pid)) < 2:  # both spawned: a signal now reaches them too
        assert time.monotonic() - t0 < 60 and proc.poll() is None, proc.stderr.read()
        time.sleep(0.002)
    rc, err = _interrupt(proc)
    assert (rc, err) == (130, "interrupted\n")


def test_ctrl_c_on_import_kitti_with_workers_resumes(tmp_path):
    """The reported case: ``import-kitti --workers 2`` printed 2-4 worker tracebacks."""
    from conftest import shared_data_dir

    date, drive = "2011_09_26", "2011_09_26_drive_sample"
    src = shared_data_dir() / "kitti_raw" / date
    if not src.is_dir():
        pytest.skip("KITTI sample not found (set STATICDEPTH_DATA)")
    root = tmp_path / "kitti"
    (root / date).mkdir(parents=True)
    for n in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        os.symlink(src / n, root / date / n)
    drives = [f"{date}_drive_{k:04d}" for k in range(12)]  # 36 frames, each drive the sample
    for dv in drives:
        shutil.copytree(src / f"{drive}_sync", root / date / f"{dv}_sync",
                        copy_function=os.symlink)
    out = tmp_path / "kw.h5"
    args = ["import-kitti", "--root", str(root), "--drives", *drives, "--name", "k",
            "--out", str(out)]
    proc = _popen([sys.executable, "-c", CLI, *args, "--workers", "2"])
    frames_written = FrameCounter(f"{out}.partial")
    t0 = time.monotonic()
    try:
        while frames_written() < 2:
            assert proc.poll() is None, f"finished before the signal: {proc.stderr.read()}"
            assert time.monotonic() - t0 < 120
            time.sleep(0.005)
    finally:
        frames_written.close()
    rc, err = _interrupt(proc)
    # the partial and how to go on, then the one interrupted line (no worker traceback)
    assert rc == 130 and re.fullmatch(
        rf"note: {re.escape(str(out))}\.partial keeps the \d+ frame\(s\) written; the same "
        r"command with --resume continues it, --restart starts over\n"
        r"staticdepth import-kitti: interrupted\n", err), err
    assert not out.exists() and os.path.exists(f"{out}.partial")
    done = subprocess.run([sys.executable, "-c", CLI, *args, "--resume", "--workers", "2"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "wrote 36 frames" in done.stdout and "resumed after frame" \
        in done.stdout, done.stderr
    serial = subprocess.run([sys.executable, "-c", CLI, *args[:-1], str(tmp_path / "s.h5")],
                            capture_output=True, text=True, timeout=300)
    assert serial.returncode == 0, serial.stderr
    assert_same_sequence(out, tmp_path / "s.h5")
