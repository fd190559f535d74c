"""OAK devices and OAK-FFC camera modules through DepthAI v3 (``pip install depthai``, optional).

``depthai`` is imported lazily, so the toolkit works without it. The pipeline: two ``Camera`` nodes
(``Camera.build(socket, sensorFps=...)``), raw (not device-rectified, not undistorted) outputs from
``requestOutput``, paired by a host-side ``Sync`` node; exposure set through ``initialControl``.
The device's calibration is exported as the toolkit's :class:`StereoRig` (intrinsics scaled to the
output size, distortion, ``right_from_left`` extrinsics from calibration, not the board's spec
translation), so a custom 27 cm bar is described by what was measured, not by its drawing.

Testing status: this source has not been run on a real OAK device (none was available when it was
written). What the tests cover without hardware (tests/test_capture_depthai.py, depthai 3.12):
the sync-and-read path on a host-only pipeline (``dai.Pipeline(False)``) with a threaded host node
playing frames (``host_outputs=``); ``open()``'s device branch against a stand-in for the device
boundary (device search by id or name, ``readCalibration`` export, the ``Camera.build`` /
``requestOutput`` / exposure settings, checked against depthai's own signatures); the calibration
export from a real ``CalibrationHandler``; and the no-device error. Not covered: that a real device
accepts those settings (sensor modes, the FPS/size combination) and its real timing.
"""
from __future__ import annotations

import datetime
import os
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterator

import numpy as np

from staticdepth.capture.sources.base import SourceError, SourceLost, StereoFrame, StereoSource
from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig


def import_depthai():
    """``import depthai`` (3.x), or a :class:`SourceError` that says how to install it."""
    try:
        import depthai as dai
    except ImportError:
        raise SourceError("the DepthAI source needs the optional package depthai 3.x: "
                          "pip install 'staticdepth[depthai]' (or pip install depthai)") from None
    if not hasattr(dai.node, "Camera") or not hasattr(dai.node, "ThreadedHostNode"):
        raise SourceError(f"depthai {getattr(dai, '__version__', '?')} is not 3.x; "
                          "pip install 'depthai>=3'")
    return dai


@dataclass(frozen=True)
class DepthAIConfig:
    """Settings of a DepthAI stereo capture.

    left_socket, right_socket: board sockets (``CAM_B``/``CAM_C`` are the stereo pair of OAK-D
        devices and the usual mono sockets of an OAK-FFC board).
    width, height: output size; fps: sensor and output rate; color: BGR (else GRAY8).
    exposure_us, iso: manual exposure (both or neither; None: auto-exposure).
    device: device id, name or IP (None: the first one found); search_timeout_s: how long to look.
    sync_threshold_s: largest accepted time difference in a pair (None: half a frame period).
    frame_timeout_s: no pair for this long means the device is lost.
    """

    left_socket: str = "CAM_B"
    right_socket: str = "CAM_C"
    width: int = 1280
    height: int = 800
    fps: float = 30.0
    color: bool = False
    exposure_us: int | None = None
    iso: int | None = None
    device: str | None = None
    search_timeout_s: float = 3.0
    sync_threshold_s: float | None = None
    frame_timeout_s: float = 3.0
    queue_size: int = 16

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0 or self.fps <= 0:
            raise InputError(f"DepthAI size and fps must be positive "
                             f"(got {self.width}x{self.height} at {self.fps})")
        if (self.exposure_us is None) != (self.iso is None):
            raise InputError("set both exposure_us and iso for manual exposure, or neither")
        if self.left_socket == self.right_socket:
            raise InputError(f"left and right sockets are both {self.left_socket}")

    @property
    def threshold_s(self) -> float:
        return 0.5 / self.fps if self.sync_threshold_s is None else self.sync_threshold_s


DEPTHAI_PRESETS: dict[str, DepthAIConfig] = {
    # OV9282 global-shutter mono pair (OAK-D, OAK-D Pro, OAK-FFC OV9282 modules on a 27 cm bar).
    "mono-800p": DepthAIConfig(),
    "mono-400p": DepthAIConfig(width=640, height=400, fps=60.0),
    # AR0234 colour global-shutter modules (OAK-FFC), raw colour pairs.
    "color-1200p": DepthAIConfig(width=1920, height=1200, fps=30.0, color=True),
}


def _socket(dai, name: str):
    try:
        return getattr(dai.CameraBoardSocket, name)
    except AttributeError:
        raise InputError(f"unknown camera socket {name!r} (use CAM_A ... CAM_H)") from None


def find_device(dai, device: str | None, timeout_s: float):
    """The ``DeviceInfo`` of the requested (or any) available device, searched for ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        for info in dai.Device.getAllAvailableDevices():
            if device is None or device in (info.getDeviceId(), info.name):
                return info
        if time.monotonic() >= deadline:
            break
        time.sleep(0.2)
    what = "no DepthAI device" if device is None else f"DepthAI device {device!r} not"
    raise SourceError(f"{what} found within {timeout_s:.1f} s (is it plugged in and powered? on "
                      "Linux, are the Luxonis udev rules installed? is another program using it?)")


def rig_from_calibration(calib, left_socket: str, right_socket: str, width: int, height: int,
                         dai=None) -> StereoRig:
    """The toolkit's rig from a DepthAI ``CalibrationHandler``, for ``width`` x ``height`` outputs.

    ``P_right = R P_left + T`` with ``T`` in metres from ``getCameraExtrinsics(left, right,
    useSpecTranslation=False)`` (centimetres on the device). The measured baseline
    (``getBaselineDistance(useSpecTranslation=False)``) and the spec baseline go into ``extra``.
    """
    dai = dai or import_depthai()
    sl, sr = _socket(dai, left_socket), _socket(dai, right_socket)
    cams = []
    for s, name in ((sl, left_socket), (sr, right_socket)):
        model = calib.getDistortionModel(s)
        if model != dai.CameraModel.Perspective:
            raise SourceError(f"camera {name} is calibrated with the {model.name} model; the "
                              "toolkit's rig supports the perspective (OpenCV) model only")
        K = np.asarray(calib.getCameraIntrinsics(s, width, height), dtype=np.float64)
        dist = np.asarray(calib.getDistortionCoefficients(s), dtype=np.float64)
        cams.append(Camera(K, width, height, dist))
    M = np.asarray(calib.getCameraExtrinsics(sl, sr, False), dtype=np.float64)
    extra = {"source": "depthai factory calibration", "left_socket": left_socket,
             "right_socket": right_socket,
             "baseline_calibrated_m": float(calib.getBaselineDistance(sr, sl, False)) / 100.0}
    try:
        extra["baseline_spec_m"] = float(calib.getBaselineDistance(sr, sl, True)) / 100.0
    except RuntimeError:
        pass
    return StereoRig(cams[0], cams[1], M[:3, :3], M[:3, 3] / 100.0, extra=extra)


def build_camera_outputs(dai, pipeline, conf: DepthAIConfig):
    """Two raw camera outputs (left, right) on ``pipeline``, with the configured exposure."""
    outs = []
    kind = dai.ImgFrame.Type.BGR888i if conf.color else dai.ImgFrame.Type.GRAY8
    for name in (conf.left_socket, conf.right_socket):
        cam = pipeline.create(dai.node.Camera).build(_socket(dai, name), sensorFps=conf.fps)
        if conf.exposure_us is not None:
            cam.initialControl.setManualExposure(int(conf.exposure_us), int(conf.iso))
        outs.append(cam.requestOutput((conf.width, conf.height), type=kind, fps=conf.fps,
                                      enableUndistortion=False))
    return outs[0], outs[1]


def sync_queue(dai, pipeline, left_out, right_out, threshold_s: float, queue_size: int = 16):
    """A host ``Sync`` node pairing the outputs as ``"left"``/``"right"``; returns its queue."""
    sync = pipeline.create(dai.node.Sync)
    sync.setRunOnHost(True)
    sync.setSyncThreshold(datetime.timedelta(seconds=threshold_s))
    left_out.link(sync.inputs["left"])
    right_out.link(sync.inputs["right"])
    return sync.out.createOutputQueue(maxSize=queue_size, blocking=True)


def _image(frame, color: bool) -> np.ndarray:
    img = frame.getCvFrame() if color else frame.getFrame()
    return np.array(img, copy=True)


def frames_from_queue(pipeline, q, conf: DepthAIConfig, stats) -> Iterator[StereoFrame]:
    """Pairs from a ``Sync`` queue until the pipeline stops or goes silent (:class:`SourceLost`)."""
    last = time.monotonic()
    while True:
        try:
            group = q.tryGet()
        except Exception as e:  # noqa: BLE001 - MessageQueue.QueueException is no RuntimeError
            raise SourceLost(f"DepthAI queue closed ({e}); device disconnected?") from None
        if group is None:
            if not pipeline.isRunning():
                raise SourceLost("DepthAI pipeline stopped (device disconnected?)")
            if time.monotonic() - last > conf.frame_timeout_s:
                raise SourceLost(f"no frames from the DepthAI device for "
                                 f"{conf.frame_timeout_s:.1f} s")
            time.sleep(0.002)
            continue
        last = time.monotonic()
        left, right = group["left"], group["right"]
        stats.pairs += 1
        yield StereoFrame.at(_image(left, conf.color), _image(right, conf.color),
                             left.getTimestamp().total_seconds(),
                             right.getTimestamp().total_seconds(), int(left.getSequenceNum()))


class DepthAISource(StereoSource):
    """A DepthAI stereo pair. ``host_outputs(dai, pipeline) -> (left_out, right_out)`` replaces the
    device with host nodes (tests); the rest of the path (Sync, queue, reading) is the same."""

    kind = "depthai"

    def __init__(self, conf: DepthAIConfig = DepthAIConfig(), *,
                 host_outputs: Callable[[Any, Any], tuple[Any, Any]] | None = None):
        super().__init__()
        self.conf = conf
        self.nominal_fps = conf.fps
        self._host_outputs = host_outputs
        self._pipeline = None
        self._device = None
        self._queue = None
        self.device_info: dict[str, Any] = {}

    def open(self) -> None:
        dai = import_depthai()
        c = self.conf
        if self._host_outputs is None:
            os.environ.setdefault("DEPTHAI_SEARCH_TIMEOUT", str(int(c.search_timeout_s * 1000)))
            info = find_device(dai, c.device, c.search_timeout_s)
            try:
                self._device = dai.Device(info)
            except RuntimeError as e:
                raise SourceError(f"cannot connect to DepthAI device {info.getDeviceId()}: {e}"
                                  ) from None
            self.device_info = {"device_id": self._device.getDeviceId(),
                                "product": self._device.getProductName(),
                                "connected_cameras": [s.name for s in
                                                      self._device.getConnectedCameras()]}
            self.rig = rig_from_calibration(self._device.readCalibration(), c.left_socket,
                                            c.right_socket, c.width, c.height, dai)
            self._pipeline = dai.Pipeline(self._device)
            left_out, right_out = build_camera_outputs(dai, self._pipeline, c)
        else:
            self._pipeline = dai.Pipeline(False)
            left_out, right_out = self._host_outputs(dai, self._pipeline)
        self._queue = sync_queue(dai, self._pipeline, left_out, right_out, c.threshold_s,
                                 c.queue_size)
        try:
            self._pipeline.start()
        except RuntimeError as e:
            self.close()
            raise SourceError(f"DepthAI pipeline does not start: {e}") from None

    def frames(self) -> Iterator[StereoFrame]:
        assert self._pipeline is not None, "open() first"
        yield from frames_from_queue(self._pipeline, self._queue, self.conf, self.stats)

    def close(self) -> None:
        if self._pipeline is not None:
            try:
                if self._pipeline.isRunning():
                    self._pipeline.stop()
                self._pipeline.wait()
            except RuntimeError:
                pass
            self._pipeline = None
        if self._device is not None:
            try:
                self._device.close()
            except RuntimeError:
                pass
            self._device = None

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), **asdict(self.conf), **self.device_info}
