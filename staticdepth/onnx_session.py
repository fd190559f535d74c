"""The one way the project opens an ONNX model: :func:`onnx_session`.

onnxruntime logs warnings (unused initialisers, unsupported optimisations, provider fallbacks) to
the terminal by default; a user's exported model can print hundreds of them. Sessions opened here
log errors only (severity 3), and a file onnxruntime cannot load is one :class:`InputError` line.
"""
from __future__ import annotations

import os
from typing import Sequence

from staticdepth.errors import InputError

ERRORS_ONLY = 3  # onnxruntime severities: 0 verbose, 1 info, 2 warning, 3 error, 4 fatal


def onnx_session(path: str | os.PathLike, providers: Sequence[str] = ("CPUExecutionProvider",),
                 *, threads: int | None = None, what: str = "ONNX model"):
    """An ``onnxruntime.InferenceSession`` for ``path`` that logs errors only."""
    import onnxruntime as ort

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{what} file not found", path)
    ort.set_default_logger_severity(ERRORS_ONLY)  # the environment's logger (before a session)
    opts = ort.SessionOptions()
    opts.log_severity_level = ERRORS_ONLY
    if threads is not None:
        opts.intra_op_num_threads = int(threads)
    try:
        return ort.InferenceSession(path, sess_options=opts, providers=list(providers))
    except Exception as e:  # onnxruntime raises its own exception types for bad files
        first = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
        raise InputError(f"onnxruntime cannot load the {what} ({first})", path) from None
