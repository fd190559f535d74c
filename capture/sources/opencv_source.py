"""UVC cameras through OpenCV: two cameras synchronised in software, or one side-by-side camera.

Two free-running cameras are read by one thread each; their frames are paired by nearest timestamp
(:class:`~staticdepth.capture.sync.NearestPairer`, tolerance half a frame period by default) and
every frame that finds no partner is counted in ``stats``. Timestamps are the host's monotonic
clock when ``grab()`` returned (``timestamps="host"``, works everywhere) or the driver's buffer
time from ``CAP_PROP_POS_MSEC`` (``"driver"``: V4L2's capture time, more precise, but only
comparable between cameras on backends that stamp with one clock).

Prefer raw pixel formats (YUYV, GREY): MJPG is a lossy codec; its artefacts reach stereo matching.
"""
from __future__ import annotations

import queue
import threading
import time
from typing import Any, Callable, Iterator

import cv2
import numpy as np

from staticdepth.capture.sources.base import SourceError, SourceLost, StereoFrame, StereoSource
from staticdepth.capture.sync import LEFT, RIGHT, NearestPairer
from staticdepth.geometry.camera import StereoRig

CaptureFactory = Callable[[Any], Any]  # cv2.VideoCapture-like: isOpened, set, get, grab, retrieve


def _open_camera(factory: CaptureFactory, device: int | str, width: int | None,
                 height: int | None, fps: float | None, fourcc: str | None,
                 exposure: float | None) -> Any:
    cap = factory(device)
    if cap is None or not cap.isOpened():
        raise SourceError(f"camera {device!r} does not open (is it connected, and not in use by "
                          f"another program?)")
    if fourcc:
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc))
    if width:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    if height:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    if fps:
        cap.set(cv2.CAP_PROP_FPS, fps)
    if exposure is not None:
        cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)   # V4L2: 1 = manual
        cap.set(cv2.CAP_PROP_EXPOSURE, exposure)
    got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    if width and height and got != (width, height):
        cap.release()
        raise SourceError(f"camera {device!r} delivers {got[0]}x{got[1]}, not the requested "
                          f"{width}x{height}")
    return cap


class _Reader(threading.Thread):
    """Reads one camera continuously into a shared queue as (side, t_s, image | exception)."""

    def __init__(self, cap: Any, side: int, out: queue.Queue, timestamps: str, grey: bool):
        super().__init__(name=f"uvc-reader-{side}", daemon=True)
        self.cap, self.side, self.out, self.timestamps, self.grey = cap, side, out, timestamps, grey
        self.stop = threading.Event()

    def run(self) -> None:
        try:
            while not self.stop.is_set():
                if not self.cap.grab():
                    self.out.put((self.side, None, SourceLost("camera stopped delivering frames")))
                    return
                t = time.monotonic()
                ok, img = self.cap.retrieve()
                if not ok or img is None:
                    self.out.put((self.side, None, SourceLost("camera returned an empty frame")))
                    return
                if self.timestamps == "driver":
                    t = float(self.cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
                if self.grey and img.ndim == 3:
                    img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                self.out.put((self.side, t, img))
        except Exception as e:  # noqa: BLE001 - a driver error is a lost camera
            self.out.put((self.side, None, SourceLost(f"camera error: {e}")))


class OpenCVStereoSource(StereoSource):
    """Two UVC cameras, paired by timestamp.

    left, right: camera indices or device paths (``/dev/video2``).
    tolerance_s: largest accepted time difference within a pair (default half a frame period).
    frame_timeout_s: a camera silent this long is lost (:class:`SourceLost`).
    capture_factory: ``cv2.VideoCapture`` (tests pass fake cameras).
    """

    kind = "uvc"

    def __init__(self, left: int | str = 0, right: int | str = 1, *, width: int | None = None,
                 height: int | None = None, fps: float = 30.0, fourcc: str | None = None,
                 exposure: float | None = None, grey: bool = True, timestamps: str = "host",
                 tolerance_s: float | None = None, frame_timeout_s: float = 2.0,
                 max_pending: int = 64, rig: StereoRig | None = None,
                 capture_factory: CaptureFactory = cv2.VideoCapture):
        super().__init__()
        if timestamps not in ("host", "driver"):
            raise SourceError(f"timestamps must be 'host' or 'driver', got {timestamps!r}")
        self.devices = (left, right)
        self.width, self.height, self.nominal_fps = width, height, float(fps)
        self.fourcc, self.exposure, self.grey, self.timestamps = fourcc, exposure, grey, timestamps
        self.tolerance_s = 0.5 / self.nominal_fps if tolerance_s is None else float(tolerance_s)
        self.frame_timeout_s, self.max_pending, self.rig = frame_timeout_s, max_pending, rig
        self._factory = capture_factory
        self._caps: list[Any] = []
        self._readers: list[_Reader] = []

    def open(self) -> None:
        try:
            for dev in self.devices:
                self._caps.append(_open_camera(self._factory, dev, self.width, self.height,
                                               self.nominal_fps, self.fourcc, self.exposure))
        except SourceError:
            self.close()
            raise

    def frames(self) -> Iterator[StereoFrame]:
        q: queue.Queue = queue.Queue()
        self._readers = [_Reader(c, side, q, self.timestamps, self.grey)
                         for side, c in zip((LEFT, RIGHT), self._caps)]
        for r in self._readers:
            r.start()
        pairer = NearestPairer(self.tolerance_s, self.max_pending)
        last = [time.monotonic()] * 2                 # arrival time of each side's last frame
        newest_t = [-float("inf")] * 2                # each side's newest timestamp
        lost: str | None = None
        dead: set[int] = set()
        try:
            while True:
                if dead:
                    # A camera is gone: keep reading the other one only until its frames are later
                    # than anything the lost camera could still pair with.
                    alive = {LEFT, RIGHT} - dead
                    if not alive or all(newest_t[a] > max(newest_t[d] for d in dead)
                                        + self.tolerance_s for a in alive):
                        break
                try:
                    side, t, item = q.get(timeout=min(0.1, self.frame_timeout_s))
                except queue.Empty:
                    side = None
                now = time.monotonic()
                if side is not None:
                    if t is None:
                        name = "left" if side == LEFT else "right"
                        lost = lost or f"{name} camera {self.devices[side]!r}: {item}"
                        dead.add(side)
                        continue
                    last[side], newest_t[side] = now, max(newest_t[side], t)
                    try:
                        pairs = pairer.push(side, t, item)
                    except ValueError:        # a camera's clock jumped back: drop that frame
                        pairer.unpaired[side] += 1
                        pairs = []
                    yield from self._emit(pairs, pairer)
                silent = [s for s in (LEFT, RIGHT)
                          if s not in dead and now - last[s] > self.frame_timeout_s]
                for s in silent:
                    name = "left" if s == LEFT else "right"
                    lost = lost or (f"{name} camera {self.devices[s]!r}: no frame for "
                                    f"{self.frame_timeout_s:.1f} s")
                    dead.add(s)
            yield from self._emit(pairer.flush(), pairer)
            raise SourceLost(lost)
        finally:
            self._stop_readers()

    def _emit(self, pairs, pairer: NearestPairer) -> Iterator[StereoFrame]:
        self.stats.unpaired_left, self.stats.unpaired_right = pairer.unpaired
        for left, right, tl, tr in pairs:
            self.stats.pairs += 1
            yield StereoFrame.at(left, right, tl, tr, self.stats.pairs - 1)

    def _stop_readers(self) -> None:
        for r in self._readers:
            r.stop.set()
        for r in self._readers:
            r.join(timeout=2.0)
        self._readers = []

    def close(self) -> None:
        self._stop_readers()
        for c in self._caps:
            c.release()
        self._caps = []

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "devices": [str(d) for d in self.devices],
                "width": self.width, "height": self.height, "fourcc": self.fourcc,
                "exposure": self.exposure, "grey": self.grey, "timestamps": self.timestamps,
                "tolerance_s": self.tolerance_s}


class SideBySideSource(StereoSource):
    """One UVC stereo camera that delivers both views in one frame (left half | right half)."""

    kind = "uvc-sbs"

    def __init__(self, device: int | str = 0, *, width: int | None = None,
                 height: int | None = None, fps: float = 30.0, fourcc: str | None = None,
                 exposure: float | None = None, grey: bool = True, timestamps: str = "host",
                 rig: StereoRig | None = None, capture_factory: CaptureFactory = cv2.VideoCapture):
        super().__init__()
        self.device, self.width, self.height, self.nominal_fps = device, width, height, float(fps)
        self.fourcc, self.exposure, self.grey, self.timestamps = fourcc, exposure, grey, timestamps
        self.rig, self._factory, self._cap = rig, capture_factory, None

    def open(self) -> None:
        self._cap = _open_camera(self._factory, self.device, self.width, self.height,
                                 self.nominal_fps, self.fourcc, self.exposure)

    def frames(self) -> Iterator[StereoFrame]:
        k = 0
        while True:
            if not self._cap.grab():
                raise SourceLost(f"camera {self.device!r} stopped delivering frames")
            t = time.monotonic()
            ok, img = self._cap.retrieve()
            if not ok or img is None:
                raise SourceLost(f"camera {self.device!r} returned an empty frame")
            if self.timestamps == "driver":
                t = float(self._cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
            if self.grey and img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            if img.shape[1] % 2:
                raise SourceLost(f"camera {self.device!r}: odd frame width {img.shape[1]} cannot "
                                 f"be split into two views")
            half = img.shape[1] // 2
            self.stats.pairs += 1
            yield StereoFrame(np.ascontiguousarray(img[:, :half]),
                              np.ascontiguousarray(img[:, half:]), t, t, t, k)
            k += 1

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), "device": str(self.device), "width": self.width,
                "height": self.height, "fourcc": self.fourcc, "exposure": self.exposure,
                "grey": self.grey, "timestamps": self.timestamps}
