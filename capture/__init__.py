"""Recording a fixed stereo rig: sources (DepthAI, UVC, replay), pairing, lossless recording.

- :mod:`staticdepth.capture.sources`: the :class:`StereoSource` interface and its implementations;
- :mod:`staticdepth.capture.sync`: pure timestamp pairing and stream statistics;
- :mod:`staticdepth.capture.record`: :func:`record` and the :class:`Recorder` (PNG, segments,
  manifest, summary);
- :mod:`staticdepth.capture.layout`: the folder layout and :func:`read_recording`;
- :mod:`staticdepth.capture.cli`: ``staticdepth capture``.
"""
