"""A writer killed in the middle of a flush: the partial's undo journal puts it back as it was
after the last complete frame, so the resume neither crashes nor keeps a half-written frame.

Every write of one frame's append (and of the final close) is a kill point: a forked child writes
three frames, arms a hook that SIGKILLs it just before write ``j`` of the next step, and another
forked child resumes the partial (a crash there must not take pytest down)."""
from __future__ import annotations

import os
import signal

import h5py
import numpy as np
import pytest

from staticdepth.dataset import resume as rs
from staticdepth.dataset.h5 import SequenceMeta, SequenceReader, SequenceWriter
from staticdepth.geometry import Camera

W, H = 64, 32


def frame(i: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(i)
    return {"left": rng.integers(0, 255, (H, W, 3), dtype=np.uint8),
            "depth": rng.uniform(1, 80, (H, W)).astype(np.float32)}


def writer(out, **kw) -> SequenceWriter:
    return SequenceWriter(str(out), SequenceMeta("j", Camera.from_fov(W, H, 90)),
                          streams=("left", "depth"), **kw)


def in_child(fn) -> int:
    """Run ``fn`` in a forked child; its exit status (negative: killed by that signal)."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 70
        try:
            code = fn()
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def write_and_kill(out, phase: str, at: int | None) -> int:
    """Write frames 0-2, then frame 3 (``append``) or finish (``close``), killed before write
    ``at`` of that step (None: count its writes and exit with the count)."""
    def child() -> int:
        w = writer(out, restart=True)
        for i in range(3):
            w.append(**frame(i))
        count = [0]
        real = rs.UndoableFile.write

        def hooked(self, b):
            if count[0] == at:
                os.kill(os.getpid(), signal.SIGKILL)
            count[0] += 1
            return real(self, b)

        rs.UndoableFile.write = hooked
        if phase == "append":
            w.append(**frame(3))
        else:
            w.close()
        return count[0]
    return in_child(child)


def resume_and_check(out) -> int:
    """Resume, finish at 6 frames, verify: 10 + the frames the resume kept, 1 when the finished
    file differs from the frames written, 2 when the partial was renamed aside."""
    def child() -> int:
        warned = []
        w = writer(out, resume=True, warn=warned.append)
        k = len(w)
        for i in range(k, 6):
            w.append(**frame(i))
        w.close()
        if warned:
            return 2
        with SequenceReader(str(out)) as r:
            same = len(r) == 6 and not r.checksum_errors() and all(
                np.array_equal(r.left(i), frame(i)["left"]) for i in range(6))
        return 10 + k if same else 1
    return in_child(child)


@pytest.mark.parametrize("phase", ["append", "close"])
def test_a_kill_at_any_write_of_a_flush_resumes_to_the_last_complete_frame(tmp_path, phase):
    n_writes = write_and_kill(tmp_path / "count.h5", phase, None)
    assert n_writes >= 5, n_writes           # a flush is many writes: data, chunk index, header
    results = {}
    for j in range(n_writes):
        out = tmp_path / f"{phase}{j}.h5"
        assert write_and_kill(out, phase, j) == -signal.SIGKILL
        assert os.path.exists(str(out) + ".partial") and not out.exists()
        results[j] = resume_and_check(out)
        assert not os.path.exists(str(out) + ".partial" + rs.JOURNAL)
    # every kill point resumes after the 3 committed frames (a kill during close: the 3 frames
    # too, since the partial is renamed only after the close) and ends verified
    assert results == {j: 13 for j in range(n_writes)}


def _opened(tmp_path) -> tuple[str, rs.UndoableFile]:
    """A 100-byte file of "A", opened as a partial (its journal records the 100 bytes)."""
    p = str(tmp_path / "f.bin")
    with open(p, "wb") as f:
        f.write(b"A" * 100)
    return p, rs.UndoableFile(p, create=False)


def test_recover_journal_restores_bytes_and_size_and_ignores_a_cut_record(tmp_path):
    p, u = _opened(tmp_path)
    u.seek(10)
    u.write(b"B" * 20)                      # over committed bytes: journaled
    u.seek(100)
    u.write(b"C" * 50)                      # beyond the commit: undone by the size
    u.seek(15)
    u.write(b"D" * 5)                       # the same bytes again: the older record wins
    with open(p + rs.JOURNAL, "ab") as j:   # a record cut by the kill
        j.write(rs._REC.pack(0, 100, 0) + b"x" * 7)
    # killed here: the journal is on disk, nothing was committed
    os.close(u._j)
    u._j = None
    u._f.close()
    assert rs.recover_journal(p) == 2
    assert open(p, "rb").read() == b"A" * 100
    assert not os.path.exists(p + rs.JOURNAL)
    assert rs.recover_journal(p) == 0       # no journal: nothing to do


def test_a_commit_empties_the_journal_and_a_clean_close_removes_it(tmp_path):
    p, u = _opened(tmp_path)
    u.seek(0)
    u.write(b"B" * 10)
    assert os.path.getsize(p + rs.JOURNAL) > rs._HEAD.size
    u.commit()
    assert os.path.getsize(p + rs.JOURNAL) == rs._HEAD.size
    u.close()
    assert not os.path.exists(p + rs.JOURNAL)
    # a journal cut between emptying and its header (at a commit): the file stays as it is
    open(p + rs.JOURNAL, "wb").close()
    assert rs.recover_journal(p) == 0 and open(p, "rb").read() == b"B" * 10 + b"A" * 90


def test_an_aborted_writer_closes_cleanly_and_resumes(tmp_path):
    """abort() (an exception, SIGTERM) flushes, closes HDF5 and commits: no journal is left and
    the resume keeps every appended frame."""
    out = tmp_path / "a.h5"
    w = writer(out)
    for i in range(2):
        w.append(**frame(i))
    w.abort()
    assert not os.path.exists(str(out) + ".partial" + rs.JOURNAL)
    w = writer(out, resume=True)
    assert len(w) == 2
    w.append(**frame(2))
    w.close()
    assert not os.path.exists(str(out) + ".partial" + rs.JOURNAL)
    with h5py.File(out, "r") as f:
        assert int(f.attrs["n_frames"]) == 3


def test_a_frame_file_killed_in_a_flush_resumes_after_its_last_flushed_frame(tmp_path):
    """The prediction store's writer shares the partial's journal: killed before any write of
    frame 3's flush, it resumes at frame 3 (before, a SIGKILLed partial did not reopen and was
    written again from frame 0) and ends identical to an uninterrupted file."""
    from staticdepth.dataset.framefile import FrameFile, FrameFileWriter, frames_left

    def ff(path):
        return FrameFileWriter(str(path), n=6, shape=(H, W), dtype=np.float32, identity="s",
                               config_hash="h")

    def write_and_kill_ff(path, at):
        def child() -> int:
            count = [0]
            real = rs.UndoableFile.write

            def hooked(self, b):
                if at is not None and count[0] == at:
                    os.kill(os.getpid(), signal.SIGKILL)
                count[0] += 1
                return real(self, b)

            with ff(path) as w:
                for i in range(3):
                    w.write(i, frame(i)["depth"])
                count[0] = 0
                rs.UndoableFile.write = hooked
                w.write(3, frame(3)["depth"])
                os._exit(count[0])      # the count of frame 3's writes (never finished)
        return in_child(child)

    def resume(path) -> int:
        def child() -> int:
            with ff(path) as w:
                start = w.start
                for i in range(start, 6):
                    w.write(i, frame(i)["depth"])
            with FrameFile(str(path)) as r:
                same = all(np.array_equal(r[i], frame(i)["depth"]) for i in range(6))
            return 10 + start if same else 1
        return in_child(child)

    n_writes = write_and_kill_ff(tmp_path / "count.h5", None)
    assert n_writes >= 3, n_writes
    results = {}
    for j in range(n_writes):
        path = tmp_path / f"f{j}.h5"
        assert write_and_kill_ff(path, j) == -signal.SIGKILL
        pending = rs.journal_pending(str(path) + ".partial")   # writes since the commit
        assert frames_left(str(path), "s", "h", 6) == (6 if pending else 3)  # not read then
        results[j] = resume(path)
        assert not os.path.exists(str(path) + ".partial" + rs.JOURNAL)
    assert results == {j: 13 for j in range(n_writes)}
