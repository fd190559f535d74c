"""The one atomic writer and the one output lock (staticdepth.fileio)."""
import os
import subprocess
import sys
import textwrap

import pytest

from staticdepth.errors import InputError
from staticdepth.fileio import (OutputLocked, atomic_path, atomic_write_text, exclusive_lock,
                                remove_stale_temporaries)


def test_atomic_write_replaces_only_on_success(tmp_path):
    out = tmp_path / "a.txt"
    atomic_write_text(out, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(out) as tmp:
            with open(tmp, "w") as f:
                f.write("half")
            raise RuntimeError("killed")
    assert out.read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["a.txt"]
    atomic_write_text(out, "new")
    assert out.read_text() == "new"


def test_atomic_write_onto_folder_is_one_error(tmp_path):
    with pytest.raises(InputError, match="is a folder"):
        atomic_write_text(tmp_path, "x")
    assert os.listdir(tmp_path) == []


def test_os_errors_become_one_line():
    import errno
    from staticdepth.fileio import os_error
    e = os_error(OSError(errno.ENOSPC, "No space left on device"), "/x/seq.h5")
    assert str(e) == "/x/seq.h5: no space left on the device"
    assert "read-only" in str(os_error(OSError(errno.EROFS, "ro"), "/x"))


def test_file_size_limit_keeps_previous_output(tmp_path):
    """A real EFBIG (RLIMIT_FSIZE) mid-write: one error, the old file intact, no temporary left."""
    out = tmp_path / "big.bin"
    out.write_bytes(b"old")
    code = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        from staticdepth.errors import InputError
        from staticdepth.fileio import atomic_write_bytes
        try:
            atomic_write_bytes({str(out)!r}, b"x" * 100000)
        except InputError as e:
            print(e); sys.exit(2)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 2 and "file too large" in r.stdout, r.stdout + r.stderr
    assert out.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["big.bin"]


def test_lock_refuses_a_second_process(tmp_path):
    out = tmp_path / "seq.h5"
    code = textwrap.dedent(f"""
        import sys
        from staticdepth.fileio import exclusive_lock, OutputLocked
        try:
            with exclusive_lock({str(out)!r}):
                pass
        except OutputLocked as e:
            print(e); sys.exit(3)
    """)
    with exclusive_lock(out):
        with exclusive_lock(out):  # re-entrant in one process
            r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 3 and f"pid {os.getpid()}" in r.stdout
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_lock_released_when_holder_is_killed(tmp_path):
    out = tmp_path / "seq.h5"
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import time
        from staticdepth.fileio import exclusive_lock
        with exclusive_lock({str(out)!r}):
            print('locked', flush=True); time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    with pytest.raises(OutputLocked):
        with exclusive_lock(out):
            pass
    p.kill(); p.wait()
    with exclusive_lock(out):
        pass


def test_stale_temporaries_removed(tmp_path):
    out = tmp_path / "seq.h5"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    stale = tmp_path / f"seq.h5.tmp-{dead}-pred"
    mine = tmp_path / f"seq.h5.tmp-{os.getpid()}-pred"
    stale.write_text("x"); mine.write_text("y")
    assert remove_stale_temporaries(out) == [str(stale)]
    assert mine.exists() and not stale.exists()


def test_write_image_is_the_one_image_writer(tmp_path):
    """RGB in, the file holds it (OpenCV's BGR stays inside); uint16 single channel written as it
    is; an image too big for the file-size limit: one error, the old file intact, nothing left."""
    import cv2
    import numpy as np

    from staticdepth.fileio import write_image

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)
    write_image(tmp_path / "a.png", rgb)
    assert np.array_equal(cv2.imread(str(tmp_path / "a.png"))[..., ::-1], rgb)
    d16 = rng.integers(0, 65536, (12, 20), dtype=np.uint16)
    write_image(tmp_path / "d.png", d16, fsync=False)
    assert np.array_equal(cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED), d16)
    with pytest.raises(InputError, match="cannot encode"):
        write_image(tmp_path / "x.notanimage", rgb)
    out = tmp_path / "big.png"
    out.write_bytes(b"old")
    code = textwrap.dedent(f"""
        import resource, signal, sys
        import numpy as np
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        from staticdepth.errors import InputError
        from staticdepth.fileio import write_image
        noise = np.random.default_rng(1).integers(0, 256, (200, 200, 3), dtype=np.uint8)
        try:
            write_image({str(out)!r}, noise)
        except InputError as e:
            print(e); sys.exit(2)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 2 and "file too large" in r.stdout, r.stdout + r.stderr
    assert out.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["a.png", "big.png", "d.png"]


def test_frames_are_listed_in_numeric_order_deterministically():
    """One frame order (sorted_frames): numbers by value, zero padding kept, any names ordered."""
    import random

    from staticdepth.fileio import sorted_frames

    assert sorted_frames(["10.png", "2.png", "1.png"]) == ["1.png", "2.png", "10.png"]
    padded = [f"{i:08d}.png" for i in (0, 9, 10, 99, 100, 12345)]
    assert sorted_frames(reversed(padded)) == padded                 # what capture writes
    assert sorted_frames(["d/f_10.png", "d/f_9.png", "d/f_007.png"]) == [
        "d/f_007.png", "d/f_9.png", "d/f_10.png"]                    # padded and unpadded mixed
    names = ["b.png", "a.png", "007.png", "7.png", "x2y10.png", "x2y9.png", "x.png", "A.png", ""]
    want = ["", "007.png", "7.png", "A.png", "a.png", "b.png", "x2y9.png", "x2y10.png", "x.png"]
    for seed in range(5):                                            # a total order: no ties
        random.Random(seed).shuffle(names)
        assert sorted_frames(names) == want


def test_no_lock_file_is_left_beside_an_output_that_was_not_made(tmp_path):
    """A refused, failed or interrupted run left OUT.lock beside an OUT that never existed."""
    out = tmp_path / "REL4"
    with pytest.raises(RuntimeError):
        with exclusive_lock(out):
            assert (tmp_path / "REL4.lock").exists()
            raise RuntimeError("refused")
    with pytest.raises(KeyboardInterrupt):
        with exclusive_lock(out):
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == []
    with exclusive_lock(out):                   # made: its (empty) lock file stays beside it
        out.mkdir()
    assert sorted(os.listdir(tmp_path)) == ["REL4", "REL4.lock"]
    assert (tmp_path / "REL4.lock").read_text() == ""


def test_a_lock_taken_on_a_removed_lock_file_is_not_kept(tmp_path, monkeypatch):
    """The race that removing lock files opens: B opens OUT.lock while A holds it, A ends (the
    file is removed while A still holds it), B then locks the removed file. B must notice and
    lock the file at the path, so that a third process C is refused while B holds it."""
    import fcntl

    out = tmp_path / "seq.h5"
    lock = str(out) + ".lock"
    with exclusive_lock(out):                                    # A
        stale = os.open(lock, os.O_RDWR)                         # B's open, before A ends
    assert not os.path.exists(lock)
    real_open = os.open
    calls = []

    def b_open(p, *a, **k):                                      # B's first open is that one
        if p == lock and not calls:
            calls.append(p)
            return stale
        return real_open(p, *a, **k)

    monkeypatch.setattr(os, "open", b_open)
    with exclusive_lock(out):                                    # B
        monkeypatch.setattr(os, "open", real_open)
        assert os.path.exists(lock)
        c = os.open(lock, os.O_RDWR)                             # C
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(c, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(c)
    assert calls and not os.path.exists(lock)


def test_stereo_lists_a_folder_and_a_glob_in_the_one_frame_order(tmp_path):
    """`stereo --left FOLDER` (and calibrate's board pairs) sorted names plainly: 1, 10, 2, so
    left and right pairs kept their pairing but the frames' order was not the capture's."""
    from staticdepth.stereo.io import expand_images

    for n in (1, 2, 10):
        (tmp_path / f"{n}.png").write_bytes(b"")
    want = [str(tmp_path / f"{n}.png") for n in (1, 2, 10)]
    assert expand_images(str(tmp_path)) == want
    assert expand_images(str(tmp_path / "*.png")) == want
