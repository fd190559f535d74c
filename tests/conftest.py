"""Shared fixtures: the real test data beside the repository, and small helpers."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("STATICDEPTH_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (or $STATICDEPTH_DATA); skips with a reason when it is absent."""
    d = shared_data_dir()
    if not d.is_dir():
        pytest.skip(f"real test data not found at {d} (set STATICDEPTH_DATA)")
    return d


def vtest_frames(shared_data: Path, step: int, n_frames: int | None = None):
    """Every ``step``-th RGB frame of the real video vtest.avi (of its first ``n_frames``, each of
    which must be readable; else of all) and the YOLOX-nano ONNX path; skips when either is
    absent."""
    import cv2

    video = shared_data / "video" / "vtest.avi"
    model = shared_data / "models" / "yolox_nano" / "yolox_nano.onnx"
    for p in (video, model):
        if not p.exists():
            pytest.skip(f"{p} not found")
    cap = cv2.VideoCapture(str(video))
    frames, i = [], 0
    while n_frames is None or i < n_frames:
        ok, f = cap.read()
        if not ok:
            assert n_frames is None, f"cannot read frame {i} of {video}"
            break
        if i % step == 0:
            frames.append(np.ascontiguousarray(f[..., ::-1]))
        i += 1
    return frames, model


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def trained_builtin(request, tmp_path_factory, train_args: list[str]) -> Path:
    """Built-in network weights from ``staticdepth train-builtin`` with ``train_args`` (seeded).

    pytest's cache folder keeps them between runs (keyed by the arguments); without the cache
    plugin (``-p no:cacheprovider``) they are trained into this session's temporary folder."""
    from staticdepth.cli import main
    from staticdepth.config import config_hash

    cache = getattr(request.config, "cache", None)
    folder = (cache.mkdir("staticdepth-builtin") if cache is not None
              else tmp_path_factory.mktemp("staticdepth-builtin"))
    path = folder / f"builtin-{config_hash(train_args)}.pt"
    if not path.exists():
        assert main(["train-builtin", "--out", str(path), "--device", "cpu", *train_args]) == 0
    return path


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread (``pytestmark = pytest.mark.usefixtures("one_thread")``, or requested):
    reproducible reductions, bit-exact in a subprocess too, and no oversubscription of a shared
    CPU."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def disk_usage_with_free(free: int):
    """A stand-in for ``shutil.disk_usage`` that reports ``free`` bytes free (the disk checks of
    adapt and synth, tested at their edge)."""
    import shutil

    real = shutil.disk_usage

    def fake(path):
        u = real(path)
        return type(u)(u.total, u.total - free, free)
    return fake
