"""Agent detectors: per frame an instance map (uint16) and AGENT_DTYPE rows.

``motion`` (background subtraction, no weights, the default), ``yolox`` (ONNX boxes, masks from
motion or GrabCut inside each box), ``mask2former`` (transformers, local weights). Build one with
:func:`staticdepth.detectors.base.make_detector`.
"""
from staticdepth.detectors.base import Detector, make_detector, rows_from_masks  # noqa: F401
