"""staticdepth: depth sensing with a fixed, high-mounted camera.

Sub-packages: ``staticdepth.geometry`` (pure math), ``staticdepth.stereo``, ``staticdepth.dataset``,
``staticdepth.capture``; the CLI is ``staticdepth.cli``.
"""
__version__ = "0.1.0"

from staticdepth.errors import InputError  # noqa: F401  (the one user-facing error type)
