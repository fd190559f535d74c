"""The DepthAI source without a device: host-only pipeline (threaded host node -> host Sync ->
queue -> recorder), calibration export, and the no-device error. Needs the optional depthai 3.x."""
from __future__ import annotations

import datetime
import sys
import time

import cv2
import numpy as np
import pytest

dai = pytest.importorskip("depthai", reason="optional dependency depthai 3.x not installed")

from staticdepth.capture import layout  # noqa: E402
from staticdepth.capture.record import record  # noqa: E402
from staticdepth.capture.sources.base import SourceError  # noqa: E402
from staticdepth.capture.sources.depthai_source import (DepthAIConfig, DepthAISource,  # noqa: E402
                                                        import_depthai, rig_from_calibration)
from staticdepth.errors import InputError  # noqa: E402

FPS = 30.0


def _image(k: int, side: int) -> np.ndarray:
    return np.random.default_rng(1000 * side + k).integers(0, 256, (16, 24), dtype=np.uint8)


class Player(dai.node.ThreadedHostNode):
    """Plays frames into the pipeline as two cameras would: GRAY8, timestamps, sequence numbers."""

    def __init__(self):
        super().__init__()
        self.left = self.createOutput()
        self.right = self.createOutput()
        self.n, self.skip_right = 0, set()

    def run(self):
        for k in range(self.n):
            if not self.isRunning():
                break
            ts = datetime.timedelta(seconds=k / FPS)
            for side, out in ((0, self.left), (1, self.right)):
                if side == 1 and k in self.skip_right:
                    continue
                f = dai.ImgFrame()
                img = _image(k, side)
                f.setFrame(img)
                f.setWidth(img.shape[1])
                f.setHeight(img.shape[0])
                f.setType(dai.ImgFrame.Type.GRAY8)
                f.setTimestamp(ts + datetime.timedelta(microseconds=300 * side))
                f.setSequenceNum(k)
                out.send(f)
            time.sleep(0.004)


def _host_outputs(n, skip_right=()):
    def build(dai_, pipeline):
        player = pipeline.create(Player)
        player.n, player.skip_right = n, set(skip_right)
        return player.left, player.right
    return build


def test_host_pipeline_sync_and_record_path(tmp_path):
    src = DepthAISource(DepthAIConfig(frame_timeout_s=0.5), host_outputs=_host_outputs(20, {7}))
    root, s = record(src, tmp_path / "rec")
    rec = layout.read_recording(root)
    seqs = [f.sequence for f in rec.frames]
    # The device path ends like an unplugged device: silence, then a clean close.
    assert s["status"] == "source_lost" and "no frames" in s["detail"]
    assert seqs == [k for k in range(20) if k != 7]          # left 7 had no partner
    assert s["sequence_gaps"] == 1 and s["gaps"] == 1
    for f in rec.frames:
        assert np.array_equal(cv2.imread(str(f.left_path), cv2.IMREAD_UNCHANGED),
                              _image(f.sequence, 0))
        assert np.array_equal(cv2.imread(str(f.right_path), cv2.IMREAD_UNCHANGED),
                              _image(f.sequence, 1))
        assert f.left_timestamp_s == pytest.approx(f.sequence / FPS, abs=1e-6)  # us ticks
        assert f.right_timestamp_s - f.left_timestamp_s == pytest.approx(300e-6, abs=2e-6)
    assert rec.manifest["source"]["kind"] == "depthai" and rec.manifest["source"]["fps"] == FPS


def test_queue_closed_mid_run_closes_the_recording(tmp_path):
    src = DepthAISource(DepthAIConfig(frame_timeout_s=5.0), host_outputs=_host_outputs(40))

    def on_frame(n, rec):
        if n == 5:
            src._queue.close()               # what a disconnect does to the host queue

    root, s = record(src, tmp_path / "rec", on_frame=on_frame)
    assert s["status"] == "source_lost" and "queue closed" in s["detail"]
    assert [f.sequence for f in layout.read_recording(root).frames] == [0, 1, 2, 3, 4]


def _calibration(baseline_cm: float, spec_cm: float):
    calib = dai.CalibrationHandler()
    K_full = [[800.0, 0.0, 640.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]]
    dist = [0.1, -0.05, 0.001, 0.002, 0.01] + [0.0] * 9
    for s in (dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C):
        calib.setCameraIntrinsics(s, K_full, 1280, 800)
        calib.setDistortionCoefficients(s, dist)
        calib.setCameraType(s, dai.CameraModel.Perspective)
    a = np.radians(0.5)
    R = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    calib.setCameraExtrinsics(dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C, R,
                              [-baseline_cm, 0.1, 0.0], [-spec_cm, 0.0, 0.0])
    calib.setStereoLeft(dai.CameraBoardSocket.CAM_B, np.eye(3).tolist())
    calib.setStereoRight(dai.CameraBoardSocket.CAM_C, np.eye(3).tolist())
    return calib, np.array(R), dist


def test_factory_calibration_exports_the_measured_rig():
    calib, R, dist = _calibration(26.83, 27.0)
    rig = rig_from_calibration(calib, "CAM_B", "CAM_C", 640, 400, dai)
    # Intrinsics scaled to the 640x400 output (exact halving of fx, fy; centre per DepthAI).
    assert rig.left.fx == pytest.approx(400.0) and rig.left.fy == pytest.approx(400.0)
    assert (rig.left.width, rig.left.height) == (640, 400)
    np.testing.assert_allclose(rig.left.dist[:5], dist[:5])
    np.testing.assert_allclose(rig.R, R, atol=1e-6)
    np.testing.assert_allclose(rig.T, [-0.2683, 0.001, 0.0], atol=1e-7)  # cm -> m, measured
    assert rig.baseline_m == pytest.approx(np.hypot(0.2683, 0.001))
    assert rig.extra["baseline_calibrated_m"] == pytest.approx(rig.baseline_m, abs=1e-6)
    assert rig.extra["baseline_spec_m"] == pytest.approx(0.27)


def test_fisheye_calibration_and_bad_sockets_are_rejected():
    calib, _, _ = _calibration(27.0, 27.0)
    with pytest.raises(InputError, match="unknown camera socket 'CAM_Z'"):
        rig_from_calibration(calib, "CAM_Z", "CAM_C", 640, 400, dai)
    calib.setCameraType(dai.CameraBoardSocket.CAM_B, dai.CameraModel.Fisheye)
    with pytest.raises(SourceError, match="Fisheye model"):
        rig_from_calibration(calib, "CAM_B", "CAM_C", 640, 400, dai)


def test_no_device_is_a_clear_error_within_seconds():
    if dai.Device.getAllAvailableDevices():
        pytest.skip("a DepthAI device is connected")
    t0 = time.monotonic()
    with pytest.raises(SourceError, match="no DepthAI device found within 1.0 s"):
        DepthAISource(DepthAIConfig(search_timeout_s=1.0)).open()
    assert time.monotonic() - t0 < 5.0


@pytest.mark.parametrize("kw, msg", [({"exposure_us": 5000}, "both exposure_us and iso"),
                                     ({"right_socket": "CAM_B"}, "both CAM_B"),
                                     ({"fps": 0}, "must be positive")])
def test_config_errors(kw, msg):
    with pytest.raises(InputError, match=msg):
        DepthAIConfig(**kw)


def test_missing_depthai_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "depthai", None)
    with pytest.raises(SourceError, match="pip install"):
        import_depthai()


class _FakeDeviceDai:
    """The real depthai module with the device boundary replaced: a fake ``Device`` (found by
    ``getAllAvailableDevices``, holding a real ``CalibrationHandler``) and a pipeline whose
    ``Camera`` nodes record how they were built and are fed by a host :class:`Player`; every other
    node (``Sync``, queues) and the whole read path are depthai's own, on a host-only pipeline."""

    def __init__(self, calib, n_frames):
        outer = self
        self.cameras, self.devices_opened = [], []

        class Info:
            def __init__(self, device_id, name):
                self._id, self.name = device_id, name

            def getDeviceId(self):
                return self._id

        class Device:
            @staticmethod
            def getAllAvailableDevices():
                return [Info("14442C10", "1.1"), Info("18443010", "192.168.1.5")]

            def __init__(self, info):
                outer.devices_opened.append(info.getDeviceId())
                self.info = info

            def getDeviceId(self):
                return self.info.getDeviceId()

            def getProductName(self):
                return "OAK-FFC-4P"

            def getConnectedCameras(self):
                return [dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C]

            def readCalibration(self):
                return calib

            def close(self):
                outer.closed = True

        class Camera:
            def __init__(self, pipeline):
                self.pipeline, self.initialControl, self.args = pipeline, dai.CameraControl(), {}

            def build(self, socket, sensorFps=None):
                self.args.update(socket=socket, sensorFps=sensorFps)
                return self

            def requestOutput(self, size, type=None, fps=None, enableUndistortion=None):
                self.args.update(size=size, type=type, fps=fps,
                                 enableUndistortion=enableUndistortion)
                if self.pipeline.player is None:
                    self.pipeline.player = self.pipeline.real.create(Player)
                    self.pipeline.player.n = n_frames
                return self.pipeline.player.left if len(outer.cameras) == 1 \
                    else self.pipeline.player.right

        class Pipeline:
            def __init__(self, device):
                assert isinstance(device, Device)
                self.real, self.player = dai.Pipeline(False), None

            def create(self, kind):
                if kind is dai.node.Camera:
                    outer.cameras.append(Camera(self))
                    return outer.cameras[-1]
                return self.real.create(kind)

            def __getattr__(self, name):
                return getattr(self.real, name)

        self.Device, self.Pipeline = Device, Pipeline

    def __getattr__(self, name):
        return getattr(dai, name)


def test_device_path_up_to_the_device_boundary(tmp_path, monkeypatch):
    """open() on a 'device': search by name, calibration export, camera settings, record."""
    from staticdepth.capture.sources import depthai_source

    calib, _, _ = _calibration(26.83, 27.0)
    fake = _FakeDeviceDai(calib, n_frames=6)
    monkeypatch.setattr(depthai_source, "import_depthai", lambda: fake)
    conf = DepthAIConfig(width=24, height=16, fps=FPS, exposure_us=5000, iso=400,
                         device="192.168.1.5", frame_timeout_s=0.5)
    root, s = record(DepthAISource(conf), tmp_path / "rec")
    assert fake.devices_opened == ["18443010"] and fake.closed
    left, right = fake.cameras
    assert left.args == {"socket": dai.CameraBoardSocket.CAM_B, "sensorFps": FPS, "size": (24, 16),
                         "type": dai.ImgFrame.Type.GRAY8, "fps": FPS, "enableUndistortion": False}
    assert right.args["socket"] == dai.CameraBoardSocket.CAM_C
    for cam in (left, right):
        assert cam.initialControl.getExposureTime() == datetime.timedelta(microseconds=5000)
        assert cam.initialControl.getSensitivity() == 400
    # the keyword names the fake accepted are the real API's
    assert "sensorFps" in dai.node.Camera.build.__doc__
    assert "enableUndistortion" in dai.node.Camera.requestOutput.__doc__
    rec = layout.read_recording(root)
    assert [f.sequence for f in rec.frames] == list(range(6))
    assert np.array_equal(cv2.imread(str(rec.frames[3].left_path), cv2.IMREAD_UNCHANGED),
                          _image(3, 0))
    expected = rig_from_calibration(calib, "CAM_B", "CAM_C", 24, 16, dai)
    assert rec.rig.baseline_m == pytest.approx(expected.baseline_m)
    np.testing.assert_allclose(rec.rig.left.K, expected.left.K)
    assert rec.manifest["source"]["device_id"] == "18443010"
    assert rec.manifest["source"]["product"] == "OAK-FFC-4P"
    # a named device that is not there: a clear error, quickly, and no folder
    t0 = time.monotonic()
    with pytest.raises(SourceError, match="DepthAI device 'nope' not found within 0.3 s"):
        record(DepthAISource(DepthAIConfig(device="nope", search_timeout_s=0.3)),
               tmp_path / "none")
    assert time.monotonic() - t0 < 3.0 and not (tmp_path / "none").exists()
