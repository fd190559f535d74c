"""Stereo sources behind one interface (:class:`~staticdepth.capture.sources.base.StereoSource`).

- ``depthai_source``: OAK devices and OAK-FFC modules (DepthAI v3, optional, imported lazily);
- ``opencv_source``: two UVC cameras (software sync) or one side-by-side stereo camera;
- ``replay``: recordings, image folders and video files;
- ``synthetic``: a deterministic moving pattern (tests, benchmarks, disk checks).
"""
from staticdepth.capture.sources.base import (SourceError, SourceLost, SourceStats,
                                              StereoFrame, StereoSource)

__all__ = ["SourceError", "SourceLost", "SourceStats", "StereoFrame", "StereoSource"]
