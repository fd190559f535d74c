"""Run a pure per-frame function over many frames: serially, in local processes, or on Ray.

Every executor has ``map(fn, items) -> iterator`` yielding ``fn(item)`` **in the order of items**,
keeping at most a bounded number of results in flight (memory stays flat over thousands of
frames). ``fn`` and the items must be picklable for the process and Ray executors (a module-level
function or a frozen dataclass instance with ``__call__``). The sequence file is assembled by one
writer in the calling process, so the output is identical whichever executor computed it.
"""
from __future__ import annotations

import collections
import contextlib
import multiprocessing
import os
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterator, Sequence

from staticdepth.errors import InputError

EXECUTORS = ("serial", "process", "ray")
#: the most workers a run may ask for (more than a machine has cores only queue and use memory)
MAX_WORKERS = 256


def check_workers(workers: int) -> None:
    """Before any work: the one ``--workers`` rule (every executor, serial included)."""
    if not 1 <= workers <= MAX_WORKERS:
        raise InputError(f"--workers must be within 1..{MAX_WORKERS} (local worker processes), "
                         f"got {workers}")


def _apply(fn: Callable[[Any], Any], x: Any) -> Any:
    return fn(x)


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Block SIGINT in this thread while worker processes may start: a started process inherits
    the mask (through ``exec``), so a Ctrl-C cannot reach a worker before :func:`init_worker`
    ignores it; this process receives it on leaving (a blocked signal waits, it is not lost)."""
    if not hasattr(signal, "pthread_sigmask"):  # Windows: no signal masks
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def init_worker(parent_pid: int) -> None:
    """Worker initializer: ignore SIGINT (Ctrl-C reaches the whole process group; the parent
    alone handles it, stops the pool and prints one line, so no worker prints a
    ``KeyboardInterrupt`` traceback) and :func:`die_with_parent`."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # discards one pending since the worker's start
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    die_with_parent(parent_pid)


def die_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this worker when its parent dies (also by SIGKILL), so that a
    killed ``pack --workers N`` leaves no processes behind.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; everywhere: a thread that exits the worker once
    its parent is gone (checked every 0.5 s).
    """
    import threading
    import time

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # died before the line above ran
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="die-with-parent").start()


class SerialExecutor:
    """In this process, one item after another."""

    name = "serial"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[Any]:
        for x in items:
            yield fn(x)

    def close(self) -> None:
        pass


class ProcessExecutor:
    """A pool of ``workers`` local processes (spawned, so no state leaks from the parent).

    Workers ignore SIGINT: on Ctrl-C the parent alone stops (its writer keeps the partial
    resumable) and :meth:`close` lets the workers finish their current frame and exit."""

    name = "process"

    def __init__(self, workers: int, window: int | None = None):
        check_workers(workers)
        self.workers = workers
        self.window = window or 2 * workers
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[Any]:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers,
                                             mp_context=multiprocessing.get_context("spawn"),
                                             initializer=init_worker,
                                             initargs=(os.getpid(),))
        pending: collections.deque = collections.deque()
        it = iter(items)
        for x in it:
            pending.append(self._submit(fn, x))
            if len(pending) >= self.window:
                break
        while pending:
            res = pending.popleft().result()
            for x in it:
                pending.append(self._submit(fn, x))
                break
            yield res

    def _submit(self, fn: Callable[[Any], Any], x: Any):
        with _sigint_deferred():  # submit starts the workers (spawn starts them on demand)
            return self._pool.submit(fn, x)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


class RayExecutor:
    """Ray tasks on an existing cluster (``address``) or a local Ray instance (``address=None``).

    Ray is an optional extra (``pip install ray``). One remote task per frame; results are fetched
    in frame order with at most ``window`` tasks in flight.
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None,
                 window: int | None = None):
        try:
            import ray
        except ImportError:
            raise InputError("--executor ray needs Ray: pip install ray") from None
        self._ray = ray
        self.address = address
        self._owns = False
        if not ray.is_initialized():
            kw: dict[str, Any] = {"address": address, "include_dashboard": False,
                                  "log_to_driver": False}
            if address is None:
                kw["num_cpus"] = workers or os.cpu_count() or 1
            try:
                ray.init(**kw)
            except ConnectionError as e:
                raise InputError(f"cannot connect to the Ray cluster at {address!r}: {e}") from None
            self._owns = True
        self.window = window or 2 * max(1, int(ray.available_resources().get("CPU", 1)))

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[Any]:
        ray = self._ray
        remote = ray.remote(_apply)
        fn_ref = ray.put(fn)  # shipped once, not with every task
        pending: collections.deque = collections.deque()
        it = iter(items)
        for x in it:
            pending.append(remote.remote(fn_ref, x))
            if len(pending) >= self.window:
                break
        while pending:
            res = ray.get(pending.popleft())
            for x in it:
                pending.append(remote.remote(fn_ref, x))
                break
            yield res

    def close(self) -> None:
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
            self._owns = False


def make_executor(kind: str = "serial", workers: int = 1, address: str | None = None):
    """The executor named ``kind`` (serial, process, ray); serial with workers > 1 is process."""
    check_workers(workers)
    if kind not in EXECUTORS:
        raise InputError(f"unknown executor {kind!r} (choose from {', '.join(EXECUTORS)})")
    if kind == "ray":
        return RayExecutor(address, workers=workers if workers > 1 else None)
    if address is not None:
        raise InputError("--address is only used with --executor ray")
    if kind == "process" or workers > 1:
        return ProcessExecutor(workers)
    return SerialExecutor()
