"""The one exception type for bad user input.

Library code raises :class:`InputError` naming the file (when there is one) and the problem; the CLI
prints it as a single line and exits with code 2.
"""
from __future__ import annotations

import os


class InputError(ValueError):
    """Bad user input: a missing or malformed file, an impossible parameter, degenerate data."""

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        self.problem = message
        super().__init__(f"{self.path}: {message}" if self.path else message)
